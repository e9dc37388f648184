"""`i2pbench.run/evaluate/compare` from Python: one code path with the CLI, so the same board cell for cell, the
same exceptions with the same messages, typed results with the tables as DataFrames."""

from pathlib import Path

import pandas as pd
import pytest

import i2pbench
from i2pbench.cli import main
from i2pbench.commands.calls import OptionError
from i2pbench.commands.results import CompareResult, EvaluateResult, RunResult
from i2pbench.errors import PluginError

SMALL = {"frames": 2, "threads": 1, "quiet": True}  # the default pipeline on the synthetic test split's first frames


@pytest.fixture(scope="module")
def both(tmp_path_factory) -> tuple[pd.DataFrame, RunResult, Path]:
    """The same small default run through the CLI and through `i2pbench.run`, each in a store of its own."""
    cli_dir, api_dir = tmp_path_factory.mktemp("cli"), tmp_path_factory.mktemp("api")
    argv = ["run", "--frames", "2", "--threads", "1", "--quiet", "--runs-dir", str(cli_dir / "runs")]
    assert main([*argv, "--out", str(cli_dir / "board")]) == 0
    result = i2pbench.run(**SMALL, runs_dir=api_dir / "runs", out=api_dir / "board")
    return pd.read_parquet(cli_dir / "board.parquet"), result, api_dir


def test_the_api_board_equals_the_cli_board_cell_for_cell_latency_aside(both):
    cli_board, result, _ = both
    timed = [c for c in cli_board.columns if "latency" in c]
    assert timed  # the columns left out exist, and only they differ between two runs
    assert list(result.board.columns) == list(cli_board.columns)
    pd.testing.assert_frame_equal(result.board.drop(columns=timed), cli_board.drop(columns=timed))


def test_the_run_result_holds_the_records_and_where_they_were_stored(both):
    _, result, api_dir = both
    assert isinstance(result, RunResult)
    assert len(result.records) == 2 and result.records["frame_id"].nunique() == 2
    assert result.run_dir == api_dir / "runs" / "synthetic-test"
    assert (result.run_dir / "invocations" / f"{result.invocation}.json").is_file()
    assert {p.name for p in result.files} >= {"board.csv", "board.md", "board.parquet"}
    assert all(p.is_file() for p in result.files)


def test_evaluate_returns_the_same_board_from_the_store_and_every_card_under_rules(both):
    _, result, _ = both
    again = i2pbench.evaluate(result.run_dir)
    assert isinstance(again, EvaluateResult)
    pd.testing.assert_frame_equal(again.board, result.board)
    per_sequence = i2pbench.evaluate(result.run_dir, by_sequence=True).by_sequence
    assert again.by_sequence is None and per_sequence["frames"].iloc[0] == 2
    table = i2pbench.evaluate(result.run_dir, rules="all")
    assert "edgeregnet Acc. (%)" in table.board.columns and table.board["frames"].tolist() == [2]
    assert table.notes[0].startswith("run under")


def test_compare_gives_the_verdict_without_raising(both):
    _, result, api_dir = both
    same = i2pbench.compare(api_dir / "board.parquet", api_dir / "board.parquet", tolerance="acc=-0")
    assert isinstance(same, CompareResult) and same.ok and not same.findings
    worse = result.board.assign(**{"Acc. (%) ↑": result.board["Acc. (%) ↑"] - 50.0})
    worse.to_parquet(api_dir / "worse.parquet")
    verdict = i2pbench.compare(api_dir / "worse.parquet", api_dir / "board.parquet", tolerance="acc=-2")
    assert not verdict.ok and [f.what for f in verdict.findings] == ["acc"]


def test_errors_are_the_cli_exceptions_with_the_cli_messages(tmp_path, capsys):
    assert main(["run", "--dataset", "no-such-data", "--runs-dir", str(tmp_path)]) == 2
    printed = capsys.readouterr().err.strip().removeprefix("i2pbench: error: ")
    with pytest.raises(PluginError) as raised:
        i2pbench.run(dataset="no-such-data", runs_dir=tmp_path)
    assert str(raised.value) == printed


def test_a_value_the_cli_refuses_is_an_option_error_and_an_unknown_keyword_a_type_error():
    with pytest.raises(OptionError, match="argument --frames: '0' is not a positive integer"):
        i2pbench.run(frames=0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'frame'; did you mean 'frames'"):
        i2pbench.run(frame=3)
