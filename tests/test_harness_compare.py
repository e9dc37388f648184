"""The regression gate: tolerances, planted regressions, NaN, missing rows, and the CLI's exit status."""

import gzip
import math

import pandas as pd
import pytest

from i2pbench.boards import leaderboard
from i2pbench.boards.leaderboard import ACC, LATENCY_MEDIAN
from i2pbench.boards.regression_gate import Tolerance, compare, format_report, parse_tolerances
from i2pbench.cli import main
from i2pbench.errors import I2PBenchError

GATE = "acc=-2,rte=+0.05,rre=+0.2,latency=x1.5"


def _board(**changes) -> pd.DataFrame:
    """Two rows; `changes` maps (row, column) spelled 'row__column' to a new value."""
    board = pd.DataFrame(
        {
            "dataset": ["kitti", "kitti"],
            "split": ["all", "all"],
            "combination": ["lsd > depth > oracle > poselib", "canny > depth > oracle > poselib"],
            "weights": ["none", "none"],
            "frames": [6, 6],
            "failures": [0, 1],
            ACC: [100.0, 83.33],
            "rte_mean": [0.10, 0.20],
            "rre_mean": [0.50, 0.70],
            LATENCY_MEDIAN: [100.0, 20.0],
        }
    )
    for spec, value in changes.items():
        row, column = spec.split("__")
        board.loc[int(row), {"acc": ACC, "latency": LATENCY_MEDIAN}.get(column, column)] = value
    return board


def _check(new, base=None, tolerance=GATE):
    return compare(new, _board() if base is None else base, parse_tolerances(tolerance))


def test_an_identical_leaderboard_passes():
    report = _check(_board())
    assert report.ok and report.compared == 2
    assert format_report(report).endswith("OK: 2 rows compared, 0 regressed, 0 missing, 0 new")


@pytest.mark.parametrize(
    "change, metric",
    [
        ({"0__acc": 97.9}, "acc"),  # 2.1 points lower, 2 allowed
        ({"1__rte_mean": 0.26}, "rte"),
        ({"0__rre_mean": 0.71}, "rre"),
        ({"1__latency": 30.5}, "latency"),  # 1.525 times slower, 1.5 allowed
        ({"0__rte_mean": math.nan}, "rte"),  # nothing passes the filter any more
        ({"0__frames": 5}, "frames"),
    ],
)
def test_a_planted_regression_fails_naming_row_and_metric(change, metric):
    report = _check(_board(**change))
    assert not report.ok and [f.what for f in report.findings] == [metric]
    assert report.findings[0].row[2] == _board().loc[int(next(iter(change))[0]), "combination"]


def test_changes_within_tolerance_and_improvements_pass():
    new = _board(**{"0__acc": 98.0, "1__rte_mean": 0.25, "0__rre_mean": 0.1, "1__latency": 29.9, "0__latency": 1.0})
    assert _check(new).ok


def test_a_metric_the_baseline_could_not_compute_is_not_a_regression():
    assert _check(_board(**{"0__rte_mean": 9.0}), base=_board(**{"0__rte_mean": math.nan})).ok


def test_a_missing_row_fails_and_a_new_row_is_reported():
    new = _board().iloc[[0]]
    report = _check(new)
    assert [f.what for f in report.findings] == ["missing"]
    assert "missing: in the baseline, not in the new leaderboard" in format_report(report)
    report = _check(_board(), base=_board().iloc[[1]])
    assert report.ok and report.added == [("kitti", "all", "lsd > depth > oracle > poselib", "none")]


def test_a_row_with_other_weights_is_another_row():
    report = _check(_board(**{"0__weights": "edgeregnet@1234abcd"}))
    assert [f.what for f in report.findings] == ["missing"] and len(report.added) == 1


def test_the_report_reads_as_a_diff():
    text = format_report(_check(_board(**{"0__acc": 50.0, "0__rte_mean": 0.2})))
    assert "FAIL  kitti / all / lsd > depth > oracle > poselib / none" in text
    assert "acc: 100 -> 50 (-50; limit 98)" in text
    assert "rte: 0.1 -> 0.2 (+0.1; limit 0.15)" in text
    assert text.endswith("FAIL: 2 rows compared, 1 regressed, 0 missing, 0 new")


@pytest.mark.parametrize(
    "text, message",
    [
        ("latency=+5", "latency tolerances are ratios"),
        ("acc=+2", "write acc=-2"),
        ("rte=-0.1", "write rte=\\+0.1"),
        ("speed=x2", "METRIC=VALUE"),
        ("latency=x0.5", "at least x1"),
        ("rre=abc", "not a number"),
    ],
)
def test_bad_tolerances_are_refused(text, message):
    with pytest.raises(I2PBenchError, match=message):
        parse_tolerances(text)


def test_tolerances_parse_both_sign_spellings():
    assert parse_tolerances("acc=2,rte=+0.05,latency.solver=x3") == [
        Tolerance("acc", slack=2.0),
        Tolerance("rte", slack=0.05),
        Tolerance("latency.solver", ratio=3.0),
    ]


def test_the_cli_exits_1_on_a_regression_and_0_otherwise(tmp_path, capsys):
    base = leaderboard.write(_board(), tmp_path / "base")[0]
    same = leaderboard.write(_board(), tmp_path / "same")[2]  # parquet against CSV
    worse = leaderboard.write(_board(**{"1__acc": 50.0}), tmp_path / "worse")[0]
    assert main(["compare", str(same), str(base), "--tolerance", GATE]) == 0
    assert main(["compare", str(worse), str(base), "--tolerance", GATE]) == 1
    assert "acc: 83.33 -> 50" in capsys.readouterr().out
    assert main(["compare", str(tmp_path / "nope.csv"), str(base)]) == 2


HEADER = "dataset,split,combination,weights,frames,Acc. (%) ↑\n"
ROW = "kitti,all,lsd > depth > oracle > poselib,none,6,100.0\n"
BROKEN = {
    "header only": (HEADER.encode(), "no rows (a header only), so nothing to compare"),
    "empty": (b"", "empty file (0 bytes), not a leaderboard"),
    "gzip bytes": (  # 1f 8b ...: 0x8b cannot start a UTF-8 character
        gzip.compress((HEADER + ROW).encode(), mtime=0),
        "binary, not a CSV leaderboard (byte 1 is not UTF-8 text)",
    ),
    "NUL bytes": (b"\0\0\0\0", "binary, not a CSV leaderboard (character 0 is NUL)"),
    "a short row": ((HEADER + ROW + "kitti,all,x,none\n").encode(), "line 3 has 4 fields, the header 6"),
    "a long row": ((HEADER + ROW.replace("\n", ",7\n")).encode(), "line 2 has 7 fields, the header 6"),
}


@pytest.mark.parametrize("case", BROKEN)
@pytest.mark.parametrize("side", ["new leaderboard", "baseline"])
def test_a_table_the_gate_cannot_trust_exits_2_naming_file_and_fault(tmp_path, capsys, case, side):
    """Not OK (a vacuous pass) nor 1 (a regression) nor a traceback: 2, and one line saying what is wrong."""
    content, problem = BROKEN[case]
    good, broken = tmp_path / "good.csv", tmp_path / "broken.csv"
    good.write_text(HEADER + ROW)
    broken.write_bytes(content)
    args = [str(broken), str(good)] if side == "new leaderboard" else [str(good), str(broken)]
    assert main(["compare", *args, "--tolerance", "acc=-2"]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == f"i2pbench: error: {side} {broken}: {problem}\n"


def test_a_good_csv_with_blank_lines_still_compares(tmp_path, capsys):
    board = tmp_path / "board.csv"
    board.write_text(HEADER + "\n" + ROW + "\n\n")
    assert main(["compare", str(board), str(board), "--tolerance", "acc=-2"]) == 0
    assert capsys.readouterr().out.endswith("OK: 1 rows compared, 0 regressed, 0 missing, 0 new\n")


def test_a_damaged_parquet_exits_2(tmp_path, capsys):
    good = leaderboard.write(_board(), tmp_path / "good")[2]
    damaged = tmp_path / "damaged.parquet"
    damaged.write_bytes(good.read_bytes()[:100])
    assert main(["compare", str(damaged), str(good)]) == 2
    assert capsys.readouterr().err.startswith(f"i2pbench: error: new leaderboard {damaged}: not a readable Parquet")


def test_an_empty_table_is_refused_by_the_api_too():
    with pytest.raises(I2PBenchError, match="baseline: no rows"):
        _check(_board(), base=_board().iloc[[]])


def test_the_help_documents_the_exit_codes(capsys):
    with pytest.raises(SystemExit):
        main(["compare", "--help"])
    codes = "exit status: 0 no regression; 1 a baseline row regressed or is missing; 2 the gate could not run"
    assert codes in " ".join(capsys.readouterr().out.split())
