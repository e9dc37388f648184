"""The official network on a reference folder's inputs (tools/reference/cofii2p.py made it with the authors' code):
every tensor the folder records, under its names, from our modules: the forward in 'val' mode (its patches and
train.py's losses) and in 'test' mode (the outputs and the coarse selection), as the script ran theirs.
tests/test_cofii2p_reference.py compares them; the same forward is what a timing against the authors' code runs."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from .loss import training_loss
from .network import CoFiI2PNetwork

STAGES = 5  # preprocess_data.py num_stages
NETWORK_OUTPUTS = (  # the forward's tuple, in order
    "img_feature_norm", "pc_feature_norm", "coarse_img_score", "coarse_pc_score",
    "fine_img_feature_patch", "fine_pc_inline_feature", "fine_center_xy", "coarse_pc_points",
)  # fmt: skip
ANCHORS = ("pc_kpt_idx", "pc_outline_idx", "coarse_img_kpt_idx", "K_4", "P", "fine_xy", "fine_center_kpt_coors")


def pyramid(inputs: Mapping[str, np.ndarray]) -> dict[str, list[torch.Tensor] | torch.Tensor]:
    """the recorded pc_data_dict (`points_i`, `neighbors_i`, `subsampling_i`, `upsampling_i`, `feats`)."""

    def stack(key: str, count: int, dtype: torch.dtype) -> list[torch.Tensor]:
        return [torch.from_numpy(inputs[f"{key}_{i}"]).to(dtype) for i in range(count)]

    return {
        "points": stack("points", STAGES, torch.float32),
        "neighbors": stack("neighbors", STAGES, torch.long),
        "subsampling": stack("subsampling", STAGES - 1, torch.long),
        "upsampling": stack("upsampling", STAGES - 1, torch.long),
        "feats": torch.from_numpy(inputs["feats"]),
    }


def image_tensor(image: np.ndarray) -> torch.Tensor:
    """[H x W x 3] uint8 RGB -> the network's [1 x 3 x H x W] float input (RGB / 255, as kitti.py:374)."""
    return torch.from_numpy(image.astype(np.float32) / 255.0).permute(2, 0, 1)[None].contiguous()


@torch.no_grad()
def reference_forward(net: CoFiI2PNetwork, inputs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """net (eval mode) on the recorded inputs -> every recorded tensor by name, whole."""
    data, image = pyramid(inputs), image_tensor(inputs["image"])
    t = {k: torch.from_numpy(np.asarray(inputs[k])) for k in (*ANCHORS, "fine_pc_inline_index")}
    trace: dict[str, torch.Tensor] = {}
    val = net(data, image, t["fine_center_kpt_coors"], t["fine_xy"], t["fine_pc_inline_index"], "val", trace)
    tensors = {f"val.{k}": v for k, v in zip(NETWORK_OUTPUTS[4:6], val[4:6], strict=True)}
    tensors |= training_loss(val, {k: t[k] for k in ANCHORS}, data["points"][-1])
    test = net(data, image, None, None, None, "test", trace)
    tensors |= trace | dict(zip(NETWORK_OUTPUTS, test, strict=True))
    return {k: v.numpy() for k, v in tensors.items()}
