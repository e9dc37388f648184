"""The report's numbers, worked out by hand: cumulative curves, Acc. against thresholds, best and worst frames."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from i2pbench.report import curves, html
from i2pbench.report.rundir import best_and_worst, frame_score, pose
from i2pbench.scoring.pose import success
from i2pbench.scoring.protocol import Protocol

INF = math.inf


def records(rte, rre, status=None, combination="a", weights="none") -> pd.DataFrame:
    status = status or ["ok" if np.isfinite(r) else "failed" for r in rte]
    return pd.DataFrame(
        {
            "rte_m": rte,
            "rre_deg": rre,
            "status": status,
            "combination": combination,
            "weights": weights,
            "frame_id": [f"00/{i:06d}" for i in range(len(rte))],
        }
    )


def test_cumulative_counts_every_frame_and_failures_never_arrive():
    errors = pd.Series([0.5, 1.0, INF, 3.0])
    assert curves.cumulative_pct(errors, np.array([0.4, 1.0, 2.9, 100.0])).tolist() == [0, 50, 50, 75]


def test_accuracy_against_thresholds_by_hand():
    rte, rre = pd.Series([0.5, 3.0, 1.0]), pd.Series([1.0, 1.0, 6.0])
    got = curves.accuracy_pct(rte, rre, 2.0, np.array([0.5, 2.0, 10.0]))
    np.testing.assert_allclose(got, [0, 100 / 3, 200 / 3])
    np.testing.assert_allclose(curves.accuracy_pct(rte, rre, np.array([0.5, 1.0, 5.0]), 5.0), [0, 100 / 3, 200 / 3])


def test_accuracy_curve_meets_the_leaderboard_acc_at_the_protocol_thresholds():
    protocol = Protocol()
    rng = np.random.default_rng(0)
    rte, rre = pd.Series(rng.uniform(0, 4, 50)), pd.Series(rng.uniform(0, 10, 50))
    at_threshold = curves.accuracy_pct(rte, rre, protocol.acc_rte_m, np.array([protocol.acc_rre_deg]))
    assert at_threshold[0] == pytest.approx(100 * success(rte, rre, protocol).mean())


def test_frames_ordered_in_units_of_the_thresholds_failures_last():
    recs = records([1.0, 0.2, INF, 0.1], [1.0, 4.0, INF, 9.0])
    # 1/2 + 1/5 = 0.7; 0.1 + 0.8 = 0.9; failed; 0.05 + 1.8 = 1.85
    np.testing.assert_allclose(frame_score(recs, Protocol()), [0.7, 0.9, INF, 1.85])
    (best_kind, best), (worst_kind, worst) = best_and_worst(recs, Protocol())
    assert (best_kind, best["frame_id"], worst_kind, worst["frame_id"]) == ("best", "00/000000", "worst", "00/000002")


def test_a_single_frame_is_only_shown_once():
    assert [kind for kind, _ in best_and_worst(records([0.1], [0.1]), Protocol())] == ["best"]


def test_stored_poses_read_back_as_matrices():
    T = np.arange(16.0).reshape(4, 4)
    assert np.array_equal(pose(pd.Series({"T_pred": T.ravel().tolist()}), "T_pred"), T)
    assert pose(pd.Series({"T_pred": None}), "T_pred") is None


def test_rows_follow_the_given_order_and_name_trained_weights():
    recs = pd.concat([records([0.1], [0.1], combination="x"), records([0.1], [0.1], combination="y", weights="w.pt")])
    assert [label for label, _ in curves.rows(recs, [("y", "w.pt"), ("x", "none")])] == ["y (w.pt)", "x"]


def test_table_cells_sort_by_raw_values_and_show_rounded_ones():
    board = pd.DataFrame(
        {
            "combination": ["<b>"],
            "weights": ["none"],
            "RTE (m) ↓": ["0.03 ± 0.01"],
            "rte_mean": [0.0312345],
            "Acc. (%) ↑": [float("nan")],
        }
    )
    out = html.table(board)
    assert '<td data-sort="0.0312345">0.03 ± 0.01</td>' in out
    assert '<td data-sort="">-</td>' in out  # NaN: shown as "-", sorted after every number
    assert "&lt;b&gt;" in out and "<b>" not in out
