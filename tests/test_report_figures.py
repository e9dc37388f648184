"""Every figure of the report keeps its text readable: no two drawn text artists overlap and none leaves the figure.

Checked from matplotlib's own bounding boxes (`get_window_extent` after `fig.canvas.draw()`) of exactly the texts a
draw renders (tick labels outside the view are not drawn, so are not checked), at the report's 100 dpi, for a
board of one row, of six rows, and of the long names a real run gives (the default EdgeRegNet combination with its
weights, and a path-like weights name with no space to wrap at).
"""

from __future__ import annotations

import itertools
from unittest import mock

import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.text import Text
from matplotlib.transforms import Bbox

from i2pbench.boards.leaderboard import LATENCY_MEDIAN, MEAN_ROW, stage_latency
from i2pbench.report import curves, robustness
from i2pbench.report.labels import number, tick, wrapped
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.components import STAGE_ORDER

CLASSIC = [f"{e} > depth+reflectance > {m} > epnp-ransac" for e in ("lsd", "canny") for m in ("oracle", "mutual-nn")]
EDGEREGNET = "lsd > depth+reflectance > superpoint-cnn > pointnet2 > attention > lightglue > epnp-ransac (cpu-size)"
DEFAULT_RUN = [(EDGEREGNET, "edgeregnet-cpu-synthetic@e5fd63c7")]  # `i2pbench run`'s one row
CASES = {
    "one row": [(CLASSIC[0], "none")],
    "the default run": DEFAULT_RUN,
    "six rows": [(c, "none") for c in CLASSIC] + [*DEFAULT_RUN, ("x", "w.pt")],
    "long names": [*DEFAULT_RUN, (EDGEREGNET, "/home/someone/checkpoints/edgeregnet-kitti-lr3e-5-step0065000-best.pt")],
}
KINDS = {"gaussian-noise": "image", "beam-reduction": "lidar", "intrinsic-error": "calibration", "fog": "image"}


def row_records(rows: list[tuple[str, str]]) -> pd.DataFrame:
    """Eight frames per row, errors spread over four decades, one failure each."""
    rng = np.random.default_rng(0)
    parts = []
    for combination, weights in rows:
        rte = np.append(10.0 ** rng.uniform(-2, 2, 7), np.inf)
        rre = np.append(10.0 ** rng.uniform(-1, 2.5, 7), np.inf)
        parts.append(pd.DataFrame({"combination": combination, "weights": weights, "rte_m": rte, "rre_deg": rre}))
    return pd.concat(parts, ignore_index=True)


def latency_board(rows: list[tuple[str, str]]) -> pd.DataFrame:
    """Totals from 4 ms to 12 s (a fast classic row beside a slow learned one), every stage timed."""
    totals = np.geomspace(4.0, 12_345.6, len(rows)) if len(rows) > 1 else np.array([1001.85])
    board = pd.DataFrame({"combination": [c for c, _ in rows], "weights": [w for _, w in rows]})
    board[LATENCY_MEDIAN] = totals
    for i, kind in enumerate(STAGE_ORDER):
        board[stage_latency(kind, "median")] = totals * (i + 1) / sum(range(1, len(STAGE_ORDER) + 1))
    return board


def labels(rows: list[tuple[str, str]]) -> list[str]:
    return [curves.row_label(*row) for row in rows]


def severity_figure(rows: list[tuple[str, str]]) -> Figure:
    """One corruption (two narrow panels with the mean) for one row; every corruption (two rows of panels) else."""
    names = list(KINDS)[: 1 if len(rows) == 1 else len(KINDS)]
    found = [
        robustness.Curve(label, name, [0, 1, 3, 5], [80.0, 60.0, 40.0, 10.0])
        for label, name in itertools.product(labels(rows), [*names, MEAN_ROW])
    ]
    return robustness.severity_figure(found, KINDS)


FIGURES = {
    "cumulative errors": lambda rows: curves.cumulative_errors(curves.rows(row_records(rows)), Protocol()),
    "Acc. curves": lambda rows: curves.accuracy_curves(curves.rows(row_records(rows)), Protocol()),
    "latency": lambda rows: curves.latency_bars(latency_board(rows), labels(rows)),
    "Acc. against severity": severity_figure,
}


def drawn_texts(fig: Figure) -> list[tuple[str, Bbox]]:
    """(text, window extent) of every non-empty text the figure's draw renders."""
    drawn: list[Text] = []
    draw = Text.draw

    def recording(self: Text, renderer) -> None:
        if self.get_visible() and self.get_text().strip():
            drawn.append(self)
        draw(self, renderer)

    FigureCanvasAgg(fig)
    with mock.patch.object(Text, "draw", recording):
        fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    return [(t.get_text(), t.get_window_extent(renderer)) for t in drawn]


def collisions(texts: list[tuple[str, Bbox]], width: float, height: float) -> list[str]:
    problems = [
        f"{a!r} overlaps {b!r}"
        for (a, box_a), (b, box_b) in itertools.combinations(texts, 2)
        if min(box_a.x1, box_b.x1) > max(box_a.x0, box_b.x0) and min(box_a.y1, box_b.y1) > max(box_a.y0, box_b.y0)
    ]
    outside = [f"{t!r} leaves the figure {box}" for t, box in texts if box.x0 < 0 or box.y0 < 0 or box.x1 > width
               or box.y1 > height]  # fmt: skip
    return problems + outside


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("figure", FIGURES)
def test_no_text_of_a_report_figure_overlaps_another_or_leaves_the_figure(figure, case):
    fig = FIGURES[figure](CASES[case])
    texts = drawn_texts(fig)
    assert len(texts) > 5  # titles, axis labels, ticks and legend were all found
    problems = collisions(texts, fig.bbox.width, fig.bbox.height)
    assert not problems, "\n".join(problems)


def test_latency_values_read_as_the_tables_write_them_and_stay_in_their_panel():
    fig = curves.latency_bars(latency_board(CASES["six rows"]), labels(CASES["six rows"]))
    texts = dict(drawn_texts(fig))
    values = [t for t in texts if t.endswith(" ms")]
    assert values == ["4.00 ms", "19.95 ms", "99.50 ms", "496.29 ms", "2,475.27 ms", "12,345.60 ms"]  # geometric
    total = fig.axes[0].get_window_extent()
    assert all(total.x0 < texts[v].x0 and texts[v].x1 < total.x1 for v in values)
    one = dict(drawn_texts(curves.latency_bars(latency_board(DEFAULT_RUN), labels(DEFAULT_RUN))))
    assert "1,001.85 ms" in one and not any("e+" in t for t in one)


def test_a_long_name_is_wrapped_after_its_stages_and_kept_whole():
    name = curves.row_label(*DEFAULT_RUN[0])
    lines = wrapped(name, 44).splitlines()
    assert lines == [
        "lsd > depth+reflectance > superpoint-cnn >",
        "pointnet2 > attention > lightglue >",
        "epnp-ransac (cpu-size)",
        "(edgeregnet-cpu-synthetic@e5fd63c7)",
    ]
    assert " ".join(lines) == name
    assert wrapped("a" * 50, 20).splitlines() == ["a" * 20, "a" * 20, "a" * 10]  # a path with no space is cut


def test_numbers_are_written_with_two_decimals_and_grouped_thousands():
    assert [number(v) for v in (1001.849, 0.5, 12345.6, float("nan"), float("inf"))] == [
        "1,001.85", "0.50", "12,345.60", "-", "inf"
    ]  # fmt: skip
    assert number(2444.9, "ms") == "2,444.90 ms"
    assert [tick(v) for v in (0.01, 0.1, 1.0, 10_000.0)] == ["0.01", "0.1", "1", "10,000"]


def test_a_board_without_stage_timings_still_draws_its_totals():
    board = latency_board(DEFAULT_RUN)[["combination", "weights", LATENCY_MEDIAN]]
    fig = curves.latency_bars(board, labels(DEFAULT_RUN))
    texts = [t for t, _ in drawn_texts(fig)]
    assert "1,001.85 ms" in texts and "extractor2d" not in texts  # no stage legend when no stage was timed
