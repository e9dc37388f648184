"""The harness on the real KITTI frames: a 6-combination grid, reproducibility, the CLI's files and metadata."""

import json
import subprocess
import sys

import pandas as pd
import pytest

from i2pbench.boards import leaderboard
from i2pbench.registry.build import default_registry
from i2pbench.runs.executors import run_grid
from i2pbench.runs.grid import expand
from i2pbench.runs.invocation import history
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol

GRID = {"extractor2d": ["canny", "sobel"], "extractor3d": ["depth", "reflectance", "depth+reflectance"]}
BASE = {"matcher": "oracle", "solver": "epnp-ransac"}


@pytest.fixture
def kitti(shared_data):
    from i2pbench.data.kitti import KittiOdometry

    return KittiOdometry("all", {"root": str(shared_data / "kitti_odometry")})


def _board(kitti, store_dir, frames=2):
    records = run_grid(
        default_registry(),
        expand([BASE], GRID),
        kitti,
        Protocol(seed=0),
        ResultsStore(store_dir),
        frame_ids=kitti.frame_ids()[:frames],
    )
    return leaderboard.build(records)


def test_a_six_combination_grid_gives_one_leaderboard_reproduced_up_to_latency(kitti, tmp_path):
    first, second = _board(kitti, tmp_path / "one"), _board(kitti, tmp_path / "two")
    assert len(first) == 6 and first["combination"].is_unique
    assert set(zip(first["extractor2d"], first["extractor3d"], strict=True)) == {
        (e2, e3) for e2 in GRID["extractor2d"] for e3 in GRID["extractor3d"]
    }
    assert (first["frames"] == 2).all() and (first["failures"] == 0).all()
    assert (first[leaderboard.INLIER_RATIO] == 100.0).all()  # the oracle's pairs are true by construction
    latency = leaderboard.latency_columns(first)
    assert leaderboard.LATENCY_MEDIAN in latency and (first[latency].fillna(1) > 0).all().all()
    pd.testing.assert_frame_equal(first.drop(columns=latency), second.drop(columns=latency))


def test_the_cli_writes_csv_markdown_parquet_and_records_the_invocation(kitti, tmp_path):
    grid = tmp_path / "grid.yaml"
    grid.write_text(f"base: {json.dumps(BASE)}\ngrid: {json.dumps(GRID)}\n")
    out = tmp_path / "lb" / "kitti-sample"
    cmd = [
        sys.executable, "-m", "i2pbench.cli", "run", "--grid", str(grid), "--dataset", "kitti", "--split", "all",
        "--data-root", kitti.conf["root"], "--frames", "1", "--runs-dir", str(tmp_path / "runs"),
        "--out", str(out), "--threads", "1", "--quiet",
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    board = leaderboard.read(out.with_name("kitti-sample.csv"))
    assert len(board) == 6 and "RTE (m) ↓" in done.stdout  # the table is printed too
    pd.testing.assert_frame_equal(board, leaderboard.read(out.with_name("kitti-sample.parquet")), check_dtype=False)
    (meta,) = history(tmp_path / "runs" / "kitti-all")
    assert meta["status"] == "finished" and meta["computed"] == 6 and meta["reused"] == 0
    assert meta["threads"] == 1 and meta["environment"]["torch_threads"] == 1
    assert {"git_commit", "packages", "machine", "cpu_count"} <= set(meta["environment"])
    assert meta["frames"] == ["00/000000"] and len(meta["combinations"]) == 6
