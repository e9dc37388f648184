"""Import of the authors' checkpoint (lijx10/DeepI2P: `torch.save` of KeypointDetector's state dict, with `module.`
prefixes when saved from DataParallel) onto the official network.

Our module names are the authors' (the checkpoint layout is the interface), so the mapping only strips `module.`
and drops the ResNet's ImageNet `fc.*`, which the network never reads. Any other key that does not fit, or a shape
that differs, is refused by name.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

import torch

from i2pbench.api import WeightsError

UNUSED = re.compile(r"img_encoder\.backbone\.fc\.(weight|bias)")


def to_network(state: Mapping[str, torch.Tensor], expected: Mapping[str, torch.Tensor], source: str):
    """the authors' state dict -> ours (prefixes stripped, `fc` dropped), refused with the misfitting keys named."""
    ours = {}
    for key, value in state.items():
        name = key.removeprefix("module.")
        if not UNUSED.fullmatch(name):
            ours[name] = value
    problems = [f"unexpected key {k}" for k in ours if k not in expected]
    problems += [f"missing key {k}" for k in expected if k not in ours]
    problems += [
        f"key {k}: shape {tuple(v.shape)}, expected {tuple(expected[k].shape)}"
        for k, v in ours.items()
        if k in expected and v.shape != expected[k].shape
    ]
    if problems:
        shown = "; ".join(problems[:12]) + (f"; and {len(problems) - 12} more" if len(problems) > 12 else "")
        raise WeightsError(f"{source} is not the authors' DeepI2P KeypointDetector state dict: {shown}")
    return ours
