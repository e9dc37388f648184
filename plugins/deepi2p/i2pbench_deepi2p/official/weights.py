"""Import of the authors' checkpoint (lijx10/DeepI2P: `torch.save` of KeypointDetector's state dict, with `module.`
prefixes when saved from DataParallel) onto the official network.

Our module names are the authors' (the checkpoint layout is the interface), so the mapping only strips `module.`
and drops the ResNet's ImageNet `fc.*`, which the network never reads. Any other key that does not fit, or a shape
that differs, is refused by name.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Mapping
from pathlib import Path

import torch

from i2pbench.api import ImportedWeights

from .network import DeepI2PNetwork

UNUSED = re.compile(r"img_encoder\.backbone\.fc\.(weight|bias)")


def to_network(
    state: Mapping[str, torch.Tensor], expected: Mapping[str, torch.Tensor], source: str
) -> dict[str, torch.Tensor]:
    """the authors' state dict -> ours (prefixes stripped, `fc` dropped), refused with the misfitting keys named."""
    ours = {}
    for key, value in state.items():
        name = key.removeprefix("module.")
        if not UNUSED.fullmatch(name):
            ours[name] = value
    ImportedWeights.require_fit(ours, expected, f"{source} is not the authors' DeepI2P KeypointDetector state dict")
    return ours


RELEASES = {  # image size -> what the authors' checkpoints at that size were trained on (README.md, issue #2)
    (160, 512): "KITTI odometry 00-08 (the authors' KITTI weights are lost: lijx10/DeepI2P issue #2)",
    (384, 640): "Oxford RobotCar (the authors' released coarse + fine classification model, README.md)",
}


def import_official(path: Path, image_hw: tuple[int, int] = (160, 512)) -> tuple[DeepI2PNetwork, dict[str, str]]:
    """the authors' checkpoint loaded into the official network for their input size (KITTI 160 x 512, Oxford
    384 x 640) -> (network, record: file, sha256, what it was trained on)."""
    network = DeepI2PNetwork(image_hw)
    network.load_state_dict(to_network(ImportedWeights.read(path), network.state_dict(), str(path)))
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return network, {"file": Path(path).name, "sha256": digest, "trained_on": RELEASES.get(tuple(image_hw), "")}
