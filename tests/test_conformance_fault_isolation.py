"""A third-party stage that hangs, raises or returns garbage fails its frame, named; blocked plugins never load."""

import pickle
import time

import numpy as np
import pytest
import toy_plugin

from i2pbench.api import Extractor3D, Keypoints3D, hookimpl
from i2pbench.execution.timeout import StageTimeout, TimeLimiter, timeout_from_env
from i2pbench.registry.build import build_registry
from i2pbench.runs.executors import run_grid
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination, Pipeline

BASE = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}


class Sleepy(Extractor3D):
    """Hangs on frame "a" only, so the frames after it show the run going on."""

    name = "sleepy"
    default_conf = {"seconds": 1.0}

    def __call__(self, frame):
        if frame.frame_id == "a":
            time.sleep(self.conf["seconds"])
        return Keypoints3D.from_index(frame, np.arange(3))


class SleepyPlugin:
    @hookimpl
    def register_extractors_3d(self, register):
        register(Sleepy)


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    return build_registry((toy_plugin, SleepyPlugin()))


def _records(registry, tmp_path, **stages):
    dataset = registry.dataset("toy")("test")
    rows = run_grid(registry, [Combination({**BASE, **stages})], dataset, Protocol(), ResultsStore(tmp_path))
    return rows.set_index("frame_id")


def test_a_hanging_stage_is_abandoned_and_named_and_the_run_goes_on(registry, tmp_path, monkeypatch):
    monkeypatch.setenv("I2PBENCH_STAGE_TIMEOUT_S", "0.2")
    combination = Combination({**BASE, "extractor3d": "sleepy"}, {"extractor3d": {"seconds": 60.0}})
    start = time.perf_counter()
    rows = run_grid(registry, [combination], registry.dataset("toy")("test"), Protocol(), ResultsStore(tmp_path))
    records = rows.set_index("frame_id")
    # a behaviour check, not a speed one: the run went on without waiting out any of the 60 s sleeps
    assert time.perf_counter() - start < 30
    assert records.loc["a", "status"] == "failed"
    assert records.loc["a", "failed_component"] == "extractor3d 'sleepy'"
    assert "timed out after 0.2 s" in records.loc["a", "error"]
    assert records.loc["c", "status"] == "ok" and records.loc["c", "n_kp3d"] == 3


def test_the_timeout_is_a_pipeline_option_and_none_disables_it(registry):
    combination = Combination({**BASE, "extractor3d": "sleepy"}, {"extractor3d": {"seconds": 0.3}})
    frame = Protocol().apply(registry.dataset("toy")("test").load("a"))
    assert Pipeline.build(registry, combination, timeout_s=0.05).run(frame).error.endswith("in the background)")
    assert Pipeline.build(registry, combination, timeout_s=None).run(frame).error == ""


def test_time_limiter_passes_values_and_errors_through_and_recovers_after_a_timeout():
    limiter = TimeLimiter(0.1)
    assert limiter.call(lambda: 42) == 42
    with pytest.raises(StageTimeout, match="timed out after 0.1 s"):
        limiter.call(lambda: time.sleep(0.5))
    assert limiter.call(lambda: "fresh worker") == "fresh worker"
    with pytest.raises(ZeroDivisionError):
        limiter.call(lambda: 1 / 0)


def test_a_pickled_limiter_starts_its_own_worker():
    limiter = TimeLimiter(1.0)
    assert limiter.call(lambda: 1) == 1
    copy = pickle.loads(pickle.dumps(limiter))  # as a pipeline sent to a process pool
    assert copy.timeout_s == 1.0 and copy.call(lambda: 2) == 2


def test_stage_timeout_reads_the_environment(monkeypatch):
    monkeypatch.delenv("I2PBENCH_STAGE_TIMEOUT_S", raising=False)
    assert timeout_from_env() == 300.0
    monkeypatch.setenv("I2PBENCH_STAGE_TIMEOUT_S", "none")
    assert timeout_from_env() is None
    monkeypatch.setenv("I2PBENCH_STAGE_TIMEOUT_S", "soon")
    with pytest.raises(ValueError, match="expected seconds or 'none'"):
        timeout_from_env()


def test_raising_and_garbage_components_fail_their_frames_by_name(registry, tmp_path):
    raised = _records(registry, tmp_path / "boom", extractor3d="boom").loc["c"]
    garbage = _records(registry, tmp_path / "shape", extractor2d="wrong-shape").loc["c"]
    assert raised["failed_component"] == "extractor3d 'boom'"
    assert garbage["failed_component"] == "extractor2d 'wrong-shape'"
    assert "exploded on purpose" in raised["error"] and "[M x 2]" in garbage["error"]


def test_a_blocked_plugin_is_never_loaded(monkeypatch):
    monkeypatch.delenv("I2PBENCH_LOAD_PLUGINS", raising=False)
    monkeypatch.setenv("I2PBENCH_BLOCK_PLUGINS", "classic, edgeregnet")
    registry = build_registry()
    loaded = {info.name for info in registry.plugins}
    assert "classic" not in loaded and "edgeregnet" not in loaded and "datasets" in loaded
    assert "lsd" not in registry.components["extractor2d"]
    monkeypatch.setenv("I2PBENCH_BLOCK_PLUGINS", "")
    assert "lsd" in build_registry().components["extractor2d"]
