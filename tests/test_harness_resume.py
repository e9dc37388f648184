"""A run killed with SIGKILL mid-way resumes: no finished frame lost, corrupted or recomputed, and the result is
the uninterrupted run's."""

import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from i2pbench.boards import leaderboard
from i2pbench.registry.build import default_registry
from i2pbench.runs.executors import run_grid
from i2pbench.runs.grid import base_combinations, expand
from i2pbench.runs.invocation import history
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol

BASE = {"extractor3d": "depth+reflectance", "matcher": "oracle"}
GRID = {"extractor2d": ["canny", "sobel"], "solver": ["epnp-ransac"]}
TOTAL = 2 * 6  # combinations x frames
KILL_AFTER = 4  # frames stored
RESULT_COLUMNS = ["combination", "frame_id", "status", "rte_m", "rre_deg", "n_kp2d", "n_kp3d", "n_matches", "T_pred"]


def _cli(kitti_root, runs):
    return [
        sys.executable, "-m", "i2pbench.cli", "run", "--extractor", ",".join(GRID["extractor2d"]),
        "--extractor3d", BASE["extractor3d"], "--matcher", BASE["matcher"], "--solver", GRID["solver"][0],
        "--dataset", "kitti", "--split", "all", "--data-root", str(kitti_root), "--runs-dir", str(runs),
        "--out", str(runs / "board"), "--threads", "1", "--quiet",
    ]  # fmt: skip


def _stored(frames_dir):
    """Finished frames: name -> (inode, mtime): a rewrite would change both."""
    return {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in frames_dir.glob("*.parquet")}


def _kill_after(cmd, frames_dir, n, timeout=120):
    process = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout
    while len(_stored(frames_dir)) < n:
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"the run ended (rc {process.returncode}) before storing {n} frames")
        time.sleep(0.01)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()


def _results(records):
    return records[RESULT_COLUMNS].sort_values(["combination", "frame_id"]).reset_index(drop=True)


@pytest.mark.slow
def test_a_sigkilled_run_resumes_to_the_uninterrupted_result(shared_data, tmp_path):
    kitti_root, runs = shared_data / "kitti_odometry", tmp_path / "runs"
    frames_dir = runs / "kitti-all" / "frames"
    _kill_after(_cli(kitti_root, runs), frames_dir, KILL_AFTER)
    before = _stored(frames_dir)
    assert KILL_AFTER <= len(before) < TOTAL

    done = subprocess.run(_cli(kitti_root, runs), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    after = _stored(frames_dir)
    assert len(after) == TOTAL
    assert {name: after[name] for name in before} == before  # not one finished frame rewritten
    killed, resumed = history(runs / "kitti-all")
    assert killed["status"] == "running" and resumed["status"] == "finished"
    assert resumed["computed"] == TOTAL - len(before) and resumed["reused"] == len(before)
    assert [p.name for p in frames_dir.iterdir() if not p.name.endswith((".parquet", ".npz"))] == []  # temp swept
    assert len(list(frames_dir.glob("*.npz"))) == TOTAL  # each frame's upstream (the extractors differ: none shared)

    from i2pbench.data.kitti import KittiOdometry

    kitti = KittiOdometry("all", {"root": str(kitti_root)})
    registry = default_registry()  # the combinations exactly as the CLI builds them: over the default pipeline
    choices = {**{kind: [name] for kind, name in BASE.items()}, **GRID}
    combinations = expand(base_combinations(registry, None), choices, None, registry)
    records = run_grid(registry, combinations, kitti, Protocol(), ResultsStore(tmp_path / "clean"))
    pd.testing.assert_frame_equal(_results(ResultsStore(runs / "kitti-all").load()), _results(records))
    board, clean = leaderboard.read(runs / "board.csv"), leaderboard.build(records)
    latency = leaderboard.latency_columns(clean)
    pd.testing.assert_frame_equal(board.drop(columns=latency), clean.drop(columns=latency), check_dtype=False)
