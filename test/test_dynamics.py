"""Bar dynamics: natural frequencies and the exact damped response of the bars to a sampled load."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from nrmpc_ros.core.dynamics import DampedResponse, bar_natural_frequencies, check_damping, ringing_decay_time
from nrmpc_ros.core.rig import Camera, Rig
from nrmpc_ros.errors import InputError
from nrmpc_ros.sim.synthetic import RigSpec, make_rig


def test_bar_natural_frequencies_follow_the_cantilever_formula():
    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.2, mass=0.1, bar_length=0.4))
    expected = math.sqrt(3 * 0.2 / (0.1 * 0.4**3)) / (2 * math.pi)  # 1.54 Hz
    assert bar_natural_frequencies(rig) == pytest.approx([expected] * 3, rel=1e-12)
    stiff = make_rig(RigSpec(num_cameras=2, layout="line", EI=2.0, mass=0.05, bar_length=0.3))
    assert bar_natural_frequencies(stiff) == pytest.approx([math.sqrt(3 * 2.0 / (0.05 * 0.3**3)) / (2 * math.pi)] * 2)
    # Rigid bars, massless tips and a camera at the body centre have no dynamics.
    base = rig.cameras[0]
    cams = (base, Camera(**{**base.__dict__, "name": "rigid", "EI": math.inf}),
            Camera(**{**base.__dict__, "name": "massless", "mass": 0.0}),
            Camera(**{**base.__dict__, "name": "centre", "position": np.zeros(3)}))
    f = bar_natural_frequencies(Rig(cameras=cams))
    assert f[0] == pytest.approx(expected) and np.all(np.isinf(f[1:]))


def _input(t):
    t = np.asarray(t, dtype=float)
    return np.stack([np.sin(3 * t) + 0.5, np.cos(5 * t) ** 2, 9.81 + 0.2 * t * np.exp(-t)], axis=-1)


@pytest.mark.parametrize("zeta", [0.02, 0.3])
def test_damped_response_matches_a_fine_ode_solution(zeta):
    dt, T = 1e-3, 2.0
    freq = np.array([1.5, 7.0, np.inf])
    t = np.concatenate([np.arange(0.0, 0.5, dt), np.arange(0.5, T + dt / 2, dt / 2)])  # two stretches of steps
    resp = DampedResponse(t, _input(t), freq, zeta)
    q = np.array([0.0, 0.0123, 0.5, 1.23456, 1.9999])
    x, v = resp.at(q)
    for i in range(2):
        w = 2 * math.pi * freq[i]

        def rhs(t, y, w=w):
            return np.concatenate([y[3:], w * w * (_input(t) - y[:3]) - 2 * zeta * w * y[3:]])

        sol = solve_ivp(rhs, (0.0, T), np.concatenate([_input(0.0), np.zeros(3)]), t_eval=q, rtol=1e-11,
                        atol=1e-12, max_step=1e-3)
        assert np.abs(sol.y[:3].T - x[:, i]).max() < 1e-4  # the 1 ms linear interpolation of the input
        assert np.abs(sol.y[3:].T - v[:, i]).max() < 1e-3
    assert np.abs(x[:, 2] - _input(q)).max() < 1e-5, "a rigid bar follows the load"
    # A constant load keeps the bars at rest, with the load (unit DC gain).
    rest = DampedResponse(np.arange(500) * dt, np.tile([0.3, -1.0, -9.7], (500, 1)), freq, zeta)
    xr, vr = rest.at(np.linspace(0, 0.499, 37))
    assert np.allclose(xr, [0.3, -1.0, -9.7], atol=1e-12) and np.allclose(vr, 0.0, atol=1e-10)


def test_free_ringing_decays_by_the_decay_time():
    """After a load step the deviation rings at the damped frequency; its amplitude falls as exp(-zeta w t)."""
    dt, zeta, f = 1e-3, 0.05, 4.0
    t = np.arange(8001) * dt
    u = np.zeros((8001, 3))
    u[:1000] = [0.0, 0.0, 1.0]
    before = u.copy()
    before[1000] = u[999]  # the load drops to 0 exactly at t = 1 s: a jump at a sample
    resp = DampedResponse(t, u, [f], zeta, u_before=before)
    w, wd = 2 * math.pi * f, 2 * math.pi * f * math.sqrt(1 - zeta**2)

    def amplitude(t):
        x, v = resp.at([t])
        y, yd = x[0, 0, 2], v[0, 0, 2]
        return math.hypot(y, (yd + zeta * w * y) / wd)

    # The free response to the step, in closed form.
    q = 1.0 + np.array([0.0, 0.0101, 0.37, 2.5])
    expected = np.exp(-zeta * w * (q - 1)) * (np.cos(wd * (q - 1)) + zeta * w / wd * np.sin(wd * (q - 1)))
    assert resp.at(q)[0][:, 0, 2] == pytest.approx(expected, abs=1e-12)
    assert np.allclose(resp.at(np.linspace(0, 0.999, 50))[0][:, 0, 2], 1.0, atol=1e-12), "at rest before the step"
    t_settle = float(ringing_decay_time(f, zeta))
    assert t_settle == pytest.approx(math.log(1000) / (zeta * w))
    assert amplitude(1.0 + t_settle) / amplitude(1.0) == pytest.approx(1e-3, rel=1e-6)
    assert resp.amplitude([1.0 + t_settle])[0, 0] / resp.amplitude([1.0])[0, 0] == pytest.approx(1e-3, rel=1e-9)
    assert resp.amplitude([0.5])[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert float(ringing_decay_time(np.inf, zeta)) == 0.0


@pytest.mark.parametrize("zeta", [0.0, 1.0, -0.1, float("nan"), "0.1"])
def test_damping_ratio_must_be_under_damped(zeta):
    with pytest.raises(InputError, match="field 'damping'"):
        check_damping(zeta)
