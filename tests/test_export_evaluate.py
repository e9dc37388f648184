"""Export, then evaluate: a solver sweep over a stored run re-solves from the stored keypoints and matches (no dataset
file read, no extractor or matcher run) and gives a fresh run's rows; `i2pbench evaluate` rebuilds the leaderboard
from the store alone; stores without upstreams, or with a damaged one, are run whole as before."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pandas as pd
import pytest
import toy_plugin
from i2pbench_classic.extract2d import CannyExtractor
from i2pbench_classic.extract3d import DepthExtractor
from i2pbench_classic.matchers import OracleMatcher

from i2pbench.boards import leaderboard
from i2pbench.cli import main
from i2pbench.data.kitti import KittiOdometry
from i2pbench.registry.build import build_registry, default_registry
from i2pbench.runs import frames
from i2pbench.runs.executors import run_grid
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination, Pipeline

STAGES = {"extractor2d": "canny", "extractor3d": "depth", "matcher": "oracle"}
FIRST = Combination({**STAGES, "solver": "epnp-ransac"})
SWEEP = [  # a RANSAC threshold and another solver over the same upstream; FIRST is already stored
    FIRST,
    Combination({**STAGES, "solver": "epnp-ransac"}, {"solver": {"reprojection_error_px": 3.0}}),
    Combination({**STAGES, "solver": "poselib"}),
]
FRAMES = 3
# what a re-solved record may differ in from a fresh one: when and how long, and which stages ran
RUN_ONLY = {"invocation", "wall_s", "stages_run"}
WHOLE = "extractor2d,extractor3d,matcher,solver"


@pytest.fixture
def kitti(shared_data) -> KittiOdometry:
    return KittiOdometry("all", {"root": str(shared_data / "kitti_odometry")})


@pytest.fixture
def calls(monkeypatch) -> Counter:
    """Calls of the stages before the solver, and reads of dataset frames."""
    counts: Counter = Counter()
    for cls, name in ((CannyExtractor, "extractor2d"), (DepthExtractor, "extractor3d"), (OracleMatcher, "matcher")):
        monkeypatch.setattr(cls, "__call__", _counting(cls.__call__, counts, name))
    monkeypatch.setattr(KittiOdometry, "load", _counting(KittiOdometry.load, counts, "load"))
    return counts


def _counting(method, counts: Counter, name: str):
    def counted(self, *args):
        counts[name] += 1
        return method(self, *args)

    return counted


def _run(kitti, store, combinations, whole=False):
    """`whole`: every frame through every stage, as before upstreams were stored (overwrite reuses nothing)."""
    frame_ids = kitti.frame_ids()[:FRAMES]
    return run_grid(default_registry(), combinations, kitti, Protocol(), store, frame_ids=frame_ids, overwrite=whole)


def _results(records: pd.DataFrame) -> pd.DataFrame:
    kept = [c for c in records.columns if c not in RUN_ONLY and not c.startswith("t_")]
    return records[kept].reset_index(drop=True)


def test_a_solver_sweep_over_a_run_reruns_no_stage_before_the_solver_and_equals_a_fresh_run(kitti, calls, tmp_path):
    store = ResultsStore(tmp_path / "run")
    first = _run(kitti, store, [FIRST])
    assert calls == {"extractor2d": FRAMES + 1, "extractor3d": FRAMES + 1, "matcher": FRAMES + 1, "load": FRAMES + 1}
    upstreams = sorted(store.frames_dir.glob("*.npz"))
    assert len(upstreams) == FRAMES  # one per frame, shared by every solver
    with np.load(upstreams[0]) as stored:
        assert stored["uv"].dtype == stored["xyz"].dtype == stored["score"].dtype == np.float32
        assert stored["index2d"].dtype == stored["kp3d_index"].dtype == np.int32

    calls.clear()
    sweep = _run(kitti, store, SWEEP)
    assert calls == {}  # no extractor, matcher or dataset read: the upstream came from the store
    resolved = sweep.iloc[FRAMES:]
    assert set(first["stages_run"]) == {WHOLE} and set(resolved["stages_run"]) == {"solver"}
    for kind in ("extractor2d", "extractor3d", "matcher"):  # the stored upstream timings, kept in the record
        column = f"t_{kind}_s"
        assert list(resolved[column]) == list(first[column]) * 2
    assert len(set(resolved["upstream_key"])) == FRAMES and set(resolved["upstream_key"]) == set(first["upstream_key"])

    fresh = _run(kitti, ResultsStore(tmp_path / "fresh"), SWEEP, whole=True)
    assert set(fresh["stages_run"]) == {WHOLE}
    pd.testing.assert_frame_equal(_results(sweep), _results(fresh))
    poselib = sweep[sweep["solver"] == "poselib"]
    assert (poselib["status"] == "ok").all() and (poselib["rte_m"] < 0.1).all()  # the oracle's matches solve


def test_evaluate_reproduces_the_run_leaderboard_and_applies_other_thresholds(shared_data, tmp_path, monkeypatch):
    runs = tmp_path / "runs"
    argv = ["run", "--extractor", "canny", "--extractor3d", "depth", "--matcher", "oracle", "--solver",
            "epnp-ransac,poselib", "--dataset", "kitti", "--split", "all", "--data-root",
            str(shared_data / "kitti_odometry"), "--frames", str(FRAMES), "--runs-dir", str(runs),
            "--quiet"]  # fmt: skip
    assert main(argv) == 0
    monkeypatch.setattr(KittiOdometry, "load", _refuse)  # evaluate reads no dataset file
    monkeypatch.setattr(Pipeline, "build", _refuse)  # and builds no stage
    store = runs / "kitti-all"
    assert main(["evaluate", str(store), "--out", str(tmp_path / "again")]) == 0
    run_board, again = (
        leaderboard.read(runs / "leaderboards" / "kitti-all-canny-depth-oracle-epnp-ransac+poselib.csv"),
        leaderboard.read(tmp_path / "again.csv"),
    )
    latency = leaderboard.latency_columns(run_board)
    pd.testing.assert_frame_equal(again.drop(columns=latency), run_board.drop(columns=latency))

    records = ResultsStore(store).load()
    rre_max, rte_max = float(records["rre_deg"].median()), float(records["rte_m"].median())  # stricter than 5° / 2 m
    assert main(["evaluate", str(store), "--acc-rre", str(rre_max), "--acc-rte", str(rte_max), "--out",
                 str(tmp_path / "strict")]) == 0  # fmt: skip
    strict = leaderboard.read(tmp_path / "strict.csv").set_index("combination")[leaderboard.ACC]
    by_hand = {}
    for combination, group in records.groupby("combination"):
        wins = sum(
            1 for rre, rte in zip(group["rre_deg"], group["rte_m"], strict=True) if rre < rre_max and rte < rte_max
        )
        by_hand[combination] = round(100.0 * wins / len(group), 2)
    assert strict.to_dict() == by_hand
    assert set(run_board[leaderboard.ACC]) == {100.0} and min(by_hand.values()) < 100.0  # the thresholds bite


def _refuse(*args, **kwargs):
    raise AssertionError("evaluate must work from the store alone")


def test_a_store_written_before_upstreams_is_run_whole_and_then_exported(kitti, calls, tmp_path):
    store = ResultsStore(tmp_path / "old")
    _run(kitti, store, [FIRST])
    for path in store.frames_dir.glob("*.npz"):  # as a store from before upstreams were exported
        path.unlink()
    for path in store.frames_dir.glob("*.parquet"):
        record = store.get(path.stem)
        store.put(path.stem, {k: v for k, v in record.items() if k not in ("upstream_key", "stages_run")})
    calls.clear()

    sweep = _run(kitti, store, SWEEP[::2])  # FIRST from the store as it was, poselib computed whole
    assert calls == {"extractor2d": FRAMES + 1, "extractor3d": FRAMES + 1, "matcher": FRAMES + 1, "load": FRAMES + 1}
    assert sweep["stages_run"].isna().sum() == FRAMES  # the old records, reused untouched
    assert len(list(store.frames_dir.glob("*.npz"))) == FRAMES  # exported now, for the next sweep
    fresh = _run(kitti, ResultsStore(tmp_path / "fresh"), SWEEP[::2], whole=True)
    pd.testing.assert_frame_equal(_results(sweep.iloc[FRAMES:]), _results(fresh.iloc[FRAMES:]))


TOY = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}


def test_a_damaged_upstream_is_set_aside_and_its_frame_run_whole(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))
    dataset, store = registry.dataset("toy")("test"), ResultsStore(tmp_path)
    run_grid(registry, [Combination(TOY)], dataset, Protocol(), store)
    for path in store.frames_dir.glob("*.parquet"):  # records gone, upstreams kept: each frame is to be re-solved
        path.unlink()
    damaged = sorted(store.frames_dir.glob("*.npz"))[0]
    with np.load(damaged) as arrays:
        damaged_frame = str(arrays["frame"][1])
    damaged.write_bytes(damaged.read_bytes()[:100])  # as a power cut could leave it
    whole, real = [], frames.compute_frame

    def compute_frame(ctx, frame_id, up_key=None):
        whole.append(frame_id)
        return real(ctx, frame_id, up_key)

    monkeypatch.setattr(frames, "compute_frame", compute_frame)
    records = run_grid(registry, [Combination(TOY)], dataset, Protocol(), store, overwrite=False)
    assert sorted(whole) == sorted(
        ["bad", damaged_frame]
    )  # the dataset error has no upstream; the damaged one is refused
    assert f"{damaged}" in capsys.readouterr().err and damaged.with_name(damaged.name + ".corrupt").is_file()
    assert list(records["status"]) == ["ok", "failed", "ok"]
    stages = dict(zip(records["frame_id"], records["stages_run"], strict=True))
    assert stages.pop("bad") == "" and stages.pop(damaged_frame) == WHOLE
    assert list(stages.values()) == ["solver"]


def test_a_frame_s_upstream_key_is_computed_once_whether_run_whole_or_re_solved(monkeypatch, tmp_path):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))
    dataset, store = registry.dataset("toy")("test"), ResultsStore(tmp_path)
    keyed, real = Counter(), frames.upstream_key

    def upstream_key(data, frame_id, job, protocol):
        keyed[frame_id] += 1
        return real(data, frame_id, job, protocol)

    monkeypatch.setattr(frames, "upstream_key", upstream_key)
    whole = run_grid(registry, [Combination(TOY)], dataset, Protocol(), store)
    assert keyed == dict.fromkeys(whole["frame_id"], 1)  # the failed load ("bad") included
    for path in store.frames_dir.glob("*.parquet"):  # records gone, upstreams kept: re-solved from the store
        path.unlink()
    keyed.clear()
    resolved = run_grid(registry, [Combination(TOY)], dataset, Protocol(), store)
    assert keyed == dict.fromkeys(whole["frame_id"], 1)
    assert list(resolved["stages_run"]) == ["solver", "", "solver"]
    assert list(resolved["upstream_key"]) == list(whole["upstream_key"])
