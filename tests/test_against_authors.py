"""benchmarks/against_authors.py's own pieces (its timing needs the authors' checkout and minutes, so it is run by
hand, docs/performance.md): the frame at the authors' sizes keeps the reference set's cloud and canvas and draws
its keypoints inside them; a folder that is not an EdgeRegNet checkout is refused by name."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import against_authors  # noqa: E402


@pytest.fixture
def recorded():
    rng = np.random.default_rng(0)
    canvas = np.zeros((10, 20), np.uint8)
    canvas[:8, :15] = rng.integers(1, 255, (8, 15))  # the image pasted at (0, 0), black beyond
    xyz = rng.standard_normal((50, 4)).astype(np.float32)
    return {"canvas": canvas, "xyz": xyz, "kp3d": xyz[:4], "kp2d": np.zeros((4, 2), np.int16)}


def test_authors_sizes_draw_keypoints_inside_the_image_and_the_cloud(recorded):
    inputs = against_authors.with_keypoints(recorded, 30)
    uv, kp3d = inputs["kp2d"], inputs["kp3d"]
    assert uv.shape == (30, 2) and uv.dtype == np.int16 and kp3d.shape == (30, 4)
    assert uv[:, 0].min() >= 0 and uv[:, 0].max() <= 14 and uv[:, 1].min() >= 0 and uv[:, 1].max() <= 7
    rows = {tuple(r) for r in recorded["xyz"]}
    assert all(tuple(r) in rows for r in kp3d) and len({tuple(r) for r in kp3d}) == 30  # distinct cloud points
    assert inputs["canvas"] is recorded["canvas"] and inputs["xyz"] is recorded["xyz"]
    assert np.array_equal(against_authors.with_keypoints(recorded, 30)["kp2d"], uv)  # seeded


def test_authors_sizes_zero_keeps_the_recorded_keypoints(recorded):
    assert against_authors.with_keypoints(recorded, 0) is recorded


def test_a_folder_without_their_model_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="no models/cali_glue.py"):
        against_authors.import_authors_edgeregnet(tmp_path)
