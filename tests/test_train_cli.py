"""`i2pbench train` as a user runs it: real KITTI frames, seeded, validated, and safe to point at an old checkpoint."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import sample

from i2pbench.weights.checkpoints import load_checkpoint

TINY = [  # EdgeRegNet shrunk to train a step in well under a second; the CPU preset's stages and extractors
    "--conf", "extractor2d.max_keypoints=256", "--conf", "extractor3d.max_keypoints=256",
    "--conf", "encoder2d.channels=[8,8,16,16]", "--conf", "encoder2d.head_channels=32",
    "--conf", "encoder2d.descriptor_dim=32", "--conf", "encoder3d.descriptor_dim=32",
    "--conf", "encoder3d.num_points=2048", "--conf", "encoder3d.sa1={npoint: 256, nsample: 8, mlp: [16, 16]}",
    "--conf", "encoder3d.sa2={npoint: 64, nsample: 8, mlp: [32, 32]}", "--conf", "encoder3d.fp_mlp=[32]",
    "--conf", "encoder3d.head_mlp=[32]", "--conf", "exchanger.descriptor_dim=32", "--conf", "exchanger.num_blocks=1",
    "--conf", "exchanger.pe_mlp=[16]", "--conf", "matcher.descriptor_dim=32",
]  # fmt: skip


def train(shared_data, tmp_path, out, *extra):
    cmd = [sys.executable, "-m", "i2pbench.cli", "train", "--dataset", "kitti", "--data-root",
           str(shared_data / "kitti_real"), "--out", str(out), "--steps", "2", "--batch-size", "2",
           "--validate-every", "2", "--val-frames", "1", "--cache-dir", str(tmp_path / "cache"), "--threads", "1",
           "--quiet", *TINY, *extra]  # fmt: skip
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """one seeded training run (a.pt, its resume file, log and extractor cache), shared by the tests that compare
    against it or try to resume it: each run is a fresh process that imports torch and builds the pipeline."""
    data = sample()
    where = tmp_path_factory.mktemp("trained")
    done = train(data, where, where / "a.pt")
    assert done.returncode == 0, done.stderr
    assert "effective batch 2" in done.stderr
    return where


def test_train_on_real_kitti_validates_without_extra_flags_and_the_seed_fixes_the_weights(
    trained, shared_data, tmp_path
):
    a, b = trained / "a.pt", tmp_path / "b.pt"
    done = train(shared_data, trained, b)  # a's cache: reading it back leaves the weights as they were
    assert done.returncode == 0, done.stderr
    assert "effective batch 2" in done.stderr
    first, second = load_checkpoint(a), load_checkpoint(b)
    assert first.meta["steps"] == 2 and first.meta["validation"]["frames"] == 1  # val: sequence 26, held out
    assert {"acc_pct", "true_matches_median", "chance"} <= set(first.meta["validation"])
    assert first.meta["trained_on"]["split"] == "train" and first.meta["trained_on"]["frames"] == 17  # sequence 04
    for kind, state in first.state.items():
        assert all(torch.equal(state[k], second.state[kind][k]) for k in state), kind
    log = [json.loads(line) for line in (trained / "a.pt.log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2] and all(0 <= r["data_wait"] <= 1 for r in log)
    assert len(list((trained / "cache").rglob("*.pt"))) >= 2  # extractor outputs and grouping kept on disk


def test_resuming_with_other_stages_is_refused_and_the_checkpoint_is_kept(trained, shared_data, tmp_path):
    shutil.copytree(trained, tmp_path, dirs_exist_ok=True)  # a.pt, its resume file, log and cache as the run left them
    out = tmp_path / "a.pt"
    before = out.read_bytes()
    done = train(shared_data, tmp_path, out, "--exchanger", "none", "--steps", "3")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "cannot resume" in done.stderr and "exchanger" in done.stderr
    assert out.read_bytes() == before
