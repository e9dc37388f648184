"""benchmarks/gpu_pass.sh, the prepared GPU figure, run on the CPU (no GPU is lent here): it times the official
EdgeRegNet frame and the default grid and writes their per-stage times and peak memory as JSON; asked for CUDA
where torch sees none, it stops before any work, saying so."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
LEARNED = ["encoder2d", "encoder3d", "exchanger", "matcher"]


@pytest.fixture(scope="module")
def cpu_pass(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("gpu_pass")
    env = {**os.environ, "XDG_CACHE_HOME": str(out / "cache"), "OMP_NUM_THREADS": "1"}
    options = ["--no-install", "--device", "cpu", "--frames", "1", "--keypoints", "64", "--repeat", "1"]
    subprocess.run(["bash", str(ROOT / "benchmarks" / "gpu_pass.sh"), str(out), *options], env=env, check=True)
    return json.loads((out / "gpu_pass.json").read_text())


def test_gpu_pass_times_each_official_stage_and_their_sum(cpu_pass):
    frame = cpu_pass["official_frame"]
    assert cpu_pass["device"] == "cpu" and cpu_pass["paper_frame_s"] == 0.18
    assert frame["keypoints"] == 64
    assert list(frame["stage_s"]) == LEARNED and all(t > 0 for t in frame["stage_s"].values())
    assert frame["frame_s"] == pytest.approx(sum(frame["stage_s"].values()), rel=1e-12)
    assert all(mb > 0 for mb in frame["peak_memory_mb"].values())


def test_gpu_pass_runs_the_default_grid_with_its_shipped_weights(cpu_pass):
    grid = cpu_pass["default_grid"]
    assert grid["frames"] == 1
    assert grid["weights"].startswith("edgeregnet-cpu-synthetic@")
    assert list(grid["stage_ms"]) == LEARNED and all(ms > 0 for ms in grid["stage_ms"].values())
    assert grid["frame_ms"] >= max(grid["stage_ms"].values()) and grid["peak_memory_mb"] > 0


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
def test_gpu_pass_without_cuda_stops_before_any_work(tmp_path):
    script = ROOT / "benchmarks" / "gpu_pass.py"
    out = subprocess.run(
        [sys.executable, str(script), "--out", str(tmp_path / "out"), "--device", "cuda"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2
    assert "--device cuda" in out.stderr and "no CUDA device" in out.stderr
    assert not (tmp_path / "out").exists()
