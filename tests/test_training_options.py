"""A researcher's training options: compiled blocks, deterministic kernels, TensorBoard, spread validation frames."""

import json

import pandas as pd
import pytest
import torch
from i2pbench_edgeregnet.attention import AttentionExchanger
from i2pbench_edgeregnet.pointnet2 import PointNet2Encoder
from test_edgeregnet_training import TINY, one_thread  # noqa: F401 (an autouse fixture)
from test_train_cli import train

from i2pbench.scoring.installed import aggregates
from i2pbench.scoring.protocol import Protocol
from i2pbench.training.loop import spread
from i2pbench.training.runtime import compile_stages
from i2pbench.weights.checkpoints import load_checkpoint


def test_validation_frames_are_spread_evenly_over_the_split():
    ids = list("abcdefghij")
    assert spread(ids, 4) == ["a", "d", "g", "j"]  # linspace(0, 9, 4) = 0, 3, 6, 9
    assert spread(ids, 2) == ["a", "j"]
    assert spread(ids[:3], 5) == ["a", "b", "c"]  # asking for more than there are: all, once


def test_compiling_the_attention_blocks_keeps_outputs_and_parameter_names():
    torch.manual_seed(0)
    exchanger = AttentionExchanger(TINY["exchanger"]).eval()
    inputs = {"uv": torch.rand(2, 40, 2), "xyz": torch.rand(2, 30, 3)}
    d2, d3 = torch.randn(2, 40, 32), torch.randn(2, 30, 32)
    mask2d, mask3d = torch.arange(40)[None] < torch.tensor([[40], [25]]), torch.ones(2, 30, dtype=torch.bool)
    with torch.no_grad():
        eager = exchanger.batched(inputs, d2, d3, mask2d, mask3d)
        keys = list(exchanger.state_dict())
        compiled = compile_stages(
            {"exchanger": exchanger, "encoder3d": PointNet2Encoder(TINY["encoder3d"])}, "aot_eager"
        )
        again = exchanger.batched(inputs, d2, d3, mask2d, mask3d)
    assert compiled == ["exchanger.ExchangeBlock"] * TINY["exchanger"]["num_blocks"]  # PointNet++: data-dependent
    assert list(exchanger.state_dict()) == keys  # checkpoints stay loadable either way
    for before, after in zip(eager, again, strict=True):
        # aot_eager runs the same aten kernels traced: measured max difference 0 here; 1e-5 leaves room for a
        # decomposition that reorders a sum, while dropping the masks moves outputs by 0.10-0.12, a skipped block by 2
        assert torch.allclose(before, after, atol=1e-5, rtol=0)


def test_deterministic_compiled_training_logs_scalars_to_tensorboard(shared_data, tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out, board = tmp_path / "w.pt", tmp_path / "tb"
    flags = ("--deterministic", "--compile", "aot_eager", "--tensorboard", str(board))
    done = train(shared_data, tmp_path, out, *flags)
    assert done.returncode == 0, done.stderr
    last = load_checkpoint(out).meta
    config = last["train_config"]
    best = load_checkpoint(out.with_name("w.best.pt")).meta  # validation ran at step 2: the best so far is kept
    assert best["steps"] == 2 and best["best_acc"] == last["validation"]["skill_acc_pct"] == last["best_acc"]
    assert config["deterministic"] is True and config["compile"] == "aot_eager"
    events = EventAccumulator(str(board))
    events.Reload()
    scalars = events.Tags()["scalars"]
    assert [e.step for e in events.Scalars("train/loss")] == [1, 2]
    assert {"train/lr", "train/data_wait", "train/max_rss_mb", "val/acc_pct", "val/true_matches_median"} <= set(scalars)
    log = [json.loads(line) for line in (tmp_path / "w.pt.log.jsonl").read_text().splitlines()]
    assert [e.value for e in events.Scalars("train/loss")] == pytest.approx([r["loss"] for r in log])
    assert all(r["max_rss_mb"] > 0 for r in log)


def test_the_best_checkpoint_is_judged_by_registrations_with_true_matches_not_by_chance():
    """validation's skill_acc_pct is the board's 'Acc. with true matches' metric, declared once."""
    records = pd.DataFrame({"rte_m": [0.1, 0.1, 0.1, 9.0], "rre_deg": [1.0, 1.0, 1.0, 1.0]})  # 3 of 4 succeed
    stats = aggregates(records.assign(n_true_matches=[12.0, 3.0, 0.0, 40.0]), Protocol())
    assert stats["acc_pct"] == 75.0 and stats["chance"] == 2  # two successes with fewer than 4 true matches
    assert stats["skill_acc_pct"] == 25.0  # Acc. 75%, of which one frame in four earned
    assert aggregates(records.assign(n_true_matches=4.0), Protocol())["skill_acc_pct"] == 75.0  # 4 is enough for PnP
