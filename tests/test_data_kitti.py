"""KITTI Odometry reader and ring recovery, on the real frames in ../shared/data and on broken copies of them."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLE_DATA, needs_sample

from i2pbench.data.kitti import KittiOdometry, camera_calib, read_frame
from i2pbench.data.scanlines import recover_rings, scan_phase
from i2pbench.errors import DataError
from i2pbench.geometry.transforms import in_image, project
from i2pbench.registry.build import build_registry

KITTI = SAMPLE_DATA / "kitti_odometry"
IDS = ["00/000000", "00/000001", "00/000002", "00/000003", "00/000004", "01/000000"]

pytestmark = needs_sample("kitti_odometry", "sequences")


@pytest.fixture(scope="module")
def dataset() -> KittiOdometry:
    return KittiOdometry("all", {"root": str(KITTI)})


@pytest.fixture(scope="module")
def frames(dataset):
    return {fid: dataset.load(fid) for fid in dataset.frame_ids()}


def _calib_matrices(path: Path) -> dict[str, np.ndarray]:
    rows = (line.split(":") for line in path.read_text().splitlines() if ":" in line)
    return {k: np.array(v.split(), float).reshape(3, 4) for k, v in rows}


def test_lists_the_six_real_frames_sorted(dataset):
    assert dataset.frame_ids() == IDS
    assert KittiOdometry("train", {"root": str(KITTI)}).frame_ids() == IDS  # 00 and 01 are both train sequences
    assert KittiOdometry("all", {"root": str(KITTI), "sequences": [1]}).frame_ids() == ["01/000000"]


def test_splits_are_whole_sequences_and_validation_never_comes_from_the_test_sequences(shared_data):
    real = {"root": str(shared_data / "kitti_real")}  # 04 (a benchmark train sequence) and 26 (a raw drive)
    assert KittiOdometry("train", real).sequences() == ["04"] and len(KittiOdometry("train", real).frame_ids()) == 17
    assert KittiOdometry("val", real).sequences() == ["26"] and len(KittiOdometry("val", real).frame_ids()) == 20
    assert KittiOdometry("trainval", real).sequences() == ["04"]
    assert KittiOdometry("all", real).sequences() == ["04", "26"]
    assert not KittiOdometry("val", {"root": str(KITTI)}).sequences()  # 00 and 01 only: no 08, nothing outside 00-21


def test_frame_contents(frames):
    for fid, f in frames.items():
        assert f.dataset == "kitti" and f.frame_id == fid and f.match_radius_px == 3.0
        assert f.image.dtype == np.uint8 and f.image.shape == (
            (375, 1242, 3) if fid.startswith("00") else (370, 1224, 3)
        )
        assert f.points.dtype == np.float32 and f.points.shape[1] == 4 and 110_000 < len(f.points) < 128_000
        assert 0.0 <= f.points[:, 3].min() and f.points[:, 3].max() <= 1.0
        assert f.ring.dtype == np.int16 and f.ring.shape == (len(f.points),)
        assert f.source.endswith(f"{fid}.bin".replace("/", "/velodyne/"))


def test_image_is_rgb_not_bgr(frames):
    # KITTI street scenes: sky and road are bluish-grey, so the top rows hold more blue than red in RGB order.
    top = frames["00/000000"].image[:60].reshape(-1, 3).astype(float).mean(axis=0)
    assert top[2] > top[0]


def test_projection_lands_about_19k_points_in_image(frames):
    # measured: 18630, 20210, 18911, 19063, 19962 (sequence 00) and 20285 (sequence 01)
    for f in frames.values():
        uv, front = project(f.K, f.T_cam_lidar, f.points[:, :3])
        assert 18_000 <= in_image(uv, front, f.image_size).sum() <= 21_000


@pytest.mark.parametrize("camera", [2, 3])
@pytest.mark.parametrize("sequence", ["00", "01"])
def test_K_times_T_equals_P_times_Tr(camera, sequence):
    mats = _calib_matrices(KITTI / "sequences" / sequence / "calib.txt")
    K, T = camera_calib(KITTI / "sequences" / sequence / "calib.txt", camera)
    Tr = np.vstack([mats["Tr"], [0, 0, 0, 1]])
    X = np.c_[np.random.default_rng(0).uniform(-30, 30, (50, 3)), np.ones(50)]
    assert np.allclose(K, mats[f"P{camera}"][:, :3])
    assert np.allclose((K @ (T @ X.T)[:3]), mats[f"P{camera}"] @ Tr @ X.T, rtol=1e-9, atol=1e-9)
    assert np.allclose(T[:3, :3], mats["Tr"][:, :3]) and np.allclose(T[3], [0, 0, 0, 1])
    # camera 2 sits about 6 cm left of camera 0 and camera 3 about 47 cm right: t moves by -b_x
    baseline = T[0, 3] - mats["Tr"][0, 3]
    assert baseline == pytest.approx(0.06 if camera == 2 else -0.47, abs=0.03)


def test_rings_are_64_lasers_top_to_bottom(frames):
    for f in frames.values():
        n = int(f.ring.max()) + 1
        assert 60 <= n <= 64 and f.ring.min() == 0 and np.all(np.diff(f.ring) >= 0)
        xyz = f.points[:, :3].astype(np.float64)
        rng = np.linalg.norm(xyz[:, :2], axis=1)
        elev = np.degrees(np.arctan2(xyz[:, 2], rng))
        median = np.array([np.median(elev[f.ring == r]) for r in range(n)])
        assert np.all(np.diff(median) < 0) and median[0] > 1.5 and median[-1] < -23  # HDL-64E: +2 to -24.8 degrees
        # the lasers sit off the sensor origin, so elevation drifts with range; far away a ring is a thin cone
        far = rng > 20
        spread = [
            np.ptp(np.percentile(elev[far & (f.ring == r)], [5, 95]))
            for r in range(n)
            if (far & (f.ring == r)).sum() > 50
        ]
        assert len(spread) > 20 and max(spread) < 0.6


def test_rings_keep_scan_order(frames):
    for f in frames.values():
        phase = scan_phase(f.points)
        for r in range(int(f.ring.max()) + 1):
            assert np.diff(phase[f.ring == r]).min() > -1e-3


def test_every_real_scan_has_its_64_rings(shared_data):
    """sequence 04's lasers step back by up to 0.22 rad inside a sweep: a tolerance that cuts them gives 134-627."""
    scans = sorted((shared_data / "kitti_real" / "sequences").glob("*/velodyne/*.bin"))
    assert len(scans) == 37
    for path in scans:
        ring = recover_rings(np.fromfile(path, np.float32).reshape(-1, 4)[:, :3])
        assert int(ring.max()) + 1 == 64, path
    assert recover_rings(np.fromfile(scans[0], np.float32).reshape(-1, 4)[:, :3], tol=0.01).max() + 1 > 100


def _ring_points(azimuth_deg: np.ndarray, z: float) -> np.ndarray:
    az = np.radians(azimuth_deg)
    return np.c_[10 * np.cos(az), 10 * np.sin(az), np.full(len(az), z)]


def test_ring_recovery_handles_gaps_and_noise_at_the_cut():
    blocks = [
        _ring_points(np.linspace(0.0, 359.9, 100), 1.0),
        _ring_points(np.linspace(200.0, 300.0, 30), 0.5),  # sees only the right side: starts late
        _ring_points(np.linspace(40.0, 120.0, 30), 0.0),  # starts before the previous ended: a new ring
        # jitter at the cut: +1e-5, -1e-5 degrees read as phase 0 then ~360; one ring, not a two-point one
        _ring_points(np.r_[1e-5, -1e-5, np.linspace(0.01, 200.0, 40)], -0.5),
        _ring_points(np.linspace(300.0, 350.0, 20), -1.0),  # starts after the previous ended: merged (documented)
    ]
    ring = recover_rings(np.concatenate(blocks))
    assert ring.dtype == np.int16
    assert np.array_equal(ring, np.repeat([0, 1, 2, 3, 3], [len(b) for b in blocks]))
    assert np.array_equal(recover_rings(np.zeros((1, 3))), [0])


def test_registered_through_the_entry_point(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "datasets")
    assert build_registry().dataset("kitti") is KittiOdometry


def test_root_from_environment(monkeypatch):
    monkeypatch.setenv("I2PBENCH_KITTI_ROOT", str(KITTI))
    assert KittiOdometry("all").frame_ids() == IDS


# ---- broken inputs: each must raise a DataError naming the file at fault ----


@pytest.fixture
def seq(tmp_path) -> Path:
    """A one-frame copy of sequence 00 in tmp_path, to break."""
    src, dst = KITTI / "sequences" / "00", tmp_path / "sequences" / "00"
    for rel in ("calib.txt", "velodyne/000000.bin", "image_2/000000.png"):
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src / rel, dst / rel)
    return dst


def _raises(match_path: Path, fn, *args) -> str:
    with pytest.raises(DataError) as info:
        fn(*args)
    assert str(match_path) in str(info.value)
    return str(info.value)


def test_copy_reads_like_the_original(seq):
    frame = read_frame(seq, "000000")
    assert frame.frame_id == "00/000000" and len(frame.points) == 120268


def test_truncated_scan(seq):
    scan = seq / "velodyne" / "000000.bin"
    with open(scan, "r+b") as fh:
        fh.truncate(scan.stat().st_size - 6)
    assert "multiple of 16" in _raises(scan, read_frame, seq, "000000")


def test_nan_points(seq):
    scan = seq / "velodyne" / "000000.bin"
    pts = np.fromfile(scan, np.float32).reshape(-1, 4)
    pts[10, 2], pts[99, 0] = np.nan, np.inf
    pts.tofile(scan)
    assert "2 of 120268 points" in _raises(scan, read_frame, seq, "000000")


def test_missing_calib(seq):
    (seq / "calib.txt").unlink()
    _raises(seq / "calib.txt", read_frame, seq, "000000")


@pytest.mark.parametrize("drop, message", [("P2", "no P2 line"), ("Tr", "no Tr line")])
def test_calib_without_a_needed_line(seq, drop, message):
    calib = seq / "calib.txt"
    calib.write_text("\n".join(ln for ln in calib.read_text().splitlines() if not ln.startswith(drop + ":")))
    assert message in _raises(calib, read_frame, seq, "000000")


def test_calib_with_wrong_number_of_values(seq):
    calib = seq / "calib.txt"
    calib.write_text(calib.read_text().replace("Tr: ", "Tr: 1.0 "))
    assert "13 values" in _raises(calib, read_frame, seq, "000000")


def test_corrupt_image(seq):
    image = seq / "image_2" / "000000.png"
    image.write_bytes(b"\x89PNG\r\n\x1a\n" + b"not really a png" * 10)
    assert "corrupt" in _raises(image, read_frame, seq, "000000")


def test_scan_without_image(seq):
    (seq / "image_2" / "000000.png").unlink()
    ds = KittiOdometry("all", {"root": str(seq.parents[1])})
    assert "000000.png" in _raises(seq, ds.frame_ids)
    _raises(seq / "image_2" / "000000.png", read_frame, seq, "000000")


def test_empty_sequence(seq):
    (seq / "velodyne" / "000000.bin").unlink()
    _raises(seq / "velodyne", KittiOdometry("all", {"root": str(seq.parents[1])}).frame_ids)


def test_split_with_no_frames_names_root_and_split(seq):
    message = _raises(seq.parent, KittiOdometry("test", {"root": str(seq.parents[1])}).frame_ids)
    assert "'test'" in message


def test_missing_root_and_bad_conf(tmp_path):
    _raises(tmp_path / "sequences", KittiOdometry("all", {"root": str(tmp_path)}).frame_ids)
    with pytest.raises(DataError, match="camera must be 2 or 3"):
        KittiOdometry("all", {"root": str(tmp_path), "camera": 1})
    with pytest.raises(DataError, match="not of the form"):
        KittiOdometry("all", {"root": str(KITTI)}).load("000000")
