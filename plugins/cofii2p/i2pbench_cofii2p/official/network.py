"""CoFiI2P's whole network as the authors' `CoFiI2P` computes it (model/network.py:14-264), on any device.

Inputs of `CoFiI2PNetwork.forward(pc_data_dict, img, fine_center_kpt_coors, fine_xy, fine_pc_inline_index, mode)`,
their forward's signature, batch size 1 (their loaders squeeze the batch axis out of every cloud tensor):
- `pc_data_dict`: the pyramid of preprocess_data.py `precompute_point_cloud_stack_mode` (five stages, each a random
  half of the one before, N0 = 20,480 on KITTI and nuScenes), every tensor on the image's device:
  `points`: 5 float32 [N_i x 3] (the cloud after the loader's random motion, camera axes), N_i = N0 // 2^i;
  `neighbors`: 5 int64 [N_i x 128], each stage's kNN-128 within itself, nearest first;
  `subsampling`: 4 int64 [N_(i+1) x 128], the kNN-128 of stage i+1's points among stage i's;
  `upsampling`: 4 int64 [N_i x 128], the kNN-128 of stage i's points among stage i+1's (column 0 is used);
  `feats`: float32 [N0 x 4], intensity and the three normal components of stage 0's points;
  `lengths` (5 ints) is carried by their loader and read by nobody;
- `img`: float32 [1 x 3 x H x W], RGB / 255 (KITTI 160 x 512, nuScenes 160 x 320);
- `fine_center_kpt_coors` int [2 x n] (x, y on the stride-2 map, centres of the training patches), `fine_xy`
  (unused by the forward, as theirs) and `fine_pc_inline_index` int64 [n] (stage-1 points of the training pairs):
  read in 'train' and 'val' mode only; pass None in 'test' mode;
- `mode`: 'train' / 'val' (patches at the given centres) or 'test' (the coarse selection below).

Outputs, their forward's tuple of 8:
`img_feature_norm` [1 x 128 x H/8 x W/8] and `pc_feature_norm` [128 x N4] (the coarse descriptors, unit length),
`coarse_img_score` [1 x 1 x H/8 x W/8] and `coarse_pc_score` [1 x 1 x N4] (overlap scores in (0, 1)),
`fine_img_feature_patch` ('train'/'val': [n x 64 x 4 x 4]; 'test': [n x 64 x 16]) and `fine_pc_inline_feature`
[n x 64] (the fine descriptors, unit length), `fine_center_xy` (float [2 x n], x and y of the patch centres on the
stride-2 map; None unless 'test') and `coarse_pc_points` (float [n x 3], the selected super-points; None unless
'test'). evaluation/eval_all.py turns the 'test' outputs into 2D-3D pairs for solvePnPRansac.

'test' mode's coarse selection (network.py:145-161, `fine_process`, `point2node`, `extract_patch`): super-points
scoring >= 0.9 (lowered by 0.02 until at least 4 survive) each take the super-pixel of least cosine distance; pairs
whose super-pixel lies outside x in [2, 62], y in [2, 18] are dropped; each super-point's nearest stage-1 point gives
the fine point descriptor, and the 4 x 4 patch of the stride-2 map around 4 x the super-pixel the fine pixel
descriptors. Where their loop would never end (fewer than 4 pairs even at threshold <= 0) this one raises.
`trace`, when given, receives every intermediate tensor by name (tools/reference/cofii2p.py records the same names).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .image import ImageEncoder, ImageUpSample
from .points import KPConvFPN
from .transformer import LocalFeatureTransformer, PositionEmbeddingCoordsSine

SCORE_START, SCORE_STEP, MIN_PAIRS = 0.9, 0.02, 4  # network.py:147-151 (PnP needs 4 pairs)
BORDER = (2, 62, 2, 18)  # network.py:184: x_min, x_max, y_min, y_max of a kept super-pixel (KITTI's 64 x 20 map)
PATCH = 4  # network.py:206 extract_patch size
FINE_PER_COARSE = 4  # network.py:156: stride-8 cell -> stride-2 pixel
DISTANCE_CHUNK = 64  # super-points per block of the cosine distances (memory; the same sums as theirs)
IMAGE_MAPS = ("img_s2", "img_s4", "img_s8_raw", "img_s16", "img_s32", "img_global")


def score_head(conv: type[nn.Module], norm: type[nn.Module]) -> nn.Sequential:
    """their pc/img_score_layer: 1x1 convs 128 -> 128 -> 64 -> 1, instance norm and ReLU between, a sigmoid."""
    return nn.Sequential(
        conv(128, 128, 1, bias=False), norm(128), nn.ReLU(),
        conv(128, 64, 1, bias=False), norm(64), nn.ReLU(),
        conv(64, 1, 1, bias=False), nn.Sigmoid(),
    )  # fmt: skip


class CoFiI2PNetwork(nn.Module):
    """the authors' `CoFiI2P` (module docstring). Left out, as their forward never uses them: `img_feature_layer`,
    `fine_img_pos_encoding`, `fine_pc_pos_encoding` and the ResNet's `fc` (official/importer.py drops their keys).
    `seed` draws the KPConv kernel dispositions of a network built without a checkpoint."""

    def __init__(self, seed: int = 0) -> None:
        super().__init__()
        self.img_encoder = ImageEncoder()
        self.pc_encoder = KPConvFPN(4, 64, 64, seed)
        self.pc_feature_layer = nn.Sequential(
            nn.Linear(2048, 1024, bias=False), nn.LayerNorm(1024), nn.ReLU(),
            nn.Linear(1024, 512, bias=False), nn.LayerNorm(512), nn.ReLU(), nn.Linear(512, 128, bias=False),
        )  # fmt: skip
        self.img_pos_encoding = PositionEmbeddingCoordsSine(2, 128)
        self.pc_pos_encoding = PositionEmbeddingCoordsSine(3, 128)
        self.transformer = LocalFeatureTransformer(128, 4)
        self.img_upsample_1 = ImageUpSample(128 + 64, 128)
        self.img_upsample_2 = ImageUpSample(128 + 64, 64)
        self.pc_score_layer = score_head(nn.Conv1d, nn.InstanceNorm1d)
        self.img_score_layer = score_head(nn.Conv2d, nn.InstanceNorm2d)

    def forward(
        self, pc_data_dict: dict, img: torch.Tensor, fine_center_kpt_coors: torch.Tensor | None = None,
        fine_xy: torch.Tensor | None = None, fine_pc_inline_index: torch.Tensor | None = None, mode: str = "test",
        trace: dict | None = None,
    ) -> tuple:  # fmt: skip
        trace = {} if trace is None else trace
        coarse = self.coarse(pc_data_dict, img, trace)
        fine_pc, fine_map = trace["pc_decode_3"], trace["img_upsample_s2"]
        if mode in ("train", "val"):
            patches = extract_patches(fine_map, fine_center_kpt_coors)
            return (*coarse, patches, fine_pc[fine_pc_inline_index], None, None)
        if mode != "test":
            raise ValueError(f"CoFiI2P forward: mode {mode!r} is none of 'train', 'val', 'test'")
        img_feature_norm, pc_feature_norm, _, coarse_pc_score = coarse
        coarse_xy, chosen = select_pairs(coarse_pc_score, pc_feature_norm, img_feature_norm, trace)
        coarse_pc_points = pc_data_dict["points"][-1][chosen]
        trace["coarse_pc_index"] = nearest_point(pc_data_dict["points"][1], coarse_pc_points)
        fine_center_xy = coarse_xy * FINE_PER_COARSE
        patches = extract_patches(fine_map, fine_center_xy).flatten(2)
        return (*coarse, patches, fine_pc[trace["coarse_pc_index"]], fine_center_xy, coarse_pc_points)

    def coarse(self, data: dict, img: torch.Tensor, trace: dict) -> tuple[torch.Tensor, ...]:
        """both branches, the transformer and the heads -> (img_feature_norm, pc_feature_norm, coarse_img_score,
        coarse_pc_score); the fine maps go to `trace` (pc_decode_3, img_upsample_s2)."""
        pc_levels = self.pc_encoder(data, trace)
        maps = self.img_encoder(img)
        trace.update(zip(IMAGE_MAPS, maps, strict=True))
        trace["pc_decode_3"] = F.normalize(pc_levels[0], dim=1)
        trace["pc_feature_layer"] = self.pc_feature_layer(pc_levels[-1])
        img_s8 = trace["img_s8"] = F.normalize(maps[2], dim=1)
        image_mid, pc_mid = self.attend(img_s8, F.normalize(trace["pc_feature_layer"], dim=1), data["points"][-1],
                                        trace)  # fmt: skip
        trace["pc_score_layer"] = coarse_pc_score = self.pc_score_layer(pc_mid)
        trace["img_score_layer"] = coarse_img_score = self.img_score_layer(image_mid)
        trace["img_upsample_1"] = up4 = self.img_upsample_1(img_s8, maps[1])
        trace["img_upsample_2"] = self.img_upsample_2(up4, maps[0])
        trace["img_upsample_s2"] = F.normalize(trace["img_upsample_2"], dim=1)
        return F.normalize(image_mid, dim=1), F.normalize(pc_mid.squeeze(), dim=0), coarse_img_score, coarse_pc_score

    def attend(self, img_s8: torch.Tensor, pc_coarse: torch.Tensor, nodes: torch.Tensor, trace: dict):
        """position-encoded stride-8 pixels and super-points through the transformer -> (image [1 x 128 x h x w],
        points [1 x 128 x N4]). The pixel grid is (row, column), the stride-8 map's own size (theirs: options
        img_H / 8 x img_W / 8, the same for the options' image size)."""
        _, channels, h, w = img_s8.shape
        rows, cols = torch.meshgrid(torch.arange(h, device=img_s8.device), torch.arange(w, device=img_s8.device),
                                    indexing="ij")  # fmt: skip
        trace["img_pos"] = self.img_pos_encoding(torch.stack([rows, cols], -1).reshape(1, h * w, 2))
        trace["pc_pos"] = self.pc_pos_encoding(nodes[None])
        image = img_s8.flatten(2).transpose(1, 2) + trace["img_pos"]
        image, points = self.transformer(image, pc_coarse[None] + trace["pc_pos"], trace)
        return image.transpose(1, 2).reshape(1, channels, h, w), points.transpose(1, 2)


def select_pairs(score: torch.Tensor, pc_desc: torch.Tensor, img_desc: torch.Tensor, trace: dict | None = None):
    """their 'test' loop over `fine_process`: (x, y) float [2 x n] of each kept super-point's super-pixel and the
    super-points' indices [n]; `trace` gets the threshold that was reached."""
    threshold = SCORE_START
    while True:
        if threshold < -SCORE_STEP:
            raise ValueError(
                f"CoFiI2P test mode: fewer than {MIN_PAIRS} super-points match a super-pixel inside x {BORDER[:2]}, "
                f"y {BORDER[2:]} at any score threshold (the authors' loop never ends)"
            )
        xy, chosen = pairs_above(score, pc_desc, img_desc, threshold)
        if chosen.numel() >= MIN_PAIRS:
            break
        threshold -= SCORE_STEP
    if trace is not None:
        trace["score_threshold"] = torch.tensor(threshold)
        trace["pc_inline_index"] = chosen
    return xy, chosen


def pairs_above(score: torch.Tensor, pc_desc: torch.Tensor, img_desc: torch.Tensor, threshold: float):
    """`fine_process`: the super-points scoring >= threshold, each with its least-cosine-distance super-pixel,
    kept when that super-pixel lies inside BORDER -> (xy float [2 x n], indices [n])."""
    chosen = torch.where(score.squeeze() >= threshold)[0]
    pixels = img_desc.squeeze(0).flatten(1)  # C x hw
    selected = pc_desc[:, chosen]
    nearest = torch.cat([
        (1 - (pixels[:, :, None] * block[:, None]).sum(0)).argmin(0)
        for block in selected.split(DISTANCE_CHUNK, dim=1)
    ]) if chosen.numel() else chosen  # fmt: skip
    w = img_desc.shape[-1]
    xy = torch.stack([nearest % w, nearest.div(w, rounding_mode="floor")]).to(pc_desc.dtype)
    x_min, x_max, y_min, y_max = BORDER
    inside = (xy[0] >= x_min) & (xy[0] <= x_max) & (xy[1] <= y_max) & (xy[1] >= y_min)
    return xy[:, inside], chosen[inside]


def nearest_point(cloud: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
    """`point2node`: index of each query's nearest point of `cloud` [N x 3], by their expanded squared distance
    (|q|^2 + |p|^2 - 2 q.p, clamped at 1e-12) and its smallest-first top-1 -> [n] int64."""
    squared = -2.0 * queries @ cloud.T
    squared = squared + queries.pow(2).sum(-1)[:, None] + cloud.pow(2).sum(-1)[None]
    return squared.clamp(min=1e-12).topk(1, dim=-1, largest=False)[1].squeeze(-1)


def extract_patches(fmap: torch.Tensor, centres: torch.Tensor, size: int = PATCH) -> torch.Tensor:
    """`extract_patch`: the size x size window of fmap [1 x C x H x W] from floor(centre - size/2) (x, y) of each
    centre [2 x n] -> [n x C x size x size]; a window reaching outside the map is refused (theirs asserts)."""
    corner = torch.floor(centres - size / 2).long()
    _, _, h, w = fmap.shape
    outside = (corner[0] < 0) | (corner[1] < 0) | (corner[0] + size > w) | (corner[1] + size > h)
    if outside.any():
        bad = centres[:, outside.nonzero()[0, 0]].tolist()
        raise ValueError(f"CoFiI2P: the {size} x {size} patch at centre {bad} reaches outside the {w} x {h} map")
    steps = torch.arange(size, device=fmap.device)
    rows = (corner[1][:, None] + steps)[:, :, None]
    cols = (corner[0][:, None] + steps)[:, None, :]
    return fmap[0][:, rows, cols].transpose(0, 1)
