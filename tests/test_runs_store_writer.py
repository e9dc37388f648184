"""One writer of the store: a worker that writes its frames itself (in process, a local pool) and a driver that
writes what its workers handed back (Ray) both go through `worker.store_result`, so the two leave the same files."""

from __future__ import annotations

import pandas as pd
import pytest
import toy_plugin

from i2pbench.registry.build import build_registry
from i2pbench.runs.executors import Collector, plan
from i2pbench.runs.jobs import frame_key, prepare
from i2pbench.runs.store import ResultsStore
from i2pbench.runs.tasks import Task, Work
from i2pbench.runs.worker import Worker
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination

TOY = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}
PER_RUN = {"invocation", "wall_s", "t_load_s", "t_total_s"}  # what two computations of a frame may differ in


@pytest.fixture
def registry(monkeypatch):
    """The toy plugin alone (the default registry the scoring reads is the one of this selection: no plugin)."""
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    return build_registry((toy_plugin,))


def _files(store: ResultsStore) -> list[str]:
    return sorted(path.name for path in store.frames_dir.iterdir())


def test_a_worker_writing_its_frames_and_a_driver_writing_handed_back_ones_leave_the_same_store(tmp_path, registry):
    dataset, protocol = registry.dataset("toy")("test"), Protocol()
    jobs = prepare(registry, [Combination(TOY)])
    frame_ids = dataset.frame_ids()
    task = Task(0, tuple(frame_ids), tuple(frame_key(dataset, f, jobs[0], protocol) for f in frame_ids))
    work = Work(jobs, dataset, protocol, "inv")
    own, driver = ResultsStore(tmp_path / "own"), ResultsStore(tmp_path / "driver")

    written = list(Worker(work, own).run(task))
    handed = list(Worker(work, None).run(task))
    assert [r.stored for r in written] == [True] * 3 and all(r.upstream is None for r in written)
    assert [r.stored for r in handed] == [False] * 3
    assert [r.upstream is not None for r in handed] == [True, False, True]  # "bad" failed to load: no upstream
    assert _files(driver) == []
    Collector(plan(jobs, dataset, frame_ids, protocol, driver), driver, None)(handed)

    assert _files(own) == _files(driver)
    assert [name.rsplit(".", 1)[1] for name in _files(own)].count("npz") == 2
    mine, theirs = own.load(), driver.load()  # both in key order
    timed = [c for c in mine.columns if c in PER_RUN or c.startswith("t_")]
    pd.testing.assert_frame_equal(mine.drop(columns=timed), theirs.drop(columns=timed))
    assert list(mine["invocation"]) == list(theirs["invocation"]) == ["inv"] * 3
