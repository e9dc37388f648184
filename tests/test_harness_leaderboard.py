"""Leaderboard aggregation with values worked out by hand, and its files."""

import math

import numpy as np
import pandas as pd
import pytest

from i2pbench.boards import leaderboard
from i2pbench.boards.leaderboard import (
    ACC,
    ACC_SKILL,
    CHANCE,
    INLIER_RATIO,
    LATENCY_MEDIAN,
    LATENCY_P90,
    RRE,
    RTE,
    TRUE_MATCHES,
    stage_latency,
)
from i2pbench.stages.components import STAGE_ORDER


def _records(combination: str, rte, rre, t_total, crashed=()) -> pd.DataFrame:
    n = len(rte)
    rows = {
        "dataset": "kitti",
        "split": "test",
        "combination": combination,
        "weights": "none",
        "weights_trained_on": "",
        **{kind: "none" for kind in STAGE_ORDER},
        "extractor2d": combination,
        "frame_id": [f"{i:06d}" for i in range(n)],
        "status": ["ok" if math.isfinite(e) else "failed" for e in rte],
        "failed_component": ["dataset 'kitti'" if i in crashed else "" for i in range(n)],
        "rte_m": rte,
        "rre_deg": rre,
        "geodesic_deg": rre,
        "model_size_mb": 0.0,
        "t_total_s": t_total,
        "t_solver_s": [t / 2 for t in t_total],
    }
    return pd.DataFrame(rows)


@pytest.fixture
def board():
    a = _records("a", [0.1, 0.3, 3.0, math.inf], [1.0, 3.0, 8.0, math.inf], [0.010, 0.020, 0.030, 0.0], crashed=(3,))
    b = _records("b", [0.2, 0.2], [1.0, 1.0], [0.001, 0.001])
    return leaderboard.build(pd.concat([a, b], ignore_index=True))


def test_one_row_per_combination_best_accuracy_first(board):
    assert list(board["combination"]) == ["b", "a"]
    assert list(board["frames"]) == [2, 4] and list(board["failures"]) == [0, 1]


def test_accuracy_counts_every_frame_and_errors_average_the_filtered_ones(board):
    row = board.set_index("combination").loc["a"]
    assert row[ACC] == 50.0  # frames 0 and 1 have RRE < 5 and RTE < 2; the failure counts against
    assert row["kept"] == 3  # frame 2 (RTE 3 m, RRE 8°) passes the filter RTE < 5, RRE < 10
    assert row["rte_mean"] == pytest.approx((0.1 + 0.3 + 3.0) / 3)
    assert row["rte_std"] == pytest.approx(
        np.sqrt(((0.1 - 3.4 / 3) ** 2 + (0.3 - 3.4 / 3) ** 2 + (3 - 3.4 / 3) ** 2) / 3)
    )
    assert row["rre_mean"] == pytest.approx(4.0) and row["rre_std"] == pytest.approx(np.sqrt(26 / 3))
    assert row[RTE] == "1.13 ± 1.32" and row[RRE] == "4.00 ± 2.94"


def test_latency_is_over_frames_whose_pipeline_ran_with_median_and_p90_per_stage(board):
    row = board.set_index("combination").loc["a"]
    assert row[LATENCY_MEDIAN] == pytest.approx(20.0)  # 10, 20, 30 ms; the crashed frame's 0 ms is left out
    assert row[LATENCY_P90] == pytest.approx(28.0)  # linear interpolation: 20 + 0.8 * 10
    assert row[stage_latency("solver", "median")] == pytest.approx(10.0)
    assert row[stage_latency("solver", "p90")] == pytest.approx(14.0)
    assert stage_latency("matcher", "median") not in board  # no record timed a matcher


def test_nothing_inside_the_filter_gives_nan_errors_not_zero():
    board = leaderboard.build(_records("far", [4.0, 6.0], [20.0, 30.0], [0.01, 0.01]))
    assert board.loc[0, ACC] == 0.0 and np.isnan(board.loc[0, "rte_mean"]) and board.loc[0, RTE] == "-"


def test_inlier_ratio_averages_frames_with_matches_and_true_matches_take_the_median_where_the_matcher_ran():
    records = _records("m", [0.1, 0.1, 0.1, math.inf], [1.0, 1.0, 1.0, math.inf], [0.01] * 4, crashed=(3,))
    records["n_matches"] = [10, 4, 0, 0]
    records["n_true_matches"] = [5.0, 1.0, 0.0, math.nan]  # frame 3 crashed before its matcher ran
    row = leaderboard.build(records).iloc[0]
    assert row[INLIER_RATIO] == pytest.approx(37.5)  # (5/10 + 1/4) / 2; frame 2 has no match to be right or wrong
    assert row[TRUE_MATCHES] == 1.0  # median of 5, 1, 0


def test_records_without_match_counts_give_nan_match_quality(board):
    assert board[INLIER_RATIO].isna().all() and board[TRUE_MATCHES].isna().all()
    assert board[CHANCE].isna().all() and board[ACC_SKILL].isna().all()


def test_a_success_with_fewer_than_four_true_matches_is_counted_as_chance():
    # frames: success with 10 true matches; successes with 3 and 0 (chance); a success whose matcher never ran
    # (NaN: chance); a failure with 12 true matches
    records = _records("m", [0.1, 0.2, 0.3, 0.4, 9.0], [1.0, 1.0, 1.0, 1.0, 20.0], [0.01] * 5)
    records["n_matches"] = [40, 30, 20, 0, 50]
    records["n_true_matches"] = [10.0, 3.0, 0.0, math.nan, 12.0]
    row = leaderboard.build(records).iloc[0]
    assert row[ACC] == 80.0  # 4 of 5 frames inside RRE < 5 and RTE < 2: the peers' Acc., luck included
    assert row[CHANCE] == 3
    assert row[ACC_SKILL] == 20.0  # only frame 0 registered from true matches
    assert CHANCE in leaderboard.to_markdown(leaderboard.build(records)).splitlines()[0]


def test_files_round_trip_and_markdown_has_arrows(board, tmp_path):
    paths = leaderboard.write(board, tmp_path / "sub" / "kitti.sample")
    assert [p.name for p in paths] == ["kitti.sample.csv", "kitti.sample.md", "kitti.sample.parquet"]
    for path in (paths[0], paths[2]):
        pd.testing.assert_frame_equal(leaderboard.read(path), board, check_dtype=False)
    markdown = paths[1].read_text()
    assert "| Acc. (%) ↑ |" in markdown and "RTE (m) ↓" in markdown and "latency p90 (ms) ↓" in markdown
    assert markdown.count("\n") == 2 + len(board)


def test_markdown_shows_trained_on_only_when_some_row_has_weights(board):
    assert "weights_trained_on" not in leaderboard.to_markdown(board)
    board.loc[0, ["weights", "weights_trained_on"]] = ["edgeregnet@0123abcd", "synthetic/train, 20000 steps"]
    assert "| edgeregnet@0123abcd | synthetic/train, 20000 steps |" in leaderboard.to_markdown(board)
