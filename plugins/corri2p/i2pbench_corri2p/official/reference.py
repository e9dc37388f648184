"""The official network on a reference folder's inputs (tools/reference/corri2p.py made it with the authors' code):
every tensor the folder records, under its names, from our modules. tests/test_corri2p_reference.py compares them;
benchmarks/against_authors.py --method corri2p times the same forward."""

from __future__ import annotations

import numpy as np
import torch

from .loss import training_loss
from .network import CorrI2PNet

NETWORK_INPUTS = ("pc", "intensity", "sn", "node_a", "node_b")
ANCHORS = ("pc", "pc_kpt_idx", "pc_outline_idx", "img_kpt_idx", "img_outline_idx", "K", "P")


def image_tensor(image: np.ndarray) -> torch.Tensor:
    """[H x W x 3] uint8 RGB -> the network's [1 x 3 x H x W] float input (RGB / 255, as the authors' loader)."""
    return torch.from_numpy(image.astype(np.float32) / 255.0).permute(2, 0, 1)[None].contiguous()


@torch.no_grad()
def reference_forward(net: CorrI2PNet, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """net (eval mode) on the recorded inputs -> every recorded tensor (batch dimension dropped)."""
    t = {k: torch.from_numpy(inputs[k])[None] for k in NETWORK_INPUTS}
    trace: dict[str, torch.Tensor] = {}
    out = net(t["pc"], t["intensity"], t["sn"], image_tensor(inputs["image"]), t["node_a"], t["node_b"], trace)
    anchors = {k: torch.from_numpy(np.asarray(inputs[k])) for k in ANCHORS}
    losses = training_loss(out, anchors)
    tensors = {k: v[0] for k, v in (trace | out).items()} | losses
    return {k: v.numpy() for k, v in tensors.items()}
