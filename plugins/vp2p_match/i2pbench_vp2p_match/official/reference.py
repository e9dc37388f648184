"""Reference vectors of the authors' VP2P-Match (a folder made by tools/reference/vp2p.py): the official modules'
forward on the recorded inputs, under the folder's names, with the weights of `i2pbench.testing.recipe`.
tests/test_vp2p_reference.py compares them."""

from __future__ import annotations

import numpy as np
import torch

from .image import ImageResNet
from .network import VP2PMatchNet
from .points import PointsEncoder
from .spvcnn import SPVCNN, voxel_coordinates


def voxel_branch_inputs(inputs: dict[str, np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    """the authors' voxel-branch input: [N x 7] (x, y, z, intensity, normal) and [N x 4] voxel coordinates."""
    pc, intensity, sn = (torch.from_numpy(inputs[k]).unsqueeze(0) for k in ("pc", "intensity", "sn"))
    feats = torch.cat([pc, intensity, sn], dim=1).transpose(2, 1).reshape(-1, 7)
    return feats, voxel_coordinates(pc)


def loaded(module: torch.nn.Module, state: dict[str, torch.Tensor], prefix: str) -> torch.nn.Module:
    """`module` in eval mode with the `prefix`ed part of the authors' state dict (strictly: every key used)."""
    module.load_state_dict({k.removeprefix(prefix): v for k, v in state.items() if k.startswith(prefix)})
    return module.eval()


def image_branch_forward(state: dict[str, torch.Tensor], inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """the official image branch with the `resnet.*` weights (VP2PMatchNet's name): the folder's `image_branch.*`."""
    branch = loaded(ImageResNet(), state, "resnet.")
    with torch.no_grad():
        trace = branch.trace(torch.from_numpy(inputs["img"]).unsqueeze(0))
    return {f"image_branch.{k}": v[0].numpy() for k, v in trace.items()}


def point_branch_forward(state: dict[str, torch.Tensor], inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """the official point branch with the `point_transformer.*` weights: the folder's `point_branch.*`."""
    branch = loaded(PointsEncoder(), state, "point_transformer.")
    cloud = torch.from_numpy(np.concatenate([inputs["pc"], inputs["intensity"], inputs["sn"]])).unsqueeze(0)
    with torch.no_grad():
        trace = branch.trace(cloud)
    return {f"point_branch.{k}": v[0].numpy() for k, v in trace.items()}


def voxel_branch_forward(state: dict[str, torch.Tensor], inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """the official voxel branch in eval mode with the `voxel_branch.*` weights: the folder's `voxel_branch.*`."""
    prefix = "voxel_branch."
    branch = loaded(SPVCNN(), state, prefix)
    feats, coords = voxel_branch_inputs(inputs)
    with torch.no_grad():
        trace = branch.trace(feats, coords)
        global_feat, pointwise = branch(feats, coords, 1)
    trace["pointwise"], trace["global"] = pointwise[0], global_feat[0]
    return {prefix + k: v.numpy() for k, v in trace.items()}


def network_forward(state: dict[str, torch.Tensor], inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """the whole official network with the whole state dict (strictly): the folder's `network.*`."""
    net = loaded(VP2PMatchNet(), state, "")
    tensors = [torch.from_numpy(inputs[k]).unsqueeze(0) for k in ("pc", "intensity", "sn", "img")]
    with torch.no_grad():
        trace = net.trace(*tensors)
    return {f"network.{k}": v[0].numpy() for k, v in trace.items()}
