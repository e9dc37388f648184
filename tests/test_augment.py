"""Photometric training augmentation: exact on hand-set parameters, seeded per sample, images only."""

import numpy as np
import pytest
import toy_plugin

from i2pbench.registry.build import build_registry
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.training.augment import Photometric, augmentations
from i2pbench.training.samples import TrainingSamples


def test_a_pure_brightness_shift_adds_grey_levels_and_clips():
    image = np.array([[[0, 100, 250]]], np.uint8)
    shift = Photometric(gamma=(1, 1), contrast=(1, 1), brightness=(10, 10), noise_std=(0, 0), blur_probability=0)
    assert shift(image, np.random.default_rng(0)).tolist() == [[[10, 110, 255]]]


def test_contrast_scales_about_the_mean():
    image = np.array([[[100, 100, 100], [200, 200, 200]]], np.uint8)  # mean 150
    stretch = Photometric(gamma=(1, 1), contrast=(2, 2), brightness=(0, 0), noise_std=(0, 0), blur_probability=0)
    assert stretch(image, np.random.default_rng(0)).tolist() == [[[50, 50, 50], [250, 250, 250]]]


def test_training_samples_augment_the_image_only_and_per_sample_seed(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    registry = build_registry((toy_plugin,))
    names = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}
    stages = Pipeline.build(registry, Combination(names)).stages
    seen = []
    monkeypatch.setattr(
        TrainingSamples, "_prepare", lambda self, kind, frame, kp2d, kp3d, caches: seen.append(frame) or {}
    )

    class Grey(toy_plugin.ToyDataset):
        def frame_ids(self):
            return ["a"]

        def load(self, frame_id):
            frame = super().load(frame_id)
            return type(frame)(**{**frame.__dict__, "image": np.full((8, 8, 3), 128, np.uint8)})

    plain = TrainingSamples({**stages, "matcher": _Prepared()}, Grey("test"), seed=0)
    augmented = TrainingSamples({**stages, "matcher": _Prepared()}, Grey("test"), seed=0, augment="photometric")
    for samples in (plain, augmented, augmented):
        samples[3]
    clean, first, again = seen
    assert (clean.image == 128).all() and not (first.image == 128).all()
    np.testing.assert_array_equal(first.image, again.image)  # a function of (seed, sample index)
    np.testing.assert_array_equal(first.points, clean.points)
    np.testing.assert_array_equal(first.T_gt, clean.T_gt)
    with pytest.raises(ValueError, match="'fog': choose from none, photometric, lidar-dropout"):
        augmentations("fog")


class _Prepared:
    """a stand-in learned stage: only its presence matters, `_prepare` is patched."""

    name, conf = "stand-in", {}


def test_the_trainer_hands_its_augmentation_to_its_samples(monkeypatch, tmp_path):
    """the option reaches the data (it once stopped at the config, and a run 'with' augmentation had none)."""
    import test_weights_and_training as toy

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    trainers = [toy.varied_trainer(tmp_path / f"{a}.pt", augment=a) for a in ("none", "photometric")]
    assert trainers[0].samples.augment.image is None and isinstance(trainers[1].samples.augment.image, Photometric)
