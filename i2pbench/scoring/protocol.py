"""The I2P test protocol the peers use (DeepI2P, CorrI2P, VP2P-Match, EdgeRegNet), made exact and reproducible.

The LiDAR cloud is moved by a random transform T_rand (rotation about LiDAR z uniform in [-2pi, 2pi], translation
uniform in [-10, 10] m on x and y, 0 on z); the ground truth is T_gt = T_cam_lidar @ inv(T_rand). Each frame's
transform comes from its own generator seeded by (seed, dataset, frame id), so it never depends on run order or on
which other frames run.

A corruption (docs/robustness.md) is part of the card too: `corrupted(corruption, severity)` names one, and `apply`
corrupts the dataset's frame before moving it, with its own generator for (seed, dataset, frame, corruption,
severity). The ground truth is always the dataset's: T_gt comes from the uncorrupted T_cam_lidar, and a corrupted K
keeps the true one beside it (`Frame.K_gt`). A corruption that moves the cloud (a tilt the yaw-only T_rand never
draws) gives its rigid motion M to the protocol, which moves the cloud by T_rand @ M and keeps the truth true:
T_gt = T_cam_lidar @ inv(T_rand @ M). The clean card is the card as it was before corruptions existed, so clean
results keep their identity and cache keys.

A protocol card other than the default (i2pbench.scoring.cards) may give its stages other inputs than the dataset's
frame: an image cut, resized and cropped (K alike), a voxel grid and a sampled point count (protocol_inputs), and a
T_rand drawn in the camera frame, the cloud first taken there (T_gt = inv(T_rand), T_init = I). Each such field
stays off the card at its default, so the default card's identity never moved. A frame of a
dataset with the peers' dataset index (`draw_index`: KITTI, its CorrI2P layout, the peers' nuScenes layouts) is
built under the corri2p and cofii2p cards as those papers' loaders build it instead (protocol_peer).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..errors import DataError, I2PBenchError
from ..geometry.transforms import invert, make_transform, rot_z, transform_points
from ..types import Frame, SensorFrame
from .rules import ScoringRules

if TYPE_CHECKING:
    from ..corruptions.base import Corruption

DEFAULT_NAME, DEFAULT_VERSION = "edgeregnet", 1  # the default card's (scoring.cards imports neither numpy nor this)
DEFAULT_RULES = ScoringRules()  # the default card's rules (a test checks they are cards.EDGEREGNET's)
CORRUPTION_FIELDS = ("corruption", "severity")
CARD_FIELDS = ("name", "version")  # which protocol card (i2pbench.scoring.cards); left out for the default
# the scoring rules a card states, by their names on the card (its identity reads them from the rules it holds)
RULE_FIELDS = {"acc_rre_deg": "acc_rre_deg", "acc_rte_m": "acc_rte_m", "filter_rre_deg": "filter_rre_deg",
               "filter_rte_m": "filter_rte_m", "rre_convention": "rre"}  # fmt: skip
# what a card may give its stages other than the dataset's frame (protocol_inputs); each left off the card at its
# default, so the default card keeps its identity
INPUT_DEFAULTS = {"image_top": 0, "image_scale": 1.0, "image_crop_h": 0, "image_crop_w": 0, "points": 0,
                  "voxel_m": 0.0, "pose_frame": "lidar"}  # fmt: skip


@dataclass(frozen=True)
class Protocol:
    """The protocol card: everything about the test set-up a result depends on."""

    seed: int = 0
    rotation_range_rad: float = 2 * np.pi  # yaw ~ U[-r, r]
    translation_range_m: float = 10.0  # tx, ty ~ U[-t, t]; tz = 0
    rules: ScoringRules = DEFAULT_RULES  # how its results are scored: its card's rules (thresholds, RRE kind)
    corruption: str = ""  # a registered corruption's name; "" is the clean protocol
    severity: int = 0  # the corruption's severity, 1..its number of levels
    name: str = DEFAULT_NAME  # the protocol card this protocol follows (`run --protocol NAME`)
    version: int = DEFAULT_VERSION  # that card's version
    image_top: int = 0  # rows cut off the image's top first
    image_scale: float = 1.0  # then the image resized by this (K with it)
    image_crop_h: int = 0  # then centre-cropped to this height and width; 0: not cropped
    image_crop_w: int = 0
    points: int = 0  # points sampled from the scan (after the voxel grid); 0: every point
    voxel_m: float = 0.0  # one point (the mean) per voxel of this side; 0: no grid
    pose_frame: str = "lidar"  # T_rand's frame: lidar (yaw about z, t on x, y) or camera (about y, t on x, z)
    corrupter: Corruption | None = field(default=None, compare=False, repr=False)  # the component, when resolved

    @classmethod
    def from_card(cls, card: dict, rules: ScoringRules = DEFAULT_RULES) -> Protocol:
        """The protocol a stored card describes, its thresholds and RRE kind set on `rules` (the rules of the card
        it names: `scoring.installed.read_back`)."""
        fields = dict(card)
        given = {attr: fields.pop(key) for key, attr in RULE_FIELDS.items() if key in fields}
        return cls(**fields, rules=dataclasses.replace(rules, **given))

    def with_thresholds(self, **thresholds: float | None) -> Protocol:
        """This protocol with some thresholds of its rules replaced (`evaluate --acc-rre ...`; None keeps one)."""
        given = {k: v for k, v in thresholds.items() if v is not None}
        return dataclasses.replace(self, rules=dataclasses.replace(self.rules, **given))

    @property
    def acc_rre_deg(self) -> float:  # success: RRE < this and RTE < acc_rte_m
        return self.rules.acc_rre_deg

    @property
    def acc_rte_m(self) -> float:
        return self.rules.acc_rte_m

    @property
    def filter_rre_deg(self) -> float:  # mean +- std use frames with RRE < this and RTE < filter_rte_m
        return self.rules.filter_rre_deg

    @property
    def filter_rte_m(self) -> float:
        return self.rules.filter_rte_m

    def card(self) -> dict:
        """The fields (the component itself is not one, the rules are by the names RULE_FIELDS gives); a clean card
        leaves the corruption fields out and the default card (edgeregnet v1) its name and version, so both keep
        the identity they had before those fields existed."""
        card = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("corrupter", "rules")}
        card |= {key: getattr(self.rules, attr) for key, attr in RULE_FIELDS.items()}
        left_out = () if self.corruption else CORRUPTION_FIELDS
        left_out += CARD_FIELDS if (self.name, self.version) == (DEFAULT_NAME, DEFAULT_VERSION) else ()
        left_out += tuple(k for k, v in INPUT_DEFAULTS.items() if card[k] == v)
        return {k: v for k, v in card.items() if k not in left_out}

    def identity(self) -> str:
        return hashlib.sha256(json.dumps(self.card(), sort_keys=True).encode()).hexdigest()[:16]

    def rng(self, dataset: str, frame_id: str, *salt: str) -> np.random.Generator:
        """A generator of its own per (seed, dataset, frame id, salt...): the corruption's name and severity are the
        salt of its randomness, which thus never shifts the frame's transform."""
        digest = hashlib.sha256("\x00".join([str(self.seed), dataset, frame_id, *salt]).encode()).digest()
        return np.random.default_rng(np.frombuffer(digest, dtype=np.uint32).tolist())

    def corrupted(self, corruption: Corruption, severity: int) -> Protocol:
        """This protocol with `corruption` at `severity` (1..its number of levels)."""
        corruption.level(severity)  # refuses a severity the corruption does not have
        return dataclasses.replace(self, corruption=corruption.name, severity=severity, corrupter=corruption)

    def component(self) -> Corruption | None:
        """The corruption component (None under the clean protocol). A card read back names its corruption only:
        whoever reads it resolves the component from the registry (`report.rundir.resolved`) before frames run."""
        if not self.corruption:
            return None
        if self.corrupter is None:
            raise I2PBenchError(f"protocol {self.identity()} names corruption {self.corruption!r} but holds no "
                                "component: resolve it from the registry first")  # fmt: skip
        return self.corrupter

    def corrupt(self, sensor: SensorFrame) -> SensorFrame:
        """The dataset's frame as the corrupted sensors deliver it (itself, under the clean protocol)."""
        corruption = self.component()
        if corruption is None:
            return sensor
        rng = self.rng(sensor.dataset, sensor.frame_id, self.corruption, str(self.severity))
        return corruption.apply(sensor, self.severity, rng)

    def motion(self, sensor: SensorFrame) -> np.ndarray | None:
        """The corruption's rigid motion of the scan (LiDAR frame), composed before T_rand; None when it has none.
        Its generator is salted apart from `corrupt`'s, so a corruption may both change the frame and move it."""
        corruption = self.component()
        if corruption is None or not corruption.moves_cloud:
            return None
        rng = self.rng(sensor.dataset, sensor.frame_id, self.corruption, str(self.severity), "motion")
        return corruption.displacement(sensor, self.severity, rng)

    def random_transform(self, dataset: str, frame_id: str) -> np.ndarray:
        """T_rand for one frame: a yaw about LiDAR z and an x/y translation (in the camera frame: about camera y,
        on x and z, the peers' 'CAM coordinate' draw)."""
        rng = self.rng(dataset, frame_id)
        yaw = rng.uniform(-self.rotation_range_rad, self.rotation_range_rad)
        tx, ty = rng.uniform(-self.translation_range_m, self.translation_range_m, size=2)
        if self.pose_frame == "camera":
            c, s = np.cos(yaw), np.sin(yaw)
            return make_transform(np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]), np.array([tx, 0.0, ty]))
        return make_transform(rot_z(yaw), np.array([tx, ty, 0.0]))

    def resamples(self) -> bool:
        """Whether the card gives its stages another image or cloud than the dataset's (protocol_inputs)."""
        return any(getattr(self, k) != v for k, v in INPUT_DEFAULTS.items() if k != "pose_frame")

    def resample(self, seen: SensorFrame, K_true: np.ndarray) -> tuple[SensorFrame, np.ndarray]:
        """The (corrupted) frame as the card's stages see it, and the true K transformed as its image was."""
        from .protocol_inputs import image_geometry, resample, transform_K

        crop = (self.image_crop_h, self.image_crop_w) if self.image_crop_h else None
        _, offset = image_geometry(seen.image.shape, self.image_top, self.image_scale, crop)
        rng = self.rng(seen.dataset, seen.frame_id, "inputs")
        seen = resample(seen, self.image_top, self.image_scale, crop, self.voxel_m, self.points, rng)
        return seen, transform_K(K_true, self.image_top, self.image_scale, offset)

    def apply(self, sensor: SensorFrame) -> Frame:
        """Turn a dataset frame into a registration problem (corrupted, under a corruption) with its ground truth.

        What the stages see comes from the corrupted frame; the ground truth only from the dataset's, and from the
        whole motion the cloud was moved by (T_rand, after a corruption's own motion)."""
        if not np.isfinite(sensor.points).all():
            where = sensor.source or f"{sensor.dataset} frame {sensor.frame_id}"
            raise DataError(f"{where}: the scan contains NaN or infinite values; datasets must drop such returns")
        if sensor.draw_index is not None:
            from .protocol_peer import follows_loader, peer_frame  # as the peers' loaders build it

            if follows_loader(self, sensor):
                return peer_frame(self, sensor)
        seen, K_true = self.corrupt(sensor), sensor.K
        if self.resamples():
            seen, K_true = self.resample(seen, K_true)
        T_rand = self.random_transform(sensor.dataset, sensor.frame_id)
        M = self.motion(sensor)
        moved = T_rand if M is None else T_rand @ M  # None: exactly the clean T_rand, bit for bit
        camera = self.pose_frame == "camera"  # the cloud taken into the camera frame, then moved there
        moved = (T_rand @ sensor.T_cam_lidar if M is None else T_rand @ sensor.T_cam_lidar @ M) if camera else moved
        points = seen.points.copy()
        points[:, :3] = transform_points(moved, seen.points[:, :3].astype(np.float64)).astype(np.float32)
        return Frame(
            dataset=sensor.dataset,
            frame_id=sensor.frame_id,
            image=seen.image,
            points=points,
            ring=seen.ring,
            ranges=np.linalg.norm(seen.points[:, :3], axis=1).astype(np.float32),
            K=seen.K,
            T_gt=sensor.T_cam_lidar @ invert(moved),
            match_radius_px=sensor.match_radius_px,
            T_init=np.eye(4) if camera else sensor.T_cam_lidar,  # camera <- the unmoved cloud's frame
            K_gt=None if np.array_equal(seen.K, K_true) else K_true,
            inputs=self.name if self.resamples() or camera else "",
        )
