from pathlib import Path

import numpy as np
import pytest
import torch
import toy_plugin

from i2pbench.api import Extractor2D, Keypoints2D, hookimpl
from i2pbench.errors import PluginError, WeightsError
from i2pbench.registry.build import build_registry
from i2pbench.runs.executors import run_grid
from i2pbench.runs.jobs import prepare
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.training.config import TrainConfig
from i2pbench.training.lineage import training_meta
from i2pbench.training.loop import Trainer
from i2pbench.weights.checkpoints import (
    apply_checkpoint,
    data_label,
    load_checkpoint,
    save_checkpoint,
    select_checkpoint,
)

LEARNED = {
    "extractor2d": "grid",
    "extractor3d": "first",
    "encoder2d": "linear",
    "matcher": "regress",
    "solver": "truth",
}


class Clean(toy_plugin.ToyDataset):
    def frame_ids(self):
        return ["a", "c"]


class FramePixels(Extractor2D):
    """pixels that differ from frame to frame, so a toy loss depends on which frames a step takes; inside the 8x8
    toy image, as the contract checks on the training path require."""

    name = "frame-grid"

    def __call__(self, frame):
        k = float(ord(frame.frame_id[0]) % 7)
        return Keypoints2D(np.array([[k, 1.0], [2.0, k / 2]], np.float32))


class VariedFrames:
    @hookimpl
    def register_extractors_2d(self, register):
        register(FramePixels)


VARIED = {**LEARNED, "extractor2d": "frame-grid"}


def varied_trainer(out, **conf) -> Trainer:
    """a toy trainer whose loss depends on the frames: 3 steps, seeded initial weights."""
    registry = build_registry((toy_plugin, VariedFrames()))
    torch.manual_seed(0)
    pipeline = Pipeline.build(registry, Combination(VARIED))
    config = TrainConfig(steps=3, lr=0.05, checkpoint_every=3, validate_every=1000, seed=1, **conf)
    return Trainer(pipeline, Clean("test"), None, Path(out), config)


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    return build_registry((toy_plugin,))


def _pipeline(registry, **confs):
    return Pipeline.build(registry, Combination(LEARNED, confs))


def _trainer(registry, out, steps):
    torch.manual_seed(0)
    pipeline = _pipeline(registry)
    config = TrainConfig(steps=steps, lr=0.05, checkpoint_every=1, validate_every=1000, seed=1)
    return Trainer(pipeline, Clean("test"), None, out, config)


def test_checkpoint_round_trips_with_its_metadata(registry, tmp_path):
    pipeline = _pipeline(registry)
    path = save_checkpoint(tmp_path / "toy.pt", pipeline, steps=12, trained_on={"dataset": "toy", "split": "test"})
    checkpoint = load_checkpoint(path)
    assert checkpoint.meta["steps"] == 12
    assert checkpoint.meta["stages"]["encoder2d"] == {"name": "linear", "conf": {"dim": 4}}
    assert checkpoint.meta["size_mb"] == pytest.approx(12 * 4 / 2**20, abs=1e-3)  # 2x4 weights + 4 biases
    assert checkpoint.trained_on == "toy/test, 12 steps"
    fresh = _pipeline(registry)
    apply_checkpoint(fresh, checkpoint)
    for a, b in zip(fresh.stages["encoder2d"].parameters(), pipeline.stages["encoder2d"].parameters(), strict=True):
        assert torch.equal(a, b)
    assert fresh.weights_identity == checkpoint.identity and checkpoint.identity.startswith("toy@")


def test_trained_on_counts_frames_when_a_step_took_several(registry, tmp_path):
    batched = {"effective_batch": 2, "batch_size": 1, "accumulate": 2}
    path = save_checkpoint(tmp_path / "b.pt", _pipeline(registry), steps=4250, train_config=batched,
                           trained_on={"dataset": "synthetic", "split": "train"})  # fmt: skip
    assert load_checkpoint(path).trained_on == "synthetic/train, 4250 steps of 2 frames"
    path = save_checkpoint(tmp_path / "one.pt", _pipeline(registry), steps=8500, train_config={"effective_batch": 1},
                           trained_on={"dataset": "synthetic", "split": "train"})  # fmt: skip
    assert load_checkpoint(path).trained_on == "synthetic/train, 8500 steps"  # as every one-frame checkpoint reads


def test_trained_on_names_a_synthetic_style_and_its_phase(registry, tmp_path):
    styled = {"dataset": "synthetic", "split": "train", "root": "", "style": "kitti"}
    path = save_checkpoint(tmp_path / "s.pt", _pipeline(registry), steps=8900, train_config={"effective_batch": 1},
                           trained_on=styled, lineage=[{"dataset": "synthetic", "split": "train", "root": "",
                                                        "steps": 8500}])  # fmt: skip
    assert load_checkpoint(path).trained_on == "synthetic/train 8500 + synthetic[kitti]/train, 8900 steps"
    assert data_label({**styled, "mix": [{"dataset": "kitti", "split": "train", "share": 0.5}]}) == (
        "synthetic[kitti]/train + kitti/train (0.5)"
    )


def test_a_checkpoint_for_another_config_is_refused_with_a_clear_message(registry, tmp_path):
    path = save_checkpoint(tmp_path / "toy.pt", _pipeline(registry), steps=1)
    with pytest.raises(WeightsError, match=r"encoder2d: the pipeline has 'linear' \{'dim': 8\}.*trained with 'linear'"):
        apply_checkpoint(_pipeline(registry, encoder2d={"dim": 8}), load_checkpoint(path))


def test_unreadable_checkpoint_names_the_file(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(WeightsError, match="bad.pt"):
        load_checkpoint(bad)


def test_rows_say_untrained_or_which_checkpoint(registry, tmp_path):
    dataset = Clean("test")
    untrained = run_grid(registry, [Combination(LEARNED)], dataset, Protocol(), ResultsStore(tmp_path / "a"))
    assert set(untrained["weights"]) == {"untrained"}
    path = save_checkpoint(tmp_path / "toy.pt", _pipeline(registry), steps=3, trained_on={"dataset": "toy"})
    trained = run_grid(
        registry, [Combination(LEARNED)], dataset, Protocol(), ResultsStore(tmp_path / "b"), weights=str(path)
    )
    assert set(trained["weights"]) == {load_checkpoint(path).identity}
    assert set(trained["weights_trained_on"]) == {"toy/?, 3 steps"}  # a summary string, never the raw record
    classic = run_grid(registry, [Combination(toy_plugin_base())], dataset, Protocol(), ResultsStore(tmp_path / "c"))
    assert set(classic["weights"]) == {"none"}


def toy_plugin_base():
    return {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}


def test_auto_weights_pick_a_shipped_checkpoint_only_when_every_stage_fits(registry, tmp_path):
    path = str(save_checkpoint(tmp_path / "toy.pt", _pipeline(registry), steps=1))
    assert select_checkpoint(_pipeline(registry), "auto", [path]) is not None
    assert select_checkpoint(_pipeline(registry, encoder2d={"dim": 8}), "auto", [path]) is None
    assert select_checkpoint(_pipeline(registry), "untrained", [path]) is None
    registry.weights.add(path, path, "test")
    assert prepare(registry, [Combination(LEARNED)])[0].weights.startswith("toy@")


def test_training_drives_the_loss_down_and_checkpoints(registry, tmp_path):
    trainer = _trainer(registry, tmp_path / "t.pt", steps=30)
    losses = []
    trainer.run(training_meta(Clean("test"), trainer.config), lambda step, terms: losses.append(terms["loss"]))
    assert losses[-1] < 0.2 * losses[0]
    checkpoint = load_checkpoint(tmp_path / "t.pt")
    assert checkpoint.meta["steps"] == 30 and checkpoint.meta["trained_on"]["dataset"] == "toy"


def test_resumed_training_equals_uninterrupted_training(registry, tmp_path):
    straight = _trainer(registry, tmp_path / "a.pt", steps=6)
    straight.run({})
    first = _trainer(registry, tmp_path / "b.pt", steps=3)
    first.run({})
    resumed = _trainer(registry, tmp_path / "b.pt", steps=6)
    assert resumed.resume() and resumed.step == 3
    resumed.run({})
    a = load_checkpoint(tmp_path / "a.pt").state["encoder2d"]
    b = load_checkpoint(tmp_path / "b.pt").state["encoder2d"]
    assert all(torch.allclose(a[k], b[k]) for k in a)


def test_training_needs_a_trainable_matcher(registry, tmp_path):
    pipeline = Pipeline.build(registry, Combination({**LEARNED, "matcher": "truth"}))
    with pytest.raises(PluginError, match="matcher 'truth' has no training loss"):
        Trainer(pipeline, Clean("test"), None, tmp_path / "x.pt", TrainConfig())


def test_training_frames_and_transforms_depend_only_on_seed_and_step(registry, tmp_path):
    a, b = _trainer(registry, tmp_path / "a.pt", 1), _trainer(registry, tmp_path / "b.pt", 1)
    assert np.array_equal(a.sample(5).T_gt, b.sample(5).T_gt)
    assert not np.array_equal(a.sample(5).T_gt, a.sample(6).T_gt)


def test_training_continues_from_the_checkpoint_alone_when_the_resume_file_is_gone(registry, tmp_path):
    first = _trainer(registry, tmp_path / "c.pt", steps=3)
    first.run({})
    (tmp_path / "c.pt.resume").unlink()
    again = _trainer(registry, tmp_path / "c.pt", steps=5)
    assert again.resume() and again.step == 3
    weights = load_checkpoint(tmp_path / "c.pt").state["encoder2d"]
    assert all(torch.equal(p, weights[k]) for k, p in again.pipeline.stages["encoder2d"].state_dict().items())


def _state(path):
    return load_checkpoint(path).state["encoder2d"]


def test_resuming_a_checkpoint_of_other_stages_is_refused_naming_the_stage(registry, tmp_path):
    _trainer(registry, tmp_path / "w.pt", steps=2).run({})
    before = (tmp_path / "w.pt").read_bytes()
    pipeline = _pipeline(registry, encoder2d={"dim": 8})
    other = Trainer(pipeline, Clean("test"), None, tmp_path / "w.pt", TrainConfig(steps=3))
    with pytest.raises(WeightsError, match=r"cannot resume .*w\.pt: encoder2d: the pipeline has 'linear' \{'dim': 8\}"):
        other.resume()
    assert (tmp_path / "w.pt").read_bytes() == before  # nothing overwritten


def test_a_resume_file_from_another_save_is_not_applied_and_says_so(registry, tmp_path):
    _trainer(registry, tmp_path / "w.pt", steps=2).run({})
    stale = (tmp_path / "w.pt.resume").read_bytes()
    _trainer(registry, tmp_path / "w.pt", steps=3).run({})  # resumes, saves step 3 and its resume file
    (tmp_path / "w.pt.resume").write_bytes(stale)  # as if killed between writing the checkpoint and its resume file
    again = _trainer(registry, tmp_path / "w.pt", steps=4)
    note = again.resume()
    assert again.step == 3 and "fresh optimiser" in note and "belongs to another save" in note
    exact = _trainer(registry, tmp_path / "w.pt", steps=4)
    exact.save({})  # a matching pair again
    assert exact.resume() == "resumed exactly at step 0"


def test_a_checkpoint_with_a_flipped_byte_is_refused(registry, tmp_path):
    pipeline = _pipeline(registry)
    path = save_checkpoint(tmp_path / "w.pt", pipeline, steps=1)
    data = bytearray(path.read_bytes())
    weights = pipeline.stages["encoder2d"].layer.weight.detach().numpy().tobytes()
    offset = bytes(data).find(weights[:8])  # the stored weight tensor's first bytes
    assert offset > 0
    data[offset + 2] ^= 0x10
    path.write_bytes(bytes(data))
    with pytest.raises(WeightsError, match=r"w\.pt is corrupt: its content no longer matches the sha256"):
        load_checkpoint(path)


def test_an_unwritable_output_folder_fails_before_the_first_step(registry, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file, not a folder")  # unwritable even as root, unlike a chmod'ed folder
    trainer = _trainer(registry, blocker / "w.pt", steps=2)
    steps = []
    with pytest.raises(WeightsError, match=r"cannot write checkpoints to .*file"):
        trainer.run({}, lambda step, terms: steps.append(step))
    assert steps == []


def test_batches_and_workers_change_neither_the_samples_nor_the_result(monkeypatch, tmp_path):
    """batch 2 x 3 steps = the mean over the same 6 samples; 2 DataLoader workers give bit-identical weights."""
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")

    def train(name, **conf):
        varied_trainer(tmp_path / name, **conf).run({})
        return _state(tmp_path / name)

    batched = train("b.pt", batch_size=2)
    workers = train("w.pt", batch_size=2, workers=2)
    accumulated = train("a.pt", batch_size=1, accumulate=2)
    assert all(torch.equal(batched[k], workers[k]) for k in batched)
    assert all(torch.allclose(batched[k], accumulated[k], atol=1e-6) for k in batched)
    assert not torch.allclose(batched["layer.weight"], train("one.pt")["layer.weight"], atol=1e-3)


def _ddp_rank(rank: int, world: int, port: int, out: str) -> None:
    import os

    os.environ.update(RANK=str(rank), WORLD_SIZE=str(world), MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    os.environ["I2PBENCH_LOAD_PLUGINS"] = ""
    torch.set_num_threads(1)
    varied_trainer(out, batch_size=1).run({})
    torch.distributed.destroy_process_group()


def test_ddp_on_two_gloo_processes_equals_one_process_with_the_same_total_batch(monkeypatch, tmp_path):
    import socket

    import torch.multiprocessing as mp

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    mp.start_processes(_ddp_rank, args=(2, port, str(tmp_path / "ddp.pt")), nprocs=2, start_method="spawn")
    varied_trainer(tmp_path / "one.pt", batch_size=2).run({})
    varied_trainer(tmp_path / "alone.pt", batch_size=1).run({})
    ddp, one, alone = (_state(tmp_path / f) for f in ("ddp.pt", "one.pt", "alone.pt"))
    assert load_checkpoint(tmp_path / "ddp.pt").meta["steps"] == 3
    assert all(torch.allclose(ddp[k], one[k], atol=1e-6) for k in ddp)  # measured: equal; one frame alone: 0.097 off
    assert not torch.allclose(ddp["layer.weight"], alone["layer.weight"], atol=1e-3)  # ranks really were averaged


def test_fine_tuning_on_other_data_keeps_the_earlier_phase_in_the_checkpoint_identity(registry, tmp_path):
    first = _trainer(registry, tmp_path / "w.pt", steps=2)
    first.run(training_meta(Clean("test"), first.config))
    config = TrainConfig(steps=3, lr=0.05, checkpoint_every=1, validate_every=1000, seed=1)
    other = Clean("test", {"root": "/data/real"})
    tuned = Trainer(_pipeline(registry), other, None, tmp_path / "w.pt", config)
    assert tuned.resume() and tuned.step == 2
    tuned.run(training_meta(other, config))
    checkpoint = load_checkpoint(tmp_path / "w.pt")
    assert checkpoint.lineage == [{"dataset": "toy", "split": "test", "root": "", "steps": 2}]
    assert checkpoint.trained_on == "toy/test 2 + toy/test, 3 steps"
    assert checkpoint.meta["trained_on"]["root"] == "/data/real"


class KittiStyled(Clean):
    def identity(self):
        return {**super().identity(), "style": "kitti"}


def test_fine_tuning_on_another_synthetic_style_is_a_phase_of_its_own(registry, tmp_path):
    first = _trainer(registry, tmp_path / "w.pt", steps=2)
    first.run(training_meta(Clean("test"), first.config))
    config = TrainConfig(steps=3, lr=0.05, checkpoint_every=1, validate_every=1000, seed=1)
    styled = KittiStyled("test")
    tuned = Trainer(_pipeline(registry), styled, None, tmp_path / "w.pt", config)
    assert tuned.resume() and tuned.step == 2
    tuned.run(training_meta(styled, config))
    assert load_checkpoint(tmp_path / "w.pt").trained_on == "toy/test 2 + toy[kitti]/test, 3 steps"


def test_auto_weights_prefer_a_checkpoint_trained_on_the_run_s_dataset(registry, tmp_path):
    pipeline = _pipeline(registry)
    general = save_checkpoint(tmp_path / "a-general.pt", pipeline, steps=5, trained_on={"dataset": "synthetic"})
    tuned = save_checkpoint(
        tmp_path / "b-tuned.pt",
        pipeline,
        steps=9,
        trained_on={"dataset": "kitti"},
        lineage=[{"dataset": "synthetic", "split": "train", "root": "", "steps": 5}],
    )
    shipped = [str(general), str(tuned)]
    assert select_checkpoint(pipeline, "auto", shipped, "kitti").path == tuned
    assert select_checkpoint(pipeline, "auto", shipped, "synthetic").path == general
    assert select_checkpoint(pipeline, "auto", shipped, "nuscenes").path == general  # fewest phases
    assert select_checkpoint(pipeline, "auto", shipped[::-1]).path == general


class Five(toy_plugin.ToyDataset):
    def frame_ids(self):
        return ["a", "c", "d", "e", "f"]


def test_epochs_pass_through_every_frame_once_in_a_seeded_order(registry):
    from i2pbench.training.loop import steps_for_epochs
    from i2pbench.training.samples import TrainingSamples

    stages = _pipeline(registry).stages
    samples = TrainingSamples(stages, Five("test"), seed=3, epochs=True)
    orders = [[samples.frame(e * 5 + i).frame_id for i in range(5)] for e in range(3)]
    assert all(sorted(order) == ["a", "c", "d", "e", "f"] for order in orders)
    assert len({tuple(o) for o in orders}) > 1  # a new permutation per epoch
    again = TrainingSamples(stages, Five("test"), seed=3, epochs=True)
    assert [again.frame(i).frame_id for i in range(5)] == orders[0]
    assert steps_for_epochs(2, 5, TrainConfig(batch_size=2, accumulate=1)) == 5  # ceil(10 / 2)
    assert steps_for_epochs(1, 5, TrainConfig(batch_size=2, accumulate=2), world=2) == 1
