"""The report's robustness section: present exactly when a run holds corrupted records, curves whose points are the
robustness summary's Acc. cells, and overlays that show the clean frame at severity 0 and the corruption above it."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from i2pbench.boards import leaderboard as lb
from i2pbench.cli import main
from i2pbench.errors import DataError
from i2pbench.registry.build import default_registry
from i2pbench.report import overlay, robustness
from i2pbench.report.rundir import load_run, open_dataset
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol

SPECS = "clean,intrinsic-error:1,intrinsic-error:5,gaussian-noise:3,beam-reduction:5"
COMBINATION = "lsd > depth+reflectance > oracle > epnp-ransac"


def oracle_run(root: Path, corruption: str | None) -> Path:
    """The oracle on two synthetic test frames (about a second per protocol), optionally under corruptions."""
    argv = ["run", "--matcher", "oracle", "--dataset", "synthetic", "--split", "test", "--frames", "2",
            "--threads", "1", "--quiet", "--runs-dir", str(root / "runs"), "--out", str(root / "lb")]  # fmt: skip
    assert main(argv + (["--corruption", corruption] if corruption else [])) == 0
    return root / "runs" / "synthetic-test"


@pytest.fixture(scope="module")
def corrupted_run(tmp_path_factory) -> Path:
    return oracle_run(tmp_path_factory.mktemp("robust"), SPECS)


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory) -> Path:
    return oracle_run(tmp_path_factory.mktemp("clean"), None)


def report(run_dir: Path, tmp_path: Path, *extra: str) -> str:
    out = tmp_path / "report.html"
    assert main(["report", str(run_dir), "--out", str(out), "--quiet", *extra]) == 0
    return out.read_text()


def test_a_clean_run_has_no_robustness_section(clean_run, tmp_path):
    assert robustness.section(load_run(clean_run)) is None
    text = report(clean_run, tmp_path)
    assert "<h2>Robustness" not in text and "<h2>Acc. against severity" not in text


def test_a_corrupted_run_has_the_summary_the_curves_and_one_overlay_per_corruption(corrupted_run, tmp_path):
    text = report(corrupted_run, tmp_path)
    tail = text[text.index("<h2>Robustness</h2>") :]
    assert "<h2>Acc. against severity</h2>" in tail and "<h2>What each corruption does</h2>" in tail
    assert "8 frame results under corruptions" in tail  # 4 corrupted protocols x 2 frames
    images = re.findall(r'<img alt="[^"]*" src="data:image/(png|jpeg);base64,', tail)
    assert images == ["png"] + ["jpeg"] * 3  # the curves, then intrinsic-error, gaussian-noise, beam-reduction
    captions = re.findall(r"<figcaption>([a-z-]+ \([a-z]+)", tail)
    assert captions == ["intrinsic-error (geometry", "gaussian-noise (image", "beam-reduction (lidar"]  # run order


def test_the_curves_are_the_summary_the_run_wrote(corrupted_run):
    """Every point of every curve is a cell of the `<out>-robustness.csv` the run wrote from the same records."""
    written = list(csv.DictReader((corrupted_run.parents[1] / "lb-robustness.csv").open()))
    curves = {c.corruption: c for c in robustness.curves(robustness.load(load_run(corrupted_run)).summary)}
    assert [r["corruption"] for r in written] == list(curves)
    for row in written:
        points = [(0, row[lb.CLEAN_ACC])] + [(s, row.get(lb.severity_column(s), "nan")) for s in range(1, 6)]
        expected = [(s, float(v)) for s, v in points if v != "nan"]
        curve = curves[row["corruption"]]
        assert list(zip(curve.severities, curve.acc, strict=True)) == expected
    assert curves["intrinsic-error"].acc == [100.0, 100.0, 0.0]  # 10 % off the focal length: no oracle survives
    assert curves["intrinsic-error"].severities == [0, 1, 5]


def records(
    corruption: str, severity: int, successes: list[bool], protocol: Protocol, combination: str = "a", first: int = 0
) -> list[dict]:
    return [
        {"dataset": "synthetic", "split": "test", "frame_id": f"f{first + i}", "combination": combination,
         "weights": "none",
         "status": "ok", "failed_component": "", "rte_m": 0.1 if ok else 9.0, "rre_deg": 1.0 if ok else 30.0,
         "geodesic_deg": 1.0, "model_size_mb": 0.0, "t_total_s": 0.01, "extractor2d": "a", "extractor3d": "b",
         "encoder2d": "none", "encoder3d": "none", "exchanger": "none", "matcher": "c", "solver": "d",
         "corruption": corruption, "severity": severity, "protocol": protocol.identity()}
        for i, ok in enumerate(successes)
    ]  # fmt: skip


@pytest.fixture
def hand_store(tmp_path) -> Path:
    """Acc. worked out by hand: clean 100 %, fog 1 50 %, fog 3 0 %, jpeg 1 100 % on frames f0 and f1; beside them
    fog 1 of another seed, a clean frame f2 and a clean row b, none of which was corrupted under this protocol."""
    registry = default_registry()
    fog, jpeg = registry.corruption("fog")(), registry.corruption("jpeg")()
    rows = (
        records("", 0, [True, True], Protocol())
        + records("fog", 1, [True, False], Protocol().corrupted(fog, 1))
        + records("fog", 3, [False, False], Protocol().corrupted(fog, 3))
        + records("jpeg", 1, [True, True], Protocol().corrupted(jpeg, 1))
        + records("fog", 1, [False, False], Protocol(seed=7).corrupted(fog, 1))  # another protocol: left out
        + records("", 0, [False], Protocol(), first=2)  # a clean frame never corrupted: left out
        + records("", 0, [False, False], Protocol(), combination="b")  # a row never corrupted: left out
    )
    store = ResultsStore(tmp_path / "hand")
    for i, row in enumerate(rows):
        store.put(f"k{i}", row)
    return store.root


def test_curve_points_are_the_hand_worked_acc_and_the_summary_cells(hand_store):
    data = robustness.load(load_run(hand_store))
    assert len(data.records) == 8 and data.kinds == {"fog": "image", "jpeg": "image"}
    curves = {c.corruption: (c.severities, c.acc) for c in robustness.curves(data.summary)}
    assert curves == {
        "fog": ([0, 1, 3], [100.0, 50.0, 0.0]),
        "jpeg": ([0, 1], [100.0, 100.0]),  # jpeg 3 was not run: no point
        lb.MEAN_ROW: ([0, 1, 3], [100.0, 75.0, 0.0]),
    }
    assert set(data.summary["combination"]) == {"a"} and set(data.records["frame_id"]) == {"f0", "f1"}


def test_the_figure_draws_exactly_the_curve_points(hand_store):
    data = robustness.load(load_run(hand_store))
    found = robustness.curves(data.summary)
    figure = robustness.severity_figure(found, data.kinds)
    drawn = [
        (ax.get_title(), list(line.get_xdata()), list(line.get_ydata())) for ax in figure.axes for line in ax.lines
    ]
    assert drawn == [
        ("fog (image)", [0, 1, 3], [100.0, 50.0, 0.0]),
        ("jpeg (image)", [0, 1], [100.0, 100.0]),
        (lb.MEAN_ROW, [0, 1, 3], [100.0, 75.0, 0.0]),
    ]


def test_records_of_one_corruption_only_still_get_a_section(hand_store, tmp_path):
    """Without clean records the curves start at severity 1 (no clean Acc. to draw at 0)."""
    store = ResultsStore(hand_store)
    kept = store.load()
    only_fog = ResultsStore(tmp_path / "fog")
    for i, row in enumerate(r for r in kept.to_dict("records") if r["corruption"] == "fog"):
        only_fog.put(f"k{i}", row)
    curve = robustness.curves(robustness.load(load_run(only_fog.root)).summary)[0]
    assert (curve.corruption, curve.severities, curve.acc) == ("fog", [1, 3], [50.0, 0.0])


@pytest.fixture(scope="module")
def sensor(corrupted_run):
    run = load_run(corrupted_run)
    return open_dataset(default_registry(), run.dataset).load(sorted(run.records["frame_id"])[0])


@pytest.mark.parametrize("name", ["gaussian-noise", "motion-blur", "fog"])
def test_an_image_corruptions_overlay_at_severity_0_is_the_clean_image(sensor, name):
    corruption = default_registry().corruption(name)()
    frames = robustness.corrupted_frames(sensor, Protocol(), corruption, [3])
    clean_panel, severe_panel = (robustness.corruption_panel(f, "image") for _, f in frames)
    assert [s for s, _ in frames] == [0, 3]
    assert np.array_equal(clean_panel, sensor.image)
    assert not np.array_equal(severe_panel, sensor.image)
    strip = robustness.strip(frames, corruption)
    top = robustness.draw.CAPTION_PX
    first = robustness._fit(sensor.image)
    assert np.array_equal(strip[top : top + first.shape[0], : first.shape[1]], first)  # left: the clean image


@pytest.mark.parametrize("name", ["beam-reduction", "intrinsic-error"])
def test_a_scan_or_calibration_overlay_at_severity_0_is_the_clean_projection(sensor, name):
    corruption = default_registry().corruption(name)()
    frames = robustness.corrupted_frames(sensor, Protocol(), corruption, [5])
    clean = Protocol().apply(sensor)
    expected = overlay.points_panel(clean, clean.T_gt, robustness.POINT_RADIUS)
    clean_panel, severe_panel = (robustness.corruption_panel(f, corruption.kind) for _, f in frames)
    assert np.array_equal(clean_panel, expected)
    assert not np.array_equal(severe_panel, expected)  # fewer rings, or points off their objects


def test_data_that_cannot_be_opened_keeps_the_curves_and_says_why_the_overlays_are_missing(corrupted_run, monkeypatch):
    def gone(*args, **kwargs):
        raise DataError("no such directory")

    monkeypatch.setattr(robustness, "open_dataset", gone)
    section = robustness.section(load_run(corrupted_run))
    assert section.overlays == [] and section.curves_png.startswith(b"\x89PNG")
    assert section.notes == [
        "corruption overlays left out: cannot open the run's dataset (no such directory); pass --data-root"
    ]


def test_the_section_table_is_the_summary(corrupted_run):
    section = robustness.section(load_run(corrupted_run))
    assert isinstance(section.summary, pd.DataFrame)
    assert list(section.summary["corruption"]) == ["intrinsic-error", "gaussian-noise", "beam-reduction", lb.MEAN_ROW]
    assert set(section.summary["combination"]) == {COMBINATION}


def test_the_page_with_the_section_runs_its_scripts_without_errors(corrupted_run, tmp_path):
    from test_report_html import TRAP, chromium

    probed = tmp_path / "probed.html"
    text = report(corrupted_run, tmp_path)
    probed.write_text(text.replace("<head>", "<head>" + TRAP, 1))
    dom = chromium("--dump-dom", probed.as_uri(), tmp=tmp_path).stdout
    assert "<html" in dom and 'data-js-errors="' not in dom
    assert dom.count('<table class="sortable">') == 3  # the leaderboard, by sequence, robustness
    assert dom.count('aria-sort="none"') == dom.count("<th ") > 20  # every header of both tables
