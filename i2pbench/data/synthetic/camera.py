"""The shaded camera image: Lambertian surfaces under sun and sky light, cast shadows, sky, optics and sensor noise."""

from __future__ import annotations

import cv2
import numpy as np

from .raycast import Caster, Hits, surface
from .rig import Camera
from .scene import Lighting
from .style import DEFAULT, Style
from .textures import fbm, value_noise

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


def render(
    caster: Caster, camera: Camera, lidar_pose: np.ndarray, rng: np.random.Generator, style: Style = DEFAULT
) -> np.ndarray:
    """[H x W x 3] uint8 RGB of the camera rigidly attached to the LiDAR at `lidar_pose` (world <- LiDAR)."""
    origin, dirs = pixel_rays(camera, lidar_pose)
    hits = caster.cast(origin, dirs)
    light = caster.scene.lighting
    radiance = np.zeros_like(dirs)
    sky = np.ones(len(dirs), bool)
    sky[hits.rows] = False
    radiance[sky] = _sky(dirs[sky], light)
    albedo, _ = surface(caster.scene, hits)
    if style.detail:
        albedo = albedo * _detail(hits, style, light.cloud_seed)[:, None]
    shaded = _shade(caster, hits, albedo, light, style.ambient)
    haze = (1 - np.exp(-hits.t / 700.0))[:, None]
    radiance[hits.rows] = shaded * (1 - haze) + light.sky_horizon * haze
    w, h = camera.size
    return _develop(radiance.reshape(h, w, 3), rng, style)


def _detail(hits: Hits, style: Style, seed: int) -> np.ndarray:
    """[M] albedo factor around 1: fine texture fixed to the surfaces (fbm of the hit points' world coordinates in
    the plane the normal faces most, as triplanar mapping does), which the camera sees and the LiDAR does not, like
    the grain of real asphalt, walls and leaves. Seeded by the frame's cloud seed, so it draws no random number."""
    axis = np.argmax(np.abs(hits.normals), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # the two world axes across the face
    rows = np.arange(len(axis))
    a, b = hits.points[rows, keep[:, 0]], hits.points[rows, keep[:, 1]]
    noise = fbm(a, b, style.detail_scale, seed + 17 * (axis + 1), octaves=4) - 0.5
    return np.clip(1 + 2 * style.detail * noise, 0, None)


def _shade(caster: Caster, hits: Hits, albedo: np.ndarray, light: Lighting, ambient: float = 1.0) -> np.ndarray:
    lambert = np.clip(np.einsum("ij,j->i", hits.normals, light.sun), 0.0, None)
    lit = np.flatnonzero(lambert > 0)
    shadow = caster.occluded(hits.points[lit] + hits.normals[lit] * 0.01, light.sun)
    lambert[lit[shadow]] = 0.0
    sky_view = 0.7 + 0.3 * hits.normals[:, 2]
    return albedo * (light.ambient_rgb * ambient * sky_view[:, None] + light.sun_rgb * lambert[:, None])


def _sky(dirs: np.ndarray, light: Lighting) -> np.ndarray:
    """Horizon-to-zenith gradient with soft clouds (image edges with no LiDAR counterpart, as in real skies)."""
    up = np.clip(dirs[:, 2] * 4, 0, 1)[:, None]
    sky = light.sky_horizon * (1 - up) + light.sky_zenith * up
    z = np.maximum(dirs[:, 2], 0.02)
    cloud = value_noise(dirs[:, 0] / z * 30, dirs[:, 1] / z * 30, 25.0, light.cloud_seed)
    cover = np.clip((cloud - light.cloud_level) * 3, 0, 1)[:, None]
    return sky * (1 - cover) + light.sky_horizon * 1.05 * cover


def _metered(lum: np.ndarray, start: float, style: Style) -> float:
    """The exposure at which the developed image's mean reads `style.mean_grey` (a camera that meters the average,
    as KITTI's appears to: its grey mean varies by 2.3 over 37 frames), found by bisection in log exposure on every
    4th pixel of every 4th row."""
    sample = lum[::4, ::4].ravel()
    lo, hi = np.log(start) - 5.0, np.log(start) + 5.0
    for _ in range(30):
        mid = (lo + hi) / 2
        grey = float((np.clip(sample * np.exp(mid), 0, 1) ** style.gamma).mean())
        lo, hi = (mid, hi) if grey < style.mean_grey else (lo, mid)
    return float(np.exp((lo + hi) / 2))


def _develop(radiance: np.ndarray, rng: np.random.Generator, style: Style = DEFAULT) -> np.ndarray:
    """Auto-exposure, optics blur, gamma (the style's tone curve), read noise, 8-bit quantisation."""
    lum = radiance.mean(axis=2)
    exposure = style.exposure / max(float(np.percentile(lum, 98)), 1e-3)
    if style.mean_grey is not None:
        exposure = _metered(lum, exposure, style)
    img = np.clip(radiance * exposure, 0, 1).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), style.blur)
    img *= rng.normal(1.0, 0.04, 3).astype(np.float32)  # white balance differs from drive to drive
    img = np.clip(img, 0, 1) ** style.gamma
    img += rng.normal(0, 0.015, img.shape).astype(np.float32)
    return np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)
