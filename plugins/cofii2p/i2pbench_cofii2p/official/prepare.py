"""CoFiI2P's data preparation (data/kitti.py:259-320, model/kpconv/preprocess_data.py) from an i2pbench frame: the
network's image, its 20,480 points with intensity and normals, and the KPConv pyramid over them (`pc_data_dict`).

Where a frame comes from decides what is left to do. A dataset's frame under the default card is the whole scan and
the full-size image: the scan is voxelised at 0.1 m and 20,480 voxels drawn as the loader's `downsample_np` draws them
(every voxel repeated when there are fewer), the image halved and centre-cropped to 160 x 512. A frame the `cofii2p`
card built (i2pbench.scoring.protocol_peer; `Frame.inputs` names it) already is the loader's: its 20,480 points and the
160 x 512 crop are taken as they are (`is_loader_cloud`, `loader_crop`; a smaller `max_keypoints` takes a seeded
subset of the points); another card's frame is refused by name.

Axes: the loader hands the network the cloud in the camera frame (P2 @ Tr) moved by its random transform. i2pbench's
`Frame.T_init` is camera <- the unmoved cloud's frame (the calibration under the default card, the identity under
`cofii2p`), so `T_init @ points` is the cloud as their network sees it up to the protocol's motion (`network_axes`).
Normals: their files' normals are Open3D's (0.6 m, 30 neighbours) on the 0.1 m voxels, turned to LiDAR +z, i.e.
camera -y once in the camera frame; here they are estimated on the frame's voxels in network axes, turned to -y, and
each point takes its nearest voxel's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from i2pbench.api import Frame, Keypoints3D, transform_points
from i2pbench.layers.peer_inputs import (
    LIDAR_TO_CAMERA_AXES,
    NORMAL_MAX_NN,
    NORMAL_RADIUS_M,
    finite_returns,
    image_input,
    loader_frame,
    open3d_voxels,
)
from i2pbench.layers.point_pyramid import NEIGHBOURS, STAGES, PointPyramid, point_pyramid
from i2pbench.layers.pointnet2 import frame_seed

NUM_POINTS = 20480  # data/options.py num_pc
CELL_PX = 2  # the fine map's stride in the crop (the network's 1/2-scale image features, K_2)
# the image preparation of data/kitti.py:306-320: no rows cut (`top_rows`: options.py's crop_original_top_rows is read
# by no loader line), x0.5, centre crop to options.py img_W x img_H
CROP: dict[str, Any] = {"top_rows": 0, "scale": 0.5, "crop": (512, 160)}
CAMERA_UP = (0.0, -1.0, 0.0)  # LiDAR +z in camera axes
LOADER_CARDS = ("cofii2p",)  # the cards whose frames are the authors' loader's (i2pbench.scoring.protocol_peer)
MIN_POINTS = NEIGHBOURS * 2 ** (STAGES - 1)  # the fewest whose coarsest level still has 128 neighbours to find


def loader_crop(width: int, height: int, crop: Mapping[str, Any]) -> dict[str, Any]:
    """the crop conf for an image of this size: the loader's, or the identity for an image that already is the crop
    (a `cofii2p` card frame)."""
    if (width, height) == tuple(crop["crop"]):
        return {**crop, "top_rows": 0, "scale": 1.0}
    return dict(crop)


def is_loader_cloud(frame: Frame) -> bool:
    """whether the frame's cloud already is the loader's draw: a `cofii2p` card frame (`Frame.inputs`); another
    card's frame is refused by name."""
    return loader_frame(frame, LOADER_CARDS, "cofii2p-official-points")


def network_axes(frame: Frame) -> np.ndarray:
    """[4 x 4] the frame's points -> the axes the authors' network sees them in (module docstring); without a
    T_init, the fixed LiDAR -> camera axis permutation."""
    if frame.T_init is not None:
        return np.asarray(frame.T_init, np.float64)
    T = np.eye(4)
    T[:3, :3] = LIDAR_TO_CAMERA_AXES
    return T


def to_network(frame: Frame, xyz: np.ndarray) -> np.ndarray:
    """points [N x 3] of the frame in network axes -> [N x 3] float32."""
    return transform_points(network_axes(frame), np.asarray(xyz, np.float64)).astype(np.float32)


def loader_draw(total: int, count: int, rng: np.random.RandomState) -> np.ndarray:
    """`downsample_np` (data/kitti.py:168-180): `count` of `total` rows without repeats, or every row as many whole
    times as fit and then a draw without repeats for the rest -> [count] indices in the loader's order."""
    if total >= count:
        return rng.choice(total, count, replace=False)
    fixed = np.arange(total)
    while total + len(fixed) < count:
        fixed = np.concatenate([fixed, np.arange(total)])
    return np.concatenate([fixed, rng.choice(total, count - len(fixed), replace=False)])


def voxels(frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """the scan's 0.1 m voxel centroids [V x 3] in the frame's axes, the nearest return's reflectance [V] and row [V]
    (the preprocessed cloud's points and intensity)."""
    from scipy.spatial import cKDTree

    rows, scan = finite_returns(frame)
    if len(scan) == 0:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64)
    xyz = np.asarray(open3d_voxels(scan[:, :3]).points, np.float32)
    _, nearest = cKDTree(scan[:, :3]).query(xyz, k=1)
    return xyz, scan[nearest, 3].astype(np.float32), rows[nearest]


def loader_cloud(frame: Frame, count: int, seed: int) -> Keypoints3D:
    """the `count` points the network reads, each with its nearest return's row as `index` (module docstring)."""
    if is_loader_cloud(frame):  # the card's draw as it is; a smaller count (a small conf) a seeded subset of it
        keep = len(frame.points) <= count
        rows = (
            np.arange(len(frame.points))
            if keep
            else np.sort(np.random.RandomState(seed).choice(len(frame.points), count, replace=False))
        )
        return Keypoints3D.from_index(frame, rows)
    xyz, intensity, rows = voxels(frame)
    if len(xyz) == 0:
        return Keypoints3D.from_index(frame, np.zeros(0, np.int64))
    pick = loader_draw(len(xyz), count, np.random.RandomState([frame_seed(frame), seed]))
    return Keypoints3D(index=rows[pick].astype(np.int64), xyz=xyz[pick], reflectance=intensity[pick])


def up_normals(frame: Frame, pc: np.ndarray) -> np.ndarray:
    """each network-axes point's [N x 3] normal: its nearest 0.1 m voxel's, by Open3D's hybrid search over the frame's
    voxels in network axes, turned to camera up -> [N x 3] float32."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    _, scan = finite_returns(frame)
    cloud = open3d_voxels(to_network(frame, scan[:, :3]))
    cloud.estimate_normals(search_param=o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS_M,
                                                                             max_nn=NORMAL_MAX_NN))  # fmt: skip
    cloud.orient_normals_to_align_with_direction(CAMERA_UP)
    _, nearest = cKDTree(np.asarray(cloud.points)).query(pc, k=1)
    return np.asarray(cloud.normals, np.float32)[nearest]


def point_features(frame: Frame, kp3d: Keypoints3D, pc: np.ndarray, conf: Mapping[str, Any]) -> torch.Tensor:
    """`feats` [N x 4]: intensity and normals (data/kitti.py:293) or, on nuScenes, intensity and the point itself
    (data/nuscenes.py:213); the intensity scaled by `intensity_scale`."""
    if conf["features"] not in ("normals", "xyz"):
        raise ValueError(f"cofii2p-official: features {conf['features']!r} is neither 'normals' nor 'xyz'")
    extra = up_normals(frame, pc) if conf["features"] == "normals" else pc
    intensity = kp3d.reflectance * np.float32(conf.get("intensity_scale", 1.0))
    return torch.from_numpy(np.column_stack([intensity, extra]).astype(np.float32))


def network_inputs(
    frame: Frame, kp3d: Keypoints3D, conf: Mapping[str, Any]
) -> tuple[dict[str, Any], torch.Tensor, PointPyramid]:
    """(the authors' `pc_data_dict`, the image [1 x 3 x H x W] in [0, 1], the pyramid; its `picks` are kp3d rows).
    Fewer than MIN_POINTS keypoints are repeated up to it as `downsample_np` repeats a small cloud."""
    rng = np.random.RandomState([frame_seed(frame), int(conf["seed"])])
    rows = loader_draw(len(kp3d), MIN_POINTS, rng) if len(kp3d) < MIN_POINTS else np.arange(len(kp3d))
    kp3d = Keypoints3D(kp3d.index[rows], kp3d.xyz[rows], kp3d.reflectance[rows])
    pc = to_network(frame, kp3d.xyz)
    pyramid = point_pyramid(pc, rng)
    pyramid = dataclasses.replace(pyramid, picks=[rows[p] for p in pyramid.picks])
    data = pyramid.as_inputs(point_features(frame, kp3d, pc, conf))
    width, height = frame.image_size
    image = image_input(frame.image, loader_crop(width, height, conf))[None]
    return data, image, pyramid
