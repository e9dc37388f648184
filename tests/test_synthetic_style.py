"""Generator styles: the default style is the default generator byte for byte, the kitti style moves the image and
the scan, a style keeps its own cache root, marker and identity, and an unknown style is refused."""

from __future__ import annotations

import argparse
import dataclasses
import json

import cv2
import numpy as np
import pytest

from i2pbench.cli import main
from i2pbench.commands.options import open_dataset
from i2pbench.data.synthetic import GENERATOR_VERSION, SyntheticStreets
from i2pbench.data.synthetic import dataset as synthetic_dataset
from i2pbench.data.synthetic.dataset import MARKER, default_root, generate, marker
from i2pbench.data.synthetic.kitti_writer import simulate
from i2pbench.data.synthetic.style import DEFAULT, STYLES, Style, get_style
from i2pbench.errors import DataError
from i2pbench.registry.build import default_registry

FRAME = (0, "01", 0)  # seed, sequence, index: one full-size val frame (~1 s to simulate)


@pytest.fixture(scope="module")
def plain_frame():
    return simulate(*FRAME)


@pytest.fixture(scope="module")
def kitti_frame():
    return simulate(*FRAME, style=STYLES["kitti"])


def grey_mean(image: np.ndarray) -> float:
    return float(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).mean())


def zero_share(points: np.ndarray) -> float:
    return float((points[:, 3] == 0).mean())


def test_default_style_is_the_generator_without_a_style(plain_frame):
    assert STYLES["default"] == DEFAULT == Style() and DEFAULT.is_default and not STYLES["kitti"].is_default
    styled = simulate(*FRAME, style=STYLES["default"])
    for a, b in zip(plain_frame, styled, strict=True):
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_a_lidar_only_knob_leaves_the_frame_rng_alone(plain_frame):
    """A style draws nothing from the frame's generator: moving only the reflectance floor keeps every point where
    it was and the image as it was, and only turns weak returns to 0."""
    points, ring, image = simulate(*FRAME, style=Style(name="floor", reflectance_floor=0.08))
    base_points, base_ring, base_image = plain_frame
    assert np.array_equal(points[:, :3], base_points[:, :3])
    assert np.array_equal(ring, base_ring) and np.array_equal(image, base_image)
    changed = points[:, 3] != base_points[:, 3]
    assert changed.any() and (points[changed, 3] == 0).all() and (base_points[changed, 3] <= 0.08).all()


def test_kitti_style_changes_image_and_scan(plain_frame, kitti_frame):
    points, ring, image = kitti_frame
    base_points, _, base_image = plain_frame
    assert image.shape == base_image.shape and image.dtype == np.uint8
    assert not np.array_equal(image, base_image)
    assert len(points) != len(base_points) or not np.array_equal(points, base_points)
    assert 90_000 < len(points) < 140_000 and ring.max() == 63
    # measured on this frame: grey mean 109.9 -> 88.5, exactly-zero reflectance 10.2% -> 21.0%
    assert grey_mean(image) < grey_mean(base_image) - 10
    assert abs(grey_mean(image) - 255 * STYLES["kitti"].mean_grey) < 3, "exposed for the style's mean grey"
    assert zero_share(points) > zero_share(base_points) + 0.05


def test_kitti_style_is_deterministic(kitti_frame):
    """Its extra clutter comes from the style's own generator, seeded by the frame and the style name."""
    again = simulate(*FRAME, style=STYLES["kitti"])
    assert all(a.tobytes() == b.tobytes() for a, b in zip(kitti_frame, again, strict=True))


def test_unknown_style_is_refused_naming_the_known_ones(tmp_path):
    with pytest.raises(DataError, match=r"unknown style 'nope'; choose one of \['default', 'kitti'\]"):
        SyntheticStreets("val", {"style": "nope", "root": str(tmp_path)})
    with pytest.raises(DataError, match="unknown style 'nope'"):
        generate(tmp_path, 1, 1, 1, style="nope")
    with pytest.raises(DataError, match="unknown style 3"):
        get_style(3)
    assert not any(tmp_path.iterdir()), "nothing is generated for an unknown style"


def test_roots_markers_and_identities(monkeypatch):
    monkeypatch.delenv("I2PBENCH_SYNTHETIC_ROOT", raising=False)
    default = SyntheticStreets("val", {})
    kitti = SyntheticStreets("val", {"style": "kitti", "seed": 3})
    assert default.root.name == f"synthetic-v{GENERATOR_VERSION}-seed0" == default_root(0).name
    assert kitti.root.name == f"synthetic-v{GENERATOR_VERSION}-kitti-seed3"
    assert kitti.root.parent == default.root.parent
    old = {"generator_version": GENERATOR_VERSION, "seed": 0, "sequence": "01", "frames": 20}
    assert marker(0, "01", 20) == marker(0, "01", 20, "default") == old, "existing caches stay valid"
    knobs = marker(0, "01", 20, "kitti").pop("style_knobs")
    assert marker(0, "01", 20, "kitti") == {**old, "style": "kitti", "style_knobs": knobs}
    assert knobs == json.loads(json.dumps(knobs)) and knobs["reflectance_floor"] == STYLES["kitti"].reflectance_floor
    assert default.identity() == {
        "dataset": "synthetic",
        "split": "val",
        "seed": 0,
        "frames": 20,
        "generator_version": GENERATOR_VERSION,
    }
    assert kitti.identity() == {**default.identity(), "seed": 3, "style": "kitti"}


def test_kitti_split_is_generated_read_and_kept_apart(tmp_path, kitti_frame):
    split = SyntheticStreets("val", {"root": str(tmp_path), "style": "kitti", "frames": {"val": 1}, "workers": 1})
    assert split.frame_ids() == ["01/000000"]
    frame = split.load("01/000000")
    assert np.array_equal(frame.points, kitti_frame[0]) and np.array_equal(frame.image, kitti_frame[2])
    written = json.loads((tmp_path / "sequences" / "01" / MARKER).read_text())
    assert written == marker(0, "01", 1, "kitti")
    # the same root asked for the default style: refused, not regenerated over the kitti frames
    with pytest.raises(DataError, match="holds synthetic style 'kitti', not 'default'"):
        SyntheticStreets("val", {"root": str(tmp_path), "frames": {"val": 1}}).frame_ids()
    assert json.loads((tmp_path / "sequences" / "01" / MARKER).read_text()) == written
    # made by an earlier fit of the kitti style: outdated, so regenerated with today's knobs
    stale = {**written, "style_knobs": {**written["style_knobs"], "detail": 0.25}}
    (tmp_path / "sequences" / "01" / MARKER).write_text(json.dumps(stale))
    assert split.frame_ids() == ["01/000000"]
    assert json.loads((tmp_path / "sequences" / "01" / MARKER).read_text()) == written


def test_data_conf_and_cli_pass_the_style(monkeypatch, tmp_path, capsys):
    monkeypatch.delenv("I2PBENCH_SYNTHETIC_ROOT", raising=False)
    args = argparse.Namespace(dataset="synthetic", split="val", data_root=None, data_conf=["style=kitti"])
    opened = open_dataset(default_registry(), args)  # run, train and domain-gap open their data this way
    assert opened.conf["style"] == "kitti" and opened.root.name.endswith("-kitti-seed0")
    calls = []
    monkeypatch.setattr(synthetic_dataset, "generate", lambda *a, **k: calls.append((a, k)) or tmp_path)
    assert main(["data", "synth", "--style", "kitti", "--val", "2", "--quiet"]) == 0
    assert calls[0][1]["style"] == "kitti" and calls[0][0][:4] == (None, 400, 2, 40)
    assert "style kitti" in capsys.readouterr().err
    monkeypatch.undo()
    assert main(["data", "synth", "--style", "nope", "--root", str(tmp_path / "x"), "--quiet"]) == 2
    assert "unknown style 'nope'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_styles_are_frozen_and_the_kitti_knobs_are_off_their_defaults():
    kitti = STYLES["kitti"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        kitti.exposure = 1.0  # type: ignore[misc]
    moved = {f.name for f in dataclasses.fields(Style) if getattr(kitti, f.name) != getattr(DEFAULT, f.name)}
    assert {"mean_grey", "gamma", "detail", "props", "foliage_depth", "reflectance_floor"} <= moved
