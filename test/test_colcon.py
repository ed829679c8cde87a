"""The colcon path: build the package in a temporary workspace (colcon from PyPI) and run what ``ros2 run`` runs."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
# What an ament_python package needs to build: nothing else (no bags, tests or caches) is copied.
PACKAGE_FILES = ("setup.py", "setup.cfg", "package.xml", "resource", "nrmpc_ros", "config")


def _colcon() -> str:
    exe = shutil.which("colcon", path=str(BIN)) or shutil.which("colcon")
    if exe is None:
        pytest.skip("colcon is not installed: pip install -e .[test] (brings colcon-core and colcon-ros)")
    return exe


def _build_env(tmp: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("COLCON", "AMENT_", "ROS_"))}
    env["COLCON_HOME"] = str(tmp / "colcon_home")  # no user config or mixins
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    env.pop("PYTHONPATH", None)
    return env


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A colcon workspace with nrmpc_ros built into install/."""
    colcon = _colcon()
    tmp = tmp_path_factory.mktemp("colcon")
    ws = tmp / "ws"
    pkg = ws / "src" / "nrmpc_ros"
    pkg.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in PACKAGE_FILES:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, pkg / name, ignore=ignore)
        else:
            shutil.copy2(src, pkg / name)
    cmd = [colcon, "--log-base", str(tmp / "log"), "build", "--base-paths", "src", "--packages-select", "nrmpc_ros",
           "--event-handlers", "console_direct+"]
    proc = subprocess.run(cmd, cwd=ws, env=_build_env(tmp), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"colcon build failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    return ws


def _run_env(ws: Path) -> dict:
    """What sourcing install/setup.bash sets for this package (colcon's local_setup for ament_python)."""
    prefix = ws / "install" / "nrmpc_ros"
    site = next(prefix.glob("lib/python3*/site-packages"))
    env = _build_env(ws)
    env["PYTHONPATH"] = str(site)
    env["AMENT_PREFIX_PATH"] = str(prefix)
    env["PATH"] = f"{prefix / 'bin'}{os.pathsep}{env['PATH']}"
    return env


def test_colcon_build_installs_the_ros2_run_executable(workspace):
    prefix = workspace / "install" / "nrmpc_ros"
    exe = prefix / "lib" / "nrmpc_ros" / "estimator"
    assert exe.is_file() and os.access(exe, os.X_OK), f"ros2 run looks for {exe}"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "nrmpc_ros").is_file()
    assert (prefix / "share" / "nrmpc_ros" / "package.xml").is_file()
    assert (prefix / "share" / "nrmpc_ros" / "config" / "estimator.yaml").is_file()


def test_installed_estimator_help(workspace):
    env = _run_env(workspace)
    exe = workspace / "install" / "nrmpc_ros" / "lib" / "nrmpc_ros" / "estimator"
    proc = subprocess.run([str(exe), "--help"], cwd=workspace, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: estimator")
    for name in ("rig_file", "method", "sync_tolerance_s", "imu_topic", "imu_max_age_s", "image_transport"):
        assert name in proc.stdout
    # the executable runs the workspace's copy of the package (the cwd must not shadow it)
    where = subprocess.run([sys.executable, "-c", "import nrmpc_ros.node as n; print(n.__file__)"], cwd=workspace,
                           env=env, capture_output=True, text=True, timeout=60)
    assert where.returncode == 0, where.stderr
    assert str(workspace / "install") in where.stdout
