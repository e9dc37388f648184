"""The report page: one self-contained HTML file (inline CSS and JS, images base64-embedded) for a runs directory.

Self-contained so it can be mailed, attached to a CI run or opened offline. The only script sorts the leaderboard
when a header is clicked; each cell carries its raw value in `data-sort`, so "0.03 ± 0.01" sorts by its mean.
The leaderboard shows the columns a terminal board shows, those a reader compares first leading (LEAD); rows scored
on different frames (invocations with other --frames) go to separate tables, plus one of every row rescored on the
frames all of them share.
"""

from __future__ import annotations

import base64
import datetime
import os
from html import escape
from pathlib import Path

import numpy as np
import pandas as pd

from ..boards import leaderboard as lb
from ..boards import uncertainty
from ..metrics import installed as installed_metrics
from ..scoring.installed import rescored
from . import curves, framesets, overlay, robustness, sequences
from .examples import Example, render_examples
from .labels import number
from .rundir import RunDir, load_run

EXTRA = ["geodesic median (°) ↓"]  # the report's own column beside the ones a terminal board shows
IN_TITLE = ("dataset", "split")  # one runs directory holds one dataset split, which the page's title names
SORT_BY = {lb.RTE: lb.RTE_MEAN, lb.RRE: lb.RRE_MEAN}  # "mean ± std" text columns sort by their mean
# What a reader compares first, each with its 95% interval after it; the board's other columns follow in its order.
LEAD = ["combination", "method", "weights", "frames", lb.ACC, lb.ACC_SKILL, lb.RTE, lb.RRE]
WRAPPED = {"combination": "name", "weights": "weights"}  # long names wrap (after a stage's ">", at a "-")

CSS = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 24px auto; max-width: 1360px; padding: 0 16px; color: #222; }
h1 { font-size: 22px; } h2 { font-size: 18px; margin-top: 32px; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: right; }
th { background: #f3f3f3; cursor: pointer; user-select: none; min-width: 5.5em; vertical-align: bottom; }
th[aria-sort=ascending]::after { content: " ▲"; } th[aria-sort=descending]::after { content: " ▼"; }
td { white-space: nowrap; } td.text { text-align: left; }
td.name { white-space: normal; min-width: 12em; max-width: 22em; } td.weights { white-space: normal; max-width: 13em; }
h3 { font-size: 15px; margin: 20px 0 6px; } .wide { overflow-x: auto; max-width: 100%; }
img { max-width: 100%; display: block; margin: 8px 0; }
figure { margin: 16px 0; } figcaption { font-weight: 600; }
.meta { color: #555; font-size: 13px; } .note { color: #8a4b00; }
"""

JS = """
(function () {
  function key(row, col) {
    var text = row.cells[col].getAttribute("data-sort");
    var number = parseFloat(text);
    return isNaN(number) ? text : number;
  }
  function compare(a, b) {
    if (typeof a === typeof b) { return a < b ? -1 : a > b ? 1 : 0; }
    return typeof a === "number" ? -1 : 1;
  }
  function sortBy(table, th, col) {
    var ascending = th.getAttribute("aria-sort") !== "ascending";
    table.querySelectorAll("th").forEach(function (h) { h.setAttribute("aria-sort", "none"); });
    th.setAttribute("aria-sort", ascending ? "ascending" : "descending");
    var body = table.tBodies[0];
    var rows = Array.prototype.slice.call(body.rows);
    rows.sort(function (a, b) { return compare(key(a, col), key(b, col)) * (ascending ? 1 : -1); });
    rows.forEach(function (row) { body.appendChild(row); });
  }
  document.querySelectorAll("table.sortable").forEach(function (table) {
    table.querySelectorAll("th").forEach(function (th, col) {
      th.setAttribute("aria-sort", "none");
      th.title = "click to sort";
      th.addEventListener("click", function () { sortBy(table, th, col); });
    });
  });
})();
"""


def write_report(
    run_root: Path, out: Path, overlays: int = 4, data_root: str | None = None, quiet: bool = True
) -> list[str]:
    """Build the page for a runs directory and write it atomically; returns the notes it shows (also for stderr)."""
    run = load_run(run_root)
    board = lb.build(run.records, run.protocol)
    examples, notes = render_examples(run, board, overlays, data_root, quiet)
    robust = robustness.section(run, data_root)
    notes = run.notes + notes + (robust.notes if robust else [])
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    tmp.write_text(render(run, board, examples, notes, robust), encoding="utf-8")
    os.replace(tmp, out)
    return notes


def render(
    run: RunDir,
    board: pd.DataFrame,
    examples: list[Example],
    notes: list[str],
    robust: robustness.Section | None = None,
) -> str:
    sets = framesets.split(board, run.records, run.protocol)
    labels = _labels(board, run.records, sets)
    groups = curves.rows(rescored(run.records, run.protocol), list(labels), labels)  # errors by the run's card
    sections = [
        _header(run, notes),
        _section("Leaderboard", _explain_board(run), _boards(run, sets)),
        _section(
            "Cumulative errors",
            f"Share of all frames (failures included) under each error. {overlay.RRE_NOTE}.",
            _png(curves.cumulative_errors(groups, run.protocol), "cumulative RTE and RRE"),
        ),
        _section(
            "Acc. against its thresholds",
            "Dashed: the protocol's thresholds, where each curve meets Acc.",
            _png(curves.accuracy_curves(groups, run.protocol), "Acc. against the RRE and RTE thresholds"),
        ),
        _section("By sequence", sequences.EXPLAIN, _by_sequence(run, list(labels))),
        _section(
            "Latency",
            "Median per frame over the frames whose pipeline ran to the end (log axis), and each stage's share.",
            _png(curves.latency_bars(board, list(labels.values())), "per-stage latency"),
        ),
        _section("Best and worst frames", _explain_examples(), "".join(_figure(e) for e in examples)),
        _robustness(robust) if robust else "",
    ]
    title = f"i2pbench report: {_dataset_name(run)}"
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{escape(title)}</title>'
        f"<style>{CSS}</style></head>\n<body><h1>{escape(title)}</h1>\n{''.join(sections)}\n"
        f"<script>{JS}</script></body></html>\n"
    )


def board_columns(board: pd.DataFrame) -> list[str]:
    """Every column a terminal board of these rows shows, as `leaderboard.to_markdown` chooses them (so columns a
    metric plugin or a later version adds come along), then EXTRA; the dataset and split only when rows differ."""
    header = lb.to_markdown(board).splitlines()[0]
    shown = [c.strip() for c in header.strip().strip("|").split(" | ")]
    shown = [c for c in shown if c in board and (c not in IN_TITLE or board[c].nunique() > 1)]
    return _lead_first(shown + [c for c in EXTRA if c in board and c not in shown])


def _lead_first(columns: list[str]) -> list[str]:
    """LEAD's columns among `columns`, each followed by its interval, then the others in their order."""
    interval = {m.summary or m.column: uncertainty.ci(m) for m in uncertainty.with_interval(installed_metrics.active())}
    lead = [name for column in LEAD for name in (column, interval.get(column)) if name in columns]
    return lead + [c for c in columns if c not in lead]


def table(board: pd.DataFrame, columns: list[str] | None = None) -> str:
    """The leaderboard (or `columns` of another table) as a sortable HTML table, in the table's order."""
    columns = [c for c in columns if c in board] if columns else board_columns(board)
    head = "".join(f"<th>{escape(c)}</th>" for c in columns)
    text = {c for c in columns if not pd.api.types.is_numeric_dtype(board[c]) and c not in SORT_BY}  # words: left
    body = "".join(
        "<tr>" + "".join(_cell(row[c], row.get(SORT_BY.get(c, c)), _kind(c, text)) for c in columns) + "</tr>\n"
        for _, row in board.iterrows()
    )
    table = f'<table class="sortable"><thead><tr>{head}</tr></thead><tbody>\n{body}</tbody></table>'
    return f"<div class=wide>{table}</div>"  # a board wider than the page scrolls on its own


def _boards(run: RunDir, sets: list[framesets.FrameSet]) -> str:
    """One table when every row ran the same frames; else one per frame set and one of all rows on the shared
    frames, each headed by its frames."""
    if len(sets) == 1:
        return table(sets[0].board)
    shared = framesets.shared_board(run.records, sets, run.protocol)
    parts = [
        f"<p class=note>These rows ran on {len(sets)} different sets of frames (invocations with other --frames or "
        "splits): each table holds the rows scored on the same frames; compare rows within a table, not across."
        + ("" if shared else " No frame is shared by every row.")
        + "</p>"
    ]
    for i, s in enumerate(sets, start=1):
        parts.append(f"<h3>Frame set {i}, {escape(framesets.describe(s.frames))}</h3>{table(s.board)}")
    if shared:
        title = f"Every row on the frames all rows ran, {framesets.describe(shared.frames)}"
        parts.append(f"<h3>{escape(title)}</h3>{table(shared.board)}")
    return "".join(parts)


def _labels(board: pd.DataFrame, records: pd.DataFrame, sets: list[framesets.FrameSet]) -> dict:
    """(combination, weights) -> its label in the figures, with its frame count when rows ran different frames."""
    frames = framesets.row_frames(records)
    keys = list(zip(board["combination"], board["weights"], strict=True))
    suffix = (lambda key: f" [{len(frames[key])} frames]") if len(sets) > 1 else (lambda key: "")
    return {key: curves.row_label(*key) + suffix(key) for key in keys}


def _by_sequence(run: RunDir, order: list[tuple[str, str]]) -> str:
    lines = sequences.table(run.records, run.protocol, order)
    return table(lines, list(lines.columns))


def _kind(column: str, text: set[str]) -> str:
    """The cell's class: words align left, and a combination's or weights' name may wrap, so that the columns
    after them stay in view."""
    classes = (["text"] if column in text else []) + ([WRAPPED[column]] if column in WRAPPED else [])
    return " ".join(classes)


def _cell(value: object, sort_value: object, kind: str = "") -> str:
    kind = f' class="{kind}"' if kind else ""
    return f'<td{kind} data-sort="{escape(_sort_text(sort_value))}">{escape(_display(value))}</td>'


def _display(value: object) -> str:
    """Floats as the figures write them (two decimals, grouped thousands), NaN as "-"."""
    return number(float(value)) if isinstance(value, float | np.floating) else str(value)


def _sort_text(value: object) -> str:
    """Numbers as full-precision text, NaN as "" (sorted after every number)."""
    if isinstance(value, float | np.floating):
        return "" if np.isnan(value) else repr(float(value))
    return str(value)


def _section(title: str, explanation: str, body: str) -> str:
    return f"<section><h2>{escape(title)}</h2><p class=meta>{escape(explanation)}</p>{body}</section>\n"


def _png(fig, alt: str) -> str:
    return _img(curves.png(fig), "image/png", alt)


def _img(data: bytes, mime: str, alt: str) -> str:
    return f'<img alt="{escape(alt)}" src="data:{mime};base64,{base64.b64encode(data).decode("ascii")}">'


def _figure(example: Example) -> str:
    caption = f"{example.title} ({example.errors})"
    return f"<figure><figcaption>{escape(caption)}</figcaption>{_img(example.jpeg, 'image/jpeg', caption)}</figure>\n"


def _dataset_name(run: RunDir) -> str:
    first = run.records.iloc[0]
    return f"{first.get('dataset', '?')}/{first.get('split', '?')}"


def _header(run: RunDir, notes: list[str]) -> str:
    commits = sorted({str(m.get("environment", {}).get("git_commit", "")) for m in run.meta} - {""})
    facts = [
        f"run: {run.root}",
        f"data: {', '.join(f'{k}={v}' for k, v in run.dataset.items()) or 'not recorded'}",
        f"protocol {run.protocol.identity()}: " + ", ".join(f"{k}={v}" for k, v in run.protocol.card().items()),
        f"{len(run.records)} frame results, {len(run.meta)} invocation(s), code {', '.join(commits) or 'unknown'}",
        f"generated {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
    ]
    items = "".join(f"<li>{escape(f)}</li>" for f in facts) + "".join(f"<li class=note>{escape(n)}</li>" for n in notes)
    return f"<ul class=meta>{items}</ul>\n"


def _explain_board(run: RunDir) -> str:
    p = run.protocol
    return (
        f"Click a header to sort. Acc. counts frames with RTE < {p.acc_rte_m:g} m and RRE < {p.acc_rre_deg:g}° over "
        f"all frames; RTE and RRE are mean ± std over frames with RTE < {p.filter_rte_m:g} m and "
        f"RRE < {p.filter_rre_deg:g}°. Latency is per frame, in milliseconds."
    )


def _robustness(robust: robustness.Section) -> str:
    """Three sections: the robustness summary, Acc. against severity, and one overlay per corruption."""
    columns = [c for c in robust.summary.columns if c not in ("dataset", "split")]
    curves_img = _img(robust.curves_png, "image/png", "Acc. against corruption severity")
    return "".join([
        _section("Robustness", robustness.explain(robust), table(robust.summary, columns)),
        _section("Acc. against severity", robustness.EXPLAIN_CURVES, curves_img),
        _section("What each corruption does", robustness.EXPLAIN_OVERLAYS, "".join(map(_figure, robust.overlays))),
    ])  # fmt: skip


def _explain_examples() -> str:
    return (
        "LiDAR points projected with the initial pose (the calibration applied to the moved cloud), the ground truth "
        "and the stored prediction; colour by distance, near warm and far cool. Under the ground truth the points "
        f"sit on the objects they hit. {overlay.RRE_NOTE}."
    )
