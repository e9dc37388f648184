"""The synthetic dataset: KITTI-layout round trip, determinism, and edges that agree between camera and LiDAR."""

from __future__ import annotations

import numpy as np
import pytest

from i2pbench.data.kitti import read_frame
from i2pbench.data.synthetic import SyntheticStreets
from i2pbench.data.synthetic.kitti_writer import generate_kitti, simulate
from i2pbench.data.synthetic.rig import camera2
from i2pbench.errors import DataError


@pytest.fixture(scope="module")
def val_split(tmp_path_factory) -> SyntheticStreets:
    root = tmp_path_factory.mktemp("synthetic")
    return SyntheticStreets("val", {"root": str(root), "frames": {"val": 2}, "workers": 1})


def test_round_trip_through_kitti_reader(val_split):
    ids = val_split.frame_ids()
    assert ids == ["01/000000", "01/000001"]
    frame = val_split.load(ids[1])
    points, ring, image = simulate(0, "01", 1)
    assert frame.image_size == (1241, 376)
    assert np.array_equal(frame.image, image)
    assert np.array_equal(frame.points, points)
    assert np.array_equal(frame.ring, ring), "the KITTI reader's ring recovery must find the simulated lasers"
    assert frame.dataset == "synthetic" and frame.frame_id == "01/000001"
    np.testing.assert_allclose(frame.K, [[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]])
    np.testing.assert_allclose(frame.T_cam_lidar, camera2().T_cam_lidar, atol=1e-12)
    assert 90_000 < len(points) < 128_000 and ring.max() == 63


def test_existing_split_is_reused_not_regenerated(val_split):
    seq = val_split.sequence_dir()
    before = (seq / "velodyne" / "000000.bin").stat().st_mtime_ns
    again = SyntheticStreets("val", {"root": val_split.conf["root"], "frames": {"val": 2}})
    assert again.frame_ids() == val_split.frame_ids()
    assert (seq / "velodyne" / "000000.bin").stat().st_mtime_ns == before


def test_foreign_folder_is_not_overwritten(tmp_path):
    (tmp_path / "sequences" / "02").mkdir(parents=True)
    with pytest.raises(DataError, match="not made by the synthetic generator"):
        SyntheticStreets("test", {"root": str(tmp_path)}).frame_ids()


def test_same_seed_gives_identical_files(tmp_path):
    a = generate_kitti(tmp_path / "a", {"03": 2}, seed=5, workers=1)
    b = generate_kitti(tmp_path / "b", {"03": 2}, seed=5, workers=2)
    for stem in ("000000", "000001"):
        for rel in (f"velodyne/{stem}.bin", f"image_2/{stem}.png"):
            assert (a / "sequences/03" / rel).read_bytes() == (b / "sequences/03" / rel).read_bytes()
    other = generate_kitti(tmp_path / "c", {"03": 1}, seed=6, workers=1)
    scan = "sequences/03/velodyne/000000.bin"
    assert (other / scan).read_bytes() != (a / scan).read_bytes()
    assert read_frame(a / "sequences/03", "000000").points.shape[1] == 4
