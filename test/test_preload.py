"""The node's workers load what the pipeline imports on first use before their first work."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# A fresh interpreter (this one has imported SciPy for other tests) preloads both workers' lists, then replays
# the bundled sample (every hold estimated) and prints the SciPy packages that frame sets and holds imported.
SCRIPT = """
import sys
from nrmpc_ros.cli.main import main
import nrmpc_ros.frontend.estimation as estimation
import nrmpc_ros.frontend.pipeline as pipeline
from nrmpc_ros.frontend.preload import ESTIMATION, INTAKE, preload
preload(INTAKE + ESTIMATION)
new = set()
def watched(fn):
    def run(*args, **kwargs):
        before = set(sys.modules)
        out = fn(*args, **kwargs)
        new.update(set(sys.modules) - before)
        return out
    return run
pipeline.Pipeline.add_frames = watched(pipeline.Pipeline.add_frames)
estimation.HoldEstimator.run = watched(estimation.HoldEstimator.run)
try:
    main(["replay", sys.argv[1], "--rig", sys.argv[2], "--out", sys.argv[3], "--no-progress"])
except SystemExit as e:
    assert not e.code, e.code
print(sorted(m for m in new if m.startswith("scipy") and m.count(".") <= 1))
"""


@pytest.mark.slow
def test_after_the_preload_frame_sets_and_holds_import_nothing_more(tmp_path):
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(ROOT / "bags" / "sample"),
                          str(ROOT / "config" / "sample_cross4.yaml"), str(tmp_path / "estimates.csv")],
                         capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
    assert (tmp_path / "estimates.csv").read_text().count("\n") > 3  # holds were estimated
