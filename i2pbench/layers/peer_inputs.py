"""The authors' KITTI input preparation that CorrI2P, DeepI2P and VP2P-Match share: the image cut, scaled and
centre-cropped; the network's cells as full-resolution pixels; the scan as 0.1 m voxels with normals; seeded draws.

Where the methods differ, the difference is a conf key or a named argument:
- `crop["top_rows"]`: rows cut off the image's top before scaling (DeepI2P kitti_pc_img_pose_loader.py:330: 50;
  CorrI2P's loader cuts none, options.py's `crop_original_top_rows` being read by no KITTI line, so its conf is 0;
  VP2P-Match kitti_dataset.py:306-319 cuts none, its conf has no such key);
- `cell_px`: the side of a cell in pixels of the crop (CorrI2P's and VP2P-Match's stride-4 map, DeepI2P's 32 px fine
  cells, kitti/options.py `img_fine_resolution_scale`);
- `in_draw_order`: VP2P-Match keeps its random draw's order (kitti_dataset.py:296-303), CorrI2P and DeepI2P sort it;
- `image_input(..., divide_by=)`: CorrI2P and VP2P-Match feed the image in [0, 1], DeepI2P in 0-255;
- `DrawnCloud.cloud`: DeepI2P's loader voxelises again at 0.3 m (its plugin's `network_cloud`), the others do not;
- `loader_cards`: the protocol cards whose frames already are the authors' loader's inputs (CorrI2P and VP2P-Match:
  `corri2p`, `vp2p-match`; DeepI2P: `deepi2p`).

Two kinds of frame. The dataset's frame (`Frame.inputs` empty) is the whole image and scan in LiDAR axes: the stages
prepare the authors' inputs from it as above. A frame one of the method's `loader_cards` built already holds them: the
image is the crop (so the crop conf becomes the identity, `frame_crop`), the cloud the drawn voxels in the camera
frame moved by the card's test pose (so the points are taken as they are, in order, and the network axes are
`Frame.T_init`, the identity there, `network_axes`); normals are then estimated on the frame's cloud and turned to
camera up (the authors' come from the whole preprocessed cloud before their draw). Any other card's frame is refused.

Geometry of a cell: the loaders scale the (cut) image with OpenCV linear to `round(side * scale)` and crop at
offsets `(scaled - crop) // 2`; the authors' PnP reads cell (x, y) with K at 1 / cell_px of the crop's. That cell is
the frame's pixel (cell_px x + dx, cell_px y + dy) / scale + (0, top_rows) under the frame's K, exactly.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any, ClassVar

import cv2
import numpy as np
import torch

from ..errors import StageError
from ..geometry.transforms import transform_points
from ..stages.components import Extractor2D, Extractor3D
from ..types import Frame, Keypoints2D, Keypoints3D
from .pointnet2 import frame_seed

REVISION = 2  # bump when an output of this module changes for the same inputs (see i2pbench.layers)

VOXEL_M = 0.1  # the preprocessed clouds' voxel grid (CorrI2P kitti_pc_bin_to_npy_with_downsample_sn.py)
NORMAL_RADIUS_M, NORMAL_MAX_NN = 0.6, 30  # the same script's hybrid normal search
# LiDAR axes (x forward, y left, z up) -> camera axes (x right, y down, z forward): a fixed permutation, no extrinsic
LIDAR_TO_CAMERA_AXES = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], np.float32)
CAMERA_UP = np.array([0.0, -1.0, 0.0])  # LiDAR +z in camera axes: the side the scripts turn normals to
Cloud = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def crop_offsets(width: int, height: int, crop: Mapping[str, Any]) -> tuple[int, int] | None:
    """(dx, dy) of the centre crop in the scaled image (rows below `top_rows`), as the loaders' test modes; None for
    a frame too small to hold it."""
    scaled_w = round(width * crop["scale"])
    scaled_h = round((height - crop.get("top_rows", 0)) * crop["scale"])
    crop_w, crop_h = crop["crop"]
    if scaled_w < crop_w or scaled_h < crop_h:
        return None
    return (scaled_w - crop_w) // 2, (scaled_h - crop_h) // 2


def network_image(image: np.ndarray, crop: Mapping[str, Any]) -> np.ndarray:
    """the frame's RGB image -> the authors' crop (H x W x 3 uint8); the frame must hold it (crop_offsets)."""
    cut = image[crop.get("top_rows", 0) :]
    size = (round(cut.shape[1] * crop["scale"]), round(cut.shape[0] * crop["scale"]))
    scaled = cut if size == (cut.shape[1], cut.shape[0]) else cv2.resize(cut, size, interpolation=cv2.INTER_LINEAR)
    dx, dy = crop_offsets(image.shape[1], image.shape[0], crop)
    crop_w, crop_h = crop["crop"]
    return np.ascontiguousarray(scaled[dy : dy + crop_h, dx : dx + crop_w])


def cell_corners(width: int, height: int, crop: Mapping[str, Any], cell_px: int) -> np.ndarray:
    """the full-resolution pixel of each cell's corner (what the authors' PnP reads), raster order -> [cells x 2];
    none for a frame too small to hold the crop."""
    offsets = crop_offsets(width, height, crop)
    if offsets is None:
        return np.zeros((0, 2), np.float32)
    (dx, dy), (crop_w, crop_h) = offsets, crop["crop"]
    rows, cols = np.divmod(np.arange((crop_h // cell_px) * (crop_w // cell_px)), crop_w // cell_px)
    step, scale = cell_px / crop["scale"], crop["scale"]
    return np.stack([step * cols + dx / scale, step * rows + dy / scale + crop.get("top_rows", 0)], 1).astype(
        np.float32
    )


def pixel_cells(uv: np.ndarray, width: int, height: int, crop: Mapping[str, Any], cell_px: int) -> np.ndarray:
    """the cell each pixel uv [M x 2] falls in (the inverse of cell_corners), raster order -> [M] int64; -1 outside
    the crop."""
    offsets = crop_offsets(width, height, crop)
    if offsets is None:
        return np.full(len(uv), -1, np.int64)
    (dx, dy), (crop_w, crop_h) = offsets, crop["crop"]
    step = cell_px / crop["scale"]
    col = np.floor((uv[:, 0] - dx / crop["scale"]) / step).astype(np.int64)
    row = np.floor((uv[:, 1] - crop.get("top_rows", 0) - dy / crop["scale"]) / step).astype(np.int64)
    inside = (col >= 0) & (col < crop_w // cell_px) & (row >= 0) & (row < crop_h // cell_px)
    return np.where(inside, row * (crop_w // cell_px) + col, -1)


def finite_returns(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """the rows of the scan's finite returns and those returns [N x 4] (a corrupt return must not poison the grid)."""
    rows = np.flatnonzero(np.isfinite(frame.points).all(1))
    return rows, frame.points[rows]


def empty_cloud() -> Cloud:
    none = np.zeros((0, 3), np.float32)
    return none, none, np.zeros(0, np.float32), np.zeros(0, np.int64)


def open3d_voxels(xyz: np.ndarray, voxel_m: float = VOXEL_M):
    """Open3D's voxel grid of points [N x 3] (the scripts' `downsample_voxel_size`) -> the open3d PointCloud."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz.astype(np.float64)))
    return cloud.voxel_down_sample(voxel_size=voxel_m)


def estimate_up_normals(cloud) -> None:
    """an open3d PointCloud's normals by the hybrid search (0.6 m, 30 neighbours), turned to +z (the scripts'
    `sn_radius`, `sn_max_nn`), in place."""
    import open3d as o3d

    cloud.estimate_normals(search_param=o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS_M,
                                                                             max_nn=NORMAL_MAX_NN))  # fmt: skip
    cloud.orient_normals_to_align_with_direction([0, 0, 1])


def voxels_with_normals(xyz: np.ndarray, voxel_m: float = VOXEL_M):
    """the voxel grid of points [N x 3] with its +z normals -> the open3d PointCloud."""
    cloud = open3d_voxels(xyz, voxel_m)
    estimate_up_normals(cloud)
    return cloud


def voxel_cloud(frame: Frame) -> Cloud:
    """the scan's 0.1 m voxel centroids [V x 3], their normals [V x 3], the nearest return's intensity [V] and row
    [V]: the preprocessed cloud CorrI2P's and VP2P-Match's loaders read."""
    from scipy.spatial import cKDTree

    rows, scan = finite_returns(frame)
    if len(scan) == 0:
        return empty_cloud()
    cloud = voxels_with_normals(scan[:, :3])
    xyz = np.asarray(cloud.points, np.float32)
    _, nearest = cKDTree(scan[:, :3]).query(xyz, k=1)
    return xyz, np.asarray(cloud.normals, np.float32), scan[nearest, 3].astype(np.float32), rows[nearest]


def drawn(total: int, count: int, rng: np.random.Generator, in_draw_order: bool = False) -> np.ndarray:
    """the loaders' random `count` of `total` points without repeats (all of a smaller cloud) -> [<= count] indices,
    sorted unless `in_draw_order` (then a smaller cloud is shuffled, as VP2P-Match's draw of all its points)."""
    if total > count:
        pick = rng.choice(total, count, replace=False)
        return pick if in_draw_order else np.sort(pick)
    return rng.permutation(total) if in_draw_order else np.arange(total)


def farthest_nodes(points: np.ndarray, count: int, pool: int, rng: np.random.Generator) -> np.ndarray:
    """the loaders' node sampling (CorrI2P kitti_pc_img_dataloader.py:330-338, DeepI2P's FarthestSampler): FPS in
    float64 (first index at a tie, from a random start) over a random pool * count of points [N x 3] -> [count x 3];
    with fewer points than nodes a point repeats once all are taken, as theirs."""
    subset = points[rng.choice(len(points), min(pool * count, len(points)), replace=False)].astype(np.float64)
    chosen = [int(rng.integers(len(subset)))]
    dist = ((subset - subset[chosen[0]]) ** 2).sum(1)
    for _ in range(1, count):
        chosen.append(int(np.argmax(dist)))
        dist = np.minimum(dist, ((subset - subset[chosen[-1]]) ** 2).sum(1))
    return subset[chosen].astype(np.float32)


def loader_frame(frame: Frame, cards: Collection[str], component: str) -> bool:
    """whether the frame is one of `cards`' (its inputs already the authors' loader's) rather than the dataset's;
    another card's frame, whose inputs are not the authors', is refused by name."""
    if not frame.inputs:
        return False
    if frame.inputs in cards:
        return True
    width, height = frame.image_size
    accepted = ", ".join(f"'{card}'" for card in sorted(cards))
    raise StageError(component, f"prepares its authors' inputs from the dataset's frame or takes them from protocol "
                                f"{accepted}, but protocol '{frame.inputs}' gives the stages its own ({width} x "
                                f"{height} image, {len(frame.points)} points in the camera frame), which are not its "
                                f"authors'; run under the default protocol or {accepted} (the card's rules still "
                                f"apply to the run: `i2pbench evaluate RUN --rules {frame.inputs}`)")  # fmt: skip


def frame_crop(frame: Frame, crop: Mapping[str, Any], cards: Collection[str], component: str) -> Mapping[str, Any]:
    """the crop conf for this frame: the authors' for the dataset's frame; for a loader card's frame, whose image
    already is the crop, the identity (no rows cut, scale 1, offsets 0), refused when its size is not the crop's."""
    if not loader_frame(frame, cards, component):
        return crop
    width, height = frame.image_size
    crop_w, crop_h = crop["crop"]
    if (width, height) != (crop_w, crop_h):
        raise StageError(component, f"protocol '{frame.inputs}' gives a {width} x {height} image, not the "
                                    f"authors' {crop_w} x {crop_h} crop")  # fmt: skip
    return {**crop, "top_rows": 0, "scale": 1.0}


def network_axes(frame: Frame, cards: Collection[str], component: str) -> np.ndarray | None:
    """[4 x 4] the frame's points -> the axes the authors' network reads them in, for a loader card's frame:
    `Frame.T_init` (camera <- the unmoved cloud's frame: the identity, the cloud already is in the camera frame);
    None for the dataset's frame, whose LiDAR axes take the fixed permutation LIDAR_TO_CAMERA_AXES."""
    if not loader_frame(frame, cards, component):
        return None
    return np.eye(4) if frame.T_init is None else np.asarray(frame.T_init, np.float64)


def frame_cloud(frame: Frame, axes: np.ndarray) -> Cloud:
    """a loader card's cloud as it is: the frame's finite points [N x 3] in its own axes and order, normals [N x 3]
    estimated on them (the scripts' hybrid search) turned to camera up in network `axes`, reflectance [N], rows [N]."""
    import open3d as o3d

    rows, scan = finite_returns(frame)
    if len(scan) == 0:
        return empty_cloud()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan[:, :3].astype(np.float64)))
    cloud.estimate_normals(search_param=o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS_M,
                                                                             max_nn=NORMAL_MAX_NN))  # fmt: skip
    cloud.orient_normals_to_align_with_direction(axes[:3, :3].T @ CAMERA_UP)  # camera up in the frame's axes
    return scan[:, :3].copy(), np.asarray(cloud.normals, np.float32), scan[:, 3].copy(), rows


def image_input(image: np.ndarray, crop: Mapping[str, Any], divide_by: float = 255.0) -> torch.Tensor:
    """the frame's RGB image as the network reads it: the authors' crop in float32 over `divide_by` -> [3 x H x W]."""
    return torch.from_numpy(network_image(image, crop).astype(np.float32) / divide_by).permute(2, 0, 1)


def point_inputs(
    kp3d: Keypoints3D, cloud: np.ndarray, normals: np.ndarray, axes: np.ndarray | None = None
) -> dict[str, torch.Tensor]:
    """the keypoints as the network reads them, in camera axes: `pc` [3 x N], `sn` [3 x N] (each point's normal is
    its nearest point's of cloud [V x 3] and normals [V x 3], both in the frame's axes) and `intensity` [1 x N];
    `axes` [4 x 4] frame -> network (network_axes), None: the fixed LiDAR -> camera permutation."""
    from scipy.spatial import cKDTree

    xyz = np.asarray(kp3d.xyz, np.float32)
    _, row = cKDTree(cloud).query(xyz, k=1)
    if axes is None:
        pc, sn = xyz @ LIDAR_TO_CAMERA_AXES.T, normals[row] @ LIDAR_TO_CAMERA_AXES.T
    else:
        pc = transform_points(axes, xyz.astype(np.float64)).astype(np.float32)
        sn = (normals[row].astype(np.float64) @ axes[:3, :3].T).astype(np.float32)
    return {
        "pc": torch.from_numpy(pc.T.copy()),
        "sn": torch.from_numpy(sn.T.copy()),
        "intensity": torch.from_numpy(np.asarray(kp3d.reflectance, np.float32))[None],
    }


def node_inputs(frame: Frame, pc: torch.Tensor, count: int, pool: int) -> dict[str, torch.Tensor]:
    """`node_a` and `node_b` [3 x count]: two farthest_nodes draws over pc [3 x N], seeded by the frame."""
    rng = np.random.default_rng(frame_seed(frame))
    points = pc.T.numpy()
    nodes = [farthest_nodes(points, count, pool, rng) for _ in range(2)]
    return {"node_a": torch.from_numpy(nodes[0].T.copy()), "node_b": torch.from_numpy(nodes[1].T.copy())}


class CropCells(Extractor2D):
    """Every cell of the authors' crop, as the frame's pixel their PnP puts it at (under a loader card, the crop's
    own pixel); a method's subclass sets `name`, `cell_px`, `loader_cards` and its crop as `default_conf`."""

    cell_px: ClassVar[int]
    loader_cards: ClassVar[frozenset[str]] = frozenset()

    def __call__(self, frame: Frame) -> Keypoints2D:
        crop = frame_crop(frame, self.conf, self.loader_cards, self.label)
        width, height = frame.image_size
        return Keypoints2D(uv=cell_corners(width, height, crop, self.cell_px))


class DrawnCloud(Extractor3D):
    """A seeded random `max_keypoints` of the scan as the authors' loader prepares it (`cloud`: the 0.1 m voxels),
    each point's `index` its nearest return's row; under a loader card the frame's own points (`card_cloud`), in
    order (a seeded draw of them only when `max_keypoints` is fewer). A method's subclass sets `name`,
    `default_conf`, `in_draw_order` and `loader_cards`."""

    in_draw_order: ClassVar[bool] = False
    loader_cards: ClassVar[frozenset[str]] = frozenset()

    def cloud(self, frame: Frame, count: int) -> Cloud:
        return voxel_cloud(frame)

    def card_cloud(self, frame: Frame, count: int, axes: np.ndarray) -> Cloud:
        return frame_cloud(frame, axes)

    def __call__(self, frame: Frame) -> Keypoints3D:
        count = int(self.conf["max_keypoints"])
        axes = network_axes(frame, self.loader_cards, self.label)
        xyz, _, intensity, rows = self.cloud(frame, count) if axes is None else self.card_cloud(frame, count, axes)
        rng = np.random.default_rng([frame_seed(frame), int(self.conf["seed"])])
        if axes is not None and len(xyz) <= count:
            pick = np.arange(len(xyz))  # the card's draw, kept as it is
        else:
            pick = drawn(len(xyz), count, rng, self.in_draw_order)
        return Keypoints3D(index=rows[pick].astype(np.int64), xyz=xyz[pick], reflectance=intensity[pick])
