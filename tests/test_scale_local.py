"""`run --workers N`: a spawned process pool gives the serial run's records and leaderboard, writes the same store,
keeps frame failures as records, resumes, and plans (combination, chunk) tasks as worked out by hand."""

import subprocess
import sys

import pandas as pd
import pytest
import toy_plugin

from i2pbench.boards import leaderboard
from i2pbench.errors import I2PBenchError
from i2pbench.registry.build import build_registry, default_registry
from i2pbench.runs import executors
from i2pbench.runs.executors import LocalExecutor, Plan, Task, make_executor, run_grid
from i2pbench.runs.grid import expand
from i2pbench.runs.invocation import history
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination

BASE = {"extractor3d": "depth", "matcher": "oracle", "solver": "epnp-ransac"}
GRID = {"extractor2d": ["canny", "sobel"]}
RESULTS = ["combination", "frame_id", "status", "error", "rte_m", "rre_deg", "n_kp2d", "n_matches", "T_pred"]
TOY = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}


@pytest.fixture
def kitti(shared_data):
    from i2pbench.data.kitti import KittiOdometry

    return KittiOdometry("all", {"root": str(shared_data / "kitti_odometry")})


def _results(records: pd.DataFrame) -> pd.DataFrame:
    return records[RESULTS].reset_index(drop=True)


def _same_board(a: pd.DataFrame, b: pd.DataFrame) -> None:
    board_a, board_b = leaderboard.build(a), leaderboard.build(b)
    latency = leaderboard.latency_columns(board_a)
    pd.testing.assert_frame_equal(board_a.drop(columns=latency), board_b.drop(columns=latency))


def test_chunks_spread_each_combinations_missing_frames_over_the_workers():
    frames = [f"f{i}" for i in range(7)]
    keys = {(j, f): f"{j}{f}" for j in range(2) for f in frames}
    plan = Plan(keys, {}, {0: frames, 1: frames[5:]})
    # job 0: 7 frames over 2 workers -> chunks of ceil(7/2) = 4; job 1: 2 frames -> chunks of 1
    assert [t.frame_ids for t in plan.tasks(workers=2)] == [
        ("f0", "f1", "f2", "f3"), ("f4", "f5", "f6"), ("f5",), ("f6",)
    ]  # fmt: skip
    assert [len(t.frame_ids) for t in plan.tasks(workers=2, chunk_size=3)] == [3, 3, 1, 1, 1]
    assert [len(t.frame_ids) for t in plan.tasks(workers=1)] == [7, 2]  # one worker: whole jobs, up to chunk_size
    assert plan.tasks(workers=1, chunk_size=3)[1] == Task(0, ("f3", "f4", "f5"), ("0f3", "0f4", "0f5"))
    assert plan.to_compute == 9


def test_two_workers_give_the_serial_records_and_leaderboard_on_real_kitti_frames(kitti, tmp_path):
    registry, combos, frames = default_registry(), expand([BASE], GRID), kitti.frame_ids()[:3]
    serial = run_grid(registry, combos, kitti, Protocol(), ResultsStore(tmp_path / "serial"), frame_ids=frames)
    store = ResultsStore(tmp_path / "pool")
    pooled = executors.run_grid(registry, combos, kitti, Protocol(), store, LocalExecutor(2), frame_ids=frames)
    pd.testing.assert_frame_equal(_results(pooled), _results(serial))
    _same_board(pooled, serial)
    assert (pooled["threads"] == 1).all()  # each worker pinned to one thread
    assert len(list(store.frames_dir.glob("*.parquet"))) == 6  # written by the workers, one file per frame
    pd.testing.assert_frame_equal(
        _results(store.load().sort_values(["combination", "frame_id"])), _results(serial), check_like=True
    )


def test_a_rerun_computes_only_the_frames_not_stored(kitti, tmp_path):
    registry, combos, frames = default_registry(), expand([BASE], GRID), kitti.frame_ids()[:3]
    store = ResultsStore(tmp_path / "runs")
    run_grid(registry, combos[:1], kitti, Protocol(), store, frame_ids=frames[:2], invocation="first")
    records = executors.run_grid(
        registry, combos, kitti, Protocol(), store, LocalExecutor(2), frame_ids=frames, invocation="second"
    )
    assert records["invocation"].tolist() == ["first", "first", "second", "second", "second", "second"]
    untouched = executors.run_grid(registry, combos, kitti, Protocol(), store, _Unstartable(), frame_ids=frames)
    pd.testing.assert_frame_equal(untouched, records)  # all stored: no worker starts


def test_frame_failures_stay_per_frame_records(tmp_path, monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))
    combos = [Combination(TOY), Combination({**TOY, "extractor3d": "boom"})]
    dataset = toy_plugin.ToyDataset("test", {})
    serial = run_grid(registry, combos, dataset, Protocol(), ResultsStore(tmp_path / "serial"))
    store = ResultsStore(tmp_path / "pool")
    pooled = executors.run_grid(registry, combos, dataset, Protocol(), store, LocalExecutor(2))
    pd.testing.assert_frame_equal(_results(pooled), _results(serial))
    assert pooled["status"].tolist() == ["ok", "failed", "ok", "failed", "failed", "failed"]
    assert pooled["failed_component"].tolist()[:2] == ["", "dataset 'toy'"]
    assert "exploded on purpose" in pooled["error"].iloc[3]


def test_a_frame_two_spellings_of_one_combination_share_is_computed_once(tmp_path, monkeypatch, counted):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    learned = {**TOY, "encoder2d": "linear"}
    combos = [Combination(learned), Combination(learned, {"encoder2d": {"dim": 4}})]  # 4 is the default: same keys
    ticks: list[int] = []
    records = run_grid(
        build_registry((toy_plugin,)), combos, toy_plugin.ToyDataset("test", {}), Protocol(),
        ResultsStore(tmp_path), progress=ticks.append,
    )  # fmt: skip
    assert counted == ["a", "bad", "c"] and sum(ticks) == 6
    assert records["combination"].tolist() == [combos[0].display] * 3 + [combos[1].display] * 3
    first, second = (_results(records.iloc[rows]).drop(columns="combination") for rows in (slice(3), slice(3, 6)))
    pd.testing.assert_frame_equal(first, second)


def test_the_cli_runs_two_workers_and_records_the_executor(kitti, tmp_path):
    cmd = [
        sys.executable, "-m", "i2pbench.cli", "run", "--extractor", "canny", "--extractor3d", "depth", "--matcher",
        "oracle", "--solver", "epnp-ransac", "--dataset", "kitti", "--split", "all", "--data-root", kitti.conf["root"],
        "--frames", "2", "--runs-dir", str(tmp_path / "runs"), "--out", str(tmp_path / "board"), "--workers", "2",
        "--quiet",
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    (meta,) = history(tmp_path / "runs" / "kitti-all")
    assert meta["status"] == "finished" and meta["computed"] == 2
    assert meta["executor"] == {"executor": "local", "workers": 2, "threads_per_worker": 1, "address": None}
    assert leaderboard.read(tmp_path / "board.csv")["frames"].tolist() == [2]


def test_one_worker_runs_serially_and_wrong_choices_are_refused(monkeypatch):
    assert make_executor("local", None) is None and make_executor("local", 1) is None
    assert isinstance(make_executor("local", 3, threads=2), LocalExecutor)
    with pytest.raises(I2PBenchError, match="--address names a Ray cluster"):
        make_executor("local", 2, address="auto")
    with pytest.raises(I2PBenchError, match="at least 1"):
        LocalExecutor(0)
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the extra were not installed
    with pytest.raises(I2PBenchError, match=r"pip install 'i2pbench\[ray\]'"):
        make_executor("ray", 2)


class _Unstartable:
    """An executor that fails the test if the run needs a worker."""

    workers = 1

    def start(self, work, store):
        raise AssertionError("nothing to compute, yet a worker was started")
