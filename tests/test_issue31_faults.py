"""Issue 31's faults: bad input, misuse and broken files get one clear error naming the file or option, and nothing
already made (real data, shipped weights, finished frames) is overwritten or lost."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_cli_errors import assert_refused, i2pbench

from i2pbench.data.synthetic.dataset import SyntheticStreets
from i2pbench.errors import DataError


def _tree(root: Path) -> dict[str, int]:
    return {str(p.relative_to(root)): p.stat().st_size for p in sorted(root.rglob("*"))}


def _kitti_copy(tmp_path: Path) -> Path:
    root = tmp_path / "kitti"
    seq = root / "sequences" / "26"
    (seq / "velodyne").mkdir(parents=True)
    (seq / "image_2").mkdir()
    (seq / "calib.txt").write_text("P2: 1 0 0 0 0 1 0 0 0 0 1 0\n")
    (seq / "velodyne" / "000000.bin").write_bytes(b"\0" * 64)
    return root


def test_synthetic_refuses_to_generate_into_a_kitti_copy(tmp_path):
    root = _kitti_copy(tmp_path)
    before = _tree(root)
    with pytest.raises(DataError, match=r"kitti holds data not made by the synthetic generator \(it looks like KITTI"):
        SyntheticStreets("test", {"root": str(root), "frames": {"test": 1}}).frame_ids()
    assert _tree(root) == before  # not even an empty sequences/02


def test_synthetic_refuses_to_generate_into_a_nuscenes_dataroot(tmp_path):
    root = tmp_path / "nuscenes"
    (root / "v1.0-mini").mkdir(parents=True)
    (root / "samples" / "CAM_FRONT").mkdir(parents=True)
    before = _tree(root)
    with pytest.raises(DataError, match=r"nuscenes holds data not made .*looks like a nuScenes dataroot.*samples"):
        SyntheticStreets("val", {"root": str(root), "frames": {"val": 1}}).frame_ids()
    assert _tree(root) == before


def test_run_with_a_kitti_data_root_and_no_dataset_is_one_error_and_writes_nothing(tmp_path):
    root = _kitti_copy(tmp_path)
    before = _tree(root)
    done = i2pbench(
        "run", "--data-root", str(root), "--frames", "1", "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path
    )
    assert_refused(done, str(root), "KITTI", "--dataset kitti")
    assert _tree(root) == before


def test_a_synthetic_root_the_generator_made_is_still_extended(tmp_path):
    """Another split generated into a root holding only the generator's own sequences is allowed."""
    root = tmp_path / "synthetic"
    conf = {"root": str(root), "frames": {"val": 1, "test": 1}, "workers": 1}
    SyntheticStreets("val", conf).frame_ids()
    assert SyntheticStreets("test", conf).frame_ids() == ["02/000000"]
    assert sorted(p.name for p in (root / "sequences").iterdir()) == ["01", "02"]
