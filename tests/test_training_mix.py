"""Sim-to-real levers of `train`: mixing datasets in one run (--mix, --val-dataset) and LiDAR dropout."""

import math
import subprocess
import sys

import numpy as np
import pytest
import toy_plugin

from i2pbench.api import Extractor3D, Keypoints3D, SensorFrame, hookimpl
from i2pbench.errors import I2PBenchError
from i2pbench.registry.build import build_registry
from i2pbench.scoring.protocol import Protocol
from i2pbench.training.lidar_dropout import LidarDropout, thin
from i2pbench.training.mix import MixedSource, SourceSpec, check_mix, choose_source, open_source, parse_source
from i2pbench.training.samples import TrainingSamples
from i2pbench.weights.checkpoints import data_label, load_checkpoint


class Clean(toy_plugin.ToyDataset):
    def frame_ids(self):
        return ["a", "c"]


class Real(toy_plugin.ToyDataset):
    """another dataset with the same frame ids as Clean, but 40 points in 4 rings of 10."""

    name = "toy-real"

    def frame_ids(self):
        return ["a", "c"]

    def load(self, frame_id):
        rng = np.random.default_rng(1)
        points = np.c_[rng.uniform(-5, 5, (40, 3)), rng.uniform(0, 1, 40)].astype(np.float32)
        ring = np.repeat(np.arange(4), 10).astype(np.int16)
        return SensorFrame("toy-real", frame_id, np.zeros((8, 8, 3), np.uint8), points, ring, np.eye(3), np.eye(4))


class LastPoints(Extractor3D):
    """the scan's last 3 rows: different indices for scans of different sizes."""

    name = "last"

    def __call__(self, frame):
        n = len(frame.points)
        return Keypoints3D.from_index(frame, np.arange(n - 3, n))


class RealPlugin:
    @hookimpl
    def register_datasets(self, register):
        register(Real)


EXTRACTORS = {"extractor2d": toy_plugin.GridPixels(), "extractor3d": LastPoints()}


def binomial_bound(n: int, p: float) -> tuple[float, float]:
    """n p +- 4 standard deviations of a binomial count."""
    sd = math.sqrt(n * p * (1 - p))
    return n * p - 4 * sd, n * p + 4 * sd


def test_binomial_bound_by_hand():
    assert binomial_bound(2000, 0.5) == pytest.approx((1000 - 89.443, 1000 + 89.443), abs=1e-3)  # 4 sqrt(500)


def test_each_source_gets_its_share_and_the_draw_is_a_pure_function_of_seed_and_index():
    mix = [MixedSource(Real("test"), 0.3), MixedSource(Real("test", {"root": "/other"}), 0.2)]
    samples = TrainingSamples(EXTRACTORS, Clean("test"), seed=5, mix=mix)
    drawn = [samples.source(i) for i in range(2000)]
    again = TrainingSamples(EXTRACTORS, Clean("test"), seed=5, mix=mix)
    assert drawn == [again.source(i) for i in range(2000)]
    for source, share in ((1, 0.3), (2, 0.2), (0, 0.5)):
        low, high = binomial_bound(2000, share)  # (518, 682), (328, 472), (911, 1089)
        assert low < drawn.count(source) < high
    assert drawn != [TrainingSamples(EXTRACTORS, Clean("test"), seed=6, mix=mix).source(i) for i in range(2000)]
    assert choose_source([], 5, 3) == 0


def test_a_sample_s_frame_comes_from_its_source_and_an_unmixed_run_draws_as_before():
    mixed = TrainingSamples(EXTRACTORS, Clean("test"), seed=2, mix=[MixedSource(Real("test"), 0.5)])
    names = {mixed.source(i): mixed.frame(i).dataset for i in range(20)}
    assert names == {0: "toy", 1: "toy-real"}
    plain = TrainingSamples(EXTRACTORS, Clean("test"), seed=2)
    for i in range(5):  # the frame draw of every run before --mix existed
        frame_id = ["a", "c"][int(np.random.default_rng([2, i]).integers(2))]
        assert plain.frame(i).frame_id == frame_id
        expected = Protocol(seed=2 * 1_000_003 + i).apply(Clean("test").load(frame_id))
        np.testing.assert_array_equal(plain.frame(i).T_gt, expected.T_gt)


def test_equal_frame_ids_of_two_sources_never_share_a_cache_entry(tmp_path):
    mix = [MixedSource(Real("test"), 0.5)]
    samples = TrainingSamples(EXTRACTORS, Clean("test"), seed=0, cache_root=tmp_path, mix=mix)
    first = {}
    for i in range(40):  # both sources draw frame "a" and "c"; each keeps its own extractor output
        source = samples.source(i)
        first.setdefault(source, samples.keypoints(samples.frame(i), source)[1].index.tolist())
    assert first == {0: [7, 8, 9], 1: [37, 38, 39]}  # the last 3 of 10 and of 40 points
    folders = {s.keypoint_cache.folder for s in samples.sources}
    assert len(folders) == 2 and all(len(list(f.glob("*.pt"))) == 2 for f in folders)
    unmixed = TrainingSamples(EXTRACTORS, Clean("test"), seed=0, cache_root=tmp_path)
    assert unmixed.sources[0].keypoint_cache.folder == samples.sources[0].keypoint_cache.folder  # same data: shared


def test_epochs_and_a_mix_are_refused_together():
    with pytest.raises(ValueError, match="epochs pass over one split"):
        TrainingSamples(EXTRACTORS, Clean("test"), seed=0, epochs=True, mix=[MixedSource(Real("test"), 0.5)])


def test_a_mix_spec_parses_with_and_without_a_root():
    assert parse_source("kitti:train@../data/kitti_real=0.5", "--mix", True) == SourceSpec(
        "kitti", "train", "../data/kitti_real", 0.5
    )
    assert parse_source("synthetic:val", "--val-dataset", False) == SourceSpec("synthetic", "val")


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("kitti=0.5", r"^--mix 'kitti=0.5': expected DATASET:SPLIT\[@ROOT\]=SHARE"),
        ("kitti:train", r"^--mix 'kitti:train': no share"),
        ("kitti:train=1.5", r"^--mix 'kitti:train=1.5': share 1.5 is outside \(0, 1\)"),
        ("kitti:train=0", r"^--mix 'kitti:train=0': share 0 is outside \(0, 1\)"),
        ("kitti:train=half", r"^--mix 'kitti:train=half': share 'half' is not a number"),
    ],
)
def test_a_malformed_mix_spec_names_the_option(spec, message):
    with pytest.raises(I2PBenchError, match=message):
        parse_source(spec, "--mix", True)


def test_shares_must_leave_the_main_dataset_samples_and_sources_be_distinct():
    main = SourceSpec("synthetic", "train")
    with pytest.raises(I2PBenchError, match=r"^--mix: the shares sum to 1.1; they must sum to under 1"):
        check_mix(main, [SourceSpec("kitti", "train", None, 0.6), SourceSpec("kitti", "val", None, 0.5)])
    with pytest.raises(I2PBenchError, match=r"^--mix: synthetic:train is named twice"):
        check_mix(main, [SourceSpec("synthetic", "train", None, 0.5)])
    check_mix(main, [SourceSpec("kitti", "train", None, 0.5), SourceSpec("kitti", "val", None, 0.25)])


def test_an_unknown_dataset_or_split_is_an_error_naming_the_option(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin, RealPlugin()))
    with pytest.raises(I2PBenchError, match=r"^--mix toy-rael:test: unknown dataset 'toy-rael'; did you mean"):
        open_source(registry, SourceSpec("toy-rael", "test", None, 0.5), "--mix")
    with pytest.raises(I2PBenchError, match=r"^--val-dataset toy-real:train: .*has no split 'train'"):
        open_source(registry, SourceSpec("toy-real", "train"), "--val-dataset")
    assert open_source(registry, SourceSpec("toy-real", "test"), "--mix").frame_ids() == ["a", "c"]


def test_the_cli_refuses_a_bad_mix_before_any_work(tmp_path):
    cmd = [sys.executable, "-m", "i2pbench.cli", "train", "--mix", "kitti:train=0.7", "--mix", "kitti:val=0.3",
           "--out", str(tmp_path / "w.pt"), "--quiet"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "--mix: the shares sum to 1" in done.stderr
    assert not (tmp_path / "w.pt").exists()


def tiny_frame() -> toy_plugin.SensorFrame:
    """6 points, 2 in each of 3 rings, at x = 0..5 so a row is recognisable by its coordinates."""
    points = np.c_[np.arange(6), np.zeros(6), np.ones(6), np.linspace(0, 1, 6)].astype(np.float32)
    ring = np.array([0, 0, 1, 1, 2, 2], np.int16)
    return SensorFrame("toy", "t", np.zeros((8, 8, 3), np.uint8), points, ring, np.eye(3), np.eye(4))


def test_thinning_removes_the_dropped_rows_and_keypoints_keep_their_coordinates():
    frame = Protocol(seed=0).apply(tiny_frame())
    kp3d = Keypoints3D.from_index(frame, np.array([1, 2, 4, 5]))
    keep = np.array([True, False, True, True, False, True])
    thinned, kept = thin(frame, kp3d, keep)
    assert len(thinned.points) == 4 and thinned.ring.tolist() == [0, 1, 1, 2]
    np.testing.assert_array_equal(thinned.points, frame.points[[0, 2, 3, 5]])
    np.testing.assert_array_equal(thinned.ranges, frame.ranges[[0, 2, 3, 5]])
    assert kept.index.tolist() == [1, 3]  # rows 2 and 5 of the scan are rows 1 and 3 of what stays; 1 and 4 went
    np.testing.assert_array_equal(kept.xyz, kp3d.xyz[[1, 3]])
    np.testing.assert_array_equal(kept.xyz, thinned.points[kept.index, :3])
    np.testing.assert_array_equal(kept.reflectance, np.float32([0.4, 1.0]))  # linspace(0, 1, 6) at rows 2 and 5
    np.testing.assert_array_equal(thinned.T_gt, frame.T_gt)


def test_ring_dropout_drops_whole_rings_and_never_all_of_them():
    ring = np.repeat(np.arange(4), 10)
    keep = LidarDropout(point_share=(0, 0), ring_share=(0.5, 0.5)).keep(ring, np.random.default_rng(0))
    per_ring = [int(keep[ring == r].sum()) for r in range(4)]
    assert sorted(per_ring) == [0, 0, 10, 10]  # int(0.5 x 4) = 2 rings gone whole, the other 2 whole
    everything = LidarDropout(point_share=(0, 0), ring_share=(1, 1)).keep(ring, np.random.default_rng(0))
    assert len(np.unique(ring[everything])) == 1 and everything.sum() == 10


def test_point_dropout_drops_its_share_of_points():
    keep = LidarDropout(point_share=(0.5, 0.5), ring_share=(0, 0)).keep(np.zeros(2000, int), np.random.default_rng(3))
    low, high = binomial_bound(2000, 0.5)
    assert low < keep.sum() < high


class SpreadPoints(Extractor3D):
    """every 7th row: keypoints in every ring of a Real scan."""

    name = "spread"

    def __call__(self, frame):
        return Keypoints3D.from_index(frame, np.arange(0, len(frame.points), 7))


def test_training_samples_thin_the_scan_per_sample_reproducibly_and_prepare_without_the_cache(monkeypatch):
    seen = []

    def prepare(self, kind, frame, kp2d, kp3d, caches):
        seen.append((frame, kp3d, caches))
        return {}

    monkeypatch.setattr(TrainingSamples, "_prepare", prepare)
    stages = {**EXTRACTORS, "extractor3d": SpreadPoints(), "matcher": _Prepared()}
    both = "photometric,lidar-dropout"
    for augment in ("none", both, both):
        assert "error" not in TrainingSamples(stages, Real("test"), seed=0, augment=augment)[4]
    (clean, clean_kp, clean_caches), (first, first_kp, caches), (again, again_kp, _) = seen
    assert clean_caches is not None and caches is None  # a thinned scan is not the one grouping was cached for
    keep = LidarDropout().keep(clean.ring, np.random.default_rng([0, 4, 11]))  # the sample's own draw
    assert 0 < keep.sum() < len(keep)
    np.testing.assert_array_equal(first.points, clean.points[keep])  # points removed, none moved
    np.testing.assert_array_equal(first_kp.xyz, clean_kp.xyz[keep[clean_kp.index]])  # the same 3D coordinates
    np.testing.assert_array_equal(first_kp.xyz, first.points[first_kp.index, :3])
    np.testing.assert_array_equal(first.points, again.points)  # a function of (seed, sample index)
    np.testing.assert_array_equal(first_kp.index, again_kp.index)
    np.testing.assert_array_equal(first.T_gt, clean.T_gt)
    assert not np.array_equal(first.image, clean.image)  # both augmentations of the comma list ran


class _Prepared:
    """a stand-in learned stage: only its presence matters, `_prepare` is patched."""

    name, conf = "stand-in", {}


def test_the_provenance_names_every_source_and_its_share():
    data = {"dataset": "synthetic", "split": "train", "mix": [{"dataset": "kitti", "split": "train", "share": 0.5}]}
    assert data_label(data) == "synthetic/train + kitti/train (0.5)"
    assert data_label({"dataset": "synthetic", "split": "train"}) == "synthetic/train"


def test_a_mixed_checkpoint_records_its_sources_and_a_run_without_the_mix_is_a_new_phase(monkeypatch, tmp_path):
    import test_weights_and_training as toy
    import torch

    from i2pbench.stages.pipeline import Combination, Pipeline
    from i2pbench.training.config import TrainConfig
    from i2pbench.training.lineage import training_meta
    from i2pbench.training.loop import Trainer

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))
    mix = [MixedSource(Real("test"), 0.5)]

    def trainer(steps, mix):
        torch.manual_seed(0)
        config = TrainConfig(steps=steps, lr=0.05, checkpoint_every=1, validate_every=1000, seed=1)
        pipeline = Pipeline.build(registry, Combination(toy.LEARNED))
        return Trainer(pipeline, Clean("test"), None, tmp_path / "w.pt", config, mix), config

    mixed, config = trainer(2, mix)
    mixed.run(training_meta(Clean("test"), config, mix=mix))
    checkpoint = load_checkpoint(tmp_path / "w.pt")
    assert checkpoint.trained_on == "toy/test + toy-real/test (0.5), 2 steps"
    assert checkpoint.meta["trained_on"]["mix"] == [
        {"dataset": "toy-real", "split": "test", "root": "", "frames": 2, "share": 0.5}
    ]
    same, _ = trainer(3, mix)
    assert same.resume() and same.lineage == []  # the same mix: one phase
    alone, config = trainer(3, ())
    alone.resume()
    alone.run(training_meta(Clean("test"), config))
    assert load_checkpoint(tmp_path / "w.pt").trained_on == "toy/test + toy-real/test (0.5) 2 + toy/test, 3 steps"


def test_a_mixed_run_with_dropout_trains_validates_on_the_named_split_and_says_what_it_was_trained_on(
    shared_data, tmp_path
):
    from test_train_cli import train

    root = shared_data / "kitti_real"
    out = tmp_path / "w.pt"
    extra = ["--mix", f"kitti:val@{root}=0.5", "--val-dataset", f"kitti:val@{root}", "--augment",
             "photometric,lidar-dropout", "--steps", "1", "--validate-every", "1"]  # fmt: skip
    done = train(shared_data, tmp_path, out, *extra)
    assert done.returncode == 0, done.stderr
    assert "on kitti/train + kitti/val (0.5), effective batch 2" in done.stderr
    checkpoint = load_checkpoint(out)
    assert checkpoint.trained_on == "kitti/train + kitti/val (0.5), 1 steps of 2 frames"
    assert checkpoint.meta["train_config"]["augment"] == "photometric,lidar-dropout"
    assert checkpoint.meta["validation"]["frames"] == 1
    assert "skipped" not in (tmp_path / "w.pt.log.jsonl").read_text()  # no sample broke
