"""Writing rosbag2 bags with ``rosbags`` (docs/CONVENTIONS.md (Bags)): images, CameraInfo, IMU and ground truth.

Messages are built from the ROS 2 Jazzy type store (named explicitly, as
rosbags >= 0.11 requires) and written with CDR serialization; storage is
sqlite3 (default) or mcap. Stamps are integer nanoseconds; the header stamp
and the bag's receive time of every message are the same.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ..core.rig import Camera
from ..core.so3 import matrix_to_quat_xyzw
from ..errors import InputError, OptionError

STORAGES = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
# Raw encodings (sensor_msgs/Image) and compressed formats (sensor_msgs/CompressedImage of a mono8 image).
BAYER_ENCODINGS = ("bayer_rggb8", "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8", "bayer_rggb16")
YUV_ENCODINGS = ("uyvy", "yuyv", "nv21")
RAW_ENCODINGS = ("mono8", "bgr8", "rgb8", "mono16", *BAYER_ENCODINGS, *YUV_ENCODINGS)
COMPRESSED_FORMATS = ("png", "jpeg")
ENCODINGS = RAW_ENCODINGS + COMPRESSED_FORMATS
BAG_VERSION = 9
DEFAULT_JPEG_QUALITY = 95
# A raw colour sensor without white balance: the blue, green and red channels' response to a grey scene. A
# Bayer image of a grey scene is then a checkerboard of three levels, as a real one is.
SENSOR_GAINS_BGR = (0.7, 1.0, 0.55)

_TYPES = {
    "image": "sensor_msgs/msg/Image",
    "compressed": "sensor_msgs/msg/CompressedImage",
    "info": "sensor_msgs/msg/CameraInfo",
    "imu": "sensor_msgs/msg/Imu",
    "pose": "geometry_msgs/msg/PoseStamped",
    "vector": "geometry_msgs/msg/Vector3Stamped",
}


def image_topic_for(image_topic: str, encoding: str) -> str:
    """The topic an image of ``encoding`` goes on: the raw image topic, or ``<image_topic>/compressed`` for png/jpeg
    (image_transport's compressed transport, which the node subscribes to with ``image_transport: compressed``)."""
    return image_topic.rstrip("/") + "/compressed" if encoding in COMPRESSED_FORMATS else image_topic


def typestore():
    """The ROS 2 Jazzy type store (explicit, rosbags >= 0.11)."""
    return get_typestore(Stores.ROS2_JAZZY)


def _mosaic(img: np.ndarray, pattern: str) -> np.ndarray:
    """A grey image seen through a colour filter array ``pattern`` (the top-left 2x2 cell, e.g. "rggb") of a
    sensor with :data:`SENSOR_GAINS_BGR`."""
    gain = dict(zip("bgr", SENSOR_GAINS_BGR))
    out = np.empty(img.shape, np.float64)
    for k, c in enumerate(pattern):
        out[k // 2::2, k % 2::2] = img[k // 2::2, k % 2::2] * gain[c]
    return out


def raw_payload(img: np.ndarray, encoding: str) -> tuple[np.ndarray, int]:
    """The data and row step of a sensor_msgs/Image of the 2-D uint8 grey image ``img`` in a raw ``encoding``:
    grey replicated in colour, 16 bit scaled to full range, a Bayer mosaic (16 bit: 12 significant bits, as
    machine-vision cameras send), or YUV with neutral chroma (4:2:2 packed, or NV21's luma plane and
    interleaved V/U plane)."""
    h, w = img.shape
    if encoding == "mono8":
        return img, w
    if encoding in ("bgr8", "rgb8"):
        return np.repeat(img[:, :, None], 3, axis=2), 3 * w
    if encoding == "mono16":
        return img.astype("<u2") * 257, 2 * w
    if encoding.startswith("bayer_"):
        pattern, bits = encoding[6:10], int(encoding[10:])
        level = _mosaic(img, pattern)
        if bits == 8:
            return np.rint(level).astype(np.uint8), w
        return np.rint(level * 16).astype("<u2"), 2 * w
    if encoding in ("uyvy", "yuyv"):
        packed = np.full((h, 2 * w), 128, np.uint8)
        packed[:, (1 if encoding == "uyvy" else 0)::2] = img
        return packed, 2 * w
    if encoding == "nv21":
        return np.concatenate([img, np.full(((h + 1) // 2, w), 128, np.uint8)]), w
    raise OptionError("bag writer", "encoding", f"unsupported image encoding {encoding!r} "
                                                f"(supported: {', '.join(ENCODINGS)})")


class BagWriter:
    """A rosbag2 writer that registers topics on first use.

    Use as a context manager; on an exception the half-written bag is left
    for inspection (rosbags closes it consistently).
    """

    def __init__(self, path, storage: str = "sqlite3"):
        if storage not in STORAGES:
            raise OptionError("bag writer", "storage", f"unknown storage {storage!r} "
                                                       f"(supported: {', '.join(STORAGES)})")
        self.path = Path(path)
        if self.path.exists():
            raise InputError(str(self.path), "output bag already exists; remove it or choose another --out")
        self.store = typestore()
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=STORAGES[storage])
        self._connections: dict[str, object] = {}
        self._types: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self._t = self.store.types  # message classes by name

    def __enter__(self):
        self._writer.open()
        return self

    def __exit__(self, *exc):
        self._writer.close()
        return False

    # -- low level --------------------------------------------------------
    def write(self, topic: str, msg, stamp_ns: int) -> None:
        """Serialize ``msg`` and write it on ``topic`` at ``stamp_ns`` (receive time)."""
        msgtype = msg.__msgtype__
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.store)
            self._connections[topic] = conn
            self._types[topic] = msgtype
        elif self._types[topic] != msgtype:
            raise InputError(topic, f"topic already carries {self._types[topic]}, cannot also write {msgtype}")
        self._writer.write(conn, int(stamp_ns), self.store.serialize_cdr(msg, msgtype))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def header(self, stamp_ns: int, frame_id: str):
        Time = self._t["builtin_interfaces/msg/Time"]
        Header = self._t["std_msgs/msg/Header"]
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        return Header(stamp=Time(sec=int(sec), nanosec=int(nsec)), frame_id=frame_id)

    # -- message builders -------------------------------------------------
    def image_msg(self, image: np.ndarray, stamp_ns: int, frame_id: str, encoding: str = "mono8",
                  jpeg_quality: int = DEFAULT_JPEG_QUALITY):
        """sensor_msgs/Image (raw encodings) or CompressedImage (png/jpeg) of a 2-D uint8 grey image.

        A CompressedImage belongs on :func:`image_topic_for` of the camera's image topic.
        """
        img = np.asarray(image)
        if img.ndim != 2 or img.dtype != np.uint8:
            raise ValueError("image_msg expects a 2-D uint8 grey image")
        header = self.header(stamp_ns, frame_id)
        if encoding in COMPRESSED_FORMATS:
            ok, buf = cv2.imencode(".png" if encoding == "png" else ".jpg", img,
                                   [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if encoding == "jpeg" else [])
            if not ok:
                raise RuntimeError(f"OpenCV could not encode a {encoding} image")
            return self._t[_TYPES["compressed"]](header=header, format=f"mono8; {encoding} compressed mono8",
                                                 data=np.frombuffer(buf.tobytes(), dtype=np.uint8))
        data, step = raw_payload(img, encoding)
        return self._t[_TYPES["image"]](
            header=header, height=img.shape[0], width=img.shape[1], encoding=encoding, is_bigendian=0,
            step=step, data=np.ascontiguousarray(data).view(np.uint8).reshape(-1),
        )

    def camera_info_msg(self, cam: Camera, stamp_ns: int):
        """sensor_msgs/CameraInfo of a rig camera (plumb_bob for pinhole, equidistant for fisheye)."""
        fx, fy, cx, cy = (float(x) for x in cam.intrinsics)
        if cam.model == "equidistant":
            model, d = "equidistant", np.zeros(4)
        else:
            model, d = "plumb_bob", np.zeros(5)
        d[: len(cam.distortion)] = cam.distortion
        K = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64)
        P = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], dtype=np.float64)
        roi = self._t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return self._t[_TYPES["info"]](
            header=self.header(stamp_ns, cam.name), height=int(cam.resolution[1]), width=int(cam.resolution[0]),
            distortion_model=model, d=d.astype(np.float64), k=K, r=np.eye(3).reshape(-1), p=P,
            binning_x=0, binning_y=0, roi=roi,
        )

    def imu_msg(self, stamp_ns: int, frame_id: str, accel, gyro, accel_sigma: float = 0.0, gyro_sigma: float = 0.0):
        """sensor_msgs/Imu: specific force ``accel`` (m/s^2), angular velocity ``gyro`` (rad/s), no orientation."""
        V3 = self._t["geometry_msgs/msg/Vector3"]
        Q = self._t["geometry_msgs/msg/Quaternion"]
        no_orientation = np.zeros(9)
        no_orientation[0] = -1.0  # REP 145: orientation not provided
        return self._t[_TYPES["imu"]](
            header=self.header(stamp_ns, frame_id), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=no_orientation,
            angular_velocity=V3(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
            angular_velocity_covariance=(np.eye(3) * gyro_sigma**2).reshape(-1),
            linear_acceleration=V3(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
            linear_acceleration_covariance=(np.eye(3) * accel_sigma**2).reshape(-1),
        )

    def pose_msg(self, stamp_ns: int, frame_id: str, R, p):
        """geometry_msgs/PoseStamped of orientation R (3, 3) and position p (3,)."""
        q = matrix_to_quat_xyzw(np.asarray(R, dtype=float))
        Pose = self._t["geometry_msgs/msg/Pose"]
        Point = self._t["geometry_msgs/msg/Point"]
        Q = self._t["geometry_msgs/msg/Quaternion"]
        return self._t[_TYPES["pose"]](
            header=self.header(stamp_ns, frame_id),
            pose=Pose(position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
                      orientation=Q(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))),
        )

    def vector_msg(self, stamp_ns: int, frame_id: str, v):
        """geometry_msgs/Vector3Stamped."""
        V3 = self._t["geometry_msgs/msg/Vector3"]
        return self._t[_TYPES["vector"]](header=self.header(stamp_ns, frame_id),
                                         vector=V3(x=float(v[0]), y=float(v[1]), z=float(v[2])))
