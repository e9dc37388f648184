"""nuScenes through the official devkit: LIDAR_TOP keyframes x chosen cameras, time-aware LiDAR -> camera extrinsics.

The devkit is imported only when a nuScenes dataset is used, so `i2pbench.data.plugin` imports fast without it.
Tables come from `nuscenes.nuscenes.NuScenes`, scene lists from `nuscenes.utils.splits.create_splits_scenes`. Points
are read from the .pcd.bin directly because `LidarPointCloud.from_file` drops the fifth column, the ring index.
A frame's `ego_motion` (the LiDAR's velocity, in its frame) comes from the ego poses of records near the sweep in time.
"""

from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import DataError
from ..geometry.transforms import invert
from ..types import SensorFrame
from .base import Dataset
from .calibration import check_finite, check_intrinsics
from .ego_motion import velocity
from .images import check_fits, read_image

CAMERAS = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_FRONT_LEFT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_BACK_RIGHT")
VERSIONS = ("v1.0-trainval", "v1.0-mini", "v1.0-test")
# split -> (devkit scene lists whose union it is, the version that holds those scenes)
SPLITS: dict[str, tuple[tuple[str, ...], str]] = {
    "trainval": (("train", "val"), "v1.0-trainval"),  # the 850 annotated scenes the paper trains on
    "train": (("train",), "v1.0-trainval"),  # the devkit's 700: trainval less val, to train with validation
    "val": (("val",), "v1.0-trainval"),  # the devkit's 150, whole scenes; never the test scenes
    "test": (("test",), "v1.0-test"),  # the 150 scenes the paper tests on
    "mini_train": (("mini_train",), "v1.0-mini"),
    "mini_val": (("mini_val",), "v1.0-mini"),
}
TABLES = ("category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose", "log",
          "scene", "sample", "sample_data", "sample_annotation", "map")  # fmt: skip  # what the devkit loads
EVAL_SPLIT = {"v1.0-trainval": "val", "v1.0-mini": "mini_val", "v1.0-test": "test"}  # what `test` falls back to
NEAR_S = (0.005, 0.2)  # seconds from the sweep a pose must be to time its motion: past pose noise, within a sweep gap
DEVKIT_INSTALL = (
    "pip install --no-deps nuscenes-devkit pyquaternion matplotlib shapely scikit-learn pycocotools descartes fire "
    "cachetools tqdm Pillow"
)


def record_matrix(record: dict[str, Any], table: str = "record") -> np.ndarray:
    """4x4 pose of a calibrated_sensor or ego_pose record (rotation is a w, x, y, z quaternion).

    `table` names the file the record came from in errors; a zero quaternion would otherwise leave scipy's
    ValueError to kill the run.
    """
    where = f"{table}: token {record.get('token', '?')}"
    q = np.asarray(record["rotation"], dtype=np.float64)
    t = np.asarray(record["translation"], dtype=np.float64)
    if q.shape != (4,) or t.shape != (3,):
        raise DataError(f"{where}: rotation must be 4 numbers and translation 3, got {q.shape} and {t.shape}")
    check_finite(np.r_[q, t], where, "the pose")
    if np.linalg.norm(q) < 1e-9:
        raise DataError(f"{where}: the rotation quaternion {q.tolist()} has zero norm")
    w, x, y, z = q
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    T[:3, 3] = t
    return T


def lidar_to_camera(
    lidar_sensor: dict[str, Any],
    lidar_pose: dict[str, Any],
    cam_sensor: dict[str, Any],
    cam_pose: dict[str, Any],
    tables: Path | None = None,
) -> np.ndarray:
    """T_cam_lidar through lidar -> ego(t_lidar) -> global -> ego(t_cam) -> camera; `tables` names them in errors.

    The car moves up to ~1 m between the LiDAR and a camera timestamp, so skipping the two ego poses is not an option.
    """
    sensors, poses = (str(tables / f"{n}.json") if tables else n for n in ("calibrated_sensor", "ego_pose"))
    ego_l_from_lidar = record_matrix(lidar_sensor, sensors)
    global_from_ego_l = record_matrix(lidar_pose, poses)
    global_from_ego_c = record_matrix(cam_pose, poses)
    ego_c_from_cam = record_matrix(cam_sensor, sensors)
    return invert(ego_c_from_cam) @ invert(global_from_ego_c) @ global_from_ego_l @ ego_l_from_lidar


def read_sweep(path: Path, ego_radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """([N x 4] float32 x, y, z, intensity in [0, 1]; [N] int16 ring) of a LIDAR_TOP .pcd.bin, ego returns removed.

    Ego returns: measured on scene-0916, 20% of a sweep hits the car's own roof within 1.2 m (horizontal) of the
    sensor, plus no-return placeholders at the origin; nothing else lies that close because the roof is in the way.
    A vertical cylinder of `ego_radius_m` round the sensor removes them (the devkit's `remove_close` uses a 1 m
    square, which misses the roof's rear edge at 1.0-1.2 m). The 0.4% of returns from the bonnet, 1.5-2.5 m ahead and
    0.85 m down, are kept: they project below every camera's image, so they never become matches.
    """
    if not path.is_file():
        raise DataError(f"{path}: LiDAR sweep not found")
    size = path.stat().st_size
    if size % 20 or size == 0:
        raise DataError(f"{path}: {size} bytes is not a positive multiple of 20 (float32 x, y, z, intensity, ring)")
    raw = np.fromfile(path, dtype=np.float32).reshape(-1, 5)
    if not np.isfinite(raw).all():
        raise DataError(f"{path}: {int((~np.isfinite(raw).all(axis=1)).sum())} points hold NaN or inf")
    raw = raw[np.hypot(raw[:, 0], raw[:, 1]) >= ego_radius_m]
    points = raw[:, :4].copy()
    points[:, 3] = np.clip(points[:, 3] / 255.0, 0.0, 1.0)
    return points, raw[:, 4].astype(np.int16)


def _devkit():
    try:
        from nuscenes.nuscenes import NuScenes as DevkitNuScenes
        from nuscenes.utils.splits import create_splits_scenes
    except ImportError as exc:
        raise DataError(
            f"dataset 'nuscenes' needs the nuScenes devkit ({exc}); install it with: {DEVKIT_INSTALL}"
        ) from exc
    return DevkitNuScenes, create_splits_scenes


@lru_cache(maxsize=2)
def open_devkit(dataroot: str, version: str) -> Any:
    """The devkit's table index for one dataroot and version, built once per process (trainval takes ~30 s)."""
    tables = Path(dataroot) / version
    if not tables.is_dir():
        raise DataError(f"{tables} not found (the nuScenes dataroot must hold the {version} tables)")
    missing = [str(tables / f"{name}.json") for name in TABLES if not (tables / f"{name}.json").is_file()]
    if missing:
        raise DataError(f"{', '.join(missing)} not found (the devkit needs all {len(TABLES)} tables of {version})")
    devkit_class, _ = _devkit()
    try:
        nusc = devkit_class(version=version, dataroot=dataroot, verbose=False)
    except OSError as exc:
        raise DataError(f"{exc.filename or tables}: the devkit cannot read it ({exc.strerror or exc})") from exc
    except (AssertionError, KeyError, IndexError, ValueError) as exc:
        raise DataError(f"{tables}: the devkit cannot load these tables: {exc!r}") from exc
    _refuse_duplicate_tokens(nusc, Path(dataroot) / version)
    return nusc


def _refuse_duplicate_tokens(nusc: Any, tables: Path) -> None:
    """the devkit indexes records by token and the last of two with one token silently wins (another image or
    calibration, read as fine): a token given twice is an error naming the table and the token."""
    for table, index in nusc._token2ind.items():
        records = getattr(nusc, table)
        if len(index) == len(records):
            continue
        seen: set[str] = set()
        for record in records:
            if record["token"] in seen:
                raise DataError(f"{tables / table}.json: token {record['token']} is given to two records")
            seen.add(record["token"])


class NuScenes(Dataset):
    """nuScenes keyframes: one frame per (LIDAR_TOP sample, camera); id "<sample_token>/<CAM>"."""

    name = "nuscenes"
    splits = tuple(SPLITS)
    default_conf: ClassVar[dict[str, Any]] = {
        "root": None,  # the devkit's dataroot (holds v1.0-*/, samples/); None reads I2PBENCH_NUSCENES_ROOT
        "version": None,  # None: the split's (see SPLITS); or v1.0-trainval, v1.0-mini, v1.0-test
        "cameras": ["CAM_FRONT"],  # any of the six cameras
        "exclude_night": False,  # drop scenes whose description mentions night
        "ego_radius_m": 1.2,  # drop returns within this horizontal distance of the LiDAR (the car's own roof)
    }
    match_radius_px = 5.0

    def __init__(self, split: str, conf: dict[str, Any] | None = None) -> None:
        super().__init__(split, conf)
        if self.conf["version"] is None:
            self.split, self.conf["version"] = self._version_on_disk(split)
        version, cameras = self.conf["version"], list(self.conf["cameras"])
        if version not in VERSIONS:
            raise DataError(f"dataset 'nuscenes': unknown version {version!r}; choose one of {list(VERSIONS)}")
        needed = SPLITS[self.split][1]
        if needed != version:
            raise DataError(f"dataset 'nuscenes': split {self.split!r} needs version {needed!r}, not {version!r}")
        unknown = sorted(set(cameras) - set(CAMERAS))
        if unknown or not cameras:
            raise DataError(f"dataset 'nuscenes': unknown cameras {unknown or cameras}; choose from {list(CAMERAS)}")
        self.cameras = cameras
        self._ids: list[str] | None = None

    def _version_on_disk(self, split: str) -> tuple[str, str]:
        """(split, version): the split's version, unless `test` (the run's default split) asks for v1.0-test and the
        dataroot holds one other version only; then that version's evaluation split, said on stderr."""
        wanted = SPLITS[split][1]
        try:
            root = self.root
        except DataError:  # no root yet: reading frames will say so
            return split, wanted
        if split != "test" or (root / wanted).is_dir():
            return split, wanted
        present = [v for v in VERSIONS if (root / v).is_dir()]
        if len(present) != 1:
            return split, wanted
        version, other = present[0], EVAL_SPLIT[present[0]]
        print(
            f"i2pbench: note: dataset 'nuscenes': {root} holds {version} only (no {wanted}): "
            f"using split {other!r} instead of {split!r}",
            file=sys.stderr,
        )
        return other, version

    @property
    def devkit(self) -> Any:
        return open_devkit(str(self.root), self.conf["version"])

    def scene_names(self) -> set[str]:
        """Names of this split's scenes (the devkit's lists), whether or not present in the tables."""
        _, create_splits_scenes = _devkit()
        lists = create_splits_scenes()
        return {name for part in SPLITS[self.split][0] for name in lists[part]}

    def _keeps(self, scene: dict[str, Any], names: set[str]) -> bool:
        night = "night" in scene["description"].lower()
        return scene["name"] in names and not (night and self.conf["exclude_night"])

    def sequence_of(self, frame_id: str) -> str:
        """The frame's scene, by name (scene-0916); its camera when the tables do not know the sample."""
        token, _, camera = frame_id.partition("/")
        try:
            return self.devkit.get("scene", self.devkit.get("sample", token)["scene_token"])["name"]
        except KeyError:
            return f"camera {camera}"

    def frame_ids(self) -> list[str]:
        if self._ids is None:
            nusc, names = self.devkit, self.scene_names()
            scenes = {s["token"] for s in nusc.scene if self._keeps(s, names)}
            samples = [s for s in nusc.sample if s["scene_token"] in scenes]  # one without a record fails, named
            ids = sorted(f"{s['token']}/{cam}" for s in samples for cam in self.cameras)
            if not ids:
                raise DataError(f"dataset 'nuscenes': no frames for split {self.split!r} in {self.root / nusc.version}")
            self._ids = ids
        return list(self._ids)

    def _sample_data(self, frame_id: str) -> tuple[dict[str, Any], dict[str, Any]]:
        token, _, camera = frame_id.partition("/")
        try:
            data = self.devkit.get("sample", token)["data"]
        except KeyError:
            raise DataError(f"dataset 'nuscenes': no frame {frame_id!r} in {self._tables / 'sample.json'}") from None
        records = []
        for channel in ("LIDAR_TOP", camera):
            if channel not in data:
                raise DataError(
                    f"{self._tables / 'sample_data.json'}: no {channel} keyframe record for sample {token} (it has "
                    f"{', '.join(sorted(data)) or 'none'})"
                )
            records.append(self._get("sample_data", data[channel], f"sample {token}"))
        for record in records:
            self._inside_root(record)
        return records[0], records[1]

    @property
    def _tables(self) -> Path:
        return self.root / self.conf["version"]

    def _get(self, table: str, token: str, referrer: str) -> dict[str, Any]:
        """A record by token; one the tables lack is an error naming the table, the token and who named it."""
        try:
            return self.devkit.get(table, token)
        except KeyError:
            raise DataError(
                f"{self._tables / table}.json: no record with token {token} (named by {referrer})"
            ) from None

    def _inside_root(self, record: dict[str, Any]) -> None:
        """Refuse a sample_data filename that is absolute or climbs out with `..`: tables name files under the
        dataroot, and a crafted one read /etc/passwd. (Symlinks inside the dataroot may point anywhere: a dataroot
        built from record folders links to them.)"""
        name = str(record.get("filename", ""))
        if not name or Path(name).is_absolute() or ".." in Path(name).parts:
            raise DataError(
                f"{self._tables / 'sample_data.json'}: record {record.get('token', '?')} names the file {name!r}, "
                "which is not a path inside the dataroot (absolute, empty or through ..): refused"
            )

    def calibration(self, frame_id: str) -> tuple[np.ndarray, np.ndarray]:
        """(K [3 x 3], T_cam_lidar [4 x 4]) of one frame."""
        lidar, cam = self._sample_data(frame_id)
        cam_sensor = self._linked(cam, "calibrated_sensor")
        tables = self._tables
        T = lidar_to_camera(
            self._linked(lidar, "calibrated_sensor"),
            self._linked(lidar, "ego_pose"),
            cam_sensor,
            self._linked(cam, "ego_pose"),
            tables,
        )
        K = np.asarray(cam_sensor["camera_intrinsic"], dtype=np.float64)
        check_intrinsics(K, f"{tables / 'calibrated_sensor.json'}: token {cam_sensor['token']}: camera_intrinsic")
        return K, T

    def _linked(self, record: dict[str, Any], table: str) -> dict[str, Any]:
        """The `table` record a sample_data record points to (its calibrated_sensor or ego_pose)."""
        return self._get(table, record[f"{table}_token"], f"sample_data {record['token']}")

    def ego_motion(self, lidar: dict[str, Any]) -> np.ndarray | None:
        """[6] the LiDAR's velocity (v m/s, w rad/s, in its frame) at the sweep: from the neighbouring sweeps' ego
        poses (the sample_data chain, 20 Hz) where the tables hold them, else from the ego pose of the sample's
        record furthest in time from the sweep (a camera, 10-45 ms off); only poses 5 ms to 0.2 s away count, so
        None where every sensor shares the sweep's timestamp (the synthetic dataroot's still scenes)."""
        tables = self._tables
        ego_from_lidar = record_matrix(self._linked(lidar, "calibrated_sensor"), str(tables / "calibrated_sensor.json"))

        def pose(record: dict[str, Any]) -> tuple[float, np.ndarray]:
            ego = record_matrix(self._linked(record, "ego_pose"), str(tables / "ego_pose.json"))
            return record["timestamp"] * 1e-6, ego @ ego_from_lidar

        near = self._near(lidar)
        if not near:
            return None
        (t_a, before), *_, (t_b, after) = sorted((pose(r) for r in [lidar, *near]), key=lambda p: p[0])
        return velocity(before, t_a, after, t_b, pose(lidar)[1])

    def _near(self, lidar: dict[str, Any]) -> list[dict[str, Any]]:
        """The records whose ego poses time the sweep's motion: its prev/next sweeps held in the tables, else the
        sample's other record furthest in time; only those 5 ms to 0.2 s from the sweep."""
        nusc = self.devkit

        def near(record: dict[str, Any]) -> bool:
            return NEAR_S[0] <= abs(record["timestamp"] - lidar["timestamp"]) * 1e-6 <= NEAR_S[1]

        sweeps = [r for r in (self._record(lidar["prev"]), self._record(lidar["next"])) if r is not None and near(r)]
        if sweeps:
            return sweeps
        data = nusc.get("sample", lidar["sample_token"])["data"]
        others = [r for r in map(self._record, data.values()) if r is not None and r["token"] != lidar["token"]]
        others = [r for r in others if near(r)]
        return [max(others, key=lambda r: abs(r["timestamp"] - lidar["timestamp"]))] if others else []

    def _record(self, token: str) -> dict[str, Any] | None:
        """A sample_data record, None when the token is empty or not in the tables (a dataroot without sweeps)."""
        try:
            return self.devkit.get("sample_data", token) if token else None
        except KeyError:
            return None

    def load(self, frame_id: str) -> SensorFrame:
        lidar, cam = self._sample_data(frame_id)
        sweep = self.root / lidar["filename"]
        points, ring = read_sweep(sweep, float(self.conf["ego_radius_m"]))
        K, T = self.calibration(frame_id)
        image = read_image(self.root / cam["filename"])
        calib = (
            f"{self.root / self.conf['version'] / 'calibrated_sensor.json'} (token {cam['calibrated_sensor_token']})"
        )
        check_fits(self.root / cam["filename"], image, K, calib)
        return SensorFrame(
            dataset=self.name,
            frame_id=frame_id,
            image=image,
            points=points,
            ring=ring,
            K=K,
            T_cam_lidar=T,
            match_radius_px=self.match_radius_px,
            source=str(sweep),
            ego_motion=self.ego_motion(lidar),
        )

    def identity(self) -> dict[str, Any]:
        keys = ("version", "cameras", "exclude_night", "ego_radius_m")
        return {**super().identity(), **{k: self.conf[k] for k in keys}}

    def frame_files(self, frame_id: str) -> list[Path]:
        """Sweep, image and the four tables the frame's records come from; a changed table recomputes every frame,
        as it does not say which of its records moved."""
        tables = self.root / self.conf["version"]
        files = [tables / f"{name}.json" for name in ("sample", "sample_data", "calibrated_sensor", "ego_pose")]
        try:
            lidar, cam = self._sample_data(frame_id)
        except DataError:  # not in the tables: load() records the failure
            return files
        return [self.root / lidar["filename"], self.root / cam["filename"], *files]
