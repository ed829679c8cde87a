"""Rig files from Kalibr calibrations (the rig format of docs/CONVENTIONS.md, Files).

A Kalibr camera chain (``camchain.yaml``, or ``camchain-imucam.yaml`` which
adds ``T_cam_imu``) lists ``cam0, cam1, ...`` with ``camera_model``
(only ``pinhole`` is supported), ``intrinsics [fu, fv, pu, pv]``,
``distortion_model`` (``radtan`` -> the rig file's ``pinhole`` k1 k2 p1 p2,
``equidistant`` -> ``equidistant`` k1..k4, ``none``),
``distortion_coeffs``, ``resolution``, ``rostopic``, chained extrinsics
``T_cn_cnm1`` (p_cn = T p_cn-1) and optionally ``T_cam_imu``
(p_cam = T p_imu). Files written by OpenCV (first line ``%YAML:1.0``,
matrices as ``!!opencv-matrix``) load too.

The body frame is placed at a chosen camera or at the IMU. Kalibr knows
nothing about bars, so every bar is left rigid: fill in ``bar: {mass, EI}``
per camera before using the bending estimators.
"""

from __future__ import annotations

import re

import numpy as np
import yaml

from .core.rig import Rig, rig_from_dict
from .core.so3 import matrix_to_quat_xyzw
from .errors import InputError, OptionError
from .safeio import YAML_MAX_BYTES, BoundedSafeLoader, read_text, yaml_from_text

SUPPORTED_CAMERA_MODELS = ("pinhole",)
_DISTORTIONS = {"radtan": ("pinhole", (4, 5)), "equidistant": ("equidistant", (4,)), "none": ("pinhole", (0,))}
_KNOWN_UNSUPPORTED = {
    "omni": "the omnidirectional (Mei) model", "ds": "the double-sphere model",
    "eucm": "the extended unified model", "fov": "the FOV distortion model",
}


class _KalibrLoader(BoundedSafeLoader):
    """The bounded SafeLoader of :mod:`nrmpc_ros.safeio` that also understands OpenCV's ``!!opencv-matrix``."""


def _opencv_matrix(loader, node):
    d = loader.construct_mapping(node, deep=True)
    try:
        rows, cols = int(d["rows"]), int(d["cols"])
        data = [float(x) for x in d["data"]]
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise yaml.constructor.ConstructorError(None, None, f"opencv-matrix needs integer rows and cols and a list "
                                                f"of numbers as data ({type(exc).__name__}: {exc})",
                                                node.start_mark) from None
    if len(data) != rows * cols:
        raise yaml.constructor.ConstructorError(None, None, f"opencv-matrix has {len(data)} values, "
                                                f"expected {rows}x{cols}", node.start_mark)
    return np.array(data).reshape(rows, cols).tolist()


_KalibrLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)
_KalibrLoader.add_constructor("!opencv-matrix", _opencv_matrix)


def load_kalibr_yaml(path) -> dict:
    """Parse a Kalibr YAML file (plain YAML or OpenCV FileStorage ``%YAML:1.0``)."""
    src = str(path)
    text = read_text(path, what="Kalibr file", max_bytes=YAML_MAX_BYTES)
    text = re.sub(r"\A\s*%YAML[:\s]\s*1\.\d+[^\n]*\n", "", text)  # OpenCV's directive is not valid YAML 1.1
    data = yaml_from_text(text, src, loader=_KalibrLoader)
    if not isinstance(data, dict):
        raise InputError(src, "expected a mapping with cam0, cam1, ... at the top level")
    return data


def _camera_keys(src, data) -> list:
    keys = sorted((k for k in data if re.fullmatch(r"cam\d+", str(k))), key=lambda k: int(str(k)[3:]))
    if not keys:
        raise InputError(src, "no cameras found (expected top-level keys cam0, cam1, ...)")
    for i, k in enumerate(keys):
        if k != f"cam{i}":
            raise InputError(src, f"cameras must be numbered cam0, cam1, ... without gaps; found {k} after "
                                  f"{keys[i - 1] if i else 'nothing'}", str(k))
    return keys


def _transform(src, fld, value) -> np.ndarray:
    try:
        T = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(src, f"expected a 4x4 matrix of numbers, got {value!r}", fld) from None
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(src, f"expected a finite 4x4 matrix, got shape {T.shape}", fld)
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        raise InputError(src, f"last row must be [0, 0, 0, 1], got {T[3].tolist()}", fld)
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise InputError(src, "the rotation part is not a rotation matrix", fld)
    U, _, Vt = np.linalg.svd(R)  # remove rounding of printed matrices
    T[:3, :3] = U @ Vt
    return T


def _inverse(T: np.ndarray) -> np.ndarray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def _numbers(src, fld, value, lengths) -> list:
    if not isinstance(value, (list, tuple)):
        raise InputError(src, f"expected a list of numbers, got {value!r}", fld)
    try:
        out = [float(x) for x in value]
    except (TypeError, ValueError):
        raise InputError(src, f"expected numbers, got {value!r}", fld) from None
    if len(out) not in lengths:
        raise InputError(src, f"expected {' or '.join(map(str, lengths))} numbers, got {len(out)}", fld)
    return out


def _camera(src, key, d) -> dict:
    """Intrinsics of one Kalibr camera as the docs/CONVENTIONS.md (Files) fields (no extrinsics yet)."""
    if not isinstance(d, dict):
        raise InputError(src, "expected a mapping", key)
    for fld in ("camera_model", "intrinsics", "resolution"):
        if fld not in d:
            raise InputError(src, "missing required field", f"{key}.{fld}")
    model = str(d["camera_model"])
    if model not in SUPPORTED_CAMERA_MODELS:
        what = _KNOWN_UNSUPPORTED.get(model, f"camera model {model!r}")
        raise InputError(src, f"{what} is not supported (supported: pinhole with radtan, equidistant or none "
                              f"distortion)", f"{key}.camera_model")
    dist_model = str(d.get("distortion_model", "none"))
    if dist_model not in _DISTORTIONS:
        what = _KNOWN_UNSUPPORTED.get(dist_model, f"distortion model {dist_model!r}")
        raise InputError(src, f"{what} is not supported (supported: {', '.join(_DISTORTIONS)})",
                         f"{key}.distortion_model")
    spec_model, lengths = _DISTORTIONS[dist_model]
    coeffs = _numbers(src, f"{key}.distortion_coeffs", d.get("distortion_coeffs", []) or [], lengths)
    intr = _numbers(src, f"{key}.intrinsics", d["intrinsics"], (4,))
    res = _numbers(src, f"{key}.resolution", d["resolution"], (2,))
    return {
        "name": str(key),
        "image_topic": str(d.get("rostopic", f"/{key}/image_raw")),
        "model": spec_model,
        "intrinsics": intr,
        "distortion": coeffs,
        "resolution": [int(round(x)) for x in res],
    }


def rig_from_kalibr(camchain, imu_chain=None, body_frame: str = "cam0", imu_topic: str = "/imu/data",
                    frame_id: str = "base_link") -> tuple[Rig, list]:
    """Rig (docs/CONVENTIONS.md (Files)) from a Kalibr camchain and optional camchain-imucam; returns (rig, notes).

    ``body_frame`` is ``camN`` or ``imu``. Every bar is rigid (Kalibr has no
    bar model); the notes say what the user still has to fill in.
    """
    src = str(camchain)
    data = load_kalibr_yaml(camchain)
    keys = _camera_keys(src, data)
    cams = [_camera(src, k, data[k]) for k in keys]
    # Chain: T_ci_c0 maps cam0 points into cam i.
    T_ci_c0 = [np.eye(4)]
    for i in range(1, len(keys)):
        fld = f"{keys[i]}.T_cn_cnm1"
        if "T_cn_cnm1" not in data[keys[i]]:
            raise InputError(src, "missing chained extrinsics (needed for every camera after cam0)", fld)
        T_ci_c0.append(_transform(src, fld, data[keys[i]]["T_cn_cnm1"]) @ T_ci_c0[-1])
    # IMU: T_cam_imu of the imu chain (preferred) or of the camchain, for any camera; chained to cam0.
    sources = [(src, data)]
    if imu_chain:
        imu_data = load_kalibr_yaml(imu_chain)
        _camera_keys(str(imu_chain), imu_data)
        sources.insert(0, (str(imu_chain), imu_data))
        imu_d = imu_data.get("imu0")
        if isinstance(imu_d, dict) and imu_d.get("rostopic"):
            imu_topic = str(imu_d["rostopic"])
    T_c0_imu, imu_src = None, None
    for path, d in sources:
        hits = [i for i, k in enumerate(keys) if isinstance(d.get(k), dict) and "T_cam_imu" in d[k]]
        if hits:
            i = hits[0]
            T = _transform(path, f"{keys[i]}.T_cam_imu", d[keys[i]]["T_cam_imu"])
            T_c0_imu, imu_src = _inverse(T_ci_c0[i]) @ T, path
            break
    if imu_chain and T_c0_imu is None:
        raise InputError(str(imu_chain), "no camera has T_cam_imu", "cam0.T_cam_imu")
    # Body frame: T_b_c0 maps cam0 points into the body frame.
    if body_frame == "imu":
        if T_c0_imu is None:
            raise InputError(src, "body frame 'imu' needs T_cam_imu (an IMU chain: camchain-imucam.yaml)", "T_cam_imu")
        T_b_c0 = _inverse(T_c0_imu)
    elif body_frame in keys:
        T_b_c0 = T_ci_c0[keys.index(body_frame)]
    else:
        raise OptionError("Kalibr import", "body_frame",
                          f"must be 'imu' or one of {', '.join(keys)}, got {body_frame!r}")
    for cam, T_ci in zip(cams, T_ci_c0):
        T_b_ci = T_b_c0 @ _inverse(T_ci)
        cam["position"] = [float(x) for x in T_b_ci[:3, 3]]
        cam["rotation_xyzw"] = [float(x) for x in matrix_to_quat_xyzw(T_b_ci[:3, :3])]
    out = {"body_frame": frame_id, "gravity_magnitude": 9.81, "cameras": cams}
    notes = [f"body frame '{frame_id}' at {body_frame} of {src}"]
    if T_c0_imu is not None:
        R_b_imu = (T_b_c0 @ T_c0_imu)[:3, :3]
        out["imu"] = {"topic": imu_topic, "mount": "body",
                      "rotation_xyzw": [float(x) for x in matrix_to_quat_xyzw(R_b_imu)]}
        notes.append(f"IMU {imu_topic} from T_cam_imu of {imu_src}, mounted rigidly on the body "
                     "(set imu.mount to a camera name if it sits on a flexible bar)")
    else:
        notes.append("no T_cam_imu: no imu block (4pt-bending will need gravity from elsewhere)")
    notes.append("all bars are RIGID: Kalibr does not know them. Fill in 'bar: {mass: KG, EI: N_M2}' for every "
                 "camera on a flexible bar, otherwise gravity is unobservable and the bending methods report none")
    notes.append("the rotations are taken as exact: add each camera's 'rotation_std_deg' (how well the calibration "
                 "knows it, e.g. 0.05) and the estimates take its error as an unknown (docs/PIPELINE.md, \"The rig "
                 "file's calibration\")")
    return rig_from_dict(out, source=src), notes
