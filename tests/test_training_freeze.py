"""`train --freeze KINDS`: fine-tuning on a few real frames keeps the named learned stages exactly as loaded."""

import shutil
import subprocess
import sys

import pytest
import torch
from test_train_cli import TINY  # EdgeRegNet's CPU preset shrunk to train a step in well under a second

from i2pbench.weights.checkpoints import load_checkpoint


def train(shared_data, tmp_path, out, steps, *extra) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "i2pbench.cli", "train", "--dataset", "kitti", "--data-root",
           str(shared_data / "kitti_real"), "--out", str(out), "--steps", str(steps), "--val-split", "none",
           "--lr", "1e-2", "--cache-dir", str(tmp_path / "cache"), "--threads", "1", "--quiet",
           *TINY, *extra]  # fmt: skip
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


def test_frozen_stages_keep_every_tensor_while_the_others_train(shared_data, tmp_path):
    first = tmp_path / "first.pt"
    done = train(shared_data, tmp_path, first, 1)
    assert done.returncode == 0, done.stderr
    tuned = tmp_path / "tuned.pt"
    shutil.copyfile(first, tuned)  # fine-tune a copy, as a user does with shipped weights
    done = train(shared_data, tmp_path, tuned, 3, "--force", "--freeze", "encoder3d,exchanger")
    assert done.returncode == 0, done.stderr
    before, after = load_checkpoint(first), load_checkpoint(tuned)
    assert after.meta["steps"] == 3 and after.meta["train_config"]["freeze"] == "encoder3d,exchanger"
    for kind in ("encoder3d", "exchanger"):  # parameters and buffers (BatchNorm statistics) bit for bit
        for key, tensor in before.state[kind].items():
            assert torch.equal(tensor, after.state[kind][key]), f"{kind}.{key} moved although frozen"
    for kind in ("encoder2d", "matcher"):  # trained: at lr 1e-2 for two steps, some tensor moves
        assert any(not torch.equal(t, after.state[kind][k]) for k, t in before.state[kind].items()), kind


@pytest.mark.parametrize(
    ("freeze", "message"),
    [
        ("encoder3d,solver", "--freeze 'solver': not a learned stage of"),
        ("encoder2d,encoder3d,exchanger,matcher", "every learned stage frozen leaves nothing to train"),
    ],
)
def test_freezing_what_is_not_learned_or_everything_is_refused_before_training(shared_data, tmp_path, freeze, message):
    out = tmp_path / "w.pt"
    done = train(shared_data, tmp_path, out, 1, "--freeze", freeze)
    assert done.returncode != 0 and message in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and not out.exists()
