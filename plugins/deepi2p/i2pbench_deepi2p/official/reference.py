"""The official network on a reference set made by tools/reference/deepi2p.py (the authors' KeypointDetector on one
KITTI frame): every tensor the set records, under its names and layouts (batch dropped, channels first), and the
authors' training losses and accuracies. tests/test_deepi2p_reference.py compares them.
"""

from __future__ import annotations

import numpy as np
import torch

from .loss import labels, training_loss
from .network import DeepI2PNetwork

INPUTS = ("pc", "intensity", "sn", "node_a", "node_b", "img")


@torch.no_grad()
def reference_forward(network: DeepI2PNetwork, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """the network (eval mode) on the recorded inputs -> {name: array} as the set's outputs.npz names them."""
    network.eval()
    batch = {k: torch.from_numpy(inputs[k])[None] for k in (*INPUTS, "P", "K")}
    out = network(*(batch[k] for k in INPUTS))
    inside, cell = labels(batch["pc"], batch["P"], batch["K"], tuple(inputs["img"].shape[1:]))
    loss = training_loss(out["coarse_scores"], out["fine_scores"], inside, cell)
    arrays = {k: v[0].numpy() for k, v in out.items() if k != "pc_label_scores"}
    coarse_hit = (out["coarse_scores"].argmax(dim=1) == inside).float().mean()
    fine_hit = (out["fine_scores"].argmax(dim=1)[inside] == cell[inside]).float().mean()
    arrays |= {"accuracy_coarse_accuracy": coarse_hit.numpy(), "accuracy_fine_accuracy": fine_hit.numpy()}
    return arrays | {f"loss_{k}": v.numpy() for k, v in loss.items()}
