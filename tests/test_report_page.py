"""The written report as a reader sees it in headless Chromium, at a wide and a narrow window: every section holds its
tables and images (loaded, inside the window), every table row is named, no two rows of a table carry the same
name, and at 1400 px the leaderboard's leading columns (Acc., with true matches, RTE, RRE and their intervals) are
in view. Built from a run on the embedded synthetic dataset, so it needs no ../shared data."""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

import pytest
from test_report_html import TRAP, chromium

from i2pbench.boards import leaderboard as lb
from i2pbench.cli import main

WIDTHS = (1400, 800)
# The page's sections and, in each, how many tables and images a run of two combinations on two frames, clean and
# under one corruption, gives (best and worst frame of each combination; one overlay for the corruption).
SECTIONS = {
    "Leaderboard": (1, 0),
    "Cumulative errors": (0, 1),
    "Acc. against its thresholds": (0, 1),
    "By sequence": (1, 0),
    "Latency": (0, 1),
    "Best and worst frames": (0, 4),
    "Robustness": (1, 0),
    "Acc. against severity": (0, 1),
    "What each corruption does": (0, 1),
}
NAMING = ("combination", "weights", "sequence", "corruption")  # the columns that say what a row is
LEAD = [lb.ACC, "Acc. 95% CI", lb.ACC_SKILL, "Acc. with true matches 95% CI", lb.RTE, "RTE 95% CI", lb.RRE,
        "RRE 95% CI"]  # fmt: skip
# Run once the page has loaded: what each section holds, as JSON on the root element.
PROBE = """<script>
window.addEventListener("load", function () {
  function inView(el) { return el.getBoundingClientRect().right <= window.innerWidth; }
  function text(cell) { return cell.textContent.trim(); }
  var sections = Array.prototype.map.call(document.querySelectorAll("section"), function (s) {
    var tables = Array.prototype.map.call(s.querySelectorAll("table"), function (t) {
      return {
        heads: Array.prototype.map.call(t.tHead.rows[0].cells, function (th) {
          return {text: text(th), inView: inView(th)};
        }),
        rows: Array.prototype.map.call(t.tBodies[0].rows, function (row) {
          return Array.prototype.map.call(row.cells, text);
        })
      };
    });
    var images = Array.prototype.map.call(s.querySelectorAll("img"), function (img) {
      return {loaded: img.complete && img.naturalWidth > 0, inView: inView(img), alt: img.alt};
    });
    return {title: text(s.querySelector("h2")), tables: tables, images: images};
  });
  document.documentElement.setAttribute("data-probe", JSON.stringify(sections));
});
</script>"""


@pytest.fixture(scope="module")
def page(tmp_path_factory) -> Path:
    """Two classic combinations on two synthetic test frames, clean and under gaussian-noise 2 (a few seconds)."""
    tmp = tmp_path_factory.mktemp("page")
    argv = ["run", "--extractor", "lsd,canny", "--extractor3d", "depth", "--matcher", "oracle", "--solver",
            "epnp-ransac", "--dataset", "synthetic", "--split", "test", "--frames", "2", "--threads", "1",
            "--corruption", "clean,gaussian-noise:2", "--runs-dir", str(tmp / "runs"), "--out", str(tmp / "lb"),
            "--quiet"]  # fmt: skip
    assert main(argv) == 0
    out = tmp / "report.html"
    assert main(["report", str(tmp / "runs" / "synthetic-test"), "--out", str(out), "--quiet"]) == 0
    return out


@pytest.fixture(scope="module", params=WIDTHS, ids=lambda w: f"{w}px")
def seen(request, page, tmp_path_factory) -> tuple[int, dict[str, dict]]:
    """(window width, {section title: what the probe found in it})."""
    tmp = tmp_path_factory.mktemp("chromium")
    probed = tmp / "probed.html"
    probed.write_text(page.read_text().replace("<head>", "<head>" + TRAP, 1).replace("</body>", PROBE + "</body>", 1))
    window = f"--window-size={request.param},2000"
    dom = chromium(window, "--virtual-time-budget=5000", "--dump-dom", probed.as_uri(), tmp=tmp).stdout
    assert 'data-js-errors="' not in dom
    found = re.search(r'data-probe="([^"]*)"', dom)
    assert found, dom[-2000:]
    return request.param, {s["title"]: s for s in json.loads(html.unescape(found.group(1)))}


def test_every_section_holds_its_tables_and_images(seen):
    width, sections = seen
    assert list(sections) == list(SECTIONS)
    for title, (n_tables, n_images) in SECTIONS.items():
        section = sections[title]
        assert (len(section["tables"]), len(section["images"])) == (n_tables, n_images), title
        for image in section["images"]:
            assert image["loaded"] and image["inView"], (width, title, image["alt"])


def names(table: dict) -> list[tuple[str, ...]]:
    """Each body row's cells under the NAMING columns the table has (the combination first)."""
    heads = [h["text"] for h in table["heads"]]
    return [tuple(row[heads.index(c)] for c in NAMING if c in heads) for row in table["rows"]]


def test_no_table_has_an_unnamed_or_repeated_row(seen):
    _, sections = seen
    for title, section in sections.items():
        for table in section["tables"]:
            assert all(head["text"] for head in table["heads"]), title
            assert table["heads"][0]["text"] == "combination", title
            named = names(table)
            assert named and all(all(name) for name in named), (title, named)
            assert len(set(named)) == len(named), (title, named)


def test_the_by_sequence_table_names_each_rows_combination_weights_and_sequence(seen):
    _, sections = seen
    (table,) = sections["By sequence"]["tables"]
    assert [h["text"] for h in table["heads"][:4]] == ["combination", "weights", "sequence", "frames"]
    combinations = [f"{e} > depth > oracle > epnp-ransac" for e in ("lsd", "canny")]
    assert sorted(names(table)) == sorted((c, "none", "02") for c in combinations)  # one sequence: no "all" line
    assert [row[3] for row in table["rows"]] == ["2", "2"]


def test_the_leaderboard_leads_with_what_a_reader_compares(seen):
    width, sections = seen
    (table,) = sections["Leaderboard"]["tables"]
    heads = [h["text"] for h in table["heads"]]
    assert heads[:12] == ["combination", "method", "weights", "frames", *LEAD]
    if width == 1400:  # the window: these columns no longer sit past the fold
        assert all(h["inView"] for h in table["heads"][:12]), table["heads"][:12]
