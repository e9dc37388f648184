"""The sensor rig: a KITTI-like HDL-64E and colour camera 2, with calibration written exactly as KITTI writes it.

The calibration numbers are KITTI odometry sequence 00's (Tr's rotation made exactly orthonormal). The camera that
renders the images is built by parsing the calib.txt text with KITTI's convention, T_cam2_lidar = Tr with P2's
baseline inv(P2[:, :3]) @ P2[:, 3] added to its translation and K = P2[:, :3], so a reader that follows the
convention recovers the rendering camera to the last bit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cache, cached_property

import numpy as np

IMAGE_SIZE = (1241, 376)  # (width, height) of KITTI odometry sequences 00-02
LIDAR_HEIGHT = 1.73  # metres above the road, as on KITTI's car
_K = [[718.856, 0.0, 607.1928], [0.0, 718.856, 185.2157], [0.0, 0.0, 1.0]]
_P_LAST_COLUMN = {  # K @ baseline of each camera relative to camera 0
    "P0": [0.0, 0.0, 0.0],
    "P1": [-386.1448, 0.0, 0.0],
    "P2": [45.38225, -0.1130887, 0.003779761],
    "P3": [-337.2877, 2.369057, 0.004915215],
}
_TR = [
    [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02],
    [-7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02],
    [9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01],
]


@dataclass(frozen=True)
class Camera:
    K: np.ndarray  # [3 x 3]
    T_cam_lidar: np.ndarray  # [4 x 4] LiDAR frame -> camera 2 frame (x right, y down, z forward)
    size: tuple[int, int] = IMAGE_SIZE


@dataclass(frozen=True)
class Lidar:
    """Spinning multi-beam scanner mounted at `pose` (world <- LiDAR frame)."""

    elevations_deg: np.ndarray  # [B] beam elevations in ring-index order
    pose: np.ndarray  # [4 x 4] world <- LiDAR
    steps: int = 2000  # azimuth steps per revolution
    azimuth0: float = np.pi / 2000  # azimuth (rad, in the LiDAR frame) of the first step
    clockwise: bool = False  # sweep direction seen from above
    max_range: float = 80.0  # KITTI's scans stop near 80 m
    range_noise: float = 0.015  # metres, 1 sigma

    @cached_property
    def directions(self) -> np.ndarray:
        """[B x steps x 3] unit rays in the LiDAR frame, ring by ring, each ring in sweep order."""
        el = np.radians(self.elevations_deg)[:, None]
        step = (-1 if self.clockwise else 1) * 2 * np.pi / self.steps
        az = self.azimuth0 + np.arange(self.steps) * step
        return np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1)


@cache
def hdl64() -> Lidar:
    """KITTI's HDL-64E: upper block +2 to -8.33 deg (1/3 deg apart), lower block to -24.8 deg; rings top first, each
    starting just left of +x and sweeping anticlockwise (atan2(y, x) rising through +-180 deg) like KITTI's files."""
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.8, 32)
    pose = np.eye(4)
    pose[2, 3] = LIDAR_HEIGHT
    return Lidar(elevations_deg=np.concatenate([upper, lower]), pose=pose)


def _orthonormal(R: list[list[float]]) -> list[list[float]]:
    """The nearest rotation (the polar factor, what an SVD's U @ Vt gives) by Newton's iteration X <- (X + X^-T) / 2,
    in Python floats: each operation is one IEEE rounding on every machine, where LAPACK's SVD rounds by CPU (it moved
    calib.txt's 13th digit between OpenBLAS's kernels)."""
    X = [list(map(float, row)) for row in R]
    for _ in range(100):
        cof = [[_cofactor(X, i, j) for j in range(3)] for i in range(3)]
        det = X[0][0] * cof[0][0] + X[0][1] * cof[0][1] + X[0][2] * cof[0][2]
        nxt = [[(X[i][j] + cof[i][j] / det) / 2 for j in range(3)] for i in range(3)]
        if nxt == X:
            break
        X = nxt
    return X


def _cofactor(X: list[list[float]], i: int, j: int) -> float:
    r, c = [k for k in range(3) if k != i], [k for k in range(3) if k != j]
    minor = X[r[0]][c[0]] * X[r[1]][c[1]] - X[r[0]][c[1]] * X[r[1]][c[0]]
    return minor if (i + j) % 2 == 0 else -minor


def calib_text() -> str:
    """calib.txt contents: P0..P3 and Tr (velodyne -> rectified camera 0), 12 numbers each in '%.12e'."""
    K = np.array(_K)
    lines = []
    for name, last in _P_LAST_COLUMN.items():
        lines.append(_line(name, np.concatenate([K, np.array(last)[:, None]], axis=1)))
    tr = np.array(_TR)
    tr[:, :3] = _orthonormal([row[:3] for row in _TR])
    lines.append(_line("Tr", tr))
    return "\n".join(lines) + "\n"


def _line(name: str, matrix: np.ndarray) -> str:
    return f"{name}: " + " ".join(f"{x:.12e}" for x in matrix.reshape(-1))


def parse_calib(text: str) -> dict[str, np.ndarray]:
    out = {}
    for line in text.strip().splitlines():
        key, values = line.split(":", 1)
        out[key.strip()] = np.array([float(x) for x in values.split()]).reshape(3, 4)
    return out


@cache
def camera2() -> Camera:
    """Camera 2 exactly as a KITTI reader derives it from calib_text()."""
    calib = parse_calib(calib_text())
    K = calib["P2"][:, :3]
    T = np.eye(4)
    T[:3] = calib["Tr"]
    T[:3, 3] += np.linalg.inv(K) @ calib["P2"][:, 3]
    return Camera(K=K, T_cam_lidar=T)


def on_uneven_road(lidar: Lidar, rng: np.random.Generator) -> Lidar:
    """The rig as mounted on a car that pitches and rolls a little (suspension, road camber and grade), so the
    ground is not always exactly 1.73 m below the LiDAR along its z axis, as in real drives."""
    pitch, roll = np.radians(rng.normal(0, 0.8)), np.radians(rng.normal(0, 0.5))
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    tilt = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    pose = lidar.pose.copy()
    pose[:3, :3] = tilt @ pose[:3, :3]
    pose[2, 3] += rng.normal(0, 0.02)
    return dataclasses.replace(lidar, pose=pose)
