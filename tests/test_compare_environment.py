"""`i2pbench compare` warns, without failing, when two boards come from different package or generator versions: each
board's `<stem>.env.json` (or its run's store) says which invocations, and so which environments, made it."""

import json
from pathlib import Path

import numpy as np
import pandas as pd

from i2pbench.boards import leaderboard
from i2pbench.cli import main
from i2pbench.runs import board_env
from i2pbench.runs.invocation import Invocation
from i2pbench.runs.store import ResultsStore

ROW = {"dataset": "synthetic", "split": "test", "combination": "lsd > depth > oracle > poselib", "weights": "none"}
# the rest of a frame's record as the store requires it (`store.REQUIRED`): one solved frame
SCORED = {"frame_id": "00/000000", "status": "ok", "failed_component": "", "rte_m": 0.1, "rre_deg": 0.5}
TIMED = {"geodesic_deg": 0.5, "model_size_mb": 0.0, "t_total_s": 0.2}
BOARD = pd.DataFrame([{**ROW, "frames": 3, "Acc. (%) ↑": 100.0, "rte_mean": 0.1, "rre_mean": 0.5}])


def _invocation(store: Path, numpy: str = "2.4.6", generator: int = 5) -> str:
    env = {"packages": {"numpy": numpy, "torch": "2.13.0"}, "python": "3.11.7", "git_commit": "abc1234"}
    dataset = {"dataset": "synthetic", "split": "test", "generator_version": generator}
    return Invocation(store, {"environment": env, "dataset": dataset}).id


def _board(tmp_path: Path, name: str, **versions) -> Path:
    """A board written as `i2pbench run` writes it, its frames computed by one invocation at `versions`."""
    store = tmp_path / "stores" / name
    invocation = _invocation(store, **versions)
    leaderboard.write(BOARD, tmp_path / name)
    board_env.write(tmp_path / name, store, pd.DataFrame({"invocation": [invocation]}))
    return tmp_path / f"{name}.csv"


def _compare(capsys, new: Path, base: Path) -> list[str]:
    """The warning lines; the gate itself passes (equal metrics), so a warning never fails it."""
    assert main(["compare", str(new), str(base)]) == 0
    captured = capsys.readouterr()
    assert captured.out.endswith("OK: 1 rows compared, 0 regressed, 0 missing, 0 new\n")
    return captured.err.splitlines()


def test_equal_environments_give_no_warning(tmp_path, capsys):
    assert _compare(capsys, _board(tmp_path, "new"), _board(tmp_path, "base")) == []


def test_a_numpy_version_that_differs_is_named_with_both_versions(tmp_path, capsys):
    new, base = _board(tmp_path, "new", numpy="2.4.6"), _board(tmp_path, "base", numpy="2.3.1")
    assert _compare(capsys, new, base) == [
        "i2pbench: warning: the boards come from different numpy versions: 2.4.6 (new) vs 2.3.1 (baseline); "
        "a difference in results may come from it, not from the code"
    ]


def test_a_generator_version_that_differs_is_named_with_both_versions(tmp_path, capsys):
    new, base = _board(tmp_path, "new", generator=6), _board(tmp_path, "base", generator=5)
    (line,) = _compare(capsys, new, base)
    assert "different synthetic generator versions (generator_version): 6 (new) vs 5 (baseline)" in line


def test_both_differences_are_reported_each_on_its_line(tmp_path, capsys):
    new = _board(tmp_path, "new", numpy="2.4.6", generator=6)
    lines = _compare(capsys, new, _board(tmp_path, "base", numpy="2.3.1", generator=5))
    assert len(lines) == 2 and "numpy versions: 2.4.6 (new) vs 2.3.1" in lines[0] and "6 (new) vs 5" in lines[1]


def test_a_board_without_a_record_warns_that_its_environment_is_unknown(tmp_path, capsys):
    new = _board(tmp_path, "new")
    base = leaderboard.write(BOARD, tmp_path / "base")[0]
    assert _compare(capsys, new, base) == [
        f"i2pbench: warning: baseline {base} has no environment record (base.env.json beside it, or its run's "
        "store): its package and generator versions are unknown, so a difference in them would go unnoticed"
    ]


def test_a_board_whose_frames_two_invocations_computed_lists_both_versions(tmp_path, capsys):
    store = tmp_path / "stores" / "mixed"
    ids = [_invocation(store, numpy="2.3.1"), _invocation(store, numpy="2.4.6")]
    leaderboard.write(BOARD, tmp_path / "mixed")
    board_env.write(tmp_path / "mixed", store, pd.DataFrame({"invocation": ids}))
    (line,) = _compare(capsys, tmp_path / "mixed.csv", _board(tmp_path, "base", numpy="2.4.6"))
    assert "numpy versions: 2.3.1, 2.4.6 (new) vs 2.4.6 (baseline)" in line


def test_a_board_without_a_record_is_traced_to_its_runs_store_in_the_default_layout(tmp_path, capsys):
    """runs/leaderboards/<name>.csv beside runs/<name>/: the invocations that computed the board's rows count, not
    one that computed another combination in the same store."""
    runs = tmp_path / "runs"
    store = ResultsStore(runs / "synthetic-test")
    old, other = _invocation(store.root, numpy="2.3.1"), _invocation(store.root, numpy="1.26.4")
    store.put("a", {**ROW, **SCORED, **TIMED, "invocation": old})
    store.put("b", {**ROW, **SCORED, **TIMED, "combination": "canny > depth > oracle > poselib", "invocation": other})
    store.put("c", {**ROW, **SCORED, **TIMED})  # written before records named their invocation: traces to none
    board = leaderboard.write(BOARD, runs / "leaderboards" / "synthetic-test")[0]
    assert [i["id"] for i in board_env.read(board, BOARD)["invocations"]] == [old]
    (line,) = _compare(capsys, board, _board(tmp_path, "base", numpy="2.4.6"))
    assert "numpy versions: 2.3.1 (new) vs 2.4.6 (baseline)" in line


def test_a_run_records_its_environment_beside_its_board_and_compare_reads_it(shared_data, tmp_path, capsys):
    def run(name: str) -> Path:
        argv = ["run", "--matcher", "oracle", "--dataset", "kitti", "--split", "all", "--frames", "1", "--threads",
                "1", "--quiet", "--data-root", str(shared_data / "kitti_odometry"), "--runs-dir",
                str(tmp_path / name), "--out", str(tmp_path / name / "board")]  # fmt: skip
        assert main(argv) == 0
        return tmp_path / name / "board.csv"

    new, base = run("new"), run("base")
    capsys.readouterr()
    sidecar = tmp_path / "base" / "board.env.json"
    (invocation,) = json.loads(sidecar.read_text())["invocations"]
    (meta,) = (tmp_path / "base" / "kitti-all" / "invocations").glob("*.json")
    assert invocation["id"] == meta.stem and invocation["environment"]["packages"]["numpy"] == np.__version__
    assert main(["compare", str(new), str(base)]) == 0 and capsys.readouterr().err == ""
    assert main(["evaluate", str(meta.parent.parent), "--out", str(tmp_path / "evaluated")]) == 0
    assert json.loads((tmp_path / "evaluated.env.json").read_text())["invocations"] == [invocation]
    invocation["environment"]["packages"]["numpy"] = "1.26.4"
    sidecar.write_text(json.dumps({"invocations": [invocation]}))
    assert main(["compare", str(new), str(base)]) == 0
    assert f"different numpy versions: {np.__version__} (new) vs 1.26.4 (baseline)" in capsys.readouterr().err
