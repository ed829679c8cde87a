"""The ``estimator`` node's settings and start-up without ROS: parameters, command line, files, topics.

- :class:`NodeConfig`: the node's own parameters, each an :func:`~nrmpc_ros.config.option` with its
  documentation and range; ``pipeline.*`` come from :class:`~nrmpc_ros.frontend.pipeline.PipelineConfig`.
  :func:`parameter_fields` lists them all, :func:`parameter_descriptor` gives each one's ROS descriptor,
  :func:`unknown_parameters` finds typos, :func:`configs_from_parameters` builds and checks both configs.
- :func:`command_line` (``--help``, stray arguments), :func:`find_file` (rig and params files: working
  directory, then share/nrmpc_ros), :func:`imu_topic` and :func:`transport` (which topics to subscribe).
"""

from __future__ import annotations

import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

from ..config import FieldInfo, describe_fields, from_mapping, option
from ..core.rig import Rig
from ..errors import InputError
from .feeder import FeederConfig
from .pipeline import PIPELINE_METHODS, PipelineConfig
from .topics import choose_transport, compressed_topic

TRANSPORTS = ("auto", "raw", "compressed")
PACKAGE = "nrmpc_ros"


@dataclass
class NodeConfig:
    """Parameters of the ``estimator`` node besides ``pipeline.*`` (docs: README, "The ROS 2 node")."""

    rig_file: str = option("", "rig YAML file (cameras, topics, bars, IMU mount); required. A relative path is "
                           "looked up in the working directory, then in share/nrmpc_ros and its config/")
    method: str = option("auto", "auto: 4pt-bending for holds with IMU gravity, 6pt-bending for the others; or "
                         "one method for all holds (a change at run time starts a new sequence)",
                         choices=PIPELINE_METHODS)
    use_imu: bool = option(True, "subscribe to the IMU when the rig file has an imu block")
    imu_topic: str = option("", "sensor_msgs/Imu topic; empty: the rig file's imu.topic")
    image_transport: str = option("auto", "auto: raw sensor_msgs/Image on each camera's image topic if that is "
                                  "published, else CompressedImage on <topic>/compressed (looked at until the "
                                  "camera's first image); raw; compressed", choices=TRANSPORTS)
    image_queue_size: int = option(100, "depth of each image subscription (messages): what a camera may deliver "
                                   "at once (a driver or link that buffers sends seconds of frames in one burst; "
                                   "the node takes them every take_period_s)", lo=1, hi=10000)
    imu_queue_size: int = option(2000, "depth of the IMU subscription (samples; 2 s at 1 kHz)", lo=1, hi=1000000)
    take_period_s: float = option(0.01, "the messages waiting in the camera and IMU subscriptions are taken "
                                  "together this often (s) and handed over in the order of their stamps: the node "
                                  "wakes at this rate, not at every message (a 1 kHz IMU), a stall of the process "
                                  "does not let one input run ahead of the others, and a message reaches the "
                                  "pipeline at most this much later; 0: each message as the executor hands it "
                                  "over", lo=0.0, hi=1.0)
    work_queue_size: int = option(8, "frame sets waiting for the estimator; sets arriving while it is full are "
                                  "dropped and counted", lo=1, hi=100000)
    camera_timeout_s: float = option(2.0, "a camera silent this long while another publishes is reported stopped; "
                                     "every camera silent this long: the input ended and the open hold is "
                                     "estimated (s); longer for a camera that delivers in bursts (1.5 x the "
                                     "spread of its delays)", lo=0.0, hi=3600.0, lo_open=True)
    diagnostics_period_s: float = option(1.0, "period of /diagnostics (s)", lo=0.0, hi=3600.0, lo_open=True)
    log_every_s: float = option(10.0, "dropped inputs of one kind after the first are logged as a count at most "
                                "this often (s)", lo=0.0, hi=86400.0, lo_open=True)
    origin_frame: str = option("", "frame_id of ~/pose: the sequence origin (the first hold's body frame, level "
                               "once gravity is known); empty: <body_frame>_origin")
    camera_frame_suffix: str = option("_optical", "TF frame of camera NAME: NAME + this suffix (OpenCV axes)")
    publish_tf: bool = option(True, "publish body -> camera frames (bent extrinsics) on /tf for every hold and, "
                              "with an IMU, for every frame set (the bars' dynamics)")
    camera_poses_rate_hz: float = option(10.0, "with an IMU, ~/camera_poses from the bars' dynamics at most this "
                                         "often (Hz, by frame-set stamps); 0: only with each hold's estimate",
                                         lo=0.0, hi=1000.0)
    markers_bend_scale: float = option(1.0, "~/markers draws the bars bent as at this many times the estimated "
                                       "gravity (the bending model is linear in it): above 1 makes millimetres of "
                                       "bending visible at the rig's scale; 1: as estimated", lo=1.0, hi=10000.0)
    input: FeederConfig = option(FeederConfig(), "stamps, frame grouping and IMU order")


# Parameters every node has, and prefixes of parameters ROS itself declares.
ROS_PARAMETERS = ("use_sim_time", "start_type_description_service")
ROS_PREFIXES = ("qos_overrides.",)


def _is_parameter(value) -> bool:
    return isinstance(value, (bool, int, float, str))


def parameter_fields() -> list:
    """Every parameter of the node: :class:`NodeConfig`'s, then ``pipeline.*`` (settable fields only)."""
    fields = describe_fields(NodeConfig) + describe_fields(PipelineConfig, "pipeline.")
    return [f for f in fields if _is_parameter(f.default)]


def unknown_parameters(names) -> list:
    """The names that are neither a parameter of the node nor one ROS declares, sorted."""
    known = {f.name for f in parameter_fields()} | set(ROS_PARAMETERS)
    return sorted(n for n in names if n not in known and not n.startswith(ROS_PREFIXES))


def configs_from_parameters(values: dict) -> tuple:
    """(NodeConfig, PipelineConfig) from flat dotted parameter values; InputError naming the parameter."""
    nested: dict = {}
    for name, value in values.items():
        *head, last = name.split(".")
        d = nested
        for h in head:
            d = d.setdefault(h, {})
        d[last] = value
    pipeline = nested.pop("pipeline", {})
    node = from_mapping(NodeConfig, nested, "parameters")
    if not node.rig_file:
        raise InputError("parameter rig_file", "required (e.g. --ros-args -p rig_file:=config/sample_cross4.yaml or "
                                               "--params-file config/estimator.yaml)")
    return node, from_mapping(PipelineConfig, pipeline, "parameters", "pipeline.")


def describe_parameter(f: FieldInfo) -> str:
    """One line: the documentation with the allowed values."""
    if f.choices:
        return f"{f.doc} (one of: {', '.join(map(str, f.choices))})"
    lo, hi = (None if v is None else str(v) if isinstance(v, int) else f"{v:g}" for v in (f.lo, f.hi))
    if lo is not None and hi is not None:
        return f"{f.doc} (range [{lo}, {hi}])"
    if lo is not None or hi is not None:
        return f"{f.doc} ({'>= ' + lo if lo is not None else '<= ' + hi})"
    return f.doc


def parameter_range(f: FieldInfo):
    """("float" | "int", lo, hi) of a numeric parameter with a range, open ends at the type's limits; else None."""
    if (f.lo, f.hi) == (None, None) or isinstance(f.default, bool) or not isinstance(f.default, (int, float)):
        return None
    if isinstance(f.default, float):
        return "float", float("-inf" if f.lo is None else f.lo), float("inf" if f.hi is None else f.hi)
    return "int", int(-2**63 if f.lo is None else f.lo), int(2**63 - 1 if f.hi is None else f.hi)


def parameter_descriptor(f: FieldInfo) -> dict:
    """The fields of the field's rcl_interfaces/ParameterDescriptor: description, read-only (all but
    ``method``), numeric range."""
    d = {"description": describe_parameter(f), "read_only": f.name != "method"}
    kind, lo, hi = parameter_range(f) or (None, None, None)
    if kind == "float":
        d["floating_point_range"] = [{"from_value": lo, "to_value": hi, "step": 0.0}]
    elif kind == "int":
        d["integer_range"] = [{"from_value": lo, "to_value": hi, "step": 1}]
    return d


def parameters_help() -> list:
    """Lines of ``estimator --help`` for the parameters."""
    lines = []
    for f in parameter_fields():
        lines.append(f"  {f.name} [default {f.default!r}]")
        lines.append(f"      {describe_parameter(f)}")
    return lines


TOPICS = ("~/pose (geometry_msgs/PoseWithCovarianceStamped, origin frame), ~/relative_pose (geometry_msgs/"
          "PoseStamped, the reference hold's body frame) with ~/relative_pose_reference (std_msgs/Header), ~/gravity "
          "(geometry_msgs/Vector3Stamped) and ~/gravity_covariance (geometry_msgs/AccelWithCovarianceStamped), "
          "~/attitude (sensor_msgs/Imu: roll, pitch), ~/camera_poses (geometry_msgs/PoseArray), all in the body "
          "frame but the first two; /tf, /diagnostics; service ~/reset (std_srvs/Trigger)")


def usage() -> str:
    """The text of ``estimator --help``."""
    about = ("ROS 2 node 'estimator' of nrmpc_ros: pose and gravity of a non-rigid multi-camera rig over holds. "
             "Subscribes to the rig file's image topics (sensor_msgs/Image or CompressedImage), their camera_info "
             f"and, optionally, sensor_msgs/Imu; publishes {TOPICS}.")
    return "\n".join([
        "usage: estimator [--help] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] [-r FROM:=TO ...]]", "",
        textwrap.fill(about, 110), "",
        "example: estimator --ros-args --params-file config/estimator.yaml -r __ns:=/rig1", "", "parameters:",
        *parameters_help()])


def user_arguments(argv: list) -> list:
    """Arguments outside any ``--ros-args ... [--]`` section."""
    out, in_ros = [], False
    for a in argv:
        in_ros = True if a == "--ros-args" else False if a == "--" and in_ros else in_ros
        if not in_ros and a != "--":
            out.append(a)
    return out


def command_line(argv: list, ros_error: str | None = None) -> int | None:
    """``--help`` printed (0), bad arguments or no ROS reported (2), or None: start the node."""
    user = user_arguments(argv)
    if "-h" in user or "--help" in user:
        print(usage())
        return 0
    if user or ros_error:
        why = f"unknown arguments {' '.join(user)} (parameters go after --ros-args; see --help)" if user else ros_error
        print(f"estimator: error: {why}", file=sys.stderr)
        return 2
    return None


def imu_topic(rig: Rig, config: NodeConfig) -> tuple:
    """(the IMU topic to subscribe or None, a warning or None)."""
    if rig.imu is None:
        warn = (f"imu_topic {config.imu_topic} is set but the rig file {rig.source} has no imu block (the IMU's "
                "mount is unknown): not subscribing to the IMU") if config.use_imu and config.imu_topic else None
        return None, warn
    return (config.imu_topic or rig.imu.topic) if config.use_imu else None, None


def transport_topics(topic: str, resolve) -> tuple:
    """(raw topic, compressed topic) of a rig file's image ``topic`` for the node's ``resolve(name,
    only_expand=False)`` (expansion and remapping).

    The compressed topic follows the image topic (a remap of ``cam0/image_raw`` moves both, as image_transport
    does) unless ``<topic>/compressed`` is remapped itself."""
    base, comp = resolve(topic), compressed_topic(topic)
    return base, resolve(comp) if resolve(comp) != resolve(comp, only_expand=True) else compressed_topic(base)


def images_reliable(offers: list) -> bool:
    """Whether to subscribe a camera's images reliably, given whether each of its publishers offers reliable
    delivery: unless one offers only best effort (then best effort, which matches every publisher). A burst of
    images (a driver or link that buffers, a bag played back) overflows the middleware's buffers, and best
    effort loses frames without a trace. With no publisher seen yet: reliable, which a best-effort publisher
    does not serve, so the node can still switch without losing an image."""
    return all(offers)


def transport(topic: str, how: str, publishers: dict, resolve) -> tuple:
    """(topic to subscribe, compressed?) for a rig file's image ``topic`` with ``image_transport`` ``how``, the
    message types *published* per topic (:func:`transport_topics` names the topics that matter; subscriptions,
    the node's own among them, say nothing about what a camera sends) and the node's ``resolve``."""
    base, compressed = transport_topics(topic, resolve)
    if how == "auto":
        return choose_transport(base, publishers, compressed)
    return (compressed, True) if how == "compressed" else (base, False)


def share_directories() -> list:
    """Where installed files of the package may be: the ament index, the Python prefix, the source tree."""
    out = []
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        try:
            out.append(Path(get_package_share_directory(PACKAGE)))
        except (PackageNotFoundError, LookupError, ValueError, OSError):  # OSError: no AMENT_PREFIX_PATH
            pass
    except ImportError:
        pass
    out.append(Path(sys.prefix) / "share" / PACKAGE)
    out.append(Path(__file__).resolve().parents[2])  # a source checkout (pip install -e)
    return list(dict.fromkeys(out))


def find_file(path: str, what: str, shares: list | None = None) -> Path:
    """``path`` as given (absolute), else in the working directory, else in each share directory (default:
    :func:`share_directories`) and its config/; InputError naming ``what`` and every place looked in."""
    p = Path(path).expanduser()
    candidates = [p] if p.is_absolute() else [Path.cwd() / p]
    if not p.is_absolute():
        for share in share_directories() if shares is None else shares:
            candidates += [share / p, share / "config" / p.name]
    candidates = list(dict.fromkeys(candidates))
    for c in candidates:
        if c.is_file():
            return c
    raise InputError(what, f"no such file: {path} (looked for {', '.join(map(str, candidates))})")


__all__ = ["NodeConfig", "PACKAGE", "TRANSPORTS", "command_line", "configs_from_parameters", "describe_parameter",
           "images_reliable",
           "find_file", "imu_topic", "parameter_descriptor", "parameter_fields", "parameter_range", "parameters_help",
           "share_directories", "transport", "unknown_parameters", "usage", "user_arguments"]
