"""The I2P test protocol the peers use (DeepI2P, CorrI2P, VP2P-Match, EdgeRegNet), made exact and reproducible.

The LiDAR cloud is moved by a random transform T_rand (rotation about LiDAR z uniform in [-2pi, 2pi], translation
uniform in [-10, 10] m on x and y, 0 on z); the ground truth is T_gt = T_cam_lidar @ inv(T_rand). Each frame's
transform comes from its own generator seeded by (seed, dataset, frame id), so it never depends on run order or on
which other frames run.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

import numpy as np

from .errors import DataError
from .geometry import invert, make_transform, rot_z, transform_points
from .types import Frame, SensorFrame


@dataclass(frozen=True)
class Protocol:
    """The protocol card: everything about the test set-up a result depends on."""

    seed: int = 0
    rotation_range_rad: float = 2 * np.pi  # yaw ~ U[-r, r]
    translation_range_m: float = 10.0  # tx, ty ~ U[-t, t]; tz = 0
    acc_rre_deg: float = 5.0  # success: RRE < this and RTE < acc_rte_m
    acc_rte_m: float = 2.0
    filter_rre_deg: float = 10.0  # mean +- std use frames with RRE < this and RTE < filter_rte_m
    filter_rte_m: float = 5.0
    rre_convention: str = "xzy-sum"  # sum of |extrinsic 'xzy' Euler angles| of inv(T_pred) @ T_gt, as the peers

    def card(self) -> dict:
        return asdict(self)

    def identity(self) -> str:
        return hashlib.sha256(json.dumps(self.card(), sort_keys=True).encode()).hexdigest()[:16]

    def rng(self, dataset: str, frame_id: str) -> np.random.Generator:
        digest = hashlib.sha256(f"{self.seed}\x00{dataset}\x00{frame_id}".encode()).digest()
        return np.random.default_rng(np.frombuffer(digest, dtype=np.uint32).tolist())

    def random_transform(self, dataset: str, frame_id: str) -> np.ndarray:
        """T_rand for one frame: a yaw about LiDAR z and an x/y translation."""
        rng = self.rng(dataset, frame_id)
        yaw = rng.uniform(-self.rotation_range_rad, self.rotation_range_rad)
        tx, ty = rng.uniform(-self.translation_range_m, self.translation_range_m, size=2)
        return make_transform(rot_z(yaw), np.array([tx, ty, 0.0]))

    def apply(self, sensor: SensorFrame) -> Frame:
        """Turn a dataset frame into a registration problem with its ground truth."""
        if not np.isfinite(sensor.points).all():
            where = sensor.source or f"{sensor.dataset} frame {sensor.frame_id}"
            raise DataError(f"{where}: the scan contains NaN or infinite values; datasets must drop such returns")
        T_rand = self.random_transform(sensor.dataset, sensor.frame_id)
        points = sensor.points.copy()
        points[:, :3] = transform_points(T_rand, sensor.points[:, :3].astype(np.float64)).astype(np.float32)
        return Frame(
            dataset=sensor.dataset,
            frame_id=sensor.frame_id,
            image=sensor.image,
            points=points,
            ring=sensor.ring,
            ranges=np.linalg.norm(sensor.points[:, :3], axis=1).astype(np.float32),
            K=sensor.K,
            T_gt=sensor.T_cam_lidar @ invert(T_rand),
            match_radius_px=sensor.match_radius_px,
            T_init=sensor.T_cam_lidar,
        )
