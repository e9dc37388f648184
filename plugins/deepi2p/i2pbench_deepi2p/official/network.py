"""DeepI2P's classifier (the authors' `KeypointDetector`, models/networks_united.py): per point, 2 frustum scores
(outside / inside the camera's view) and one score per fine image cell (80 cells of 32 px on the 160 x 512 input).

The point and image features meet by attention: each node scores the image's cells from its own and the image's
global feature, takes the score-weighted mean of the cell features, and the fused node features are interpolated
back to the points (3 nearest nodes, weights 1 - d / sum d).
"""

from __future__ import annotations

import torch
from torch import nn

from .blocks import PointMLP, interpolate, nearest
from .image import ResNet34
from .points import PointEncoder


class ImageEncoder(nn.Module):
    """the authors' wrapper: `backbone` is the ResNet-34 (their state dict's `img_encoder.backbone.*`)."""

    def __init__(self) -> None:
        super().__init__()
        self.backbone = ResNet34()

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.backbone(image)


def attend(scores: torch.Tensor, cells: torch.Tensor) -> torch.Tensor:
    """[B x L x M] node scores over [B x C x L] cell features -> [B x C x M] their score-weighted mean."""
    return (cells[:, :, :, None] * scores[:, None]).mean(dim=2)


class DeepI2PNetwork(nn.Module):
    """pc, intensity, sn [B x 3|1|3 x N], node_a, node_b [B x 3 x M], image [B x 3 x H x W] (0-255) ->
    coarse [B x 2 x N], fine [B x (H/32 * W/32) x N] scores, and every intermediate under the authors' names."""

    def __init__(
        self, image_hw: tuple[int, int] = (160, 512), cell_px: int = 32, k_interp_ab: int = 3, k_interp_b: int = 3
    ) -> None:
        super().__init__()
        self.k_interp_ab, self.k_interp_b = k_interp_ab, k_interp_b
        cells = round(image_hw[0] / cell_px) * round(image_hw[1] / cell_px)
        self.pc_encoder = PointEncoder()
        self.img_encoder = ImageEncoder()
        self.node_b_attention_pn = PointMLP(256 + 512, (256, cells), plain_last=True)
        self.node_b_pn = PointMLP(256 + 512 + 512 + 512, (1024, 512, 512), plain_last=True)
        self.node_a_attention_pn = PointMLP(64 + 512, (256, 4 * cells), plain_last=True)
        self.node_a_pn = PointMLP(64 + 256 + 512, (512, 128, 128), plain_last=True)
        self.per_point_pn = PointMLP(32 + 64 + 128 + 512, (256, 256, 2 + cells), True, dropout=(0.5, 0.5, 0))

    def forward(
        self, pc: torch.Tensor, intensity: torch.Tensor, sn: torch.Tensor, node_a: torch.Tensor,
        node_b: torch.Tensor, image: torch.Tensor,
    ) -> dict[str, torch.Tensor]:  # fmt: skip
        out = self.pc_encoder(pc, intensity, sn, node_a, node_b)
        s16, s32, image_global = self.img_encoder(image)
        out |= {"img_s16_feature_map": s16, "img_s32_feature_map": s32, "img_global_feature": image_global}
        glob = image_global[:, :, :, 0]
        node_a_f, node_b_f = out["node_a_features"], out["node_b_features"]

        b_scores = self.node_b_attention_pn(torch.cat([node_b_f, glob.expand(-1, -1, node_b.shape[2])], dim=1))
        b_image = attend(b_scores, s32.flatten(2))
        b_inputs = [node_b_f, out["global_feature"].expand(-1, -1, node_b.shape[2]), b_image]
        up_b = self.node_b_pn(torch.cat([*b_inputs, glob.expand(-1, -1, node_b.shape[2])], dim=1))
        point_b = interpolate(nearest(pc, node_b, self.k_interp_b), pc, node_b, up_b)

        a_scores = self.node_a_attention_pn(torch.cat([node_a_f, glob.expand(-1, -1, node_a.shape[2])], dim=1))
        a_image = attend(a_scores, s16.flatten(2))
        a_from_b = interpolate(nearest(node_a, node_b, self.k_interp_ab), node_a, node_b, up_b)
        up_a = self.node_a_pn(torch.cat([node_a_f, a_from_b, a_image], dim=1))
        point_a = interpolate(out["node_a_min_k_idx"], pc, node_a, up_a)

        scores = self.per_point_pn(torch.cat([point_a, point_b, out["first_pn_out"], out["second_pn_out"]], dim=1))
        out |= {
            "node_b_attention_score": b_scores, "node_b_weighted_img_s32_feature_map": b_image,
            "up_node_b_features": up_b, "interp_pb_weighted_node_b_features": point_b,
            "node_a_attention_score": a_scores, "node_a_weighted_img_s16_feature_map": a_image,
            "interp_ab_weighted_node_b_features": a_from_b, "up_node_a_features": up_a,
            "interp_pa_weighted_node_a_features": point_a, "pc_label_scores": scores,
        }  # fmt: skip
        return out | {"coarse_scores": scores[:, :2], "fine_scores": scores[:, 2:]}
