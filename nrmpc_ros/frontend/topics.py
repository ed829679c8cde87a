"""Which topic carries each rig camera's images, raw or compressed, in a bag or on the ROS graph.

Policy (compressed fallback): a camera's ``image_topic`` from the rig file is
used when it exists; its type decides how it is decoded (a sensor_msgs/Image,
or a sensor_msgs/CompressedImage recorded under the plain name). When it is
absent but ``image_topic + '/compressed'`` exists as a CompressedImage (what
image_transport records), that topic is used and the choice is reported in
the :class:`ImageTopic`'s ``note``. Neither present: one
:class:`~nrmpc_ros.errors.InputError` naming the topic and listing the image
topics the bag has. The topic used having another type is an error too. Decoding is
:func:`nrmpc_ros.frontend.images.decode_image`'s job (it takes both types).

The other topics a bag is read for have one message type each (the
``*_TYPE`` constants); :func:`check_topic_type` refuses a topic of another
type with one error naming the topic, before any message is decoded.

For the node's ``image_transport: auto``, :func:`choose_transport` makes the
same choice from the types the graph's *publishers* send on each topic (a
subscription, the node's own among them, says nothing about what a camera
sends); with neither published yet it takes the raw topic, and the node looks
again until images arrive, so it follows a camera started after it.

Names: a rig file's topics may be relative (``cam0/image_raw``), so that
``-r __ns:=/rig1`` moves a node's inputs with its outputs. Offline there is
no namespace: a relative name resolves in the root namespace, as a node
started without one resolves it (:func:`expand_topic`), and matches the bag's
``/cam0/image_raw``. See docs/CONVENTIONS.md, "Bags".
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError

RAW_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
COMPRESSED_SUFFIX = "/compressed"
IMU_TYPE = "sensor_msgs/msg/Imu"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
VECTOR_TYPE = "geometry_msgs/msg/Vector3Stamped"


@dataclass(frozen=True)
class ImageTopic:
    """The topic a camera's images are read from."""

    topic: str
    msgtype: str
    compressed: bool
    note: str = ""  # why this topic, when it is not the rig file's image_topic as is


def expand_topic(name: str, namespace: str = "/", node_name: str = "estimator") -> str:
    """The fully qualified name ROS 2 gives ``name`` before remapping: absolute names stay, relative ones lie
    in ``namespace`` ('/' is the root), ``~`` is the node's own namespace (``namespace/node_name``)."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    if name.startswith("/"):
        return name
    if name == "~" or name.startswith("~/"):
        return f"{ns}/{node_name}{name[1:]}"
    return f"{ns}/{name}"


def bag_topic(name: str) -> str:
    """The topic a bag records for a rig file's topic ``name`` (a relative name lies in the root namespace)."""
    return expand_topic(name)


def _kind(msgtype: str) -> str | None:
    """'raw' or 'compressed' for the image message types (ROS 2 or ROS 1 spelling), else None."""
    name = str(msgtype).replace("/msg/", "/")
    return {"sensor_msgs/Image": "raw", "sensor_msgs/CompressedImage": "compressed"}.get(name)


def same_type(msgtype: str, expected: str) -> bool:
    """Whether ``msgtype`` is ``expected``, in its ROS 2 (pkg/msg/Name) or ROS 1 (pkg/Name) spelling."""
    return str(msgtype).replace("/msg/", "/") == expected.replace("/msg/", "/")


def check_topic_type(bag, topic: str, expected: str, source: str, what: str, field: str | None = None) -> None:
    """InputError naming ``source`` (and ``field``) when ``topic`` is in the open bag with another type than
    ``expected``; ``what`` says what the topic was meant to carry ("the IMU")."""
    have = bag.topics.get(topic)
    if have is not None and not same_type(have[0], expected):
        raise InputError(source, f"topic {topic!r} ({what}) carries {have[0]} in the bag {bag.source}, not "
                                 f"{expected}", field)


def compressed_topic(topic: str) -> str:
    """The image_transport topic of compressed images beside ``topic``."""
    return topic.rstrip("/") + COMPRESSED_SUFFIX


def _image_topics(bag_topics: dict) -> str:
    listed = [f"{t} ({m})" for t, m in sorted(bag_topics.items()) if _kind(m)]
    return ", ".join(listed) or "none"


def resolve_image_topics(bag_topics: dict, rig, source: str = "bag") -> list:
    """One :class:`ImageTopic` per rig camera (rig order) from the bag's topics (name -> message type).

    Raises :class:`InputError` naming ``source`` (the bag) and the topic when a
    camera's images are in neither the raw nor the compressed topic.
    """
    out = []
    for cam in rig.cameras:
        if not cam.image_topic:
            raise InputError(rig.source, f"camera {cam.name!r} has no image_topic", f"cameras[{cam.name}].image_topic")
        topic = bag_topic(cam.image_topic)
        comp = compressed_topic(topic)
        used = topic if topic in bag_topics else comp if comp in bag_topics else None
        if used is None:
            raise InputError(source, f"camera {cam.name!r}: image topic {topic!r} not in the bag, nor {comp!r} (rig "
                                     f"file {rig.source}); image topics in the bag: {_image_topics(bag_topics)}",
                             "topic")
        msgtype = bag_topics[used]
        kind = _kind(msgtype)
        if kind is None or (used == comp and kind == "raw"):
            want = f"{RAW_TYPE} or {COMPRESSED_TYPE}" if used == topic else COMPRESSED_TYPE
            raise InputError(source, f"camera {cam.name!r}: topic {used!r} has type {msgtype}, not {want}", "topic")
        note = ""
        if used == comp:
            note = f"camera {cam.name}: {comp} ({topic} is not in the bag)"
        elif kind == "compressed":
            note = f"{topic} (camera {cam.name}) holds compressed images ({msgtype})"
        out.append(ImageTopic(used, msgtype, kind == "compressed", note))
    return out


def bag_image_topics(bag, rig, warn=None) -> list:
    """:func:`resolve_image_topics` for an open :class:`~nrmpc_ros.bag.reader.BagReader`; ``warn(note)`` is
    called once with every fallback taken (one line)."""
    out = resolve_image_topics({t: m for t, (m, _) in bag.topics.items()}, rig, bag.source)
    notes = [t.note for t in out if t.note]
    if notes and warn is not None:
        warn("; ".join(notes))
    return out


def choose_transport(topic: str, available: dict, compressed: str | None = None) -> tuple:
    """(topic to subscribe, compressed?) for ``image_transport: auto``.

    ``available`` maps topic names to the type names their publishers send
    (from rclpy's ``get_publishers_info_by_topic``). Raw images on ``topic``
    win; else CompressedImage on ``compressed`` (default ``topic + '/compressed'``);
    else CompressedImage on ``topic`` itself; with nothing there yet, the raw topic.
    """
    kinds = {t: {_kind(m) for m in types} for t, types in available.items()}
    comp = compressed or compressed_topic(topic)
    if "raw" in kinds.get(topic, ()):
        return topic, False
    if "compressed" in kinds.get(comp, ()):
        return comp, True
    if "compressed" in kinds.get(topic, ()):
        return topic, True
    return topic, False


__all__ = ["CAMERA_INFO_TYPE", "COMPRESSED_TYPE", "IMU_TYPE", "POSE_TYPE", "RAW_TYPE", "VECTOR_TYPE", "ImageTopic",
           "bag_image_topics", "bag_topic", "check_topic_type", "choose_transport", "compressed_topic", "expand_topic",
           "resolve_image_topics", "same_type"]
