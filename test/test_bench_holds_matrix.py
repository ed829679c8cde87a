"""The holds benchmark's matrix (scripts/bench_holds.py): every style and rig that share a rig file render the
same rig into it (the file is written once, by whichever cell comes first, and read by all)."""

import importlib.util
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "bench_holds.py"


def load_script():
    spec = importlib.util.spec_from_file_location("bench_holds", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_cells_that_share_a_rig_file_share_its_rig():
    """A style without an IMU on a rig must not leave a rig file without one for the styles with an IMU on that
    rig (nor the other way round): the file's name tells every difference in what it carries."""
    bench = load_script()
    rigs, styles = bench.matrix_rigs(), bench.matrix_styles()
    written: dict = {}
    for style, rig_name in bench.matrix_cells(full=True):
        rig = rigs[rig_name]
        _, style_bag = styles[style](rig.num_cameras)
        rig, _, suffix = bench.style_rig(rig, style_bag)
        file_rig = bench.file_rig(rig, style_bag)
        name = f"{rig_name}{suffix}.yaml"
        imu = None if file_rig.imu is None else (file_rig.imu.mount, np.round(file_rig.imu.rotation, 9).tobytes())
        first = written.setdefault(name, (style, imu))
        assert first[1] == imu, f"{name}: {first[0]} and {style} need other IMUs in one file"
    assert len(written) > len(rigs)  # the styles without an IMU, with one in a camera or turned, have their own
