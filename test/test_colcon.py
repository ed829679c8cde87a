"""The colcon path: build the package in a temporary workspace (colcon from PyPI), check what it installs
(package.xml, parameters, sample rig, launch file) and run what ``ros2 run`` and ``ros2 launch`` run."""

from __future__ import annotations

import ast
import importlib.metadata
import importlib.util
import os
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from dds import domain_id

from nrmpc_ros.core.rig import load_rig
from nrmpc_ros.errors import InputError

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
# What an ament_python package needs to build: nothing else (no bags, tests or caches) is copied.
PACKAGE_FILES = ("setup.py", "setup.cfg", "package.xml", "resource", "nrmpc_ros", "config", "launch", "rviz")
LAUNCH = REPO / "launch" / "estimator.launch.py"
RIG = REPO / "config" / "sample_cross4.yaml"
# Files of share/nrmpc_ros, installed by setup.py's data_files.
SHARED = ("package.xml", "config/estimator.yaml", "config/sample_cross4.yaml", "launch/estimator.launch.py",
          "rviz/nrmpc.rviz")
LAUNCH_ARGUMENTS = ("rig_file", "params_file", "method", "namespace", "imu_topic", "image_remaps", "use_sim_time",
                    "log_level", "rviz")
# Imported Python packages and their rosdep keys (rosdistro's rosdep/python.yaml); any other imported package is a
# ROS package and its module name is its package name.
PYTHON_KEYS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "cv2": "python3-opencv", "yaml": "python3-yaml",
               "matplotlib": "python3-matplotlib", "tqdm": "python3-tqdm", "rosbags": "python3-rosbags-pip"}
# No rosdep key: installed with pip (README.md, "ROS 2 workspace (colcon)"); dask only for `--scheduler dask`.
PIP_ONLY = {"poselib", "dask"}
# package.xml children in the order the format-3 schema's sequence requires; dependencies interleave freely.
DEPENDS = ("build_depend", "build_export_depend", "buildtool_depend", "buildtool_export_depend", "exec_depend",
           "depend", "doc_depend", "test_depend", "conflict", "replace")
FORMAT3_ORDER = ("name", "version", "description", "maintainer", "license", "url", "author", DEPENDS, "group_depend",
                 "member_of_group", "export")


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
    """The environment after ``. install/setup.sh``: colcon's own script sets PYTHONPATH, AMENT_PREFIX_PATH, ..."""
    env = _build_env(ws)
    env["NRMPC_SETUP_SCRIPT"] = str(ws / "install" / "setup.sh")
    proc = subprocess.run(["sh", "-c", '. "$NRMPC_SETUP_SCRIPT" && exec env -0'], env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, f"sourcing install/setup.sh failed:\n{proc.stderr}"
    out = dict(item.split("=", 1) for item in proc.stdout.split("\0") if "=" in item)
    out.pop("NRMPC_SETUP_SCRIPT")
    return out


def _share(ws: Path) -> Path:
    return ws / "install" / "nrmpc_ros" / "share" / "nrmpc_ros"


def _load_launch_file(path: Path):
    """The launch file as a Python module (what ``ros2 launch`` does before it calls generate_launch_description)."""
    spec = importlib.util.spec_from_file_location("estimator_launch", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --------------------------------------------------------------------------- what colcon installs
@pytest.mark.slow
def test_colcon_build_installs_the_ros2_run_executable(workspace):
    prefix = workspace / "install" / "nrmpc_ros"
    exe = prefix / "lib" / "nrmpc_ros" / "estimator"
    assert exe.is_file() and os.access(exe, os.X_OK), f"ros2 run looks for {exe}"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "nrmpc_ros").is_file()
    for rel in SHARED:
        installed = _share(workspace) / rel
        assert installed.is_file(), f"colcon build did not install share/nrmpc_ros/{rel}"
        assert installed.read_bytes() == (REPO / rel).read_bytes(), rel


@pytest.mark.slow
def test_installed_launch_file_is_python_that_imports_without_launch(workspace):
    path = _share(workspace) / "launch" / "estimator.launch.py"
    compile(path.read_text(), str(path), "exec")
    module = _load_launch_file(path)
    assert callable(module.generate_launch_description)
    assert tuple(name for name, *_ in module.ARGUMENTS) == LAUNCH_ARGUMENTS


@pytest.mark.slow
def test_generate_launch_description_declares_the_arguments(workspace, monkeypatch):
    try:
        from launch.utilities import perform_substitutions
        from launch_ros.actions import Node  # noqa: F401  (the launch file's second dependency)

        from launch import LaunchContext, LaunchDescription
    except ImportError as exc:
        pytest.skip(f"the launch packages are not installed here ({exc}): launch and launch_ros come with a "
                    "ROS 2 install (no PyPI wheels); rosdep installs them from package.xml")
    monkeypatch.setenv("AMENT_PREFIX_PATH", _run_env(workspace)["AMENT_PREFIX_PATH"])
    ld = _load_launch_file(_share(workspace) / "launch" / "estimator.launch.py").generate_launch_description()
    assert isinstance(ld, LaunchDescription)
    args = {a.name: a for a in ld.get_launch_arguments()}
    assert tuple(args) == LAUNCH_ARGUMENTS
    default = {name: perform_substitutions(LaunchContext(), a.default_value) for name, a in args.items()}
    assert default["rig_file"] == str(_share(workspace) / "config" / "sample_cross4.yaml")
    assert default["params_file"] == str(_share(workspace) / "config" / "estimator.yaml")
    assert (default["method"], default["namespace"], default["use_sim_time"]) == ("auto", "", "false")
    assert set(args["method"].choices) == {"auto", "4pt-bending", "6pt-bending", "6pt-nonbending"}


# --------------------------------------------------------------------------- the launch file's argument handling
def test_launch_image_remaps_are_pairs_separated_by_spaces_or_semicolons():
    parse = _load_launch_file(LAUNCH).parse_remaps
    text = " /cam0/image_raw:=/rig1/front/image_raw; /cam1/image_raw:=left/image_raw\n/cam2/image_raw:=/c ;"
    assert parse(text) == [("/cam0/image_raw", "/rig1/front/image_raw"), ("/cam1/image_raw", "left/image_raw"),
                           ("/cam2/image_raw", "/c")]
    assert parse("") == [] and parse(" ; ") == []
    for bad in ("/cam0/image_raw=/x", ":=/x", "/cam0/image_raw:=", "/a:=/b:=/c", "/a:=/b; /a:=/c"):
        with pytest.raises(InputError, match="launch argument image_remaps"):
            parse(bad)


def test_launch_image_remaps_must_name_camera_topics_of_the_rig():
    check = _load_launch_file(LAUNCH).check_image_remaps
    topics = [c.image_topic for c in load_rig(RIG).cameras]
    check([("/cam0/image_raw", "/a"), ("/cam3/image_raw/compressed", "/b/compressed")], topics, "/", str(RIG))
    with pytest.raises(InputError, match=r"image_remaps: /cam9/image_raw is no camera topic .*/cam0/image_raw"):
        check([("/cam0/image_raw", "/a"), ("/cam9/image_raw", "/b")], topics, "/", str(RIG))
    # relative names lie in the node's namespace, on both sides of the comparison
    check([("cam0/image_raw", "/a"), ("/rig1/cam1/image_raw", "/b")], ["cam0/image_raw", "cam1/image_raw"], "/rig1",
          "rig.yaml")
    with pytest.raises(InputError, match="/cam0/image_raw is no camera topic"):
        check([("/cam0/image_raw", "/a")], ["cam0/image_raw"], "/rig1", "rig.yaml")


def test_launch_files_are_found_in_the_working_directory_then_in_share(tmp_path, monkeypatch):
    find = _load_launch_file(LAUNCH).find_file
    share, cwd = tmp_path / "share", tmp_path / "cwd"
    (share / "config").mkdir(parents=True)
    cwd.mkdir()
    (share / "config" / "rig.yaml").write_text("cameras: []\n")
    monkeypatch.chdir(cwd)
    assert find("rig.yaml", share, "rig_file") == share / "config" / "rig.yaml"
    assert find("config/rig.yaml", share, "rig_file") == share / "config" / "rig.yaml"
    (cwd / "rig.yaml").write_text("cameras: []\n")
    assert find("rig.yaml", share, "rig_file") == cwd / "rig.yaml"
    assert find(str(share / "config" / "rig.yaml"), None, "rig_file") == share / "config" / "rig.yaml"
    with pytest.raises(InputError, match="launch argument params_file: no such file: other.yaml"):
        find("other.yaml", share, "params_file")


# --------------------------------------------------------------------------- the RViz config
RVIZ = REPO / "rviz" / "nrmpc.rviz"


def _rviz_names(cfg: dict) -> tuple:
    """(topics, frames) an RViz config names."""
    topics, frames = set(), set()

    def walk(d):
        if isinstance(d, dict):
            for k, v in d.items():
                if k == "Topic" and isinstance(v, dict):
                    topics.add(v["Value"])
                elif k in ("Fixed Frame", "Reference Frame", "Target Frame") and v != "<Fixed Frame>":
                    frames.add(v)
                else:
                    walk(v)
        elif isinstance(d, list):
            for x in d:
                walk(x)

    walk(cfg)
    return topics, frames


def _published(rig, namespace: str = "/") -> tuple:
    """(topics, frames) the estimator node in ``namespace`` publishes for ``rig`` with the default parameters, and
    the camera topics it reads (the image display shows one)."""
    from nrmpc_ros.frontend.node_config import NodeConfig
    from nrmpc_ros.frontend.outputs import OUTPUTS
    from nrmpc_ros.frontend.topics import expand_topic
    from nrmpc_ros.node import MARKERS

    node = expand_topic("estimator", namespace)
    topics = {t.replace("~", node) for _, t in [*OUTPUTS.values(), MARKERS]} | {"/diagnostics"}
    topics |= {expand_topic(c.image_topic, namespace) for c in rig.cameras}
    cfg = NodeConfig()
    frames = {rig.body_frame, f"{rig.body_frame}_origin", *(c.name + cfg.camera_frame_suffix for c in rig.cameras)}
    return topics, frames


def test_the_rviz_config_is_yaml_naming_only_what_the_node_publishes():
    import yaml

    cfg = yaml.safe_load(RVIZ.read_text())
    topics, frames = _rviz_names(cfg)
    published, node_frames = _published(load_rig(RIG))
    assert topics and topics <= published, topics - published
    assert frames and frames <= node_frames, frames - node_frames
    classes = {d["Class"] for d in cfg["Visualization Manager"]["Displays"]}
    assert {"rviz_default_plugins/TF", "rviz_default_plugins/MarkerArray", "rviz_default_plugins/PoseWithCovariance",
            "rviz_default_plugins/Image"} <= classes
    markers = next(d for d in cfg["Visualization Manager"]["Displays"] if d["Class"].endswith("/MarkerArray"))
    assert markers["Topic"]["Durability Policy"] == "Transient Local"  # the node latches the last state


def test_launch_makes_the_rviz_config_for_the_rig_and_namespace():
    import yaml

    make = _load_launch_file(LAUNCH).rviz_config_for
    cfg = yaml.safe_load(make(RVIZ.read_text(), "/rig1", "body", "/rig1/front/image_raw"))
    topics, frames = _rviz_names(cfg)
    assert topics == {"/rig1/estimator/markers", "/rig1/estimator/pose", "/rig1/front/image_raw"}
    assert frames == {"body"}


@pytest.mark.slow
def test_colcon_installs_the_rviz_config(workspace):
    import yaml

    installed = _share(workspace) / "rviz" / "nrmpc.rviz"
    assert installed.is_file(), "setup.py data_files: share/nrmpc_ros/rviz"
    assert yaml.safe_load(installed.read_text()) == yaml.safe_load(RVIZ.read_text())


# --------------------------------------------------------------------------- package.xml
def test_package_xml_follows_the_format_3_schema():
    parse_package = pytest.importorskip("catkin_pkg.package", reason="catkin_pkg comes with colcon-ros").parse_package
    root = ET.parse(REPO / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    tags = [child.tag for child in root]
    rank = {tag: i for i, group in enumerate(FORMAT3_ORDER) for tag in ((group,) if isinstance(group, str) else group)}
    assert set(tags) <= set(rank), f"elements the schema does not know: {set(tags) - set(rank)}"
    ranks = [rank[t] for t in tags]
    assert ranks == sorted(ranks), f"element order breaks the schema's sequence: {tags}"
    for tag in ("name", "version", "description"):
        assert tags.count(tag) == 1, tag
    assert tags.count("maintainer") >= 1 and tags.count("license") >= 1 and tags.count("export") <= 1
    warnings = []
    package = parse_package(str(REPO / "package.xml"), warnings=warnings)
    assert warnings == []
    assert package.name == "nrmpc_ros" and package.get_build_type() == "ament_python"
    assert package.version == importlib.metadata.version("nrmpc_ros"), "package.xml and setup.py versions differ"


def test_package_xml_declares_every_runtime_import():
    imported = set()
    for path in [*sorted((REPO / "nrmpc_ros").rglob("*.py")), LAUNCH]:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                imported.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                imported.add(node.module.split(".")[0])
    imported -= set(sys.stdlib_module_names) | {"nrmpc_ros"} | PIP_ONLY
    root = ET.parse(REPO / "package.xml").getroot()
    declared = {e.text.strip(): e for e in root if e.tag in ("exec_depend", "depend")}
    missing = sorted(f"{m} ({PYTHON_KEYS.get(m, m)})" for m in imported if PYTHON_KEYS.get(m, m) not in declared)
    assert not missing, f"imported at run time but not an exec_depend of package.xml: {missing}"
    # rosdep ignores versions, but the declared range is the one setup.py installs
    rosbags = next(r for r in importlib.metadata.requires("nrmpc_ros") if r.startswith("rosbags"))
    element = declared["python3-rosbags-pip"]
    assert rosbags.replace(" ", "") == f"rosbags<{element.get('version_lt')},>={element.get('version_gte')}"


# --------------------------------------------------------------------------- what ros2 run runs
@pytest.mark.slow
def test_installed_estimator_help_from_another_directory(workspace, tmp_path):
    env = _run_env(workspace)
    exe = workspace / "install" / "nrmpc_ros" / "lib" / "nrmpc_ros" / "estimator"
    proc = subprocess.run([str(exe), "--help"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: estimator")
    for name in ("rig_file", "method", "input.sync_tolerance_s", "imu_topic", "pipeline.imu.max_age_s",
                 "image_transport"):
        assert name in proc.stdout
    # the executable runs the workspace's copy of the package (the source tree does not shadow it)
    where = subprocess.run([sys.executable, "-c", "import nrmpc_ros.node as n; print(n.__file__)"], cwd=tmp_path,
                           env=env, capture_output=True, text=True, timeout=60)
    assert where.returncode == 0, where.stderr
    assert str(workspace / "install") in where.stdout


@pytest.mark.slow
def test_installed_estimator_runs_with_the_installed_params_and_rig_from_another_directory(workspace, tmp_path):
    """``ros2 run nrmpc_ros estimator --ros-args --params-file <share>/config/estimator.yaml`` from a directory
    without config/: the params file's relative rig_file is found in share/nrmpc_ros, the node publishes
    /diagnostics over DDS and stops cleanly on SIGINT."""
    pytest.importorskip("rclpy", reason="rclpy is not importable: install the ros extra (pip install -e .[ros])")
    from diagnostic_msgs.msg import DiagnosticArray

    from nrmpc_ros.ros_play import BackgroundNode

    domain = domain_id(1, 100)
    env = {**_run_env(workspace), "ROS_DOMAIN_ID": str(domain), "ROS_LOG_DIR": str(tmp_path / "ros_log"),
           "PYTHONUNBUFFERED": "1", "RCUTILS_COLORIZED_OUTPUT": "0"}
    share = _share(workspace)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    log = tmp_path / "estimator.log"
    probe = BackgroundNode("colcon_probe", domain)
    received = []
    probe.node.create_subscription(DiagnosticArray, "/diagnostics", received.append, 10)
    probe.start()
    proc = None
    try:
        with open(log, "w") as out:
            proc = subprocess.Popen([str(workspace / "install" / "nrmpc_ros" / "lib" / "nrmpc_ros" / "estimator"),
                                     "--ros-args", "--params-file", str(share / "config" / "estimator.yaml")],
                                    cwd=elsewhere, env=env, stdout=out, stderr=subprocess.STDOUT,
                                    start_new_session=True)
        deadline = time.monotonic() + 40.0
        while not received and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert received, f"no /diagnostics from the installed node (exit code {proc.poll()}):\n{log.read_text()}"
        os.killpg(proc.pid, signal.SIGINT)
        returncode = proc.wait(20)
    finally:
        if proc is not None and proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)
        probe.close()
    text = log.read_text()
    assert returncode == 0, text
    assert str(share / "config" / "sample_cross4.yaml") in text, f"the node did not load the installed rig:\n{text}"
