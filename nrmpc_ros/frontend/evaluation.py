"""Scoring estimates against the IMU and a bag's ground truth; the estimates CSV (docs/CONVENTIONS.md, "Bags").

One implementation for ``nrmpc replay``'s summary and ``nrmpc compare``:
:func:`read_reference` loads the IMU and ``/ground_truth/*`` of a bag,
:func:`evaluate` computes per-estimate errors (gravity vs IMU and vs ground
truth, relative pose vs ground truth), which ground-truth holds got an
estimate and which estimates lie outside every hold, :func:`format_report`
prints them and :func:`plot_errors` draws them.
"""

from __future__ import annotations

import csv
import io
import math
import sys
from dataclasses import dataclass, field

import numpy as np

from ..core.deformation import gravity_from_accelerometer
from ..core.metrics import pose_errors
from ..core.rig import Rig
from ..core.so3 import angle_between, matrix_to_quat_xyzw, quat_xyzw_to_matrix
from ..errors import InputError
from ..safeio import AtomicFile, MiB, read_text
from .images import stamp_seconds
from .topics import IMU_TYPE, POSE_TYPE, VECTOR_TYPE, check_topic_type, same_type

CSV_HEADER = ["stamp", "ref_stamp", "method", "qx", "qy", "qz", "qw", "tx", "ty", "tz", "gx", "gy", "gz",
              "num_inliers", "time_ms"]
ORIGIN_COLUMNS = ["origin_stamp", "oqx", "oqy", "oqz", "oqw", "otx", "oty", "otz"]  # pose in the sequence origin
CSV_EXTRA = ["gravity_sigma_deg", "num_observations", *ORIGIN_COLUMNS, "sequence", "hold", "window", "hold_frames",
             "settled_frames", "settle_s", "residual_px", "noise_px", "averaged_noise_px", "links_klt",
             "links_descriptor"]
GT_POSE_TOPIC = "/ground_truth/pose"
GT_GRAVITY_TOPIC = "/ground_truth/gravity"
CSV_MAX_BYTES = 256 * MiB  # a row per hold is ~500 bytes: half a million holds, far beyond any recording
STAMP_TOLERANCE_S = 0.02  # ground truth is matched to an estimate's stamp within this (cameras may jitter)


# ---------------------------------------------------------------------------
# CSV
# ---------------------------------------------------------------------------

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
             "links_klt": e.links.get("klt", 0), "links_descriptor": e.links.get("descriptor", 0)}
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


# ---------------------------------------------------------------------------
# Reference data from a bag
# ---------------------------------------------------------------------------

@dataclass
class Reference:
    """IMU samples and ground truth of a bag (arrays sorted by stamp, seconds)."""

    imu_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    imu_a: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    imu_w: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    pose_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pose_R: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))  # body -> world
    pose_p: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    grav_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    grav_g: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # gravity in the body frame

    @property
    def has_imu(self) -> bool:
        return len(self.imu_t) > 0

    @property
    def has_pose(self) -> bool:
        return len(self.pose_t) > 0

    @property
    def has_gravity(self) -> bool:
        return len(self.grav_t) > 0


def _vec(v) -> list:
    return [float(v.x), float(v.y), float(v.z)]


def _warn(msg: str) -> None:
    print(f"nrmpc: warning: {msg}", file=sys.stderr)


def read_reference(bag, imu_topic: str | None = "/imu/data", warn=_warn) -> Reference:
    """IMU (if ``imu_topic`` is in the bag) and /ground_truth/* (if present) of a :class:`BagReader`.

    The IMU topic must carry sensor_msgs/Imu (InputError naming the topic otherwise). Ground truth is
    optional: a ground-truth topic of another type than the one nrmpc make-bag writes is ignored with one
    ``warn`` each, and so are samples that are not finite (or a pose with a zero quaternion).
    """
    if imu_topic:
        check_topic_type(bag, imu_topic, IMU_TYPE, bag.source, "the IMU", imu_topic)
    topics = [t for t in (imu_topic, GT_POSE_TOPIC, GT_GRAVITY_TOPIC) if t and bag.has_topic(t)]
    for topic, expected in ((GT_POSE_TOPIC, POSE_TYPE), (GT_GRAVITY_TOPIC, VECTOR_TYPE)):
        if topic in topics and not same_type(bag.topics[topic][0], expected):
            warn(f"{bag.source}: ground truth {topic} carries {bag.topics[topic][0]}, not {expected}: ignored")
            topics.remove(topic)
    imu, pose, grav = [], [], []
    for topic, _, msg in bag.messages(topics):
        st = stamp_seconds(msg)
        if topic == imu_topic:
            imu.append([st, *_vec(msg.linear_acceleration), *_vec(msg.angular_velocity)])
        elif topic == GT_POSE_TOPIC:
            p, o = msg.pose.position, msg.pose.orientation
            pose.append([st, p.x, p.y, p.z, o.x, o.y, o.z, o.w])
        else:
            grav.append([st, *_vec(msg.vector)])
    ref = Reference()
    if imu:
        a = np.array(imu, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        ok = np.all(np.isfinite(a), axis=1)
        ref.imu_t, ref.imu_a, ref.imu_w = a[ok, 0], a[ok, 1:4], a[ok, 4:7]
    if pose:
        a = np.array(pose, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        a = a[np.all(np.isfinite(a), axis=1) & (np.linalg.norm(a[:, 4:8], axis=1) > 1e-9)]
        ref.pose_t, ref.pose_p = a[:, 0], a[:, 1:4]
        ref.pose_R = np.array([quat_xyzw_to_matrix(q / np.linalg.norm(q)) for q in a[:, 4:8]]).reshape(-1, 3, 3)
    if grav:
        a = np.array(grav, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        a = a[np.all(np.isfinite(a), axis=1) & (np.linalg.norm(a[:, 1:4], axis=1) > 0)]
        ref.grav_t, ref.grav_g = a[:, 0], a[:, 1:4]
    return ref


def _nearest(ts: np.ndarray, t: float, tol: float = STAMP_TOLERANCE_S) -> int | None:
    if len(ts) == 0:
        return None
    i = int(np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)) if len(ts) > 1 else 0
    if len(ts) > 1 and abs(ts[i - 1] - t) <= abs(ts[i] - t):
        i -= 1
    return i if abs(ts[i] - t) <= tol else None


def imu_gravity_at(ref: Reference, stamp: float, rig: Rig | None = None, window_s: float = 0.25,
                   still_gyro: float = 0.05):
    """Body-frame gravity from the accelerometer averaged over still samples within +-window_s of ``stamp``.

    With a rig that has an ``imu`` block its mount is used (docs/CONVENTIONS.md (Gravity measurements));
    otherwise the IMU frame is taken as the body frame (g = -a). None without samples.
    """
    i, j = np.searchsorted(ref.imu_t, [stamp - window_s, stamp + window_s])
    a, w = ref.imu_a[i:j], ref.imu_w[i:j]
    still = np.linalg.norm(w, axis=1) <= still_gyro
    if still.sum() < 3:
        return None
    mean = a[still].mean(axis=0)
    if rig is not None and rig.imu is not None:
        return gravity_from_accelerometer(rig, mean)
    gm = rig.gravity_magnitude if rig is not None else 9.81
    return -gm * mean / np.linalg.norm(mean)


# ---------------------------------------------------------------------------
# Errors and statistics
# ---------------------------------------------------------------------------

METRICS = {
    "gravity_vs_gt_deg": "gravity vs ground truth (deg)",
    "gravity_vs_imu_deg": "gravity vs IMU (deg)",
    "imu_vs_gt_deg": "IMU gravity vs ground truth (deg)",
    "rotation_deg": "relative rotation vs ground truth (deg)",
    "translation_deg": "translation direction vs ground truth (deg)",
    "translation_m": "|t - t_gt| (m)",
}


@dataclass
class Evaluation:
    rows: list  # EstimateRow
    errors: dict  # metric -> (N,) array, NaN where not available
    holds: int = 0  # holds (still intervals) found in the ground truth
    holds_with_estimate: int = 0
    outside_holds: int = 0  # estimates stamped outside every ground-truth hold

    def stats(self, metric: str, method: str | None = None) -> dict:
        """n, median, mean, p90 of one metric (optionally for one method), ignoring NaN."""
        x = self.errors[metric]
        if method is not None:
            x = x[np.array([r.method == method for r in self.rows], dtype=bool)]
        x = x[np.isfinite(x)]
        if len(x) == 0:
            return {"n": 0, "median": math.nan, "mean": math.nan, "p90": math.nan}
        return {"n": int(len(x)), "median": float(np.median(x)), "mean": float(np.mean(x)),
                "p90": float(np.percentile(x, 90))}

    @property
    def methods(self) -> list:
        return sorted({r.method for r in self.rows})

    @property
    def coverage(self) -> float:
        """Fraction of the ground-truth holds (after the first) that got an estimate."""
        return self.holds_with_estimate / (self.holds - 1) if self.holds > 1 else math.nan


def static_holds(ref: Reference, tol_deg: float = 0.01, tol_m: float = 1e-4) -> list:
    """(start, end) stamps of runs of identical ground-truth poses (the rig held still)."""
    if not ref.has_pose:
        return []
    dR = np.einsum("nji,njk->nik", ref.pose_R[:-1], ref.pose_R[1:])
    ang = np.degrees(np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    same = (ang < tol_deg) & (np.linalg.norm(np.diff(ref.pose_p, axis=0), axis=1) < tol_m)
    runs, start = [], 0
    for k in range(1, len(ref.pose_t) + 1):
        if k == len(ref.pose_t) or not same[k - 1]:
            runs.append((start, k - 1))
            start = k
    min_len = 2 if any(b > a for a, b in runs) else 1
    return [(float(ref.pose_t[a]), float(ref.pose_t[b])) for a, b in runs if b - a + 1 >= min_len]


def evaluate(rows: list, ref: Reference, rig: Rig | None = None, imu_window_s: float = 0.25) -> Evaluation:
    """Per-estimate errors against the IMU and the ground truth (NaN where unavailable)."""
    n = len(rows)
    err = {k: np.full(n, np.nan) for k in METRICS}
    for k, r in enumerate(rows):
        g_imu = imu_gravity_at(ref, r.stamp, rig, imu_window_s) if ref.has_imu else None
        j = _nearest(ref.grav_t, r.stamp)
        g_gt = ref.grav_g[j] if j is not None else None
        if r.gravity is not None and g_imu is not None:
            err["gravity_vs_imu_deg"][k] = math.degrees(float(angle_between(r.gravity, g_imu)))
        if r.gravity is not None and g_gt is not None:
            err["gravity_vs_gt_deg"][k] = math.degrees(float(angle_between(r.gravity, g_gt)))
        if g_imu is not None and g_gt is not None:
            err["imu_vs_gt_deg"][k] = math.degrees(float(angle_between(g_imu, g_gt)))
        i1, i2 = _nearest(ref.pose_t, r.ref_stamp), _nearest(ref.pose_t, r.stamp)
        if i1 is not None and i2 is not None:
            R1, R2 = ref.pose_R[i1], ref.pose_R[i2]
            R_gt = R1.T @ R2
            t_gt = R1.T @ (ref.pose_p[i2] - ref.pose_p[i1])
            pe = pose_errors(r.R, r.t, R_gt, t_gt)
            err["rotation_deg"][k] = math.degrees(pe["rotation"])
            err["translation_deg"][k] = math.degrees(pe["translation"])
            err["translation_m"][k] = pe["translation_m"]
    ev = Evaluation(rows, err)
    holds = static_holds(ref)
    ev.holds = len(holds)
    stamps = np.array([r.stamp for r in rows])
    inside = np.zeros(len(stamps), bool)
    for a, b in holds:
        inside |= (stamps >= a - STAMP_TOLERANCE_S) & (stamps <= b + STAMP_TOLERANCE_S)
    ev.holds_with_estimate = sum(
        1 for a, b in holds[1:] if np.any((stamps >= a - STAMP_TOLERANCE_S) & (stamps <= b + STAMP_TOLERANCE_S)))
    ev.outside_holds = int(np.count_nonzero(~inside)) if holds else 0
    return ev


def format_report(ev: Evaluation, per_estimate: bool = True) -> str:
    """Text table of the estimates and their errors, then statistics per method and the hold coverage."""
    lines = []
    e = ev.errors
    if per_estimate and ev.rows:
        t0 = min(min(r.stamp, r.ref_stamp) for r in ev.rows)
        lines.append(f"{'stamp':>9} {'ref':>9} {'method':<15}{'inl':>5} {'ms':>6} {'g_vs_gt':>8} {'g_vs_imu':>8} "
                     f"{'imu_vs_gt':>9} {'rot':>7} {'t_dir':>6}   (times from {t0:.3f} s, errors in deg)")
        for k, r in enumerate(ev.rows):
            lines.append(f"{r.stamp - t0:9.3f} {r.ref_stamp - t0:9.3f} {r.method:<15}{r.num_inliers:5d} "
                         f"{r.time_ms:6.0f} {e['gravity_vs_gt_deg'][k]:8.3f} {e['gravity_vs_imu_deg'][k]:8.3f} "
                         f"{e['imu_vs_gt_deg'][k]:9.3f} {e['rotation_deg'][k]:7.3f} {e['translation_deg'][k]:6.2f}")
    for method in ev.methods:
        lines.append(f"{method}: {sum(r.method == method for r in ev.rows)} estimates")
        for key, label in METRICS.items():
            s = ev.stats(key, method)
            if s["n"]:
                lines.append(f"  {label:<45} median {s['median']:.3f}  mean {s['mean']:.3f}  p90 {s['p90']:.3f}"
                             f"  (n={s['n']})")
    if ev.holds:
        lines.append(f"holds in the ground truth: {ev.holds}; with an estimate (after the first): "
                     f"{ev.holds_with_estimate}/{max(ev.holds - 1, 0)}; estimates outside every hold: "
                     f"{ev.outside_holds}")
    if not ev.rows:
        lines.append("no estimates")
    return "\n".join(lines)


def plot_errors(ev: Evaluation, path, flag: str | None = None) -> None:
    """PNG: gravity error over time (vs IMU and ground truth, and the IMU's own) and relative-pose errors.

    Written atomically (:func:`~nrmpc_ros.plots.save_png`); ``flag`` names the option in errors."""
    from ..plots import draw_series, figure, save_png

    fig, axes = figure(2, 1, figsize=(9, 6), sharex=True)
    t = np.array([r.stamp for r in ev.rows])
    t = t - t.min() if len(t) else t
    e = ev.errors
    title = ", ".join(f"{m}: {sum(r.method == m for r in ev.rows)}" for m in ev.methods) or "no estimates"
    draw_series(axes[0], [(t, e[key], style, colour, METRICS[key]) for key, style, colour in (
        ("gravity_vs_gt_deg", "o-", "C0"), ("gravity_vs_imu_deg", "s--", "C0"), ("imu_vs_gt_deg", ":", "C7"))],
        "gravity error (deg)", title=title, fontsize=9)
    draw_series(axes[1], [(t, e[key], style, None, METRICS[key]) for key, style in (
        ("rotation_deg", "o-"), ("translation_deg", "s--"))], "pose error (deg)", xlabel="time (s)", fontsize=9)
    fig.tight_layout()
    save_png(fig, path, flag, dpi=100)
