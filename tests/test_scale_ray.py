"""`run --executor ray`: on a local Ray instance a classic grid on the real KITTI frames gives the serial leaderboard,
the driver writes every frame, a worker lost mid-chunk costs only its unfinished frames, and actors ask for GPUs only
for learned stages on a cluster that has them."""

import os
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from i2pbench.boards import leaderboard
from i2pbench.data.kitti import KittiOdometry
from i2pbench.registry.build import default_registry
from i2pbench.runs import executors, ray_executor
from i2pbench.runs.executors import run_grid
from i2pbench.runs.grid import expand
from i2pbench.runs.jobs import prepare
from i2pbench.runs.ray_executor import RayExecutor
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination

ray = pytest.importorskip("ray", reason="the ray extra is not installed (pip install 'i2pbench[ray]')")

BASE = {"extractor3d": "depth", "matcher": "oracle", "solver": "epnp-ransac"}
GRID = {"extractor2d": ["canny", "sobel"]}
RESULTS = ["combination", "frame_id", "status", "rte_m", "rre_deg", "n_kp2d", "n_matches", "T_pred"]


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance for the module: starting one costs seconds."""
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import this test module
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="WARNING")
    yield
    ray.shutdown()


@pytest.fixture
def kitti(shared_data):
    return KittiOdometry("all", {"root": str(shared_data / "kitti_odometry")})


class CrashOnce(KittiOdometry):
    """KITTI whose loader kills its process the first time it reaches `crash_at`, once the driver has stored a frame
    (a result still in flight when a worker dies is recomputed, rightly: waiting makes the test deterministic);
    every load is logged with its pid."""

    def arm(self, crash_at: str, marker: Path, log: Path, stored: Path) -> "CrashOnce":
        self.crash_at, self.marker, self.log, self.stored = crash_at, str(marker), str(log), str(stored)
        return self

    def load(self, frame_id):
        with open(self.log, "a") as log:
            log.write(f"{os.getpid()} {frame_id}\n")
        if frame_id == self.crash_at and not os.path.exists(self.marker):
            deadline = time.monotonic() + 60
            while not list(Path(self.stored).glob("*.parquet")) and time.monotonic() < deadline:
                time.sleep(0.01)
            Path(self.marker).touch()
            os._exit(1)  # a worker lost mid-task, as to a node failure or the OOM killer
        return super().load(frame_id)


def _serial(kitti, tmp_path, combos, frames):
    return run_grid(default_registry(), combos, kitti, Protocol(), ResultsStore(tmp_path / "serial"), frame_ids=frames)


def test_a_ray_grid_gives_the_serial_leaderboard_written_by_the_driver(local_ray, kitti, tmp_path):
    combos, frames = expand([BASE], GRID), kitti.frame_ids()[:3]
    store = ResultsStore(tmp_path / "ray")
    on_ray = executors.run_grid(default_registry(), combos, kitti, Protocol(), store, RayExecutor(), frame_ids=frames)
    serial = _serial(kitti, tmp_path, combos, frames)
    pd.testing.assert_frame_equal(on_ray[RESULTS], serial[RESULTS])
    board, expected = leaderboard.build(on_ray), leaderboard.build(serial)
    latency = leaderboard.latency_columns(expected)
    pd.testing.assert_frame_equal(board.drop(columns=latency), expected.drop(columns=latency))
    assert len(list(store.frames_dir.glob("*.parquet"))) == 6
    assert ray.is_initialized()  # the executor joined the test's Ray and left it running


def test_a_worker_lost_mid_chunk_recomputes_only_its_unfinished_frames(local_ray, kitti, tmp_path, capfd):
    frames = kitti.frame_ids()[:3]
    store, combos = ResultsStore(tmp_path / "ray"), [Combination({**BASE, "extractor2d": "canny"})]
    flaky = CrashOnce("all", kitti.conf).arm(frames[1], tmp_path / "crashed", tmp_path / "loads.log", store.frames_dir)
    executor = RayExecutor(workers=1)  # one actor, one chunk of all three frames
    records = executors.run_grid(default_registry(), combos, flaky, Protocol(), store, executor, frame_ids=frames)
    pd.testing.assert_frame_equal(records[RESULTS], _serial(kitti, tmp_path, combos, frames)[RESULTS])
    assert len(list(store.frames_dir.glob("*.parquet"))) == 3
    loads = [line.split() for line in (tmp_path / "loads.log").read_text().splitlines()]
    first_pid = loads[0][0]
    assert [f for pid, f in loads if pid == first_pid] == [frames[0], frames[0], frames[1]]  # warm-up, run, crash
    assert {f for pid, f in loads if pid != first_pid} == {frames[1], frames[2]}  # the first frame is not redone
    assert "resubmitting its unfinished frame(s)" in capfd.readouterr().err


class _FakeRay:
    """Just enough of `ray` for an executor to read the cluster's resources."""

    def __init__(self, resources):
        self.resources = resources

    def is_initialized(self):
        return True

    def cluster_resources(self):
        return self.resources

    def put(self, value):
        return value

    def remote(self, *args):
        return self  # stands in for the actor class, and for each actor it creates

    def options(self, **options):
        return self


@pytest.mark.parametrize("gpus", [2, 0])
def test_learned_stages_ask_for_a_gpu_only_where_the_cluster_has_one(monkeypatch, gpus):
    monkeypatch.setattr(ray_executor, "import_ray", lambda: _FakeRay({"CPU": 8.0, "GPU": float(gpus)}))
    learned = {**BASE, "extractor2d": "canny", "encoder2d": "superpoint-cnn", "encoder3d": "pointnet2",
               "matcher": "lightglue"}  # fmt: skip
    jobs = prepare(default_registry(), [Combination(learned), Combination({**BASE, "extractor2d": "canny"})])
    executor = RayExecutor(threads=1)
    executor.start(executors.Work(jobs, None, Protocol()), store=None)
    learned_options, classic_options = (executor.actor_options(executor.shape(j)) for j in (0, 1))
    assert learned_options.get("num_gpus") == (1.0 if gpus else None) and learned_options["num_cpus"] == 1
    assert "num_gpus" not in classic_options and classic_options["num_cpus"] == 1
    assert executor.workers == 8  # one single-threaded actor per cluster CPU
    if gpus:  # GPU actors hold a CPU each too: CPU actors get the rest, so neither kind waits on the other forever
        assert len(executor._actors(ray_executor.GPU, tasks=5)) == 2
        assert len(executor._actors(ray_executor.CPU, tasks=50)) == 6
