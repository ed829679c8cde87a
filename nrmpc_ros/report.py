"""The recording's report: one self-contained HTML page of what the pipeline saw and did (``nrmpc report``,
``nrmpc replay --report``; README, "Command line").

Everything comes from the one pipeline run of the replay (:class:`ReportData`, :func:`collect`): the holds it
closed (``Pipeline.hold_log``: each one's settling series, measurement and estimate), its counters and dropped
inputs, the bag's IMU and ground truth (:class:`~nrmpc_ros.frontend.reference.Reference`). :func:`write_report`
draws the figures with matplotlib (:mod:`nrmpc_ros.plots`, Agg) as PNG embedded in base64 and builds the page
with the standard library (``html.escape``, ``string.Template``): no script, no stylesheet or font from
elsewhere, no URL; it opens from a file without a network.

Sections: the timeline (holds shaded, the IMU stillness statistic), per hold the settling (each camera's image
offset, the bar periods, the fitted decay of the ringing) and the measurement (frames used, noise before and
after averaging), gravity per hold against the IMU and the ground truth with the 2-std band, the holds seen
from above, the bar calibration when it ran, and every refused input, frame and hold by reason.
"""

from __future__ import annotations

import base64
import html
import io
import math
import string
from dataclasses import dataclass, field

import numpy as np

from .core.attitude import roll_pitch_from_gravity, tangent_covariance
from .core.rig import Rig
from .core.so3 import angle_between
from .frontend.drops import sorted_counts
from .frontend.evaluation import Evaluation
from .frontend.imu_reference import ImuReference
from .frontend.outputs import origin_pose
from .frontend.pipeline import HoldAttempt, PipelineStats
from .frontend.reference import Reference, nearest_stamp
from .frontend.zupt import ImuNoise, ZuptConfig, still_statistic
from .safeio import atomic_write

DPI = 72  # figures are read on a screen; the page stays small
BAND_SIGMAS = 2.0
SETTLING_COLUMNS = 3
MIN_DECAY = 0.1  # a fitted envelope must fall by this share over the periods it spans to be called a decay
SETTLING_PER_FIGURE = 12  # holds per settling figure (one PNG each: the page's cost grows with the figures)
HOLD_COLOURS = {"estimated": "tab:green", "origin": "tab:blue", "refused": "tab:red"}


@dataclass
class Decay:
    """The ringing's envelope fitted over whole bar periods: offset = amplitude exp(-(t - t0) / tau)."""

    amplitude_px: float
    tau_s: float
    t0: float
    periods: int  # bar periods the fit used

    def at(self, t) -> np.ndarray:
        return self.amplitude_px * np.exp(-(np.asarray(t, dtype=float) - self.t0) / self.tau_s)


@dataclass
class ReportData:
    """What the page shows (see the module docstring); ``drops`` maps (source, Drop) to a count."""

    bag: str
    rig: Rig
    method: str
    attempts: list  # HoldAttempt, in order
    stats: PipelineStats
    drops: dict
    ref: Reference
    evaluation: Evaluation | None
    bar_period_s: float
    imu_noise: ImuNoise | None = None
    zupt: ZuptConfig = field(default_factory=ZuptConfig)
    calibration: str | None = None  # the bar calibration's description when it ran
    notes: list = field(default_factory=list)


def collect(bag: str, runner, drops: dict, ref: Reference, evaluation: Evaluation | None,
            calibration: str | None = None) -> ReportData:
    """The report's data from a :class:`~nrmpc_ros.frontend.runner.PipelineRunner` that ran a bag with its
    pipeline's ``hold_log`` kept (a list)."""
    p = runner.pipeline
    if p.hold_log is None:
        raise ValueError("the pipeline did not keep its hold log (set pipeline.hold_log = [] before the run)")
    noise = p.zupt.noise if p.rig.imu is not None and len(p.imu) else None
    return ReportData(bag, p.rig, runner.method, list(p.hold_log), runner.stats, dict(drops), ref, evaluation,
                      p.bar_period_s, noise, p.zupt.config, calibration)


def fit_decay(t: np.ndarray, offset_px: np.ndarray, start: float, period_s: float) -> Decay | None:
    """The exponential envelope of a hold's ringing: the largest camera offset per whole bar period after the stop,
    a straight line through their logarithms (least squares). None with fewer than three periods, or an envelope
    that does not fall: by at least ``MIN_DECAY`` over the periods fitted and by more than twice the slope's
    standard error."""
    if not period_s > 0 or len(t) < 3:
        return None
    dev = np.nanmax(np.where(np.isfinite(offset_px), offset_px, -np.inf), axis=1)
    k = np.floor((t - start) / period_s).astype(int)
    ok = np.isfinite(dev) & (dev > 0) & (k >= 0)
    if not ok.any():
        return None
    bins = np.unique(k[ok])
    if len(bins) < 3:
        return None
    peak = np.array([dev[ok & (k == b)].max() for b in bins])  # one per period: a handful, not per frame
    tp = np.array([t[ok & (k == b)][np.argmax(dev[ok & (k == b)])] for b in bins])
    x, y = tp - start, np.log(peak)
    (slope, icpt), res, *_ = np.polyfit(x, y, 1, full=True)
    span = float(x.max() - x.min())
    dof = len(x) - 2
    se = math.sqrt(float(res[0]) / dof / float(np.sum((x - x.mean()) ** 2))) if dof > 0 and len(res) else 0.0
    if not (slope + 2.0 * se < 0 and slope * span < math.log(1 - MIN_DECAY)):  # it falls, beyond its own spread
        return None
    return Decay(float(np.exp(icpt)), float(-1.0 / slope), float(start), int(len(bins)))


# --------------------------------------------------------------------------- figures
def _png(fig) -> str:
    from .plots import pyplot

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=DPI)
    finally:
        pyplot().close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _t0(data: ReportData) -> float:
    stamps = [a.start for a in data.attempts]
    if data.ref.has_imu:
        stamps.append(float(data.ref.imu_t[0]))
    return min(stamps) if stamps else 0.0


def _kind(a: HoldAttempt) -> str:
    if a.estimate is not None:
        return "estimated"
    return "origin" if a.hold is not None and a.index == 0 else "refused"


def _log_axis(ax) -> None:
    """A log y axis with a few plain decade labels (tick text is most of a figure's drawing time)."""
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullLocator

    ax.set_yscale("log")
    ax.yaxis.set_major_locator(LogLocator(numticks=5))
    ax.yaxis.set_minor_locator(NullLocator())
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))


def timeline_figure(data: ReportData) -> str:
    from .plots import figure

    fig, ax = figure(1, 1, figsize=(10, 2.8))
    t0 = _t0(data)
    if data.ref.has_imu and data.imu_noise is not None:
        stat = still_statistic(data.ref.imu_t, data.ref.imu_a, data.ref.imu_w, data.imu_noise, data.zupt)
        ax.plot(data.ref.imu_t - t0, np.where(stat > 0, stat, np.nan), lw=0.6, color="k",
                label="IMU stillness statistic (test / threshold)")
        _log_axis(ax)
        ax.axhline(1.0, color="k", ls=":", lw=0.8, label="still below 1")
    else:
        ax.set_yticks([])
        ax.text(0.01, 0.9, "no IMU: the images decided", transform=ax.transAxes, fontsize=8)
    seen = set()
    for a in data.attempts:
        kind = _kind(a)
        ax.axvspan(a.start - t0, a.end - t0, color=HOLD_COLOURS[kind], alpha=0.15, lw=0,
                   label=None if kind in seen else f"hold: {kind}")
        seen.add(kind)
        if a.hold is not None:
            ax.axvspan(a.hold.settled_start - t0, max(a.hold.settled_end, a.hold.settled_start + 1e-3) - t0,
                       color=HOLD_COLOURS[kind], alpha=0.35, lw=0)
    ax.set_xlabel(f"time (s) from {t0:.3f}", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="upper right", ncol=3)
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.17, top=0.96)
    return _png(fig)


def settling_figure(data: ReportData, holds: list) -> str:
    """One panel per hold of ``holds`` ([(title, HoldAttempt, Decay or None)], each with a settling series), three
    to a row: each camera's offset from its rest position since the stop (symmetric log scale), the bar periods
    (dashed), the settle time (dotted), the threshold (red), the frames averaged (green) and the fitted decay."""
    from .plots import figure

    rows = (len(holds) + SETTLING_COLUMNS - 1) // SETTLING_COLUMNS
    fig, axes = figure(rows, SETTLING_COLUMNS, figsize=(11, 2.3 * rows), squeeze=False)  # see height below
    for ax in axes.ravel()[len(holds):]:
        ax.set_visible(False)
    for ax, (title, a, decay) in zip(axes.ravel(), holds):
        s = a.hold.settling
        t = s.t - a.start
        floor = 0.01 * s.threshold_px  # a frame at its rest position (offset 0) shows at the axis' floor
        for i, cam in enumerate(data.rig.cameras):
            if np.isfinite(s.offset_px[:, i]).any():
                ax.plot(t, np.maximum(s.offset_px[:, i], floor), ".-", ms=2, lw=0.7, label=cam.name)
        if data.bar_period_s > 0:
            for k in range(1, int(t[-1] / data.bar_period_s) + 1):
                ax.axvline(k * data.bar_period_s, color="0.7", lw=0.5, ls="--")
        ax.axvline(s.settle_after - a.start, color="k", lw=0.8, ls=":", label="settled from")
        ax.axhline(s.threshold_px, color="tab:red", lw=0.8, ls=":", label="settled below")
        ax.axvspan(a.hold.settled_start - a.start, a.hold.settled_end - a.start, color="tab:green", alpha=0.12,
                   lw=0, label="averaged")
        if decay is not None:
            ax.plot(t, decay.at(s.t), color="k", lw=0.8, label=f"decay {decay.tau_s:.2f} s")
        _log_axis(ax)
        ax.set_title(title, fontsize=8)
        ax.tick_params(labelsize=6)
    if holds:
        axes[0, 0].legend(fontsize=5, ncol=2, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("time since the stop (s)", fontsize=7)
    for ax in axes[:, 0]:
        ax.set_ylabel("offset (px)", fontsize=7)
    height = 2.3 * rows  # inches: margins of 0.45 in below and 0.25 in above
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.45 / height, top=1 - 0.25 / height, wspace=0.18, hspace=0.45)
    return _png(fig)


def _gravity_rows(data: ReportData) -> list:
    """Per estimated hold with gravity: (time, error vs IMU, vs ground truth, 2-std (deg), roll, pitch and their
    2-std (deg), IMU roll, pitch, ground-truth roll, pitch)."""
    out = []
    t0 = _t0(data)
    imu_ref = ImuReference(data.ref, data.rig, data.zupt) if data.ref.has_imu else None
    for a in data.attempts:
        e = a.estimate
        if e is None or e.gravity is None:
            continue
        g = np.asarray(e.gravity, dtype=float)
        g_imu = imu_ref.gravity_at(e.stamp) if imu_ref is not None else None
        if g_imu is None and e.imu_gravity is not None:
            g_imu = np.asarray(e.imu_gravity, dtype=float)
        j = nearest_stamp(data.ref.grav_t, e.stamp)
        g_gt = None if j is None else data.ref.grav_g[j]
        cov = e.cov_gravity if e.cov_gravity is not None and np.all(np.isfinite(e.cov_gravity)) else None
        roll, pitch, _, cov_rp = roll_pitch_from_gravity(g, tangent_covariance(g, cov) if cov is not None else None)
        sd = np.degrees(np.sqrt(np.diag(cov_rp))) if cov_rp is not None else np.full(2, np.nan)
        rp_imu = roll_pitch_from_gravity(g_imu)[:2] if g_imu is not None else (math.nan, math.nan)
        rp_gt = roll_pitch_from_gravity(g_gt)[:2] if g_gt is not None else (math.nan, math.nan)
        err = [math.degrees(float(angle_between(g, x))) if x is not None else math.nan for x in (g_imu, g_gt)]
        out.append((e.stamp - t0, *err, BAND_SIGMAS * e.gravity_sigma_deg, math.degrees(roll), math.degrees(pitch),
                    *(BAND_SIGMAS * sd), *np.degrees(rp_imu), *np.degrees(rp_gt)))
    return out


def gravity_figure(rows: list) -> str:
    from .plots import figure

    r = np.array(rows, dtype=float)
    fig, axes = figure(1, 2, figsize=(10, 3))
    t = r[:, 0]
    ax = axes[0]
    order = np.argsort(t)
    ax.fill_between(t[order], 0.0, r[order, 3], color="C0", alpha=0.2, lw=0, label=f"{BAND_SIGMAS:g} std")
    ax.plot(t, r[:, 1], "s", ms=4, color="C1", label="vs IMU")
    if np.isfinite(r[:, 2]).any():
        ax.plot(t, r[:, 2], "o", ms=4, color="C2", label="vs ground truth")
    ax.set_ylabel("gravity error (deg)", fontsize=8)
    ax.set_xlabel("hold time (s)", fontsize=8)
    ax.legend(fontsize=7)
    ax = axes[1]
    for col, sd, imu, gt, name, c in ((4, 6, 8, 10, "roll", "C0"), (5, 7, 9, 11, "pitch", "C3")):
        ax.errorbar(t, r[:, col], yerr=r[:, sd], fmt="o", ms=3, color=c, capsize=2,
                    label=f"{name} +-{BAND_SIGMAS:g} std")
        ax.plot(t, r[:, imu], "x", color=c, ms=5, label=f"{name} IMU")
        if np.isfinite(r[:, gt]).any():
            ax.plot(t, r[:, gt], "+", color="k", ms=6, label=f"{name} ground truth")
    ax.set_ylabel("deg", fontsize=8)
    ax.set_xlabel("hold time (s)", fontsize=8)
    ax.legend(fontsize=6, ncol=3)
    for ax in axes:
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3, lw=0.3)
    fig.subplots_adjust(left=0.07, right=0.99, bottom=0.16, top=0.96, wspace=0.2)
    return _png(fig)


def trajectory_figure(data: ReportData) -> str:
    """The holds in their sequence's origin frame, levelled once gravity is known, seen from above (x, y)."""
    from .plots import figure

    fig, ax = figure(1, 1, figsize=(5, 4))
    seqs: dict = {}
    for a in data.attempts:
        if a.index == 0 and a.sequence is not None:
            seqs.setdefault(a.sequence, []).append((0, np.zeros(3)))
        if a.estimate is not None:
            _, _, t, _ = origin_pose(a.estimate)
            seqs.setdefault(a.estimate.sequence, []).append((a.estimate.hold_index, t))
    for s, pts in sorted(seqs.items()):
        pts.sort(key=lambda p: p[0])
        xy = np.array([p[1][:2] for p in pts])
        ax.plot(xy[:, 0], xy[:, 1], "o-", ms=4, lw=0.8, label=f"sequence {s}")
        for k, (x, y) in zip([p[0] for p in pts], xy):
            ax.annotate(str(k), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3, lw=0.3)
    if seqs:
        ax.legend(fontsize=7)
    fig.subplots_adjust(left=0.15, right=0.97, bottom=0.13, top=0.97)
    return _png(fig)


# --------------------------------------------------------------------------- page
PAGE = string.Template("""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>$title</title>
<style>
body { font: 14px/1.4 sans-serif; margin: 1.5em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
h3 { font-size: 1em; margin-bottom: 0.2em; }
table { border-collapse: collapse; margin: 0.5em 0; } td, th { border: 1px solid #ccc; padding: 2px 6px; }
th { background: #f0f0f0; } td.n { text-align: right; font-variant-numeric: tabular-nums; }
img { max-width: 100%; display: block; } .hold { display: inline-block; vertical-align: top; margin: 0 1em 1em 0; }
.note { color: #555; }
</style></head>
<body>
<h1>$title</h1>
<p class="note">$summary</p>
$sections
</body></html>
""")


def _fig(b64: str, alt: str) -> str:
    return f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{b64}"></figure>'


def _table(header: list, rows: list) -> str:
    def cell(v):
        if isinstance(v, float):
            return f'<td class="n">{"" if not math.isfinite(v) else f"{v:.3g}"}</td>'
        if isinstance(v, int):
            return f'<td class="n">{v}</td>'
        return f"<td>{html.escape(str(v))}</td>"

    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(cell(v) for v in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _section(key: str, title: str, body: str) -> str:
    return f'<section id="{key}"><h2>{html.escape(title)}</h2>\n{body}\n</section>'


SECTIONS = ("timeline", "holds", "gravity", "trajectory", "calibration", "refused")


def render_html(data: ReportData) -> str:
    """The page (see the module docstring)."""
    esc = html.escape
    parts = []
    kinds = [_kind(a) for a in data.attempts]
    parts.append(_section("timeline", "Timeline", _fig(timeline_figure(data), "timeline") + (
        "<p class='note'>Shaded: each hold from the stop to its last frame (green estimated, blue a sequence's "
        "origin, red refused), darker its averaged frames. The line is the IMU's windowed zero-velocity test "
        "over its threshold: below 1 the rig is still (docs/PIPELINE.md, Holds).</p>")))
    panels, rows = [], []
    t0 = _t0(data)
    for n, a in enumerate(data.attempts):
        h = a.hold
        title = f"hold {a.index}" if a.index is not None else f"closed hold {n}"
        if a.sequence is not None:
            title += f", sequence {a.sequence}"
        d = fit_decay(h.settling.t, h.settling.offset_px, a.start, data.bar_period_s) if h and h.settling else None
        if h is not None and h.settling is not None:
            panels.append((f"{title} ({kinds[n]})", a, d))
        e = a.estimate
        if h is None:
            rows.append((title, kinds[n], a.start - t0, f"0 / {a.frames}", math.nan, math.nan, math.nan, math.nan,
                         "", "", "", a.why))
            continue
        rows.append((title, kinds[n], a.start - t0, f"{h.settled_frames} / {h.frames}", h.settle_s,
                     h.residual_px, h.noise_px, h.averaged_noise_px, "yes" if h.ringing else "no",
                     d.tau_s if d else "", f"{e.method}, {e.num_inliers}" if e else "",
                     f"{e.gravity_sigma_deg:.3g}" if e else a.why))
    figs = "".join(_fig(settling_figure(data, panels[k:k + SETTLING_PER_FIGURE]), "settling of the holds")
                   for k in range(0, len(panels), SETTLING_PER_FIGURE))
    table = _table(["hold", "kind", "stop (s)", "frames averaged / all", "settled after (s)", "residual (px)",
                    "noise per frame (px)", "noise averaged (px)", "ringing at the end", "decay time (s)",
                    "method, inliers", "gravity std (deg) or why not"], rows)
    period = (f"slowest bar period {data.bar_period_s:.3f} s" if data.bar_period_s > 0 else "a rigid rig")
    parts.append(_section("holds", "Holds: settling and measurement", (
        f"<p class='note'>Each camera's image offset from its rest position after the stop ({period}, dashed: "
        "its periods); frames count from the settle time once below the threshold; the black line is the "
        "envelope of the ringing fitted over whole periods. The table gives each hold's measurement: frames "
        "averaged, the track noise of one frame and of the average.</p>") + figs + (
        table if rows else "<p>no hold was closed</p>")))
    grav = _gravity_rows(data)
    if grav:
        table = _table(["hold time (s)", "vs IMU (deg)", "vs ground truth (deg)", f"{BAND_SIGMAS:g} std (deg)"],
                       [tuple(float(x) for x in r[:4]) for r in grav])
        within = []
        for col, name in ((1, "the IMU"), (2, "the ground truth")):
            known = [r for r in grav if math.isfinite(r[col])]
            if known:
                inside = sum(1 for r in known if r[col] <= r[3])
                within.append(f"{inside} of {len(known)} holds within {BAND_SIGMAS:g} std of {name}")
        note = ("<p class='note'>The IMU's gravity is its accelerometer averaged over the still samples around "
                "the hold, its own tilt included; the estimate's std is what it promises against the truth.</p>")
        body = _fig(gravity_figure(grav), "gravity per hold") + (
            f"<p>{'; '.join(within)}.</p>" if within else "") + note + table
    else:
        body = "<p>no hold was estimated with gravity</p>"
    parts.append(_section("gravity", "Gravity per hold", body))
    parts.append(_section("trajectory", "Holds seen from above", _fig(trajectory_figure(data), "trajectory") +
                          "<p class='note'>Positions in each sequence's origin frame (levelled once gravity is "
                          "known), numbered by hold.</p>"))
    parts.append(_section("calibration", "Bar calibration", f"<pre>{esc(data.calibration)}</pre>"
                          if data.calibration else "<p>not run (nrmpc calibrate-bars BAG --rig RIG)</p>"))
    refused = [("pipeline", k.message, int(v)) for k, v in sorted_counts(data.stats.dropped)]
    refused += [(src, reason.message, int(n)) for (src, reason), n in sorted_counts(data.drops)]
    parts.append(_section("refused", "Refused inputs, frames and holds", _table(["where", "reason", "count"], refused)
                          if refused else "<p>nothing was refused</p>"))
    st = data.stats
    summary = (f"{esc(data.bag)}: {st.frames} frame sets, {len(data.attempts)} holds closed, {st.holds} measured, "
               f"{st.estimates} estimated ({esc(', '.join(f'{m}: {n}' for m, n in sorted(st.methods.items())))}"
               f"), {st.sequences} sequences; method {esc(data.method)}; rig {esc(data.rig.source)} "
               f"({data.rig.num_cameras} cameras)")
    return PAGE.substitute(title=esc(f"nrmpc report: {data.bag}"), summary=summary, sections="\n".join(parts))


def write_report(data: ReportData, path, flag: str | None = None) -> int:
    """Write the page to ``path`` atomically; returns its size in bytes."""
    text = render_html(data)
    with atomic_write(path, flag=flag) as fh:
        fh.write(text)
    return len(text.encode("utf-8"))


__all__ = ["Decay", "ReportData", "SECTIONS", "collect", "fit_decay", "render_html", "write_report"]
