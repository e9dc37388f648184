"""The two corruptions of the scan's geometry: `tilt` (a rigid roll/pitch the protocol composes into its transform and
its ground truth) and `time-offset` (the scan moved by the ego motion over a clock offset, for frames whose dataset
knows it), with the ego motion the KITTI and nuScenes readers give, and the path of a corruption that does not apply."""

import dataclasses
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import nuscenes_sample
from test_corruptions import conformance_sensor, scan

from i2pbench.api import Corruption
from i2pbench.corruptions.base import CorruptionError, NotApplicable, check_class
from i2pbench.data.base import Dataset
from i2pbench.data.kitti import KittiOdometry, read_frame
from i2pbench.errors import DataError, PluginError
from i2pbench.geometry.transforms import in_image, invert, make_transform, project, rot_z, transform_points
from i2pbench.registry.build import default_registry
from i2pbench.runs.grid import protocols
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.types import SensorFrame

TILTS = (1, 2, 3, 5, 8)  # degrees
OFFSETS_S = (0.010, 0.025, 0.050, 0.100, 0.200)
FORWARD = np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # 10 m/s along LiDAR x, no turn
CLASSIC = {"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle", "solver": "epnp-ransac"}


def corruption(name: str) -> Corruption:
    return default_registry().corruption(name)()


def under(name: str, severity: int, seed: int = 0) -> Protocol:
    return Protocol(seed=seed).corrupted(corruption(name), severity)


def moving(ego: np.ndarray = FORWARD) -> SensorFrame:
    return dataclasses.replace(scan(), ego_motion=ego)


def tilt_deg(M: np.ndarray) -> float:
    """The angle between the moved z axis and z: how far the scan's 'up' leans."""
    return math.degrees(math.acos(np.clip(M[2, 2], -1.0, 1.0)))


# tilt


def test_tilt_is_a_geometry_corruption_that_moves_the_cloud_with_its_table():
    cls = default_registry().corruption("tilt")
    assert (cls.kind, cls.moves_cloud, cls.needs, cls.levels) == ("geometry", True, (), TILTS)


def test_tilt_leans_the_scan_by_exactly_its_level_about_a_horizontal_axis():
    sensor = scan()
    for severity, degrees in enumerate(TILTS, start=1):
        M = under("tilt", severity).motion(sensor)
        assert tilt_deg(M) == pytest.approx(degrees, abs=1e-9)
        assert np.allclose(M[:3, 3], 0) and abs(M[1, 0] - M[0, 1]) < 1e-15  # a pure rotation with no yaw part
    angles = [0.0, *(tilt_deg(under("tilt", s).motion(sensor)) for s in range(1, 6))]
    assert angles == sorted(angles)


def test_tilt_is_deterministic_per_seed_and_its_direction_is_drawn():
    sensor = scan()
    first, again = under("tilt", 3, seed=1).motion(sensor), under("tilt", 3, seed=1).motion(sensor)
    assert np.array_equal(first, again)
    others = [under("tilt", 3, seed=s).motion(sensor) for s in (2, 3, 4)]
    assert all(not np.array_equal(first, o) for o in others)
    assert all(tilt_deg(o) == pytest.approx(3.0, abs=1e-9) for o in others)  # the split changes, not the size
    signs = {tuple(np.sign([M[2, 1], M[0, 2]])) for M in [first, *others]}  # roll and pitch signs
    assert len(signs) > 1


def test_tilt_severity_zero_is_the_identity():
    sensor, tilt = scan(), corruption("tilt")
    assert tilt.apply(sensor, 0, np.random.default_rng(0)) is sensor
    assert tilt.displacement(sensor, 0, np.random.default_rng(0)) is None
    assert Protocol().motion(sensor) is None  # clean: T_rand alone, bit for bit
    clean = Protocol(seed=2).apply(sensor)
    assert np.array_equal(clean.T_gt, sensor.T_cam_lidar @ invert(Protocol(seed=2).random_transform("hand", "f0")))


def test_a_tilted_frame_moved_back_by_its_ground_truth_projects_as_the_clean_one():
    sensor = conformance_sensor()
    clean = Protocol(seed=5).apply(sensor)
    in_camera_clean = transform_points(clean.T_gt, clean.points[:, :3].astype(np.float64))
    uv_clean, front = project(clean.K, clean.T_gt, clean.points[:, :3])
    seen = in_image(uv_clean, front, clean.image_size)
    worst_m = worst_px = 0.0
    for severity in range(1, 6):
        protocol = under("tilt", severity, seed=5)
        frame = protocol.apply(sensor)
        M, T_rand = protocol.motion(sensor), protocol.random_transform(sensor.dataset, sensor.frame_id)
        assert np.array_equal(frame.T_gt, sensor.T_cam_lidar @ invert(T_rand @ M))  # the whole motion, inverted
        assert not np.allclose(frame.T_gt, clean.T_gt) and np.array_equal(frame.T_init, clean.T_init)
        assert np.array_equal(frame.image, clean.image) and np.array_equal(frame.K, clean.K) and frame.K_gt is None
        assert np.array_equal(frame.ranges, clean.ranges) and np.array_equal(frame.ring, clean.ring)
        in_camera = transform_points(frame.T_gt, frame.points[:, :3].astype(np.float64))
        worst_m = max(worst_m, float(np.abs(in_camera - in_camera_clean).max()))
        uv, _ = project(frame.K, frame.T_gt, frame.points[:, :3])
        worst_px = max(worst_px, float(np.abs(uv[seen] - uv_clean[seen]).max()))
        lean = math.degrees(math.acos(np.clip((T_rand @ M)[2, 2], -1, 1)))
        assert lean == pytest.approx(TILTS[severity - 1], abs=1e-9)  # T_rand's yaw adds no tilt
    # measured: 1.9e-6 m and 8.4e-6 px at most, the float32 rounding of coordinates up to 19 m (the tilted cloud is
    # stored as float32 like the clean one); the bounds leave 5x and 12x margin. Off the image, points 0.1 m in front
    # of the camera magnify the same rounding to 0.05 px, which no true match can involve.
    assert worst_m < 1e-5 and worst_px < 1e-4


def test_the_oracle_registers_a_tilted_frame_as_well_as_a_clean_one():
    pipeline = Pipeline.build(default_registry(), Combination(CLASSIC))

    def errors(protocol: Protocol) -> tuple[int, float, float]:
        frame = protocol.apply(conformance_sensor())
        outcome = pipeline.run(frame)
        assert outcome.failed_component == "", outcome.error
        error = invert(outcome.estimate.T) @ frame.T_gt
        angle = math.degrees(math.acos(min(1.0, (np.trace(error[:3, :3]) - 1) / 2)))
        return outcome.n_matches, float(np.linalg.norm(error[:3, 3])), angle

    # this small 16-ring scene leaves the oracle 0.4 m and 1.6 deg off even clean; the tilt changes neither
    (n, rte, angle), (n_clean, rte_clean, angle_clean) = errors(under("tilt", 5)), errors(Protocol())
    assert n == n_clean and abs(rte - rte_clean) < 0.05 and abs(angle - angle_clean) < 0.01


class Stretch(Corruption):
    """A broken corruption: its 'motion' scales the cloud, which no rigid ground truth can undo."""

    name, kind, meaning, parameter, levels = "stretch", "geometry", "wrong", "-", (1, 2, 3)
    moves_cloud = True

    def motion(self, sensor, level, rng):
        return np.diag([1.0 + level, 1.0, 1.0, 1.0])


def test_a_motion_that_is_not_rigid_and_bad_declarations_are_refused():
    with pytest.raises(CorruptionError, match="'stretch' .* not a rigid transform"):
        Stretch().displacement(scan(), 1, np.random.default_rng(0))
    with pytest.raises(PluginError, match="'still' that moves_cloud without a motion"):
        check_class(type("Still", (Corruption,), {"name": "still", "kind": "geometry", "levels": (1, 2, 3),
                                                  "moves_cloud": True}), "p")  # fmt: skip
    with pytest.raises(PluginError, match=r"'odd' needing \['speed'\]; .* \['ego_motion'\]"):
        check_class(type("Odd", (Corruption,), {"name": "odd", "kind": "lidar", "levels": (1, 2, 3),
                                                "needs": ("speed",)}), "p")  # fmt: skip


# time-offset


def test_time_offset_moves_every_point_by_v_dt_for_a_pure_translation():
    sensor = moving()
    shifts = []
    for severity, dt in enumerate(OFFSETS_S, start=1):
        out = under("time-offset", severity).corrupt(sensor)
        delta = out.points[:, :3].astype(np.float64) - sensor.points[:, :3]
        assert np.allclose(np.abs(delta[:, 0]), 10.0 * dt, atol=1e-5) and np.allclose(delta[:, 1:], 0, atol=1e-5)
        assert len(np.unique(np.sign(delta[:, 0]))) == 1  # one offset for the whole scan
        shifts.append(float(np.linalg.norm(delta, axis=1).mean()))
    assert np.allclose(shifts, [0.1, 0.25, 0.5, 1.0, 2.0], atol=1e-5)  # |v| dt
    assert shifts == sorted(shifts)
    out = under("time-offset", 5).corrupt(sensor)
    assert np.array_equal(out.image, sensor.image) and np.array_equal(out.ring, sensor.ring)
    assert np.array_equal(out.K, sensor.K) and out.ego_motion is sensor.ego_motion


def test_time_offset_turns_the_scan_by_the_yaw_rate_times_dt():
    sensor = moving(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5]))  # turning at 0.5 rad/s, not moving
    out = under("time-offset", 5).corrupt(sensor)
    turned = np.arctan2(out.points[:, 1], out.points[:, 0]) - np.arctan2(sensor.points[:, 1], sensor.points[:, 0])
    turned = (turned + np.pi) % (2 * np.pi) - np.pi
    assert np.allclose(np.abs(turned), 0.5 * 0.2, atol=1e-6) and len(np.unique(np.sign(turned))) == 1
    assert np.allclose(out.points[:, 2], sensor.points[:, 2])  # a yaw keeps heights


def test_time_offset_is_deterministic_per_seed_and_its_sign_is_drawn():
    sensor = moving()
    first = under("time-offset", 3, seed=1).corrupt(sensor).points
    assert np.array_equal(first, under("time-offset", 3, seed=1).corrupt(sensor).points)
    signs = {float(np.sign(under("time-offset", 3, seed=s).corrupt(sensor).points[0, 0] - sensor.points[0, 0]))
             for s in range(8)}  # fmt: skip
    assert signs == {-1.0, 1.0}


def test_time_offset_severity_zero_is_the_identity_and_the_ground_truth_stays():
    sensor = moving()
    assert corruption("time-offset").apply(sensor, 0, np.random.default_rng(0)) is sensor
    clean = Protocol(seed=2).apply(sensor)
    frame = under("time-offset", 5, seed=2).apply(sensor)
    assert np.array_equal(frame.T_gt, clean.T_gt) and frame.K_gt is None
    assert np.array_equal(frame.image, clean.image) and not np.array_equal(frame.points, clean.points)
    T_rand = Protocol(seed=2).random_transform("hand", "f0")
    assert np.allclose(np.linalg.norm(frame.points[:, :3] - T_rand[:3, 3], axis=1), frame.ranges, atol=1e-4)


def test_a_time_offset_frame_passes_the_stage_contracts():
    sensor = dataclasses.replace(conformance_sensor(), ego_motion=FORWARD)
    frame = under("time-offset", 5).apply(sensor)
    outcome = Pipeline.build(default_registry(), Combination(CLASSIC)).run(frame)
    assert outcome.failed_component in ("", "solver 'epnp-ransac'"), outcome.error
    assert outcome.n_kp2d > 0 and outcome.n_kp3d > 0


class Brake(Corruption):
    """A broken corruption: it rewrites the ego motion, which is the dataset's, not the sensors' output."""

    name, kind, meaning, parameter, levels = "brake", "lidar", "wrong", "-", (1, 2, 3)

    def corrupt(self, sensor, level, rng):
        return dataclasses.replace(sensor, ego_motion=np.zeros(6))


def test_a_corruption_changing_the_ego_motion_is_refused():
    with pytest.raises(CorruptionError, match=r"'brake' .* changed \['ego_motion'\]"):
        Brake().apply(moving(), 1, np.random.default_rng(0))


# not applicable: a frame without ego motion


def test_time_offset_does_not_apply_to_a_frame_without_ego_motion():
    time_offset = corruption("time-offset")
    assert not time_offset.applies(scan()) and time_offset.applies(moving())
    with pytest.raises(NotApplicable, match="does not apply to hand frame f0: it needs the LiDAR's ego motion"):
        under("time-offset", 1).apply(scan())


class Hand(Dataset):
    """Two hand-built frames, with or without ego motion (conf `moving`)."""

    name = "hand"
    default_conf = {"root": None, "moving": True}

    def frame_ids(self):
        return ["f0", "f1"]

    def load(self, frame_id):
        return dataclasses.replace(scan(), frame_id=frame_id, ego_motion=FORWARD if self.conf["moving"] else None)


def test_all_leaves_out_a_corruption_the_data_cannot_take_and_a_named_one_is_refused_before_the_run(capsys):
    registry, base = default_registry(), Protocol()
    names = lambda ps: {p.corruption for p in ps}  # noqa: E731
    still = Hand("test", {"moving": False})
    assert "time-offset" not in names(protocols(registry, base, ["all"], [1], still)) and "tilt" in names(
        protocols(registry, base, ["all"], [1], still)
    )
    note = "corruption 'time-offset' left out of 'all': 2 of the 2 hand frames (the first f0)"
    assert note in capsys.readouterr().err
    with pytest.raises(NotApplicable, match="--corruption time-offset:2: 2 of the 2 hand frames .* ego motion"):
        protocols(registry, base, ["clean", "time-offset:2"], None, still)
    assert "time-offset" in names(protocols(registry, base, ["all"], [1], Hand("test", {})))
    assert [p.severity for p in protocols(registry, base, ["time-offset"], [1, 5], Hand("test", {}))] == [1, 5]
    one_frame = protocols(registry, base, ["time-offset:1"], None, Hand("test", {"moving": False}), frame_ids=[])
    assert names(one_frame) == {"time-offset"}  # no frame lacks it: nothing to refuse


def test_without_a_dataset_to_check_all_leaves_out_what_needs_optional_data(capsys):
    chosen = protocols(default_registry(), Protocol(), ["all"], [1])
    assert {p.corruption for p in chosen} == set(default_registry().corruptions) - {"time-offset"}
    assert "'time-offset' left out of 'all': it needs ego_motion, with no dataset to check" in capsys.readouterr().err


def test_the_cli_runs_tilt_and_refuses_time_offset_on_kitti_without_poses(shared_data, tmp_path):
    def run(spec: str) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "i2pbench.cli", "run", "--matcher", "oracle", "--dataset", "kitti", "--split",
               "all", "--data-root", str(shared_data / "kitti_odometry"), "--frames", "2", "--threads", "1",
               "--quiet", "--corruption", spec, "--runs-dir", str(tmp_path / "runs" / spec),
               "--out", str(tmp_path / spec)]  # fmt: skip
        return subprocess.run(cmd, capture_output=True, text=True, timeout=300)

    done = run("tilt:5")
    assert done.returncode == 0, done.stderr
    rows = (tmp_path / "tilt:5.csv").read_text().splitlines()
    assert len(rows) == 2 and ",tilt,5," in rows[1] and ",100.0," in rows[1]
    refused = run("time-offset:1")
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert "time-offset:1: 2 of the 2 kitti frames (the first 00/000000) cannot take it" in refused.stderr
    assert (tmp_path / "runs" / "tilt:5" / "kitti-all").is_dir()
    assert not (tmp_path / "runs" / "time-offset:1" / "kitti-all").exists()  # refused before any frame: no store


# the ego motion the datasets give


def kitti_copy(shared_data: Path, root: Path, stems: int) -> Path:
    """Sequence 04's first real frame under `stems` frame numbers, in the KITTI layout under `root`."""
    source = shared_data / "kitti_real" / "sequences" / "04"
    first = sorted(p.stem for p in (source / "velodyne").glob("*.bin"))[0]
    seq = root / "sequences" / "04"
    for folder in ("velodyne", "image_2"):
        (seq / folder).mkdir(parents=True)
    shutil.copy(source / "calib.txt", seq / "calib.txt")
    for i in range(stems):
        (seq / "velodyne" / f"{i:06d}.bin").symlink_to(source / "velodyne" / f"{first}.bin")
        (seq / "image_2" / f"{i:06d}.png").symlink_to(source / "image_2" / f"{first}.png")
    return seq


def write_poses(root: Path, seq: Path, lidar_step: np.ndarray, n: int) -> None:
    """poses/04.txt for a LiDAR moving by `lidar_step` (its own frame) each frame, written as KITTI does: camera 0's
    poses, P_i = W_i @ inv(Tr) for LiDAR poses W_i."""
    tr = np.eye(4)
    calib = dict(line.split(":", 1) for line in (seq / "calib.txt").read_text().splitlines() if ":" in line)
    tr[:3] = np.array(calib["Tr"].split(), dtype=float).reshape(3, 4)
    W = np.eye(4)
    lines = []
    for _ in range(n):
        lines.append(" ".join(f"{x:.12e}" for x in (W @ invert(tr))[:3].reshape(-1)))
        W = W @ lidar_step
    (root / "poses").mkdir(exist_ok=True)
    (root / "poses" / "04.txt").write_text("\n".join(lines) + "\n")


def test_kitti_ego_motion_from_the_poses_file_in_the_lidar_frame(shared_data, tmp_path):
    seq = kitti_copy(shared_data, tmp_path, 4)
    write_poses(tmp_path, seq, make_transform(np.eye(3), [1.0, 0.0, 0.0]), 4)  # 1 m forward per frame
    for stem in ("000000", "000001", "000003"):  # one-sided, central, one-sided
        assert np.allclose(read_frame(seq, stem).ego_motion, FORWARD, atol=1e-6)  # 1 m per 0.1 s
    write_poses(tmp_path, seq, make_transform(rot_z(0.02), [0.0, 0.0, 0.0]), 4)  # turning on the spot
    for stem in ("000000", "000002"):
        assert np.allclose(read_frame(seq, stem).ego_motion, [0, 0, 0, 0, 0, 0.2], atol=1e-6)  # 0.02 rad / 0.1 s
    (seq / "times.txt").write_text("".join(f"{0.05 * i:.6e}\n" for i in range(4)))  # 20 Hz, by its times
    assert np.allclose(read_frame(seq, "000001").ego_motion, [0, 0, 0, 0, 0, 0.4], atol=1e-6)
    files = KittiOdometry("all", {"root": str(tmp_path)}).frame_files("04/000001")
    assert files[3:] == [tmp_path / "poses" / "04.txt", seq / "times.txt"]  # an edited pose recomputes


def test_kitti_poses_that_are_malformed_or_too_few_name_the_file(shared_data, tmp_path):
    seq = kitti_copy(shared_data, tmp_path, 3)
    write_poses(tmp_path, seq, np.eye(4), 2)
    with pytest.raises(DataError, match=r"poses/04.txt: 2 poses, none for frame 000002"):
        read_frame(seq, "000002")
    (tmp_path / "poses" / "04.txt").write_text("1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(DataError, match=r"poses/04.txt:1: expected 12 finite numbers"):
        read_frame(seq, "000000")


def test_kitti_without_poses_has_no_ego_motion_and_its_files_are_as_before(shared_data):
    dataset = KittiOdometry("all", {"root": str(shared_data / "kitti_real")})
    frame_id = dataset.frame_ids()[0]
    assert dataset.load(frame_id).ego_motion is None
    assert len(dataset.frame_files(frame_id)) == 3  # scan, image, calib: clean cache keys unchanged


SAMPLE = "b5989651183643369174912bc5641d3b"


@pytest.fixture
def nuscenes_root(tmp_path):
    records = nuscenes_sample()
    from i2pbench.data.nuscenes_dataroot import build_dataroot

    build_dataroot([records], tmp_path / "nuscenes", "v1.0-trainval")
    return tmp_path / "nuscenes"


def _tables(root: Path) -> dict[str, list[dict]]:
    return {n: json.loads((root / "v1.0-trainval" / f"{n}.json").read_text()) for n in ("sample_data", "ego_pose")}


def _save(root: Path, tables: dict[str, list[dict]]) -> None:
    for name, rows in tables.items():
        (root / "v1.0-trainval" / f"{name}.json").write_text(json.dumps(rows))


def _lidar_parts(tables):
    lidar = next(r for r in tables["sample_data"] if "LIDAR_TOP" in r["filename"])
    poses = {p["token"]: p for p in tables["ego_pose"]}
    return lidar, poses


def test_nuscenes_ego_motion_from_the_camera_record_furthest_in_time(nuscenes_root):
    from i2pbench.data.nuscenes import NuScenes, record_matrix

    dataset = NuScenes("val", {"root": str(nuscenes_root)})
    ego = dataset.load(f"{SAMPLE}/CAM_FRONT").ego_motion
    assert np.array_equal(ego, dataset.load(f"{SAMPLE}/CAM_BACK").ego_motion)  # the LiDAR's, whatever the camera
    tables = _tables(nuscenes_root)
    lidar, poses = _lidar_parts(tables)
    others = [r for r in tables["sample_data"] if r is not lidar]
    far = max(others, key=lambda r: abs(r["timestamp"] - lidar["timestamp"]))
    sensors = json.loads((nuscenes_root / "v1.0-trainval" / "calibrated_sensor.json").read_text())
    L = record_matrix(next(s for s in sensors if s["token"] == lidar["calibrated_sensor_token"]))
    at, there = record_matrix(poses[lidar["ego_pose_token"]]) @ L, record_matrix(poses[far["ego_pose_token"]]) @ L
    dt = (lidar["timestamp"] - far["timestamp"]) * 1e-6
    assert 0.005 < dt < 0.2  # the camera fired before the sweep's stamp
    assert np.allclose(ego[:3], at[:3, :3].T @ (at[:3, 3] - there[:3, 3]) / dt)
    assert 3.5 < np.linalg.norm(ego[:3]) < 5.0 and abs(ego[5]) < 0.5  # scene-0916 drives at about 4 m/s


def test_nuscenes_ego_motion_from_neighbouring_sweeps_and_none_when_all_share_the_stamp(nuscenes_root, tmp_path):
    from i2pbench.data.nuscenes import NuScenes, record_matrix

    tables = _tables(nuscenes_root)
    lidar, poses = _lidar_parts(tables)
    here = poses[lidar["ego_pose_token"]]
    E = record_matrix(here)
    for name, sign in (("prev", -1), ("next", 1)):  # sweeps 50 ms either side, the car 5 m/s along its own x
        t = E[:3, 3] + E[:3, :3] @ [sign * 0.25, 0.0, 0.0]
        tables["ego_pose"].append({**here, "token": name, "timestamp": lidar["timestamp"] + sign * 50_000,
                                   "translation": t.tolist()})  # fmt: skip
        stamp = lidar["timestamp"] + sign * 50_000
        tables["sample_data"].append({**lidar, "token": name, "ego_pose_token": name, "is_key_frame": False,
                                      "timestamp": stamp, "prev": "", "next": ""})  # fmt: skip
        lidar[name] = name
    _save(nuscenes_root, tables)
    sensors = json.loads((nuscenes_root / "v1.0-trainval" / "calibrated_sensor.json").read_text())
    L = record_matrix(next(s for s in sensors if s["token"] == lidar["calibrated_sensor_token"]))
    ego = NuScenes("val", {"root": str(nuscenes_root)}).load(f"{SAMPLE}/CAM_FRONT").ego_motion
    assert np.allclose(ego, [*(L[:3, :3].T @ [5.0, 0.0, 0.0]), 0, 0, 0], atol=1e-6)  # central, in the LiDAR frame:
    assert np.linalg.norm(ego[:3]) == pytest.approx(5.0, rel=1e-5) and ego[1] > 4.99  # its y: about the car's x

    still = shutil.copytree(nuscenes_root, tmp_path / "still")
    tables = _tables(still)
    lidar, _ = _lidar_parts(tables)
    tables["sample_data"] = [{**r, "timestamp": lidar["timestamp"], "prev": "", "next": ""}
                             for r in tables["sample_data"] if r["token"] not in ("prev", "next")]  # fmt: skip
    _save(still, tables)
    assert NuScenes("val", {"root": str(still)}).load(f"{SAMPLE}/CAM_FRONT").ego_motion is None
