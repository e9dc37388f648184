"""CorrI2P's official size around the authors' network (whose tensors tests/test_corri2p_reference.py proves): the
importer of their state-dict layout, the pixel geometry that lets EPnP-RANSAC run their PnP, their inference rule,
and the size's declaration."""

from __future__ import annotations

import json
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from i2pbench_corri2p.official import importer
from i2pbench_corri2p.official.checkpoint import ours
from i2pbench_corri2p.official.stages import OfficialCorrI2P, grid_pixels, pixel_cells

from i2pbench.api import Keypoints2D, Keypoints3D, WeightsError
from i2pbench.cli import main
from i2pbench.registry.build import default_registry
from i2pbench.testing.recipe import recipe_value
from i2pbench.weights.checkpoints import load_checkpoint

SHAPES = Path(__file__).parent / "data" / "reference" / "corri2p" / "state_dict_shapes.json"


@pytest.fixture(scope="module")
def authors_state() -> dict[str, torch.Tensor]:
    """a seeded state dict in the authors' layout as DataParallel saves it (`module.` before every key)."""
    shapes = json.loads(SHAPES.read_text())
    return {f"module.{k}": torch.from_numpy(recipe_value(k, tuple(s), "/import")) for k, s in shapes.items()}


@pytest.fixture(scope="module")
def authors_file(authors_state, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("authors") / "mode_best_t.t7"
    torch.save(authors_state, path)
    return path


def test_import_round_trips_the_authors_state_dict(authors_state, authors_file, tmp_path):
    out = tmp_path / "W.pt"
    assert main(["weights", "import", "corri2p-official", str(authors_file), "--out", str(out)]) == 0
    checkpoint = load_checkpoint(out)
    state = checkpoint.state["matcher"]
    assert len(state) == len(authors_state) - 2  # all but the ResNet's unused ImageNet fc (weight, bias)
    for key, value in authors_state.items():
        target = ours(key)
        if target is None:
            assert key.endswith(("fc.weight", "fc.bias"))
        else:
            assert torch.equal(state["net." + target], value), key
    origin = checkpoint.meta["imported_from"]
    assert origin["importer"] == "corri2p-official" and origin["file"] == "mode_best_t.t7"
    assert origin["sha256"] == __import__("hashlib").sha256(authors_file.read_bytes()).hexdigest()
    assert origin["dropped"] == ["img_encoder.backbone.fc.bias", "img_encoder.backbone.fc.weight"]
    assert "user-supplied" in str(checkpoint.trained_on) and "released no weights" in str(checkpoint.trained_on)


def test_import_refuses_a_key_that_does_not_fit_by_name(authors_state, tmp_path):
    state = dict(authors_state)
    state["module.pc_encoder.extra_pointnet.layers.0.conv.weight"] = torch.zeros(1)
    state["module.node_a_pn.layers.0.conv.weight"] = state["module.node_a_pn.layers.0.conv.weight"][:, :10]
    del state["module.per_point_pn.layers.2.norm.running_var"]
    torch.save(state, tmp_path / "bad.t7")
    with pytest.raises(WeightsError, match="pc_encoder.extra_pointnet.layers.0.conv.weight") as err:
        importer.import_official(tmp_path / "bad.t7")
    assert "missing key net.exchange.per_point.2.1.running_var" in str(err.value)
    assert "key net.exchange.node_a_mlp.0.0.weight: shape (512, 10, 1), expected (512, 832, 1)" in str(err.value)


def test_grid_pixels_are_the_authors_cells_under_the_frames_K():
    # a 1242 x 375 KITTI image, whole (the loader cuts no rows), halved to 621 x 188 (Python's round(187.5) = 188, as
    # the loader's), crop offsets dx = (621 - 512) // 2 = 54, dy = (188 - 160) // 2 = 14; cell (x, y) at
    # u = 8x + 108, v = 8y + 28
    uv = grid_pixels(1242, 375)
    assert uv.shape == (40 * 128, 2)
    np.testing.assert_array_equal(uv[[0, 1, 128, -1]], [[108, 28], [116, 28], [108, 36], [1124, 340]])
    # the authors' PnP reads cell (x, y) with K4 = K of the crop / 4; the same 3D point under the full K lands on
    # our pixel of that cell, so EPnP at 8 px here is theirs at 1 px
    K = np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]])
    crop = 0.5 * K
    crop[2, 2] = 1
    crop[0, 2] -= 54
    crop[1, 2] -= 14
    K4 = 0.25 * crop
    K4[2, 2] = 1
    points = np.random.default_rng(0).uniform([-10, -2, 5], [10, 2, 40], (50, 3))
    x4 = (points @ K4.T)[:, :2] / points[:, 2:]
    full = (points @ K.T)[:, :2] / points[:, 2:]
    np.testing.assert_allclose(full, 8 * x4 + [108, 28], atol=1e-9)


def test_the_matcher_pairs_each_confident_point_with_its_nearest_confident_pixel(monkeypatch):
    stage = OfficialCorrI2P()
    # six pixels of a KITTI frame's official grid: cells 0, 1, 2 and 128, 129, 130 (two rows of three)
    cells = [0, 1, 2, 128, 129, 130]
    kp2d = Keypoints2D(grid_pixels(1242, 375)[cells])
    pixel, img_score = torch.zeros(1, 2, 40 * 128), torch.zeros(1, 1, 40 * 128)
    for cell, feature, score in zip(
        cells, ([0, 0], [1, 0], [0, 0], [0, 0], [0, 1], [0.6, 0.8]), (0.1, 0.95, 0.2, 0.5, 0.91, 0.99), strict=True
    ):
        pixel[0, :, cell], img_score[0, 0, cell] = torch.tensor(feature), score
    points = torch.tensor([[0.8, 0.6], [0.0, -1.0], [0.0, 1.0]]).t()[None]  # point 1 is not confident
    out = {"img_feature": pixel.view(1, 2, 40, 128), "img_score": img_score.view(1, 1, 40, 128), "pc_feature": points,
           "pc_score": torch.tensor([[[0.95, 0.5, 0.93]]])}  # fmt: skip
    monkeypatch.setattr(stage, "one", lambda *args: {})
    monkeypatch.setattr(stage, "batched", lambda inputs: out)
    kp3d = Keypoints3D(np.arange(3), np.zeros((3, 3), np.float32), np.zeros(3, np.float32))
    matches = stage(types.SimpleNamespace(image_size=(1242, 375), inputs=""), kp2d, kp3d, None)
    # confident pixels: rows 1, 4, 5. Point 0 (0.8, 0.6): cosine 0.8 with row 1, 0.6 with 4, 0.96 with 5 -> 5;
    # point 2 (0, 1): 0, 1, 0.8 -> 4
    np.testing.assert_array_equal(matches.index3d, [0, 2])
    np.testing.assert_array_equal(matches.index2d, [5, 4])
    np.testing.assert_allclose(matches.score, [0.96, 1.0], rtol=1e-6)
    assert matches.radius_px == 8.0


def test_a_pixel_reads_the_cell_it_falls_in_and_none_outside_the_crop():
    uv = grid_pixels(1242, 375)
    np.testing.assert_array_equal(pixel_cells(uv, 1242, 375), np.arange(len(uv)))  # the grid: every cell once
    inside = uv[[5, 300]] + [7.9, 7.9]  # anywhere in a cell's 8 x 8 full-size block
    np.testing.assert_array_equal(pixel_cells(inside, 1242, 375), [5, 300])
    np.testing.assert_array_equal(pixel_cells(np.array([[107.0, 28], [108, 27], [1132, 28]]), 1242, 375), [-1, -1, -1])
    assert len(grid_pixels(160, 96)) == 0  # a frame too small for the authors' crop has no pixel


def test_the_official_size_runs_the_authors_stages_and_solver_settings():
    registry = default_registry()
    (row,) = registry.preset_rows("corri2p-official")
    assert row["matcher"] == "corri2p-official" and row["encoder2d"] == row["encoder3d"] == row["exchanger"] == "none"
    assert row["extractor2d"] == "corri2p-official-grid" and row["extractor3d"] == "corri2p-official-points"
    assert row["solver"] == "epnp-ransac" and row["confs"]["solver"] == {
        "iterations": 500,
        "reprojection_error_px": 8.0,
    }
    stage = OfficialCorrI2P()
    assert sum(p.numel() for p in stage.parameters()) == 36_381_392  # the authors' 36,894,392 less fc's 513,000
