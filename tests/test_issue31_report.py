"""Issue 31, first contact 3: the report of a runs folder made by two invocations on different frames puts rows on
the same frames in one table (one per frame set, and one of every row on the shared frames), shows every column the
terminal board shows, and draws latency on a log axis with a unit under an uncut title. Checked in headless Chromium
as the report's own test does."""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

import pytest
from conftest import require
from test_cli_errors import i2pbench
from test_report_html import KITTI, TRAP, chromium

from i2pbench.boards import leaderboard as lb
from i2pbench.report import curves
from i2pbench.report.rundir import load_run

CLASSIC = ["--extractor3d", "depth", "--matcher", "oracle", "--solver", "epnp-ransac"]
LSD, CANNY = (f"{name} &gt; depth &gt; oracle &gt; epnp-ransac" for name in ("lsd", "canny"))


def _run(runs: Path, extractors: str, frames: int):
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(KITTI), *CLASSIC]
    args += ["--extractor", extractors, "--frames", str(frames), "--runs-dir", str(runs), "--quiet"]
    done = i2pbench(*args, cwd=runs.parent)
    assert done.returncode == 0, done.stderr
    return done


@pytest.fixture(scope="module")
def two_invocations(tmp_path_factory) -> tuple[Path, list[str], Path]:
    """canny on 3 frames, then lsd and canny on 2 (canny's 2 come from the cache): canny's row holds 3 frames,
    lsd's 2. Gives (runs folder, the header of the second invocation's terminal board, the report)."""
    require(KITTI)
    runs = tmp_path_factory.mktemp("two") / "runs"
    _run(runs, "canny", 3)
    board = _run(runs, "lsd,canny", 2).stdout
    header = next(line for line in board.splitlines() if line.startswith("| dataset"))
    columns = [c.strip() for c in header.strip("|").split("|")]
    out = runs.parent / "report.html"
    done = i2pbench("report", str(runs / "kitti-all"), "--out", str(out), "--overlays", "0", "--quiet", cwd=runs.parent)
    assert done.returncode == 0, done.stderr
    return runs / "kitti-all", columns, out


def _leaderboard(text: str) -> str:
    """The page's Leaderboard section (other sections have tables of their own)."""
    start = text.index("<section><h2>Leaderboard</h2>")
    return text[start : text.index("</section>", start)]


def _tables(text: str) -> list[tuple[str, list[str]]]:
    """[(heading before the table, [first cell of each body row])] of every table in the Leaderboard section."""
    text = _leaderboard(text)
    found = re.findall(
        r"(?:<h3>([^<]*)</h3>)?<div class=wide><table class=\"sortable\">(.*?)</table>", text, flags=re.S
    )
    return [(heading, re.findall(r"<tr><td[^>]*>([^<]*)</td>", body)) for heading, body in found]


def test_rows_on_different_frames_are_split_into_one_table_per_frame_set_and_a_shared_one(two_invocations):
    _, _, page = two_invocations
    text = page.read_text()
    assert "These rows ran on 2 different sets of frames" in _leaderboard(text)
    assert _tables(text) == [
        ("Frame set 1, 3 frames: 00/000000, 00/000001, 00/000002", [CANNY]),
        ("Frame set 2, 2 frames: 00/000000, 00/000001", [LSD]),
        ("Every row on the frames all rows ran, 2 frames: 00/000000, 00/000001", [LSD, CANNY]),
    ]
    assert _column(text, "frames") == [["3"], ["2"], ["2", "2"]]  # each row scored on its table's frames


def _column(text: str, name: str) -> list[list[str]]:
    """The cells of column `name` in each Leaderboard table, row by row."""
    cells = []
    for table in re.findall(r"<table.*?</table>", _leaderboard(text), flags=re.S):
        index = re.findall(r"<th>([^<]*)</th>", table).index(name)
        rows = re.findall(r"<tr>(.*?)</tr>", table.split("<tbody>")[1], flags=re.S)
        cells.append([re.findall(r"<td[^>]*>([^<]*)</td>", row)[index] for row in rows])
    return cells


def test_the_curves_name_each_rows_frame_count_when_rows_ran_different_frames(two_invocations):
    run_dir, _, _ = two_invocations
    from i2pbench.report.framesets import split
    from i2pbench.report.html import _labels

    run = load_run(run_dir)
    board = lb.build(run.records, run.protocol)
    labels = _labels(board, run.records, split(board, run.records, run.protocol))
    assert sorted(labels.values()) == [
        "canny > depth > oracle > epnp-ransac [3 frames]",
        "lsd > depth > oracle > epnp-ransac [2 frames]",
    ]


def test_the_report_shows_every_column_the_terminal_board_shows(two_invocations):
    _, columns, page = two_invocations
    text = page.read_text()
    heads = [
        re.findall(r"<th>([^<]*)</th>", h) for h in re.findall(r"<thead><tr>(.*?)</tr></thead>", _leaderboard(text))
    ]
    expected = [html.escape(c, quote=False) for c in columns if c not in ("dataset", "split")]
    lead = ["combination", "method", "weights", "frames", lb.ACC, "Acc. 95% CI", lb.ACC_SKILL,
            "Acc. with true matches 95% CI", lb.RTE, "RTE 95% CI", lb.RRE, "RRE 95% CI"]  # fmt: skip
    assert heads[2][: len(lead)] == lead  # the shared table holds the terminal board's two rows, these first (#45)
    rest = [c for c in expected if c not in lead] + ["geodesic median (°) ↓"]  # the report's own column last
    assert heads[2][len(lead) :] == rest
    for head in heads[:2]:  # one row each: only columns empty in that row (the verdict on a row above) are left out
        assert set(head) <= set(heads[2]) and {lb.CHANCE, lb.ACC_SKILL, "weights"} <= set(head)
    assert {lb.CHANCE, lb.ACC_SKILL} <= set(columns)  # the columns issue 31 found missing are among them
    assert "<h1>i2pbench report: kitti/all</h1>" in text  # dataset and split: named once, in the title


def test_weights_trained_on_is_a_column_when_a_row_has_weights():
    import pandas as pd

    from i2pbench.report.html import board_columns

    board = pd.DataFrame({"combination": ["a", "b"], "weights": ["w.pt", "none"], "weights_trained_on": ["kitti", ""]})
    assert board_columns(board) == ["combination", "weights", "weights_trained_on"]
    assert board_columns(board.assign(weights_trained_on="")) == ["combination", "weights"]


def test_the_latency_chart_has_a_log_axis_in_ms_and_an_uncut_title(two_invocations):
    run_dir, _, _ = two_invocations
    run = load_run(run_dir)
    board = lb.build(run.records, run.protocol)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    for rows in (board.iloc[:1], board):  # one row gave the shortest figure
        fig = curves.latency_bars(rows)
        canvas = FigureCanvasAgg(fig)
        canvas.draw()  # lays the figure out as png() does
        total, share = fig.axes
        assert total.get_xscale() == "log" and "(ms, log scale)" in total.get_xlabel()
        assert share.get_xlabel() == "share of the summed stage medians (%)"
        title = fig._suptitle.get_window_extent(canvas.get_renderer())
        assert fig.bbox.x0 <= title.x0 and title.x1 <= fig.bbox.x1 and title.y1 <= fig.bbox.y1
    fastest = board[lb.LATENCY_MEDIAN].min()
    assert total.get_xlim()[0] < fastest / 5  # the fastest row's bar is drawn, not hidden at the axis' edge


def test_no_overlays_asked_draws_none(two_invocations):
    _, _, page = two_invocations
    assert "<figure>" not in page.read_text()


def test_the_split_tables_render_and_sort_each_on_its_own_in_headless_chromium(two_invocations, tmp_path):
    _, _, page = two_invocations
    probe = """<script>
    var board = document.querySelector("section"), d = document.documentElement, seen = [];
    var tables = board.querySelectorAll("table.sortable");
    tables.forEach(function (t) { t.querySelectorAll("th")[0].click(); t.querySelectorAll("th")[0].click(); });
    tables.forEach(function (t) {
      seen.push(Array.prototype.map.call(t.tBodies[0].rows, function (r) { return r.cells[0].textContent; }));
    });
    d.setAttribute("data-rows", JSON.stringify(seen));
    d.setAttribute("data-headings", Array.prototype.map.call(board.querySelectorAll("h3"),
      function (h) { return h.textContent; }).join("|"));
    </script>"""
    probed = tmp_path / "probed.html"
    probed.write_text(page.read_text().replace("<head>", "<head>" + TRAP, 1).replace("</body>", probe + "</body>", 1))
    dom = chromium("--dump-dom", probed.as_uri(), tmp=tmp_path).stdout
    assert "<html" in dom and 'data-js-errors="' not in dom
    rows = json.loads(html.unescape(re.search(r'data-rows="([^"]*)"', dom).group(1)))
    lsd, canny = html.unescape(LSD), html.unescape(CANNY)
    assert rows == [[canny], [lsd], [lsd, canny]]  # sorted by name, descending: each table keeps only its own rows
    headings = html.unescape(re.search(r'data-headings="([^"]*)"', dom).group(1)).split("|")
    assert [h.split(",")[0] for h in headings] == ["Frame set 1", "Frame set 2", "Every row on the frames all rows ran"]
