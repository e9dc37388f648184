"""The first end-to-end run: `i2pbench run --matcher oracle` on the real KITTI frames is exact (ground truth is)."""

import subprocess
import sys
from pathlib import Path

import pandas as pd

from i2pbench.runs.store import ResultsStore


def test_oracle_run_on_real_kitti_frames_is_fully_accurate(shared_data, tmp_path):
    out = tmp_path / "board"
    cmd = [sys.executable, "-m", "i2pbench.cli", "run", "--matcher", "oracle", "--dataset", "kitti", "--split", "all",
           "--data-root", str(shared_data / "kitti_odometry"), "--runs-dir", str(tmp_path / "runs"), "--out", str(out),
           "--threads", "1", "--quiet"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    board = pd.read_csv(out.with_suffix(".csv"))
    assert len(board) == 1
    row = board.iloc[0]
    assert row["combination"] == "lsd > depth+reflectance > oracle > epnp-ransac"
    assert row["weights"] == "none" and row["frames"] == 6 and row["failures"] == 0
    assert row["Acc. (%) ↑"] == 100.0
    records = ResultsStore(tmp_path / "runs" / "kitti-all").load()
    assert len(records) == 6
    assert (records["rre_deg"] < 1.0).all() and (records["rte_m"] < 0.2).all()
    assert "| lsd > depth+reflectance > oracle > epnp-ransac |" in done.stdout  # the leaderboard is printed


def test_by_default_the_leaderboard_goes_under_runs_not_into_the_committed_leaderboards(shared_data, tmp_path):
    cmd = [sys.executable, "-m", "i2pbench.cli", "run", "--matcher", "oracle", "--dataset", "kitti", "--split", "all",
           "--data-root", str(shared_data / "kitti_odometry"), "--frames", "2", "--threads", "1"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    boards = tmp_path / "runs" / "leaderboards"
    written = ["kitti-all-oracle.csv", "kitti-all-oracle.env.json", "kitti-all-oracle.md", "kitti-all-oracle.parquet"]
    assert sorted(p.name for p in boards.iterdir()) == written  # named by what was run: --matcher oracle
    assert pd.read_csv(boards / "kitti-all-oracle.csv").iloc[0]["frames"] == 2
    assert not (tmp_path / "leaderboards").exists()
    assert f"written: {Path('runs/leaderboards/kitti-all-oracle.csv')}" in done.stderr


def test_an_unknown_component_is_refused_with_the_closest_name(tmp_path):
    done = subprocess.run([sys.executable, "-m", "i2pbench.cli", "run", "--matcher", "lightgleu", "--runs-dir",
                           str(tmp_path)], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2
    assert "unknown matcher 'lightgleu'; did you mean 'lightglue'?" in done.stderr
