"""Small rendered bags in every recording style, for the end-to-end tests (made once per test session).

Rigs: two cameras on one straight bar, three cameras of which one fisheye, the four-camera cross, all at
320x240 with bars that ring at about 4.3 Hz (EI 1 N m^2, 0.15 kg, 0.3 m). Styles: one snapshot per hold with
and without an IMU, a 10 Hz stream with smooth (minimum-jerk) moves, a stream with abrupt (trapezoidal) moves,
ringing bars (damping 0.03), +-8 ms camera stamp jitter and 2 % frame drops, JPEG-compressed images, a raw
colour sensor's Bayer mosaic (no white balance: a checkerboard of three levels on a grey scene), a 1 kHz IMU
that low-pass filters its output at 40 Hz (its noise correlated over a dozen samples), an IMU whose messages'
covariances claim a fifth of its noise, and
each camera at its own rate (10, 15, 30, 20 Hz, the first of them; phases 7 ms apart) on bars that ring through
the hold (damping 0.02), and an IMU inside the second camera (turned in it), whose bar rings through the hold
(damping 0.02) after trapezoidal moves. Misconfigured (not among the styles every rig's tests run): six holds
streamed with the IMU's stamps 2 s late (another clock).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from nrmpc_ros.core import save_rig
from nrmpc_ros.core.rig import Camera
from nrmpc_ros.core.so3 import exp_so3
from nrmpc_ros.render.bagmaker import BagOptions, make_bag
from nrmpc_ros.render.sequence import MotionOptions
from nrmpc_ros.sim.synthetic import RigSpec, make_rig

BAR = {"EI": 1.0, "mass": 0.15, "bar_length": 0.3}
RES = (320, 240)


def rig(name: str):
    if name == "line2":
        return make_rig(RigSpec(num_cameras=2, layout="line", focal=235.0, resolution=RES, **BAR))
    if name == "fish3":
        r = make_rig(RigSpec(num_cameras=3, layout="ring", focal=235.0, resolution=RES, **BAR))
        c = r.cameras[2]
        fish = Camera(name=c.name, model="equidistant", intrinsics=(150.0, 150.0, 159.5, 119.5),
                      distortion=(0.02, -0.01, 0.003, -0.001), resolution=RES, position=c.position,
                      rotation=c.rotation, mass=c.mass, EI=c.EI, image_topic=c.image_topic, info_topic=c.info_topic)
        return replace(r, cameras=r.cameras[:2] + (fish,), source="<3 cameras, one fisheye>")
    if name == "cross4":
        return make_rig(RigSpec(num_cameras=4, layout="cross", focal=235.0, resolution=RES, **BAR))
    raise KeyError(name)


RIGS = ("line2", "fish3", "cross4")
BASE = {"views": 3, "hold_seconds": 2.0, "min_move_seconds": 1.0}
STYLES = {
    "snapshot-imu": ({**BASE, "capture": "snapshot"}, {}),
    "snapshot-noimu": ({**BASE, "capture": "snapshot"}, {"imu": False}),
    "stream-smooth": ({**BASE, "capture": "stream", "rate": 10.0, "move_profile": "min-jerk"}, {}),
    "stream-ringing": ({**BASE, "hold_seconds": 4.0, "capture": "stream", "rate": 10.0, "move_profile": "trapezoid"},
                       {"damping": 0.03, "jitter_ms": 8.0, "drop_rate": 0.02}),
    "compressed": ({**BASE, "capture": "stream", "rate": 10.0}, {"encoding": "jpeg"}),
    "bayer": ({**BASE, "capture": "stream", "rate": 10.0}, {"encoding": "bayer_grbg8"}),
    "imu-filtered": ({**BASE, "capture": "stream", "rate": 10.0, "imu_rate": 1000.0}, {"imu_lowpass_hz": 40.0}),
    "imu-claims-little": ({**BASE, "capture": "stream", "rate": 10.0}, {"imu_covariance_scale": 0.2}),
    "camrates-ringing": ({**BASE, "hold_seconds": 2.5, "capture": "stream", "rate": 10.0,
                          "camera_rates": (10.0, 15.0, 30.0, 20.0)}, {"damping": 0.02}),
    "imu-on-bar": ({**BASE, "capture": "stream", "rate": 10.0, "move_profile": "trapezoid"},
                   {"damping": 0.02, "imu_mount": 1}),
}
MISCONFIGURED = {  # recordings the pipeline as set up cannot serve: what replay measures and mends
    "imu-clock-2s": ({**BASE, "views": 6, "capture": "stream", "rate": 10.0}, {"imu_time_offset_ms": 2000.0}),
}
IMU_IN_CAMERA = np.array([0.4, -1.2, 0.3])  # rotation vector of the IMU in its camera (imu-on-bar)


def recording(root: Path, rig_name: str, style: str, seed: int = 0):
    """(bag dir, rig file, make_bag summary or None when it existed) of one rendered recording."""
    root.mkdir(parents=True, exist_ok=True)
    r = rig(rig_name)
    motion, bag = {**STYLES, **MISCONFIGURED}[style]
    if "camera_rates" in motion:  # one rate and phase per camera of this rig
        M = r.num_cameras
        motion = {**motion, "camera_rates": motion["camera_rates"][:M],
                  "camera_phases_ms": tuple(7.0 * i for i in range(M))}
    if not bag.get("imu", True):
        r = replace(r, imu=None)
    if "imu_mount" in bag:
        bag = dict(bag)
        r = r.with_imu_in(r.cameras[bag.pop("imu_mount")].name, exp_so3(IMU_IN_CAMERA))
    rig_file = root / f"{rig_name}-{style}.yaml"
    path = root / f"{rig_name}-{style}-{seed}"
    summary = None
    if not path.exists():
        summary = make_bag(r, path, BagOptions(motion=MotionOptions(**motion), seed=seed, supersample=1, **bag),
                           progress=False)
        save_rig(r, rig_file)
    return path, rig_file, summary
