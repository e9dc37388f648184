"""The small typed values that cross stage boundaries.

Shapes are documented per field; arrays are numpy unless a field says tensor. Stages never receive a grab-bag dict.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # annotations only: numpy is imported where an array is made, torch by the learned stages
    import numpy as np
    import torch


@dataclass(frozen=True)
class SensorFrame:
    """One synchronised camera image and LiDAR sweep, as a dataset stores it (LiDAR frame, no protocol applied)."""

    dataset: str
    frame_id: str
    image: np.ndarray  # [H x W x 3] uint8 RGB
    points: np.ndarray  # [N x 4] float32 x, y, z (m, LiDAR frame), reflectance in [0, 1]
    ring: np.ndarray  # [N] int16 laser index; within a ring, points are in scan (azimuth) order
    K: np.ndarray  # [3 x 3] float64 camera intrinsics
    T_cam_lidar: np.ndarray  # [4 x 4] float64, maps LiDAR points into the camera frame
    match_radius_px: float = 3.0  # eps_c: a projected 3D point within this many pixels of a 2D point is a true match
    source: str = ""  # file or record the frame was read from, for error messages
    # [6] float64 (vx, vy, vz in m/s, wx, wy, wz in rad/s): the LiDAR's own velocity, in its frame, at the scan's
    # time; None when the dataset does not know it (corruptions needing it do not apply: docs/robustness.md)
    ego_motion: np.ndarray | None = None
    # the frame's index in the list the peers' loaders build over its split (KITTI: 2 x its position, + 1 for camera
    # 3): under the corri2p and cofii2p cards the protocol builds the frame as their loader does for that index
    # (i2pbench.scoring.protocol_peer); None: the card's own resampling (protocol_inputs)
    draw_index: int | None = None
    preprocessed: bool = False  # the points are already the peers' preprocessed cloud (0.1 m grid, 1-NN reflectance)

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.image.shape[1]), int(self.image.shape[0])


@dataclass(frozen=True)
class Frame:
    """A registration problem: the image and a LiDAR sweep moved by the protocol's random transform.

    `ranges` is the distance each return travelled from the sensor, a measurement the protocol's transform leaves
    unchanged (real LiDARs report it), so scan-line edge detectors still see the sensor's geometry.
    `T_gt` is hidden (None) from every stage that does not declare it consumes ground truth. So is `K_gt`: set only
    when `K`, what the stages are told, is a corrupted calibration (docs/robustness.md), it holds the intrinsics the
    image was really formed with, which ground-truth projections (true matches, the oracle) use.
    """

    dataset: str
    frame_id: str
    image: np.ndarray  # [H x W x 3] uint8 RGB
    points: np.ndarray  # [N x 4] float32 x, y, z (moved LiDAR frame), reflectance in [0, 1]
    ring: np.ndarray  # [N] int16
    ranges: np.ndarray  # [N] float32 metres from the sensor
    K: np.ndarray  # [3 x 3] float64
    T_gt: np.ndarray | None  # [4 x 4] float64, camera <- moved LiDAR
    match_radius_px: float = 3.0
    T_init: np.ndarray | None = None  # [4 x 4] the pose a solver would assume with no information (for overlays)
    K_gt: np.ndarray | None = None  # [3 x 3] float64 true intrinsics when K is corrupted; None: K is the true one
    # the protocol card whose own inputs these are (image cut, resized and cropped; cloud voxelised, drawn and in the
    # camera frame): stages that prepare their authors' inputs from the dataset's frame cannot prepare them again;
    # "" for the dataset's frame, in its LiDAR axes
    inputs: str = ""

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.image.shape[1]), int(self.image.shape[0])

    @property
    def K_true(self) -> np.ndarray:
        """The intrinsics the image was formed with: what a ground-truth projection uses."""
        return self.K if self.K_gt is None else self.K_gt

    def without_ground_truth(self) -> Frame:
        return dataclasses.replace(self, T_gt=None, K_gt=None)


@dataclass(frozen=True)
class Keypoints2D:
    """Image keypoints (edge pixels)."""

    uv: np.ndarray  # [M x 2] float32 pixel coordinates (u = column, v = row)

    def __len__(self) -> int:
        return int(self.uv.shape[0])


@dataclass(frozen=True)
class Keypoints3D:
    """LiDAR keypoints (edge points), as indices into `Frame.points` plus their values."""

    index: np.ndarray  # [M] int64 rows of Frame.points
    xyz: np.ndarray  # [M x 3] float32 in the moved LiDAR frame
    reflectance: np.ndarray  # [M] float32

    def __len__(self) -> int:
        return int(self.index.shape[0])

    @classmethod
    def from_index(cls, frame: Frame, index: np.ndarray) -> Keypoints3D:
        import numpy as np

        index = np.asarray(index, dtype=np.int64)
        pts = np.take(frame.points, index, axis=0)  # the same rows as points[index], ~10x faster on [N x 4]
        return cls(index=index, xyz=np.ascontiguousarray(pts[:, :3]), reflectance=np.ascontiguousarray(pts[:, 3]))


@dataclass(frozen=True)
class Features:
    """Descriptors for both keypoint sets; `None` on a side means no encoder ran there."""

    desc2d: torch.Tensor | None  # [M2 x D] float32
    desc3d: torch.Tensor | None  # [M3 x D] float32


@dataclass(frozen=True)
class Matches:
    """2D-3D correspondences, and optionally what the matcher believes of every 3D keypoint.

    `frustum` is set by a matcher that declares FRUSTUM_SCORES (i2pbench.stages.components) in `provides`: for each 3D
    keypoint, its probability of lying in the camera frustum (DeepI2P's classification), which an inverse-projection
    solver fits a pose to. None: the matcher gives none.

    `radius_px` is set by a matcher whose pairs are coarse by design: DeepI2P pairs a point with the centre of the
    grid cell it predicts, so its pair is true when the point projects within the cell's half diagonal of that
    centre, not within eps_c. None: a pair is true within the frame's eps_c (`Frame.match_radius_px`).
    """

    index2d: np.ndarray  # [K] int64 rows of Keypoints2D.uv
    index3d: np.ndarray  # [K] int64 rows of Keypoints3D
    score: np.ndarray  # [K] float32, higher is more confident
    frustum: np.ndarray | None = None  # [M3] float32 in [0, 1], one per 3D keypoint (not per match)
    radius_px: float | None = None  # px within which this matcher's pairs count as true (None: the frame's eps_c)

    def __len__(self) -> int:
        return int(self.index2d.shape[0])

    @classmethod
    def empty(cls) -> Matches:
        import numpy as np

        return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))


def _no_rows() -> np.ndarray:
    """An empty [0] int64 index array (a solve without inliers)."""
    import numpy as np

    return np.zeros(0, np.int64)


@dataclass(frozen=True)
class PoseEstimate:
    """A solver's answer. A failed solve carries `T=None` and a message, never an exception."""

    T: np.ndarray | None  # [4 x 4] float64 camera <- moved LiDAR
    inliers: np.ndarray = field(default_factory=_no_rows)  # [I] int64 rows of Matches
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.T is not None

    @classmethod
    def failed(cls, message: str) -> PoseEstimate:
        return cls(T=None, message=message)
