"""The shaded camera image: Lambertian surfaces under sun and sky light, cast shadows, sky, optics and sensor noise."""

from __future__ import annotations

import cv2
import numpy as np

from .raycast import Caster, Hits, surface
from .rig import Camera
from .scene import Lighting
from .textures import value_noise

_RAYS: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}


def pixel_rays(camera: Camera, lidar_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World origin [3] and unit directions [H*W x 3] through pixel centres: the ray of pixel (u, v) projects to
    exactly (u, v) with K, the convention of KITTI and OpenCV. The rays in the LiDAR frame are cached (one rig)."""
    key = camera.K.tobytes() + camera.T_cam_lidar.tobytes() + np.array(camera.size).tobytes()
    if key not in _RAYS:
        w, h = camera.size
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
        T_lidar_cam = np.linalg.inv(camera.T_cam_lidar)
        dirs = pix @ np.linalg.inv(camera.K).T @ T_lidar_cam[:3, :3].T
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        _RAYS[key] = (T_lidar_cam[:3, 3].copy(), dirs)
    origin, dirs = _RAYS[key]
    R, t = lidar_pose[:3, :3], lidar_pose[:3, 3]
    return R @ origin + t, np.einsum("ij,kj->ik", dirs, R)  # einsum: numpy matmul is slow on [N x 3] here


def render(caster: Caster, camera: Camera, lidar_pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """[H x W x 3] uint8 RGB of the camera rigidly attached to the LiDAR at `lidar_pose` (world <- LiDAR)."""
    origin, dirs = pixel_rays(camera, lidar_pose)
    hits = caster.cast(origin, dirs)
    light = caster.scene.lighting
    radiance = np.zeros_like(dirs)
    sky = np.ones(len(dirs), bool)
    sky[hits.rows] = False
    radiance[sky] = _sky(dirs[sky], light)
    albedo, _ = surface(caster.scene, hits)
    shaded = _shade(caster, hits, albedo, light)
    haze = (1 - np.exp(-hits.t / 700.0))[:, None]
    radiance[hits.rows] = shaded * (1 - haze) + light.sky_horizon * haze
    w, h = camera.size
    return _develop(radiance.reshape(h, w, 3), rng)


def _shade(caster: Caster, hits: Hits, albedo: np.ndarray, light: Lighting) -> np.ndarray:
    lambert = np.clip(np.einsum("ij,j->i", hits.normals, light.sun), 0.0, None)
    lit = np.flatnonzero(lambert > 0)
    shadow = caster.occluded(hits.points[lit] + hits.normals[lit] * 0.01, light.sun)
    lambert[lit[shadow]] = 0.0
    sky_view = 0.7 + 0.3 * hits.normals[:, 2]
    return albedo * (light.ambient_rgb * sky_view[:, None] + light.sun_rgb * lambert[:, None])


def _sky(dirs: np.ndarray, light: Lighting) -> np.ndarray:
    """Horizon-to-zenith gradient with soft clouds (image edges with no LiDAR counterpart, as in real skies)."""
    up = np.clip(dirs[:, 2] * 4, 0, 1)[:, None]
    sky = light.sky_horizon * (1 - up) + light.sky_zenith * up
    z = np.maximum(dirs[:, 2], 0.02)
    cloud = value_noise(dirs[:, 0] / z * 30, dirs[:, 1] / z * 30, 25.0, light.cloud_seed)
    cover = np.clip((cloud - light.cloud_level) * 3, 0, 1)[:, None]
    return sky * (1 - cover) + light.sky_horizon * 1.05 * cover


def _develop(radiance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Auto-exposure, optics blur, gamma, read noise, 8-bit quantisation."""
    lum = radiance.mean(axis=2)
    exposure = 0.9 / max(float(np.percentile(lum, 98)), 1e-3)
    img = np.clip(radiance * exposure, 0, 1).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), 0.6)
    img *= rng.normal(1.0, 0.04, 3).astype(np.float32)  # white balance differs from drive to drive
    img = np.clip(img, 0, 1) ** (1 / 2.2)
    img += rng.normal(0, 0.015, img.shape).astype(np.float32)
    return np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)
