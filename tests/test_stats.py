"""Intervals and paired tests against values worked out by hand, and a compare that does not call one frame in twenty a
regression beyond noise."""

import math

import numpy as np
import pandas as pd
import pytest

from i2pbench.boards import leaderboard, stats, uncertainty
from i2pbench.boards.paper_table import TableRow, build
from i2pbench.boards.regression_gate import compare, format_report, parse_tolerances
from i2pbench.cli import main
from i2pbench.scoring.installed import by_name
from i2pbench.stages.components import STAGE_ORDER


def test_the_wilson_interval_of_9_successes_in_20_frames():
    # Wilson's score interval, z = 1.959964 (the 97.5% normal quantile), p = 9/20 = 0.45, n = 20:
    #   z^2 = 3.841459;  1 + z^2/n = 1.192073
    #   centre = (p + z^2/(2n)) / (1 + z^2/n) = (0.45 + 0.096036) / 1.192073 = 0.458058
    #   half   = z * sqrt(p(1-p)/n + z^2/(4n^2)) / (1 + z^2/n)
    #          = 1.959964 * sqrt(0.012375 + 0.002401) / 1.192073 = 1.959964 * 0.121556 / 1.192073 = 0.199859
    #   -> [0.258199, 0.657917]; the normal approximation would give 0.45 -+ 0.218 = [0.232, 0.668]
    low, high = stats.wilson(9, 20)
    assert round(low, 4) == 0.2582 and round(high, 4) == 0.6579
    z = 1.959963984540054
    centre = (0.45 + z**2 / 40) / (1 + z**2 / 20)
    half = z * math.sqrt(0.45 * 0.55 / 20 + z**2 / 1600) / (1 + z**2 / 20)
    assert (low, high) == pytest.approx((centre - half, centre + half), rel=1e-9)


def test_the_wilson_interval_at_all_successes_is_not_zero_width():
    # p = 1: centre - half = (1 + z^2/(2n) - z^2/(2n)) / (1 + z^2/n) = n / (n + z^2) = 6 / 9.841459 = 0.609666
    low, high = stats.wilson(6, 6)
    assert round(low, 4) == 0.6097 and high == pytest.approx(1.0, abs=1e-12)
    assert all(math.isnan(v) for v in stats.wilson(0, 0))


@pytest.mark.parametrize(
    ("only_a", "only_b", "p"),
    [
        (1, 0, 1.0),  # one discordant frame: P(X <= 0) = 1/2, doubled = 1
        (0, 8, 2 / 256),  # 8 of 8 one way: 2 * (1/2)^8 = 0.0078125
        (5, 0, 2 / 32),  # 5 of 5: 0.0625, not below 0.05 (why the 6-frame golden gate cannot use significance)
        (7, 2, 92 / 512),  # P(X <= 2 | 9) = (1 + 9 + 36) / 512 = 46/512, doubled = 0.1796875
    ],
)
def test_mcnemars_exact_p_is_the_doubled_binomial_tail_of_the_discordant_frames(only_a, only_b, p):
    both = 3  # frames both rows register, and 2 neither does: they do not enter the test
    a = [1] * both + [1] * only_a + [0] * only_b + [0, 0]
    b = [1] * both + [0] * only_a + [1] * only_b + [0, 0]
    test = stats.mcnemar(np.array(a), np.array(b))
    assert test.p == pytest.approx(p, rel=1e-12)
    assert test.detail.startswith(f"{only_a} vs {only_b} frames")


def test_the_paired_bootstrap_finds_a_consistent_shift_and_not_a_zero_one():
    a = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, np.nan])  # the last frame is outside a's filter
    shifted = stats.paired_bootstrap(a + 0.5, a)  # every frame 0.5 worse: no resample has a difference <= 0
    assert shifted.p == 0.0 and shifted.significant
    assert stats.paired_bootstrap(a, a).p == 1.0  # no difference to test
    seeded = stats.paired_bootstrap(a + np.array([1, -1, 1, -1, 1, -1, 1, -1, 0]), a)
    assert seeded.p == stats.paired_bootstrap(a + np.array([1, -1, 1, -1, 1, -1, 1, -1, 0]), a).p  # seeded


def _records(successes: list[int], combination: str) -> pd.DataFrame:
    """one row's frames: a success has RTE 0.5 m, a failure RTE 3 m (outside 2 m, inside the 10 m filter)."""
    n = len(successes)
    return pd.DataFrame({
        "dataset": "synthetic", "split": "test", "combination": combination, "weights": "none",
        **{kind: "none" for kind in STAGE_ORDER}, "matcher": "oracle", "status": "ok", "failed_component": "",
        "frame_id": [f"{i:06d}" for i in range(n)], "rte_m": [0.5 if s else 3.0 for s in successes],
        "rre_deg": 1.0, "geodesic_deg": 1.0, "n_matches": 10, "n_true_matches": 10.0, "model_size_mb": 0.0,
        "t_total_s": 0.1,
    })  # fmt: skip


def test_the_board_shows_each_acc_with_its_wilson_interval_and_says_a_one_frame_gap_is_noise():
    board = leaderboard.build(pd.concat([_records([1] * 10 + [0] * 10, "b"), _records([1] * 9 + [0] * 11, "a")]))
    acc = by_name()["acc_pct"]
    assert board["combination"].tolist() == ["b", "a"] and board[leaderboard.ACC].tolist() == [50.0, 45.0]
    assert round(board.loc[1, uncertainty.low(acc)], 2) == 25.82  # 9 of 20, as worked out above
    assert board.loc[1, uncertainty.VERSUS] == "no (McNemar p=1)"  # frame 9 alone: 1 vs 0
    markdown = leaderboard.to_markdown(board)
    assert "| 45.00 | [25.82, 65.79] | no (McNemar p=1) |" in markdown


def test_compare_reports_one_frame_lost_of_20_as_not_significant_and_alpha_lets_it_pass():
    base = leaderboard.build(_records([1] * 10 + [0] * 10, "row"))
    new = leaderboard.build(_records([0] + [1] * 9 + [0] * 10, "row"))  # frame 0 lost: Acc. 50 -> 45
    tolerances = parse_tolerances("acc=-2")
    strict = compare(new, base, tolerances)
    assert not strict.ok  # 5 points beyond the 2-point tolerance: the gate's behaviour without --alpha
    text = format_report(strict)
    assert "acc: 50 -> 45 (-5; limit 48; not significant (McNemar p=1; 0 vs 1 frames" in text
    lenient = compare(new, base, tolerances, alpha=0.05)
    assert lenient.ok and [f.what for f in lenient.moves] == ["acc"]
    assert "moved synthetic / test / row / none" in format_report(
        lenient
    ) and "OK: 1 rows compared, 0 regressed" in format_report(lenient)


def test_compare_with_alpha_still_fails_a_real_regression():
    base = leaderboard.build(_records([1] * 10 + [0] * 10, "row"))
    new = leaderboard.build(_records([0] * 8 + [1] * 2 + [0] * 10, "row"))  # 8 frames lost, none gained
    report = compare(new, base, parse_tolerances("acc=-2"), alpha=0.05)
    assert not report.ok and report.findings[0].test.p == 2 / 256  # 0 vs 8: 2 * (1/2)^8


def test_compare_against_a_board_without_per_frame_values_checks_tolerances_only():
    base = leaderboard.build(_records([1] * 10 + [0] * 10, "row"))
    old = base.drop(columns=[c for c in base.columns if c.startswith("per frame") or c == uncertainty.DIGEST])
    new = leaderboard.build(_records([0] + [1] * 9 + [0] * 10, "row"))
    report = compare(new, old, parse_tolerances("acc=-2"), alpha=0.05)
    assert not report.ok and report.findings[0].test is None  # nothing to pair with: the tolerance decides


def test_the_paper_table_says_whether_a_row_differs_from_the_one_above():
    boards = {
        "KITTI": leaderboard.build(pd.concat([_records([1] * 10 + [0] * 10, "b"), _records([1] * 2 + [0] * 18, "a")]))
    }
    table = build([TableRow("B", "b"), TableRow("A", "a")], boards)
    assert table["KITTI Acc. vs row above"].tolist() == ["", "yes (McNemar p=0.0078)"]  # 8 vs 0: 2/256


@pytest.mark.parametrize("alpha", ["0", "1", "-0.1", "5"])
def test_an_alpha_outside_0_1_is_refused_by_name(alpha, tmp_path, capsys):
    board = tmp_path / "b.csv"
    leaderboard.build(_records([1, 0], "row")).to_csv(board, index=False)
    assert main(["compare", str(board), str(board), "--alpha", alpha]) == 2
    assert f"--alpha {float(alpha):g}: a significance level between 0 and 1" in capsys.readouterr().err
