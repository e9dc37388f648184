"""A peer card's frame built as the peers' own loaders build it, for a frame with their dataset index.

CorrI2P's kitti_pc_img_dataloader.py:250-287,324-326,345 and CoFiI2P's data/kitti.py:259-320,379, for the dataset index
`SensorFrame.draw_index`: the cloud taken into the camera frame (P's baseline @ Tr), Open3D's 0.1 m voxel grid there
(reflectance averaged as their fake colour channel), `num_pc` points drawn by numpy's legacy generator
(`np.random.choice` without replacement; fewer: every point, repeated, then the rest drawn), the test pose drawn by
Python's `random` (t_x, t_y, t_z, r_x, r_y, r_z uniform in their ranges, in that order; R = Rz Ry Rx; float32) and
applied to the cloud; the image resized x0.5 and centre-cropped, K with it. The ground truth is their `P`,
inv(P_random). Both generators are seeded as CoFiI2P seeds them, `SeedSequence([index]).generate_state(1)`; CorrI2P
seeds nothing, and i2pbench uses CoFiI2P's seeding for both (a protocol seed s other than 0 seeds [index, s]).

A raw KITTI scan (the `kitti` dataset) is first preprocessed as the layout's cloud was made (corri2p_export: 0.1 m
grid in the LiDAR frame, 1-NN reflectance), so `--protocol corri2p` gives the same frames on the original layout as
on its export. Where this departs from protocol_inputs' own resampling (used for every other dataset and card): the
voxel grid is anchored in the camera frame, not the LiDAR's; voxels come in Open3D's order; the draws follow the
dataset index, not (seed, dataset, frame id); the sampled points keep the draw's order.
"""

from __future__ import annotations

import dataclasses
import random
from dataclasses import dataclass

import numpy as np

from ..geometry.transforms import invert
from ..types import Frame, SensorFrame
from .protocol_inputs import image_geometry, resample_image, transform_K

# CoFiI2P's KittiCalibHelper builds its matrices in float32 (data/kitti.py:39,55), so its camera-frame cloud, voxel grid
# and moved cloud are float32; CorrI2P's are float64 (kitti_pc_img_dataloader.py:40,56). A point on a voxel's face can
# fall either side in the two, changing the grid and every draw after it, so each card follows its own loader.
FLOAT32_CARDS = frozenset({"cofii2p"})
LOADER_CARDS = frozenset({"corri2p", "cofii2p"})  # the cards whose loaders this module follows


@dataclass(frozen=True)
class NuScenesLoader:
    """What a peer's nuScenes loader does to its layout's stored frame (cloud already in the camera frame, image
    already cut and resized): `points` drawn, the image resized by `image_scale` and centre-cropped to 160 x 320."""

    card: str
    points: int
    image_scale: float
    crop: tuple[int, int] = (160, 320)


# CoFiI2P's data/nuscenes.py:180-229 (Options_Nuscenes: 20480 points; x0.5, then 160 x 320) and CorrI2P's
# nuscenes_pc_img_dataloader.py:223-278 (input_pt_num 40960; the stored 320 x 160 image cropped as it is)
NUSCENES_LOADERS = {
    "cofii2p-nuscenes": NuScenesLoader("cofii2p", 20480, 0.5),
    "corri2p-nuscenes": NuScenesLoader("corri2p", 40960, 1.0),
}


def follows_loader(protocol, sensor: SensorFrame) -> bool:
    """Whether `protocol` builds this frame as its paper's loader does: a frame with a dataset index and a loader
    card (on a peer's nuScenes layout, that layout's own paper's card)."""
    if sensor.draw_index is None:
        return False
    layout = NUSCENES_LOADERS.get(sensor.dataset)
    return protocol.name == layout.card if layout else protocol.name in LOADER_CARDS


def seed_of(index: int, seed: int = 0) -> int:
    """The integer CoFiI2P seeds numpy's and Python's generators with for dataset index `index`."""
    entropy = [index] if seed == 0 else [index, seed]
    return int(np.random.SeedSequence(entropy).generate_state(1)[0])


def voxel_grid(cloud: np.ndarray, voxel_m: float) -> np.ndarray:
    """[V x 4] Open3D's voxel_down_sample of [N x 4] x, y, z, reflectance (reflectance as a colour channel, scaled
    to [0, 1] by its maximum and back), in the cloud's dtype as the loaders keep it."""
    import open3d as o3d

    intensity = cloud[:, 3].astype(np.float32)
    top = intensity.max() if len(intensity) else np.float32(0)
    colours = np.zeros((len(cloud), 3))
    colours[:, 0] = intensity / top if top > 0 else 0.0
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(np.ascontiguousarray(cloud[:, :3], dtype=np.float64))
    pcd.colors = o3d.utility.Vector3dVector(colours)
    down = pcd.voxel_down_sample(voxel_size=voxel_m)
    dtype = cloud.dtype
    return np.column_stack([np.asarray(down.points, dtype=dtype), np.asarray(down.colors, dtype=dtype)[:, 0] * top])


def moved(T: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """The cloud's points moved by T as the loaders write it (np.dot(R, pc) + t on 3 x N, in the cloud's dtype)."""
    out = cloud.copy()
    out[:, :3] = (np.dot(T[:3, :3].astype(cloud.dtype), cloud[:, :3].T) + T[:3, 3:].astype(cloud.dtype)).T
    return out


def draw_points(n: int, count: int, state: np.random.RandomState) -> np.ndarray:
    """`count` indices into n points as their downsample_np draws them (unsorted)."""
    if n >= count:
        return state.choice(n, count, replace=False)
    fixed = np.arange(n)
    while n + len(fixed) < count:
        fixed = np.concatenate([fixed, np.arange(n)])
    return np.concatenate([fixed, state.choice(n, count - len(fixed), replace=False)])


def draw_pose(rand: random.Random, translation_m: float, rotation_rad: float) -> np.ndarray:
    """[4 x 4] P_random as their generate_random_transform draws it in the camera frame (t_y, r_x, r_z ranges 0)."""
    tx, _, tz = (rand.uniform(-r, r) for r in (translation_m, 0.0, translation_m))
    _, yaw, _ = (rand.uniform(-r, r) for r in (0.0, rotation_rad, 0.0))
    c, s = np.cos(yaw), np.sin(yaw)
    P = np.eye(4, dtype=np.float32)
    P[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    P[:3, 3] = [tx, 0.0, tz]
    return P.astype(np.float64)


def as_stored(matrix: np.ndarray) -> np.ndarray:
    """A calibration matrix as the layout and the loaders hold it: each value rounded to float32 (K_P2 files; their
    KittiCalibHelper's Tr). The rotation is then theirs exactly; the translation within ~1e-8 m (their float32
    baseline solve cannot be redone from the summed float64 one), which moves a point across a voxel face only when
    it lies that close to one."""
    return matrix.astype(np.float32).astype(np.float64)


def nuscenes_layout_frame(protocol, sensor: SensorFrame, loader: NuScenesLoader) -> Frame:
    """The problem a peer's nuScenes loader builds from its layout's frame for the frame's index: numpy and Python
    seeded with the index (CoFiI2P's `np.random.seed(index)`, `random.seed(index)`; CorrI2P seeds nothing, and gets
    the same), `points` drawn, P_random drawn and applied in the camera frame, the image resized and centre-cropped.
    The ground truth is their P, inv(P_random)."""
    seen, M = protocol.corrupt(sensor), protocol.motion(sensor)
    index = int(sensor.draw_index)
    seed = index if protocol.seed == 0 else seed_of(index, protocol.seed)
    cloud = seen.points if M is None else moved(M, seen.points)
    cloud = cloud[draw_points(len(cloud), loader.points, np.random.RandomState(seed))]
    T_rand = draw_pose(random.Random(seed), protocol.translation_range_m, protocol.rotation_range_rad)
    _, offset = image_geometry(seen.image.shape, 0, loader.image_scale, loader.crop)
    K, K_true = transform_K(seen.K, 0, loader.image_scale, offset), transform_K(sensor.K, 0, loader.image_scale, offset)
    points = moved(T_rand, cloud)
    to_camera = np.eye(4) if M is None else M
    return Frame(
        dataset=sensor.dataset,
        frame_id=sensor.frame_id,
        image=resample_image(seen.image, 0, loader.image_scale, loader.crop),
        points=points.astype(np.float32),
        ring=np.zeros(len(points), np.int16),
        ranges=np.linalg.norm(cloud[:, :3], axis=1).astype(np.float32),
        K=K,
        T_gt=invert(T_rand @ to_camera),
        match_radius_px=sensor.match_radius_px,
        T_init=np.eye(4),
        K_gt=None if np.array_equal(K, K_true) else K_true,
        inputs=protocol.name,
    )


def peer_frame(protocol, sensor: SensorFrame) -> Frame:
    """The registration problem a peer card's stages get for a frame of the peers' layout."""
    if sensor.dataset in NUSCENES_LOADERS:
        return nuscenes_layout_frame(protocol, sensor, NUSCENES_LOADERS[sensor.dataset])
    seen, M = protocol.corrupt(sensor), protocol.motion(sensor)
    if not sensor.preprocessed:  # a raw scan: the preprocessing that made the layout's cloud, its rounded calibration
        from ..data.corri2p_export import grid_points

        sensor = dataclasses.replace(sensor, K=as_stored(sensor.K), T_cam_lidar=as_stored(sensor.T_cam_lidar))
        seen = dataclasses.replace(seen, points=grid_points(seen.points), K=as_stored(seen.K))
    to_camera = sensor.T_cam_lidar if M is None else sensor.T_cam_lidar @ M
    seed = seed_of(int(sensor.draw_index), protocol.seed)
    dtype = np.float32 if protocol.name in FLOAT32_CARDS else np.float64
    cloud = moved(to_camera, seen.points.astype(dtype))
    if protocol.voxel_m:
        cloud = voxel_grid(cloud, protocol.voxel_m)
    if protocol.points:
        cloud = cloud[draw_points(len(cloud), protocol.points, np.random.RandomState(seed))]
    T_rand = draw_pose(random.Random(seed), protocol.translation_range_m, protocol.rotation_range_rad)
    crop = (protocol.image_crop_h, protocol.image_crop_w) if protocol.image_crop_h else None
    top, scale = protocol.image_top, protocol.image_scale
    _, offset = image_geometry(seen.image.shape, top, scale, crop)
    K, K_true = transform_K(seen.K, top, scale, offset), transform_K(sensor.K, top, scale, offset)
    points = moved(T_rand, cloud)
    return Frame(
        dataset=sensor.dataset,
        frame_id=sensor.frame_id,
        image=resample_image(seen.image, top, scale, crop),
        points=points.astype(np.float32),
        ring=np.zeros(len(points), np.int16),
        ranges=np.linalg.norm(cloud[:, :3] - to_camera[:3, 3].astype(dtype), axis=1).astype(np.float32),
        K=K,
        T_gt=sensor.T_cam_lidar @ invert(T_rand @ to_camera),
        match_radius_px=sensor.match_radius_px,
        T_init=np.eye(4),
        K_gt=None if np.array_equal(K, K_true) else K_true,
        inputs=protocol.name,
    )
