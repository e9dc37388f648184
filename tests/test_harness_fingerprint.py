"""Cached results follow the frame's files: a repaired scan is recomputed without --overwrite; unchanged, reused."""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import toy_plugin

from i2pbench.data.base import Dataset, file_stamp
from i2pbench.data.kitti import KittiOdometry
from i2pbench.data.nuscenes import NuScenes
from i2pbench.data.synthetic.dataset import SyntheticStreets
from i2pbench.errors import DataError
from i2pbench.registry.build import build_registry
from i2pbench.runs.executors import plan, run_grid
from i2pbench.runs.jobs import frame_key, prepare
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination

BASE = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}
FRAMES = ["00/000000", "00/000001"]


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    return build_registry((toy_plugin,))


@pytest.fixture
def kitti(shared_data, tmp_path) -> KittiOdometry:
    """Two real frames of sequence 00 copied to a writable KITTI layout."""
    source, seq = shared_data / "kitti_odometry" / "sequences" / "00", tmp_path / "kitti" / "sequences" / "00"
    for folder in ("velodyne", "image_2"):
        (seq / folder).mkdir(parents=True)
    for frame_id in FRAMES:
        stem = frame_id.split("/")[1]
        for name in (f"velodyne/{stem}.bin", f"image_2/{stem}.png"):
            shutil.copyfile(source / name, seq / name)
    shutil.copyfile(source / "calib.txt", seq / "calib.txt")
    return KittiOdometry("all", {"root": str(tmp_path / "kitti")})


def _run(registry, dataset, store):
    records = run_grid(registry, [Combination(BASE)], dataset, Protocol(), store)
    return dict(zip(records["frame_id"], records["status"], strict=True))


def _put_nan(scan: Path) -> None:
    """Point 0's x becomes NaN: same size, as a flipped bit in a copy would leave it."""
    points = np.fromfile(scan, np.float32)
    points[0] = np.nan
    points.tofile(scan)


def test_a_repaired_scan_is_recomputed_and_an_unchanged_frame_reused(registry, kitti, tmp_path, counted):
    store, scan = ResultsStore(tmp_path / "runs"), kitti.root / "sequences" / "00" / "velodyne" / "000001.bin"
    good = scan.read_bytes()
    _put_nan(scan)
    broken = scan.stat()
    assert _run(registry, kitti, store) == {"00/000000": "ok", "00/000001": "failed"}

    scan.write_bytes(good)  # the repair, written back as `cp -p` from a backup would: same size, old mtime
    os.utime(scan, ns=(broken.st_atime_ns, broken.st_mtime_ns))
    repaired = scan.stat()
    assert (repaired.st_size, repaired.st_mtime_ns) == (broken.st_size, broken.st_mtime_ns)
    assert repaired.st_ctime_ns != broken.st_ctime_ns  # what tells the two apart (a whole run lies between)
    assert _run(registry, kitti, store) == {"00/000000": "ok", "00/000001": "ok"}
    assert counted == ["00/000000", "00/000001", "00/000001"]  # only the repaired frame, no --overwrite

    assert _run(registry, kitti, store) == {"00/000000": "ok", "00/000001": "ok"}
    assert counted == ["00/000000", "00/000001", "00/000001"]  # unchanged: every frame a cache hit
    assert sorted(store.load()["frame_id"]) == FRAMES  # the failed record was replaced, not kept beside the new one
    assert len(list(store.frames_dir.glob("*.parquet"))) == 2


def test_a_new_revision_recomputes_what_the_old_code_cached(registry, kitti, tmp_path, counted, monkeypatch):
    store = ResultsStore(tmp_path / "runs")
    assert _run(registry, kitti, store) == {"00/000000": "ok", "00/000001": "ok"}
    job = prepare(registry, [Combination(BASE)])[0]
    assert "revision" not in job.stages()["matcher"]  # revision 0: keys as they were before revisions existed
    monkeypatch.setattr(type(job.pipeline.stages["matcher"]), "revision", 1)
    assert job.stages()["matcher"]["revision"] == 1
    assert _run(registry, kitti, store) == {"00/000000": "ok", "00/000001": "ok"}
    assert _run(registry, kitti, store) == {"00/000000": "ok", "00/000001": "ok"}
    assert counted == [*FRAMES, *FRAMES]  # recomputed once for the new revision, then reused


def test_a_changed_calibration_recomputes_every_frame_of_its_sequence(registry, kitti, tmp_path, counted):
    store, calib = ResultsStore(tmp_path / "runs"), kitti.root / "sequences" / "00" / "calib.txt"
    _run(registry, kitti, store)
    calib.write_text(calib.read_text() + "\n")  # a blank line: same matrices, but the file is not the same
    _run(registry, kitti, store)
    assert counted == FRAMES * 2


def test_the_parallel_planner_sees_the_change_too(registry, kitti, tmp_path):
    store, image = ResultsStore(tmp_path / "runs"), kitti.root / "sequences" / "00" / "image_2" / "000000.png"
    _run(registry, kitti, store)
    jobs = prepare(registry, [Combination(BASE)])
    assert plan(jobs, kitti, FRAMES, Protocol(), store).missing == {}
    image.write_bytes(image.read_bytes() + b"\0")  # a trailing byte: size changes
    assert plan(jobs, kitti, FRAMES, Protocol(), store).missing == {0: ["00/000000"]}


def test_kitti_lists_scan_image_and_calibration_of_the_chosen_camera(tmp_path):
    (tmp_path / "sequences").mkdir()
    seq = tmp_path / "sequences" / "04"
    left = KittiOdometry("all", {"root": str(tmp_path)}).frame_files("04/000123")
    right = KittiOdometry("all", {"root": str(tmp_path), "camera": 3}).frame_files("04/000123")
    assert left == [seq / "velodyne" / "000123.bin", seq / "image_2" / "000123.png", seq / "calib.txt"]
    assert right[1] == seq / "image_3" / "000123.png"


def test_synthetic_lists_its_kitti_layout_files_without_generating_them(tmp_path):
    files = SyntheticStreets("test", {"root": str(tmp_path)}).frame_files("02/000007")
    seq = tmp_path / "sequences" / "02"
    assert files == [seq / "velodyne" / "000007.bin", seq / "image_2" / "000007.png", seq / "calib.txt"]
    assert not seq.exists()


def test_nuscenes_lists_sweep_image_and_the_tables_its_calibration_comes_from(tmp_path):
    dataset = NuScenes("val", {"root": str(tmp_path), "version": "v1.0-trainval"})
    records = {"tok/CAM_FRONT": ({"filename": "samples/LIDAR_TOP/s.pcd.bin"}, {"filename": "samples/CAM_FRONT/c.jpg"})}

    def sample_data(frame_id):
        if frame_id not in records:
            raise DataError(f"no frame {frame_id!r}")
        return records[frame_id]

    dataset._sample_data = sample_data  # the devkit's lookup, without building its tables
    names = ("sample", "sample_data", "calibrated_sensor", "ego_pose")
    tables = [tmp_path / "v1.0-trainval" / f"{name}.json" for name in names]
    assert dataset.frame_files("tok/CAM_FRONT") == [
        tmp_path / "samples" / "LIDAR_TOP" / "s.pcd.bin",
        tmp_path / "samples" / "CAM_FRONT" / "c.jpg",
        *tables,
    ]
    assert dataset.frame_files("gone/CAM_FRONT") == tables  # load() will record the failure; the tables still count


class Listed(Dataset):
    name, splits = "listed", ("test",)

    def __init__(self, files):
        super().__init__("test")
        self.files = files

    def frame_files(self, frame_id):
        return self.files


def test_the_fingerprint_stamps_each_file_and_marks_a_missing_one(tmp_path):
    present = tmp_path / "scan.bin"
    present.write_bytes(b"12345")
    st = present.stat()
    assert file_stamp(present) == [5, st.st_mtime_ns, st.st_ctime_ns]
    assert Listed([present, tmp_path / "gone.bin"]).fingerprint("f") == [[5, st.st_mtime_ns, st.st_ctime_ns], None]


def test_a_dataset_that_lists_no_files_keeps_one_key_per_frame(registry):
    """The default for a third-party dataset: keyed by frame id and config alone, stable from run to run."""
    job = prepare(registry, [Combination(BASE)])[0]
    toy = registry.dataset("toy")("test")
    assert toy.frame_files("a") == [] and toy.fingerprint("a") == []
    assert frame_key(toy, "a", job, Protocol()) == frame_key(toy, "a", job, Protocol())
    assert frame_key(toy, "a", job, Protocol()) != frame_key(toy, "c", job, Protocol())
