"""The built-in corruptions, registered by the `datasets` plugin (docs/robustness.md has every table).

Image corruptions act on the [H x W x 3] uint8 RGB image, LiDAR ones on the scan in the sensor's own frame (rays from
its origin, rings in scan order), the geometry ones on the K the stages are told or, `tilt`, by a rigid motion of the
cloud that the protocol composes into its random transform. Each table has five severities,
mild to severe, in the spirit of ImageNet-C and KITTI-C; the levels are chosen for full-resolution KITTI frames
(about 1241 x 376 px, a 64-ring scan) and are the same for every dataset, so boards compare.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.transforms import invert, make_transform, transform_points
from ..types import SensorFrame
from .base import Corruption, with_points


def _image(sensor: SensorFrame, image: np.ndarray) -> SensorFrame:
    """The frame with a new image, rounded and clipped back to uint8."""
    return dataclasses.replace(sensor, image=np.clip(np.rint(image), 0, 255).astype(np.uint8))


def _filtered(sensor: SensorFrame, kernel: np.ndarray) -> SensorFrame:
    """The image convolved with a normalised kernel, borders mirrored (no dark frame edge)."""
    out = cv2.filter2D(sensor.image, -1, (kernel / kernel.sum()).astype(np.float32), borderType=cv2.BORDER_REFLECT_101)
    return dataclasses.replace(sensor, image=out)


class GaussianNoise(Corruption):
    """Sensor noise: zero-mean Gaussian noise of sigma grey levels, independent per pixel and channel (8..48)."""

    name, kind = "gaussian-noise", "image"
    meaning = "photon and read noise of the image sensor (a high gain, a small sensor)"
    parameter = "noise sigma (grey levels of 255)"
    levels = (8, 16, 24, 32, 48)

    def corrupt(self, sensor, level, rng):
        return _image(sensor, sensor.image + rng.normal(0.0, level, sensor.image.shape))


class MotionBlur(Corruption):
    """Camera shake or ego-motion during the exposure: a line kernel of L px (3..21) at a random angle."""

    name, kind = "motion-blur", "image"
    meaning = "the camera moving during the exposure (vehicle motion, vibration)"
    parameter = "blur length (px)"
    levels = (3, 7, 11, 15, 21)

    def corrupt(self, sensor, level, rng):
        angle = rng.uniform(0.0, np.pi)
        half = (level - 1) / 2
        kernel = np.zeros((level, level), np.float32)
        end = (half * np.cos(angle), half * np.sin(angle))
        shift = 4  # cv2.line's sub-pixel bits: the segment's ends are not rounded to whole pixels
        points = [tuple(int(round((half + s * e) * (1 << shift))) for e in end) for s in (-1, 1)]
        cv2.line(kernel, points[0], points[1], 1.0, 1, cv2.LINE_AA, shift)
        return _filtered(sensor, kernel)


class DefocusBlur(Corruption):
    """An out-of-focus lens: the image convolved with a disk of radius r px (1..7), the lens's circle of confusion."""

    name, kind = "defocus-blur", "image"
    meaning = "an out-of-focus lens (focus drift, a dirty or fogged lens cover)"
    parameter = "disk radius (px)"
    levels = (1, 2, 3, 5, 7)

    def corrupt(self, sensor, level, rng):
        y, x = np.mgrid[-level : level + 1, -level : level + 1]
        return _filtered(sensor, (x**2 + y**2 <= level**2).astype(np.float32))


class LowLight(Corruption):
    """Dusk or a tunnel: intensities x in [0, 1] become x ** gamma (1.5..3.5), plus read noise of sigma grey levels
    (2..10), which a dark image makes relatively larger."""

    name, kind = "low-light", "image"
    meaning = "too little light: a darker tone curve and read noise that is no longer small against the signal"
    parameter = "(gamma, noise sigma in grey levels)"
    levels = ((1.5, 2), (2.0, 4), (2.5, 6), (3.0, 8), (3.5, 10))

    def corrupt(self, sensor, level, rng):
        gamma, sigma = level
        dark = 255.0 * (sensor.image / 255.0) ** gamma
        return _image(sensor, dark + rng.normal(0.0, sigma, sensor.image.shape))


class JPEG(Corruption):
    """Lossy compression: the image encoded as JPEG at quality q (25..7) and decoded, ImageNet-C's qualities."""

    name, kind = "jpeg", "image"
    meaning = "lossy compression on the way from the camera (bandwidth-limited logging or streaming)"
    parameter = "JPEG quality (100 best)"
    levels = (25, 18, 15, 10, 7)

    def corrupt(self, sensor, level, rng):
        bgr = np.ascontiguousarray(sensor.image[..., ::-1])
        ok, encoded = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(level)])
        if not ok:
            raise ValueError("OpenCV could not encode the image as JPEG")
        return dataclasses.replace(
            sensor, image=np.ascontiguousarray(cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1])
        )


class Fog(Corruption):
    """Fog or haze: I = t * J + (1 - t) * A, the scene J seen through a transmission t (0.8..0.2) towards the airlight
    A = 200 grey levels. No dense depth is known for the image, so t is uniform: one fog layer, not exp(-beta d)."""

    name, kind = "fog", "image"
    meaning = "scattering in fog or haze: contrast lost towards a bright airlight"
    parameter = "transmission t (1 = clear)"
    levels = (0.8, 0.65, 0.5, 0.35, 0.2)
    airlight = 200.0

    def corrupt(self, sensor, level, rng):
        return _image(sensor, level * sensor.image.astype(np.float64) + (1.0 - level) * self.airlight)


class BeamReduction(Corruption):
    """A sensor with fewer lasers: of the scan's R rings (in ring-id order) n = R * share (3/4..1/16) evenly spread
    ones are kept, so a 64-ring scan keeps 48, 32, 16, 8, 4; each kept set contains the next severity's."""

    name, kind = "beam-reduction", "lidar"
    meaning = "a cheaper LiDAR with fewer beams (or dead lasers): a sparser scan in elevation"
    parameter = "share of rings kept"
    levels = (0.75, 0.5, 0.25, 0.125, 0.0625)

    def corrupt(self, sensor, level, rng):
        rings = np.unique(sensor.ring)
        n = max(1, round(len(rings) * level))
        i = np.arange(len(rings))
        kept = rings[(i + 1) * n // len(rings) > i * n // len(rings)]  # exactly n, evenly spread, nested in n
        return with_points(sensor, np.isin(sensor.ring, kept))


class PointDropout(Corruption):
    """Lost returns: each point is dropped independently with probability p (0.2..0.9)."""

    name, kind = "point-dropout", "lidar"
    meaning = "returns lost to absorbing or specular surfaces, rain or packet loss: a uniformly sparser scan"
    parameter = "share of points dropped"
    levels = (0.2, 0.4, 0.6, 0.75, 0.9)

    def corrupt(self, sensor, level, rng):
        return with_points(sensor, rng.random(len(sensor.points)) >= level)


class RangeNoise(Corruption):
    """Ranging error: each return moves along its own ray by Gaussian noise of sigma m (0.02..0.4), so its
    direction is kept and the range the protocol reports changes with it (floored at 0.1 m)."""

    name, kind = "range-noise", "lidar"
    meaning = "time-of-flight jitter (the HDL-64E's is about 2 cm), worse on weak or oblique returns"
    parameter = "range noise sigma (m)"
    levels = (0.02, 0.05, 0.1, 0.2, 0.4)
    min_range = 0.1

    def corrupt(self, sensor, level, rng):
        xyz = sensor.points[:, :3].astype(np.float64)
        r = np.linalg.norm(xyz, axis=1)
        noisy = np.maximum(r + rng.normal(0.0, level, len(r)), self.min_range)
        scale = np.divide(noisy, r, out=np.ones_like(r), where=r > 0)  # a return at the origin has no ray
        points = sensor.points.copy()
        points[:, :3] = (xyz * scale[:, None]).astype(np.float32)
        return dataclasses.replace(sensor, points=points)


class ReflectanceNoise(Corruption):
    """Intensity miscalibration: each laser's reflectance scaled by its own gain exp(N(0, spread)) (spread
    0.05..0.5), plus per-point noise of sigma (0.02..0.16), clipped to [0, 1]."""

    name, kind = "reflectance-noise", "lidar"
    meaning = "uncalibrated per-laser intensity gains and noisy intensity readings (wet surfaces, ageing lasers)"
    parameter = "(per-ring gain spread, noise sigma)"
    levels = ((0.05, 0.02), (0.1, 0.04), (0.2, 0.08), (0.3, 0.12), (0.5, 0.16))

    def corrupt(self, sensor, level, rng):
        spread, sigma = level
        rings, which = np.unique(sensor.ring, return_inverse=True)
        gain = np.exp(rng.normal(0.0, spread, len(rings)))[which]
        points = sensor.points.copy()
        noisy = points[:, 3] * gain + rng.normal(0.0, sigma, len(points))
        points[:, 3] = np.clip(noisy, 0.0, 1.0).astype(np.float32)
        return dataclasses.replace(sensor, points=points)


class MissingSector(Corruption):
    """Occlusion: every return in an azimuth wedge of w degrees (10..60) is removed. The wedge lies in the camera's
    field of view (its centre within (fov - w) / 2 of the optical axis), where the loss matters to registration."""

    name, kind = "missing-sector", "lidar"
    meaning = "a nearby obstacle (a truck, a wall, a mounting bracket) hiding part of the view the sensors share"
    parameter = "wedge width (degrees of azimuth)"
    levels = (10, 20, 30, 45, 60)

    def corrupt(self, sensor, level, rng):
        axis = sensor.T_cam_lidar[2, :3]  # the camera's optical axis in the LiDAR frame (row 3 of R)
        width = sensor.image_size[0]
        fov = np.degrees(2 * np.arctan2(width / 2, sensor.K[0, 0]))
        slack = max(0.0, (fov - level) / 2)
        centre = np.degrees(np.arctan2(axis[1], axis[0])) + rng.uniform(-slack, slack)
        azimuth = np.degrees(np.arctan2(sensor.points[:, 1], sensor.points[:, 0]))
        offset = (azimuth - centre + 180.0) % 360.0 - 180.0
        return with_points(sensor, np.abs(offset) >= level / 2)


class IntrinsicError(Corruption):
    """A wrong calibration: the K the stages see has fx and fy off by e% (0..10%, one random sign: a zoom error) and
    cx, cy each off by e% of their value (own random signs). The image and the true K (ground truth) are unchanged."""

    name, kind = "intrinsic-error", "geometry"
    meaning = "a stale or wrong camera calibration (refocused lens, a different unit's intrinsics)"
    parameter = "error of focal length and principal point (%)"
    levels = (1, 2, 4, 7, 10)

    def corrupt(self, sensor, level, rng):
        sign = rng.choice([-1.0, 1.0], size=3)
        K = sensor.K.astype(np.float64).copy()
        K[0, 0] *= 1 + sign[0] * level / 100
        K[1, 1] *= 1 + sign[0] * level / 100
        K[0, 2] *= 1 + sign[1] * level / 100
        K[1, 2] *= 1 + sign[2] * level / 100
        return dataclasses.replace(sensor, K=K)


class Tilt(Corruption):
    """A tilted mount or a sloped road: the cloud rotated by theta degrees (1..8) about a horizontal LiDAR axis at a
    random azimuth (roll and pitch split by it, their signs with it), so its z axis leans by exactly theta. The
    protocol composes the motion into its yaw-only T_rand and into T_gt: the registration problem is the same, only
    a method assuming a gravity-aligned scan (a yaw-canonical frame, a 2D solver) meets a pose it never drew."""

    name, kind = "tilt", "geometry"
    meaning = "a tilted LiDAR mount or a sloped, cambered road: a scan whose z axis is not vertical"
    parameter = "tilt: roll and pitch together (degrees)"
    levels = (1, 2, 3, 5, 8)
    moves_cloud = True

    def motion(self, sensor, level, rng):
        azimuth = rng.uniform(0.0, 2 * np.pi)
        axis = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])  # horizontal: no yaw, which T_rand already draws
        return make_transform(Rotation.from_rotvec(np.radians(level) * axis).as_matrix(), np.zeros(3))


class TimeOffset(Corruption):
    """Unsynchronised clocks: the scan as the LiDAR saw it dt ms (10..200, random sign) after or before the stamp it
    is paired with. The sensor moved by M = [R(w dt) | v dt] meanwhile (its ego motion, in its own frame), so each
    point is p' = inv(M) p; the image and T_gt stay those of the stamp. Needs the frame's ego motion."""

    name, kind = "time-offset", "lidar"
    meaning = "unsynchronised LiDAR and camera clocks on a moving car: the scan taken dt before or after the image"
    parameter = "clock offset (ms)"
    levels = (10, 25, 50, 100, 200)
    needs = ("ego_motion",)

    def corrupt(self, sensor, level, rng):
        ego = np.asarray(sensor.ego_motion, dtype=np.float64)
        if ego.shape != (6,) or not np.isfinite(ego).all():
            raise ValueError(f"ego_motion must be 6 finite numbers (v in m/s, w in rad/s), got {ego.tolist()}")
        dt = rng.choice([-1.0, 1.0]) * level / 1000.0
        moved = make_transform(Rotation.from_rotvec(ego[3:] * dt).as_matrix(), ego[:3] * dt)  # the LiDAR at t + dt
        points = sensor.points.copy()
        points[:, :3] = transform_points(invert(moved), sensor.points[:, :3].astype(np.float64)).astype(np.float32)
        return dataclasses.replace(sensor, points=points)
