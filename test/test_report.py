"""nrmpc report / replay --report: one self-contained HTML page of the bundled sample (every section and figure, no
external reference, small), the fitted decay of the ringing, and (slow) the page in a headless Chromium: no
console error, no request leaving the file, a screenshot that is not blank."""

from __future__ import annotations

import base64
import csv
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from headless_chromium import Chromium, find_chromium

from nrmpc_ros.cli.main import main
from nrmpc_ros.frontend.drops import Drop
from nrmpc_ros.report import SECTIONS, fit_decay

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "bags" / "sample"
RIG = REPO / "config" / "sample_cross4.yaml"
MAX_BYTES = 3_000_000


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """(html text, path, the replay's CSV rows) of the sample through ``nrmpc replay --report``."""
    tmp = tmp_path_factory.mktemp("report")
    out, rows = tmp / "sample.html", tmp / "sample.csv"
    assert main(["replay", str(SAMPLE), "--rig", str(RIG), "--out", str(rows), "--report", str(out), "--quiet",
                 "--no-progress"]) == 0
    with open(rows) as fh:
        return out.read_text(encoding="utf-8"), out, list(csv.DictReader(fh))


def test_the_page_has_every_section_and_embeds_every_figure(page):
    text, path, rows = page
    assert path.stat().st_size <= MAX_BYTES
    for key in SECTIONS:
        assert f'<section id="{key}">' in text, key
    images = re.findall(r'<img [^>]*src="([^"]*)"', text)
    assert len(images) >= 4  # timeline, settling, gravity, trajectory
    for src in images:
        assert src.startswith("data:image/png;base64,")
        png = base64.b64decode(src.split(",", 1)[1], validate=True)
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 100
    # nothing from elsewhere: no URL, script, stylesheet link or CSS import
    stripped = re.sub(r'src="data:image/png;base64,[^"]*"', "", text)
    for needle in ("http:", "https:", "//", "<script", "<link", "@import", "url("):
        assert needle not in stripped.replace("<!DOCTYPE", ""), needle


def test_the_page_tells_the_replays_story(page):
    text, _, rows = page
    assert f"{len(rows)} estimated" in text
    # a table row per hold; the sequence's first hold is estimated too (with the second)
    assert text.count("<td>estimated</td>") == len(rows) and "<td>origin</td>" not in text
    assert "frame not at rest (the IMU says the rig moved)" in text  # the refusals by reason
    assert re.search(r"\d+ of \d+ holds within 2 std of the IMU; \d+ of \d+ holds within 2 std of the ground truth",
                     text)
    assert "not run (nrmpc calibrate-bars" in text


def test_nrmpc_report_writes_the_same_sections_and_the_bar_calibration(tmp_path, capsys):
    out = tmp_path / "r.html"
    assert main(["report", str(SAMPLE), "--rig", str(RIG), "--out", str(out), "--no-progress",
                 "--calibrate-bars"]) == 0
    printed = capsys.readouterr().out
    assert "wrote the report" in printed and "estimates to" not in printed  # no word of the temporary CSV
    text = out.read_text(encoding="utf-8")
    assert all(f'<section id="{key}">' in text for key in SECTIONS)
    # the sample's bars: EI 0.2 N m^2 with a 0.1 kg tip mass, compliance 0.5 kg/(N m^2)
    cal = re.findall(r"cam\d: compliance ([0-9.]+) \+- ([0-9.]+)", text)
    assert len(cal) == 4 and all(abs(float(k) - 0.5) < 4 * float(s) + 0.01 for k, s in cal), cal


def test_the_report_does_not_write_into_its_inputs(tmp_path, capsys):
    assert main(["report", str(SAMPLE), "--rig", str(RIG), "--out", str(RIG)]) == 2
    assert "nrmpc report: error: --out: " in capsys.readouterr().err
    assert main(["replay", str(SAMPLE), "--rig", str(RIG), "--out", str(tmp_path / "o.csv"), "--report",
                 str(SAMPLE / "metadata.yaml")]) == 2
    assert "nrmpc replay: error: --report: " in capsys.readouterr().err


def test_the_decay_of_a_ringing_bar_is_recovered(rng):
    period, tau = 0.5, 0.8
    t = np.arange(0.0, 4.0, 1 / 30)
    ringing = 5.0 * np.exp(-t / tau) * np.abs(np.cos(2 * math.pi * t / period))
    offsets = np.stack([ringing, 0.7 * ringing], axis=1) + rng.normal(scale=0.002, size=(len(t), 2))
    d = fit_decay(100.0 + t, np.abs(offsets), 100.0, period)
    assert d is not None and abs(d.tau_s - tau) < 0.1 * tau and d.periods == 8
    assert fit_decay(100.0 + t, np.full((len(t), 2), 0.3), 100.0, period) is None  # nothing decays
    assert fit_decay(100.0 + t[:20], np.abs(offsets[:20]), 100.0, period) is None  # fewer than three periods


@pytest.mark.slow
def test_the_page_opens_in_a_headless_chromium_without_errors(page):
    if find_chromium() is None:
        pytest.skip("chromium is not installed (apt-get install chromium; .ci/run installs it)")
    _, path, _ = page
    with Chromium() as browser:
        shown = browser.open(path)
    assert shown.errors == [], shown.errors
    assert shown.requests[0] == path.resolve().as_uri()
    assert all(u.startswith("data:image/png;base64,") for u in shown.requests[1:]), "the page asked for more"
    img = cv2.imdecode(np.frombuffer(shown.png, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img is not None and img.shape[0] > 1000  # the whole page, its figures included
    ink = np.count_nonzero(img < 200) / img.size
    assert ink > 0.02 and float(img.std()) > 10, (ink, img.std())  # text and figures, not a blank page


def test_a_vision_only_run_without_ground_truth_still_gives_every_section():
    from test_pipeline import make_stream

    from nrmpc_ros.frontend.pipeline import FrameSet, Pipeline, PipelineConfig
    from nrmpc_ros.frontend.reference import Reference
    from nrmpc_ros.frontend.runner import PipelineRunner
    from nrmpc_ros.report import collect, render_html
    from nrmpc_ros.sim.synthetic import RigSpec, make_rig

    rig = make_rig(RigSpec(num_cameras=3, layout="ring", EI=0.3, mass=0.15, bar_length=0.3, focal=235.0,
                           resolution=(320, 240)))
    frames, _ = make_stream(rig)
    pipe = Pipeline(rig, PipelineConfig(), method="6pt-bending")
    pipe.hold_log = []
    runner = PipelineRunner.around(pipe)
    for st, _, _, imgs in frames[:45]:  # three holds, the last cut short by the end of the input
        pipe.add_frames(FrameSet(st, imgs))
    pipe.flush()
    text = render_html(collect("stream <3>", runner, {("/cam0", Drop.BAD_FRAME_SET): 2}, Reference(), None))
    assert all(f'<section id="{key}">' in text for key in SECTIONS)
    assert text.count("<td>estimated</td>") == 3 and "<td>origin</td>" not in text  # (its estimate with the 2nd)
    assert "stream &lt;3&gt;" in text and "<3>" not in text  # names are escaped
    assert "<td>/cam0</td><td>bad frame set</td>" in text and "within 2 std of the IMU" not in text
