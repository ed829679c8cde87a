"""The estimates CSV: its columns (docs/CONVENTIONS.md, "Bags"), its rows, an atomic writer and a checked reader.

One schema for ``nrmpc replay`` (which writes it), ``nrmpc compare`` (which reads it) and the benchmarks.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field

import numpy as np

from ..core.so3 import matrix_to_quat_xyzw, quat_xyzw_to_matrix
from ..errors import InputError
from ..safeio import AtomicFile, MiB, read_text

CSV_HEADER = ["stamp", "ref_stamp", "method", "qx", "qy", "qz", "qw", "tx", "ty", "tz", "gx", "gy", "gz",
              "num_inliers", "time_ms"]
ORIGIN_COLUMNS = ["origin_stamp", "oqx", "oqy", "oqz", "oqw", "otx", "oty", "otz"]  # pose in the sequence origin
CSV_EXTRA = ["gravity_sigma_deg", "num_observations", *ORIGIN_COLUMNS, "sequence", "hold", "window", "hold_frames",
             "settled_frames", "settle_s", "residual_px", "noise_px", "averaged_noise_px", "links_klt",
             "links_descriptor", "ringing_px", "ringing_source", "noise_scale", "imu_calibrated_weight"]
CSV_MAX_BYTES = 256 * MiB  # a row per hold is ~500 bytes: half a million holds, far beyond any recording


@dataclass
class EstimateRow:
    """One CSV row: pose of the current hold in the reference hold, gravity in the current body frame."""

    stamp: float
    ref_stamp: float
    method: str
    R: np.ndarray
    t: np.ndarray
    gravity: np.ndarray | None
    num_inliers: int
    time_ms: float
    extra: dict = field(default_factory=dict)
    origin: tuple | None = None  # (origin stamp, R, t): the hold's pose in the sequence origin


def row_from_estimate(e) -> EstimateRow:
    """A :class:`~nrmpc_ros.frontend.pipeline.HoldEstimate` as a CSV row."""
    h = e.hold
    extra = {"gravity_sigma_deg": e.gravity_sigma_deg, "num_observations": e.num_observations,
             "sequence": e.sequence, "hold": e.hold_index, "window": e.window, "hold_frames": h.frames,
             "settled_frames": h.settled_frames, "settle_s": h.settle_s, "residual_px": h.residual_px,
             "noise_px": h.noise_px, "averaged_noise_px": h.averaged_noise_px,
             "links_klt": e.links.get("klt", 0), "links_descriptor": e.links.get("descriptor", 0),
             "ringing_px": h.ringing_px, "ringing_source": h.ringing_source.value, "noise_scale": e.noise_scale,
             "imu_calibrated_weight": e.imu_calibrated_weight}
    g = None if e.gravity is None else np.asarray(e.gravity)
    return EstimateRow(e.stamp, e.ref_stamp, e.method, np.asarray(e.R), np.asarray(e.t), g, int(e.num_inliers),
                       float(e.time_ms), extra, (e.origin_stamp, np.asarray(e.R_origin), np.asarray(e.t_origin)))


def batch_rows(batch: list, method: str) -> list:
    """CSV rows of a joint solution of every hold ((stamp, R_origin, t_origin, gravity, sigma_deg) per hold,
    origin first, see Pipeline.batch): each hold relative to the one before it."""
    rows = []
    for (s0, R0, t0, _, _), (s1, R1, t1, g, sig) in zip(batch[:-1], batch[1:]):
        rows.append(EstimateRow(s1, s0, method, R0.T @ R1, R0.T @ (t1 - t0), g, 0, 0.0,
                                {"gravity_sigma_deg": sig}, (batch[0][0], R1, t1)))
    return rows


def _fmt(x) -> str:
    if isinstance(x, str):
        return x
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return ""
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    return repr(float(x))


class CsvWriter:
    """Writes estimate rows (the header of docs/CONVENTIONS.md, then the extra columns), one flush per row.

    The rows go to a temporary file beside ``path`` (:class:`~nrmpc_ros.safeio.AtomicFile`), flushed after
    every row so a long run's progress can be watched there; :meth:`close` renames it onto ``path`` and
    :meth:`discard` drops it, leaving an earlier ``path`` as it was. As a context manager it closes when the
    block ends normally and discards when it raises. ``flag`` names the option in errors.
    """

    def __init__(self, path, flag: str | None = None):
        self.path = str(path)
        self._out = AtomicFile(path, "w", flag=flag, newline="")
        self._f = self._out.file
        self._w = csv.writer(self._f)
        self._w.writerow(CSV_HEADER + CSV_EXTRA)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.discard()
        return False

    def write(self, row: EstimateRow) -> None:
        q = matrix_to_quat_xyzw(row.R)
        g = [None] * 3 if row.gravity is None else list(row.gravity)
        vals = [row.stamp, row.ref_stamp, row.method, *q, *row.t, *g, row.num_inliers, row.time_ms]
        origin = dict.fromkeys(ORIGIN_COLUMNS)
        if row.origin is not None:
            s0, R0, t0 = row.origin
            origin.update(zip(ORIGIN_COLUMNS, [s0, *matrix_to_quat_xyzw(R0), *t0]))
        vals += [origin[k] if k in origin else row.extra.get(k) for k in CSV_EXTRA]
        self._w.writerow([_fmt(v) for v in vals])
        self._f.flush()

    def close(self) -> None:
        """Finish the file: the rows written so far become ``path``."""
        self._out.commit()

    def discard(self) -> None:
        """Drop the rows: ``path`` keeps what it held before (or stays absent)."""
        self._out.discard()


def read_csv(path) -> list:
    """Rows of an estimates CSV; InputError naming the file, line and column when malformed.

    Read through :func:`nrmpc_ros.safeio.read_text`: UTF-8 text of at most ``CSV_MAX_BYTES``.
    """
    src = str(path)
    text = read_text(path, what="estimates CSV", max_bytes=CSV_MAX_BYTES)
    rows = []
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader, None)
        if header is None or header[: len(CSV_HEADER)] != CSV_HEADER:
            raise InputError(src, f"not an estimates CSV: the header must start with {','.join(CSV_HEADER)}",
                             "header")
        if len(set(header)) != len(header):
            raise InputError(src, "not an estimates CSV: a column name repeats", "header")
        for rec in reader:
            if rec:
                rows.append(_row(src, reader.line_num, rec, header))
    except csv.Error as exc:
        raise InputError(src, f"line {reader.line_num}: not valid CSV ({exc})") from None
    return rows


def _row(src: str, line: int, rec: list, header: list) -> EstimateRow:
    if len(rec) != len(header):
        raise InputError(src, f"line {line}: {len(rec)} columns, the header has {len(header)} (a truncated or "
                              f"edited file?)")
    d = dict(zip(header, rec))

    def number(key):
        try:
            v = float(d[key])
        except ValueError:
            raise InputError(src, f"line {line}: not a number: {d[key]!r}", key) from None
        if not math.isfinite(v):
            raise InputError(src, f"line {line}: must be finite, got {d[key]!r}", key)
        return v

    num = {k: number(k) for k in CSV_HEADER if k not in ("method", "gx", "gy", "gz")}
    g = None
    if any(d[k] != "" for k in ("gx", "gy", "gz")):
        g = np.array([number(k) for k in ("gx", "gy", "gz")])
        if not np.linalg.norm(g) > 0:
            raise InputError(src, f"line {line}: gravity is a zero vector (leave gx, gy, gz empty for none)", "gx")
    if not (num["num_inliers"] >= 0 and num["num_inliers"].is_integer()):
        raise InputError(src, f"line {line}: must be an integer >= 0, got {d['num_inliers']!r}", "num_inliers")
    q = np.array([num["qx"], num["qy"], num["qz"], num["qw"]])
    if abs(np.linalg.norm(q) - 1) > 1e-3:
        raise InputError(src, f"line {line}: quaternion must have unit norm", "qx")
    origin = None
    if all(d.get(k, "") != "" for k in ORIGIN_COLUMNS):
        try:
            o = [float(d[k]) for k in ORIGIN_COLUMNS]
        except ValueError as exc:
            raise InputError(src, f"line {line}: bad origin pose ({exc})", "origin_stamp") from None
        qo = np.array(o[1:5])
        if not np.all(np.isfinite(o)) or abs(np.linalg.norm(qo) - 1) > 1e-3:
            raise InputError(src, f"line {line}: origin pose must be finite with a unit quaternion", "oqx")
        origin = (o[0], quat_xyzw_to_matrix(qo), np.array(o[5:8]))
    extra = {k: d[k] for k in header[len(CSV_HEADER):] if k in d and k not in ORIGIN_COLUMNS}
    return EstimateRow(num["stamp"], num["ref_stamp"], d["method"], quat_xyzw_to_matrix(q),
                       np.array([num["tx"], num["ty"], num["tz"]]), g, int(num["num_inliers"]), num["time_ms"],
                       extra, origin)


__all__ = ["CSV_EXTRA", "CSV_HEADER", "CSV_MAX_BYTES", "ORIGIN_COLUMNS", "CsvWriter", "EstimateRow", "batch_rows",
           "read_csv", "row_from_estimate"]
