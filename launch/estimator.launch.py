"""Launch the nrmpc_ros ``estimator`` node: relative pose and gravity of a non-rigid multi-camera rig.

    ros2 launch nrmpc_ros estimator.launch.py rig_file:=my_rig.yaml namespace:=rig1 \\
        image_remaps:='/cam0/image_raw:=/rig1/front/image_raw; /cam1/image_raw:=/rig1/left/image_raw'

``ros2 launch nrmpc_ros estimator.launch.py --show-args`` lists the arguments.
The node reads ``params_file`` first and then the overrides given here
(``rig_file``, ``method``, ``use_sim_time``, and ``imu_topic`` when not empty).
``rviz:=true`` also starts rviz2 with share/nrmpc_ros/rviz/nrmpc.rviz, its topics
and fixed frame made for the launched rig and namespace (a log line instead
when rviz2 is not installed).
Relative ``rig_file`` and ``params_file`` paths are looked up in the working
directory first, then in share/nrmpc_ros (and its config/), as the node does.

Only ``generate_launch_description`` and the launch-time function import
launch / launch_ros (and nrmpc_ros), so the file imports without them.
"""

from __future__ import annotations

import re
from pathlib import Path

PACKAGE = "nrmpc_ros"
EXECUTABLE = "estimator"
METHODS = ["auto", "4pt-bending", "6pt-bending", "6pt-nonbending"]
LOG_LEVELS = ["debug", "info", "warn", "error", "fatal"]
BOOLEANS = ["true", "false", "True", "False"]
#: (name, default, description, choices); None defaults are the installed files of share/nrmpc_ros/config.
ARGUMENTS = (
    ("rig_file", None, "rig YAML file (cameras, bars, IMU mount); default: the installed sample_cross4.yaml", None),
    ("params_file", None, "node parameter file (--params-file); default: the installed estimator.yaml", None),
    ("method", "auto", "estimator: auto runs 4pt-bending for holds with IMU gravity, 6pt-bending for the others",
     METHODS),
    ("namespace", "", "namespace of the node and of its relative topics (empty: the root namespace)", None),
    ("imu_topic", "", "sensor_msgs/Imu topic the node subscribes to (remap target of its IMU input); "
                      "empty: the params file's imu_topic, else the rig file's imu.topic", None),
    ("image_remaps", "", "camera topic remaps FROM:=TO separated by spaces or ';', FROM being a rig file "
                         "image_topic (its /compressed topic follows it) or image_topic/compressed", None),
    ("use_sim_time", "false", "take time from /clock (e.g. with nrmpc play or ros2 bag play --clock)", BOOLEANS),
    ("log_level", "info", "log level of the node", LOG_LEVELS),
    ("rviz", "false", "also start rviz2 with share/nrmpc_ros/rviz/nrmpc.rviz made for this rig and namespace "
                      "(when rviz2 is installed; a log line says so when it is not)", BOOLEANS),
)
DEFAULT_FILES = {"rig_file": ("config", "sample_cross4.yaml"), "params_file": ("config", "estimator.yaml")}
RVIZ_FILE = "rviz/nrmpc.rviz"
# The node's outputs the RViz config shows, relative to the node (in its namespace).
RVIZ_TOPICS = {"rviz_default_plugins/MarkerArray": "estimator/markers",
               "rviz_default_plugins/PoseWithCovariance": "estimator/pose"}


def parse_remaps(text: str, argument: str = "image_remaps") -> list[tuple[str, str]]:
    """The ``FROM:=TO`` pairs of ``text`` (separated by whitespace or ';'), in order; empty text gives none."""
    from nrmpc_ros.errors import InputError

    pairs = []
    for token in re.split(r"[;\s]+", text.strip()):
        if not token:
            continue
        src, sep, dst = token.partition(":=")
        if not sep or not src or not dst or ":=" in dst:
            raise InputError(f"launch argument {argument}", f"'{token}' is not FROM:=TO (pairs are separated by "
                                                            "spaces or ';')")
        pairs.append((src, dst))
    sources = [s for s, _ in pairs]
    duplicated = sorted({s for s in sources if sources.count(s) > 1})
    if duplicated:
        raise InputError(f"launch argument {argument}", f"{', '.join(duplicated)} remapped more than once")
    return pairs


def find_file(path: str, share: Path | None, argument: str) -> Path:
    """``path`` as the node resolves it: absolute, or relative to the working directory, then to ``share``."""
    from nrmpc_ros.frontend.node_config import find_file as find

    return find(path, f"launch argument {argument}", [share] if share is not None else [])


def expand_topic(name: str, namespace: str) -> str:
    """Fully qualified topic name: a relative ``name`` lies in ``namespace`` (absolute, '/' for the root)."""
    from nrmpc_ros.frontend.topics import expand_topic as expand

    return expand(name, namespace)


def check_image_remaps(remaps: list[tuple[str, str]], image_topics: list[str], namespace: str, rig_source: str):
    """Every remap source must be a camera topic of the rig: a remap that matches nothing would leave a camera
    unsubscribed without a word. ``image_topic/compressed`` counts too (``image_transport: compressed``)."""
    from nrmpc_ros.errors import InputError

    known = {}
    for topic in image_topics:
        for name in (topic, topic.rstrip("/") + "/compressed"):
            known[expand_topic(name, namespace)] = name
    unknown = [src for src, _ in remaps if expand_topic(src, namespace) not in known]
    if unknown:
        here = ", ".join(expand_topic(t, namespace) for t in image_topics)
        raise InputError("launch argument image_remaps", f"{', '.join(unknown)} is no camera topic of the rig file "
                                                         f"{rig_source} (its topics here: {here})")


def rviz_config_for(text: str, namespace: str, body_frame: str, image_topic: str) -> str:
    """The RViz config ``text`` (rviz/nrmpc.rviz) for a launched node: the node's topics in ``namespace``, the rig's
    body frame as the fixed frame, ``image_topic`` (fully qualified, after remapping) in the image display."""
    import yaml

    cfg = yaml.safe_load(text)
    manager = cfg["Visualization Manager"]
    manager["Global Options"]["Fixed Frame"] = body_frame
    for display in manager["Displays"]:
        cls = display["Class"]
        if cls in RVIZ_TOPICS:
            display["Topic"]["Value"] = expand_topic(RVIZ_TOPICS[cls], namespace)
        elif cls == "rviz_default_plugins/Image":
            display["Topic"]["Value"] = image_topic
    return yaml.safe_dump(cfg, sort_keys=False)


def _rviz_actions(share: Path | None, rig, namespace: str, remaps: list) -> list:
    """rviz2 with the config made for this node, or a log line saying why not."""
    import tempfile

    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    from launch.actions import LogInfo
    from launch_ros.actions import Node

    try:
        get_package_share_directory("rviz2")
    except PackageNotFoundError:
        return [LogInfo(msg="rviz:=true but rviz2 is not installed (apt install ros-jazzy-rviz2): the estimator "
                            "runs without it")]
    config = find_file(RVIZ_FILE, share, "rviz")
    image = expand_topic(rig.cameras[0].image_topic, namespace)
    image = dict((expand_topic(a, namespace), expand_topic(b, namespace)) for a, b in remaps).get(image, image)
    out = Path(tempfile.mkdtemp(prefix="nrmpc_rviz_")) / "nrmpc.rviz"
    out.write_text(rviz_config_for(config.read_text(), namespace, rig.body_frame, image))
    return [LogInfo(msg=f"rviz2 with {out} (from {config})"),
            Node(package="rviz2", executable="rviz2", arguments=["-d", str(out)], output="screen")]


def _launch_setup(context, *args, **kwargs):
    """The estimator Node with every launch argument resolved (runs at launch time, inside the launch service)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    from launch_ros.actions import Node
    from launch_ros.utilities import make_namespace_absolute, prefix_namespace

    from nrmpc_ros.core.rig import load_rig

    value = {name: context.launch_configurations.get(name, "") for name, *_ in ARGUMENTS}
    try:
        share = Path(get_package_share_directory(PACKAGE))
    except PackageNotFoundError:
        share = None
    for name, (folder, file) in DEFAULT_FILES.items():
        if not value[name] and share is not None:
            value[name] = str(share / folder / file)
    params_file = find_file(value["params_file"], share, "params_file")
    rig_file = find_file(value["rig_file"], share, "rig_file")
    rig = load_rig(rig_file)  # a bad rig file fails here with its file and field named
    namespace = make_namespace_absolute(prefix_namespace(context.launch_configurations.get("ros_namespace"),
                                                         value["namespace"] or None)) or "/"
    remaps = parse_remaps(value["image_remaps"])
    check_image_remaps(remaps, [c.image_topic for c in rig.cameras], namespace, str(rig_file))

    overrides = {"rig_file": str(rig_file), "method": value["method"],
                 "use_sim_time": value["use_sim_time"].lower() == "true"}
    if value["imu_topic"]:
        # The node subscribes to its imu_topic parameter (falling back to the rig file's imu.topic), so setting
        # it is the remap that always names the right source topic.
        overrides["imu_topic"] = value["imu_topic"]
    node = Node(
        package=PACKAGE,
        executable=EXECUTABLE,
        namespace=value["namespace"],
        parameters=[str(params_file), overrides],
        remappings=remaps,
        ros_arguments=["--log-level", value["log_level"]],
        output="screen",
        emulate_tty=True,
    )
    if value["rviz"].lower() == "true":
        return [node, *_rviz_actions(share, rig, namespace, remaps)]
    return [node]


def generate_launch_description():
    """The launch arguments and the estimator node (see the module docstring)."""
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch.substitutions import PathJoinSubstitution
    from launch_ros.substitutions import FindPackageShare

    from launch import LaunchDescription

    declared = []
    for name, default, description, choices in ARGUMENTS:
        if default is None:
            default = PathJoinSubstitution([FindPackageShare(PACKAGE), *DEFAULT_FILES[name]])
        declared.append(DeclareLaunchArgument(name, default_value=default, description=description, choices=choices))
    return LaunchDescription([*declared, OpaqueFunction(function=_launch_setup)])

