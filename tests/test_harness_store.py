"""The results store and the runner's caching: what is done is reused, damaged files are recomputed, history is kept."""

import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import toy_plugin

from i2pbench.boards import leaderboard
from i2pbench.registry.build import build_registry
from i2pbench.runs.executors import run_grid
from i2pbench.runs.invocation import Invocation, history
from i2pbench.runs.jobs import frame_key, prepare
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination

BASE = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}
# The columns a result must hold, with values of their types; tests add what they check.
RESULT = {
    **dict.fromkeys(["dataset", "split", "combination", "weights", "status", "failed_component"], ""),
    **dict.fromkeys(["rte_m", "rre_deg", "geodesic_deg", "model_size_mb", "t_total_s"], 0.0),
}


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    return build_registry((toy_plugin,))


def _run(registry, store, **kwargs):
    dataset = registry.dataset("toy")("test")
    return run_grid(registry, [Combination(BASE)], dataset, Protocol(), store, **kwargs)


def test_put_then_get_round_trips_a_record(tmp_path):
    store = ResultsStore(tmp_path)
    pose = [float(v) for v in range(16)]
    record = {**RESULT, "frame_id": "a", "rte_m": 0.5, "T_pred": pose, "error": "", "t_encoder2d_s": float("nan")}
    store.put("k", record)
    got = store.get("k")
    assert got["frame_id"] == "a" and got["rte_m"] == 0.5 and got["T_pred"] == pose
    assert pd.isna(got["t_encoder2d_s"])
    assert store.get("absent") is None
    assert [p.name for p in (tmp_path / "frames").iterdir()] == ["k.parquet"]  # no temp file left behind


def test_a_rerun_reuses_every_stored_frame_and_overwrite_recomputes(registry, tmp_path, counted):
    store = ResultsStore(tmp_path)
    first = _run(registry, store, invocation="one")
    assert counted == ["a", "bad", "c"]
    second = _run(registry, store, invocation="two")
    assert counted == ["a", "bad", "c"]  # nothing recomputed
    assert list(second["invocation"]) == ["one"] * 3
    pd.testing.assert_frame_equal(first, second)
    third = _run(registry, store, overwrite=True, invocation="three")
    assert counted == ["a", "bad", "c"] * 2
    assert list(third["invocation"]) == ["three"] * 3


def test_a_truncated_result_is_reported_by_path_and_recomputed(registry, tmp_path, counted, capsys):
    store = ResultsStore(tmp_path)
    _run(registry, store)
    job = prepare(registry, [Combination(BASE)])[0]
    path = store.path(frame_key(registry.dataset("toy")("test"), "c", job, Protocol()))
    path.write_bytes(path.read_bytes()[:40])  # as a power cut could leave it
    records = _run(registry, store)
    assert counted == ["a", "bad", "c", "c"]
    assert str(path) in capsys.readouterr().err
    assert records.set_index("frame_id").loc["c", "status"] == "ok"
    assert path.with_name(path.name + ".corrupt").is_file()  # kept aside for inspection
    assert store.get(path.stem) is not None


NOT_RESULTS = {
    "a leaderboard": (pa.table({"combination": ["x"], "frames": [3], "acc": [50.0]}), "no column dataset, split, "),
    "a mistyped column": (pa.Table.from_pylist([{**RESULT, "frame_id": "c", "rte_m": "0.5"}]), "rte_m is string"),
    "two rows": (pa.Table.from_pylist([{**RESULT, "frame_id": "c"}] * 2), "2 rows, not 1"),
}


@pytest.mark.parametrize("name", NOT_RESULTS)
def test_a_readable_file_that_is_not_a_result_is_named_and_set_aside(registry, tmp_path, capsys, name):
    table, problem = NOT_RESULTS[name]
    store = ResultsStore(tmp_path)
    _run(registry, store)
    stray = store.path("stray")
    pq.write_table(table, stray)
    records = store.load()
    assert sorted(records["frame_id"]) == ["a", "bad", "c"]  # no NaN row beside the three frames
    assert list(leaderboard.build(records)["frames"]) == [3]
    err = capsys.readouterr().err
    assert f"malformed result {stray}" in err and problem in err
    assert stray.with_name("stray.parquet.corrupt").is_file() and not stray.exists()


def test_a_frame_whose_file_is_not_a_result_is_recomputed(registry, tmp_path, counted):
    store = ResultsStore(tmp_path)
    _run(registry, store)
    job = prepare(registry, [Combination(BASE)])[0]
    path = store.path(frame_key(registry.dataset("toy")("test"), "c", job, Protocol()))
    pq.write_table(NOT_RESULTS["a leaderboard"][0], path)
    records = _run(registry, store)
    assert counted == ["a", "bad", "c", "c"]
    assert records.set_index("frame_id").loc["c", "status"] == "ok" and store.get(path.stem) is not None


def test_a_new_version_of_a_slot_replaces_the_older_ones(tmp_path):
    """Keys are `<slot>-<version>`: a frame recomputed on changed files leaves one result, not two."""
    first = ResultsStore(tmp_path)
    for key in ("s1-v1", "s2-v1", "s1"):  # "s1": a key from before versions, with no separator
        first.put(key, {**RESULT, "frame_id": key})
    second = ResultsStore(tmp_path)  # another run: lists the stored versions on its first put
    second.put("s1-v2", {**RESULT, "frame_id": "s1 again"})
    assert sorted(p.stem for p in second.frames_dir.glob("*.parquet")) == ["s1-v2", "s2-v1"]
    second.put("s1-v3", {**RESULT, "frame_id": "s1 once more"})
    assert sorted(second.load()["frame_id"]) == ["s1 once more", "s2-v1"]


def test_stray_temp_files_are_ignored_and_dead_writers_temps_swept(tmp_path):
    store = ResultsStore(tmp_path)
    store.put("k", {**RESULT, "frame_id": "a"})
    dead_pid = 2**22 + 12345  # above the default pid_max: no such process
    dead = tmp_path / "frames" / f".k2.{dead_pid}.tmp"
    live = tmp_path / "frames" / f".k3.{os.getpid()}.tmp"
    for temp in (dead, live):
        temp.write_bytes(b"PAR1 half written")
    assert list(store.load()["frame_id"]) == ["a"]
    ResultsStore(tmp_path)  # a new run opening the store
    assert not dead.exists() and live.exists()


def test_the_store_lists_its_records_keys_only_and_a_store_never_made_reads_as_empty(tmp_path):
    store = ResultsStore(tmp_path / "run")
    for key, frame in (("k2", "b"), ("k1", "a")):
        store.put(key, {**RESULT, "frame_id": frame})
    store.put_upstream("k1", {"uv": pd.Series([1.0]).to_numpy()})
    (store.frames_dir / f".k3.{os.getpid()}.tmp").write_bytes(b"PAR1 half written")
    (store.frames_dir / "k4.parquet.corrupt").write_bytes(b"set aside")
    assert store.keys() == ["k1", "k2"]
    assert list(store.load()["frame_id"]) == ["a", "b"]  # in key order
    absent = ResultsStore(tmp_path / "never-run", read_only=True)
    assert absent.keys() == [] and absent.load().empty and not absent.root.exists()


def test_the_cache_key_follows_the_resolved_config(registry):
    dataset, protocol = registry.dataset("toy")("test"), Protocol()
    learned = {**BASE, "encoder2d": "linear"}
    default, explicit, other = prepare(
        registry,
        [
            Combination(learned),
            Combination(learned, {"encoder2d": {"dim": 4}}),
            Combination(learned, {"encoder2d": {"dim": 8}}),
        ],
    )
    assert frame_key(dataset, "a", default, protocol) == frame_key(dataset, "a", explicit, protocol)  # 4 is the default
    assert frame_key(dataset, "a", default, protocol) != frame_key(dataset, "a", other, protocol)
    assert frame_key(dataset, "a", default, protocol) != frame_key(dataset, "a", default, Protocol(seed=1))
    assert frame_key(dataset, "a", default, protocol) != frame_key(dataset, "c", default, protocol)


def test_each_invocation_keeps_its_own_metadata(tmp_path):
    first = Invocation(tmp_path, {"argv": ["one"]})
    second = Invocation(tmp_path, {"argv": ["two"]})
    second.finish(computed=3)
    runs = history(tmp_path)
    assert [r["argv"] for r in runs] == [["one"], ["two"]]
    assert [r["status"] for r in runs] == ["running", "finished"]  # the first never finished: it was killed
    assert runs[1]["computed"] == 3 and first.id != second.id


def test_an_equivalent_spelling_reuses_the_frames_under_its_own_label(registry, tmp_path, counted):
    store, dataset = ResultsStore(tmp_path), registry.dataset("toy")("test")
    learned = {**BASE, "encoder2d": "linear"}
    run_grid(registry, [Combination(learned)], dataset, Protocol(), store)
    spelled = run_grid(registry, [Combination(learned, {"encoder2d": {"dim": 4}})], dataset, Protocol(), store)
    assert counted == ["a", "bad", "c"]
    assert set(spelled["combination"]) == {"grid > first > linear > truth > truth [encoder2d.dim=4]"}


def test_untrained_rows_start_from_the_same_weights_in_every_run(registry):
    learned = Combination({**BASE, "encoder2d": "linear"})
    (a,), (b,) = prepare(registry, [learned]), prepare(registry, [learned])
    assert a.weights == b.weights == "untrained"
    first, second = (dict(j.pipeline.stages["encoder2d"].named_parameters()) for j in (a, b))
    assert all((first[name] == second[name]).all() for name in first)


WRITER = f"""
import sys
from i2pbench.runs.store import ResultsStore
store = ResultsStore(sys.argv[1])
for i in range(1000):
    store.put(f"k{{i:04d}}", {{**{RESULT!r}, "frame_id": str(i), "payload": [float(i)] * 2_000_000}})
"""


def test_a_writer_killed_in_the_middle_of_a_write_leaves_only_whole_files(tmp_path):
    process = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path)])
    frames = tmp_path / "frames"
    deadline = time.monotonic() + 60
    while not (len(list(frames.glob("*.parquet"))) >= 2 and list(frames.glob(".*.tmp"))):
        assert process.poll() is None and time.monotonic() < deadline, "the writer never got going"
        time.sleep(0.001)
    os.kill(process.pid, signal.SIGKILL)  # a temp file exists: the kill lands during a write
    process.wait()
    store = ResultsStore.__new__(ResultsStore)  # open without sweeping, to see what the kill left
    store.root, store.frames_dir = tmp_path, frames
    finished = store.load()
    assert len(finished) >= 2 and all(len(t) == 2_000_000 for t in finished["payload"])
    assert list(frames.glob(".*.tmp"))  # the interrupted write is still there, unseen by load
    ResultsStore(tmp_path)
    assert not list(frames.glob(".*.tmp"))  # and is swept once its writer is dead
