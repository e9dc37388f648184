"""VP2P-Match's official size around the authors' network (whose tensors tests/test_vp2p_reference.py proves): the
`vp2p-match-official` importer through the command line, the pixel geometry that lets EPnP-RANSAC run their PnP,
run_kitti.py's inference rule, the size's declaration, and one untrained frame end to end."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from i2pbench_vp2p_match.official.importer import RELEASE
from i2pbench_vp2p_match.official.prepare import grid_pixels
from i2pbench_vp2p_match.official.stages import CROP, OfficialVP2PMatch, confident_pairs

from i2pbench.boards import leaderboard
from i2pbench.cli import main
from i2pbench.registry.build import default_registry
from i2pbench.testing.recipe import recipe_state
from i2pbench.weights.checkpoints import load_checkpoint

SHAPES = Path(__file__).parent / "data" / "vp2p_reference" / "state_dict_shapes.json"


@pytest.fixture(scope="module")
def authors_state() -> dict[str, torch.Tensor]:
    state, _ = recipe_state(json.loads(SHAPES.read_text()), "cli-import")
    return state


def test_the_command_imports_the_authors_state_dict_tensor_for_tensor(authors_state, tmp_path):
    source, out = tmp_path / "vp2p_kitti.pth", tmp_path / "W.pt"
    torch.save(authors_state, source)
    assert main(["weights", "import", "vp2p-match-official", str(source), "--out", str(out)]) == 0
    checkpoint = load_checkpoint(out)
    state = checkpoint.state["matcher"]
    assert sorted(state) == sorted("net." + k for k in authors_state)
    assert all(torch.equal(state["net." + k], v) for k, v in authors_state.items())
    origin = checkpoint.meta["imported_from"]
    assert origin["importer"] == "vp2p-match-official" and origin["file"] == "vp2p_kitti.pth"
    assert origin["sha256"] == hashlib.sha256(source.read_bytes()).hexdigest()
    assert checkpoint.trained_on == RELEASE == "authors' release (KITTI)"


def test_the_command_refuses_a_wrong_key_by_name(authors_state, tmp_path, capsys):
    state = dict(authors_state)
    state["resnet.extra.weight"] = state.pop("pc_score_head.0.weight")
    torch.save(state, tmp_path / "bad.pth")
    assert (
        main(["weights", "import", "vp2p-match-official", str(tmp_path / "bad.pth"), "--out", str(tmp_path / "W.pt")])
        == 2
    )
    err = capsys.readouterr().err
    assert "missing key pc_score_head.0.weight" in err and "unexpected key resnet.extra.weight" in err
    assert not (tmp_path / "W.pt").exists()


def test_grid_pixels_are_the_authors_cells_under_the_frames_K():
    # a 1242 x 375 KITTI image halved to 621 x 188 (round(187.5) = 188, as the loader's int(round())), crop offsets
    # dx = int((621 - 512) / 2) = 54, dy = int((188 - 160) / 2) = 14; cell (x, y) at u = 8x + 108, v = 8y + 28
    uv = grid_pixels(1242, 375, CROP)
    assert uv.shape == (40 * 128, 2)
    np.testing.assert_array_equal(uv[[0, 1, 128, -1]], [[108, 28], [116, 28], [108, 36], [1124, 340]])
    # run_kitti.py reads cell (x, y) with K_4 = (K x 0.5, cropped) x 0.25; a 3D point lands on our pixel of its cell
    K = np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]])
    K4 = K * 0.5
    K4[2, 2] = 1
    K4[0, 2] -= 54
    K4[1, 2] -= 14
    K4 = K4 * 0.25
    K4[2, 2] = 1
    points = np.random.default_rng(0).uniform([-10, -2, 5], [10, 2, 40], (50, 3))
    x4 = (points @ K4.T)[:, :2] / points[:, 2:]
    full = (points @ K.T)[:, :2] / points[:, 2:]
    np.testing.assert_allclose(full, 8 * x4 + [108, 28], atol=1e-9)


def test_each_confident_pixel_takes_its_nearest_confident_point_within_the_caps():
    pixel_feat = torch.tensor([[1.0, 0], [0, 1], [0.6, 0.8], [1, 0]]).t()  # 4 pixels, 2-d
    pixel_score = torch.tensor([0.96, 0.5, 0.99, 0.97])
    point_feat = torch.tensor([[0.8, 0.6], [0, 1], [1, 0], [0.6, 0.8]]).t()
    point_score = torch.tensor([0.96, 0.99, 0.2, 0.98])
    conf = {"pixel_threshold": 0.95, "point_threshold": 0.95, "max_pixels": 2, "max_points": 8500}
    rows, points, score = confident_pairs(pixel_feat, pixel_score, point_feat, point_score, conf)
    # confident pixels 0, 2, 3, the first two kept; points 0, 1, 3 (2 is not confident).
    # pixel 0 (1, 0): cosine 0.8, 0, 0.6 -> point 0; pixel 2 (0.6, 0.8): 0.96, 0.8, 1.0 -> point 3
    np.testing.assert_array_equal(rows, [0, 2])
    np.testing.assert_array_equal(points, [0, 3])
    np.testing.assert_allclose(score, [0.8, 1.0], rtol=1e-6)
    rows, points, _ = confident_pairs(pixel_feat, pixel_score, point_feat, point_score, {**conf, "max_points": 1})
    np.testing.assert_array_equal(points, [0, 0])  # only the first confident point is left to pair with
    nothing = confident_pairs(pixel_feat, pixel_score, point_feat, point_score, {**conf, "point_threshold": 0.995})
    assert [len(t) for t in nothing] == [0, 0, 0]


def test_the_official_size_runs_the_authors_stages_and_solver_settings():
    (row,) = default_registry().preset_rows("vp2p-match-official")
    assert (
        row["matcher"] == "vp2p-match-official" and row["encoder2d"] == row["encoder3d"] == row["exchanger"] == "none"
    )
    assert row["extractor2d"] == "vp2p-match-official-grid" and row["extractor3d"] == "vp2p-match-official-points"
    assert row["solver"] == "epnp-ransac" and row["confs"]["solver"] == {
        "iterations": 500,
        "reprojection_error_px": 8.0,
    }
    stage = OfficialVP2PMatch()
    assert sum(p.numel() for p in stage.parameters()) == 36_677_448  # the authors' VP2PMatchNet's count
    assert (stage.conf["pixel_threshold"], stage.conf["max_pixels"], stage.conf["max_points"]) == (0.95, 2800, 8500)


def test_the_preset_runs_a_kitti_frame_untrained_and_says_so(shared_data, tmp_path):
    torch.set_num_threads(1)
    runs = tmp_path / "runs"
    data = ["--dataset", "kitti", "--data-root", str(shared_data / "kitti_odometry"), "--split", "all", "--frames", "1"]
    small = ["--conf", "extractor3d.max_keypoints=4096", "--threads", "1"]  # the authors' network, fewer points
    assert main(["run", "--preset", "vp2p-match-official", *data, *small, "--runs-dir", str(runs), "--quiet"]) == 0
    board = leaderboard.read(next((runs / "leaderboards").glob("*.csv")))
    assert len(board) == 1 and board.iloc[0]["weights"] == "untrained"
    assert board.iloc[0]["frames"] == 1
