"""The one part of CorrI2P's and DeepI2P's networks whose structure ours shares: their ResNet-34 image encoder
(torchvision's layout, `img_encoder.backbone.*` in both authors' state dicts). tests/data/peer_resnet34 holds what the
authors' own code computed with seeded weights on a real KITTI crop (its README says how); our paper-size encoders,
given the same weights under the key mapping below and BatchNorm in place of our GroupNorm, must compute it. What
GroupNorm and our input normalisation change, measured: docs/methods.md, "Against the authors' code"."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from i2pbench_corri2p.image import CorrI2PImageEncoder
from i2pbench_deepi2p.image import DeepI2PImageEncoder
from torch import nn

from i2pbench.testing.recipe import recipe_value

REFERENCE = Path(__file__).parent / "data" / "peer_resnet34" / "reference.npz"
PREFIX = "img_encoder.backbone."  # both authors' state dicts
NORMS = {"norm1": "bn1", "norm2": "bn2"}


def peer_key(ours: str) -> str | None:
    """our encoder key -> the authors' (torchvision ResNet-34 names); None for our heads, which they lack."""
    part = ours.split(".")
    if part[0] == "stem":
        return PREFIX + {"0": "conv1", "1": "bn1"}[part[1]] + "." + part[2]
    if part[0] != "stages":
        return None
    block = f"layer{int(part[1]) + 1}.{part[2]}."
    if part[3] == "shortcut":
        return PREFIX + block + "downsample." + ".".join(part[4:])
    return PREFIX + block + NORMS.get(part[3], part[3]) + "." + ".".join(part[4:])


def with_peer_weights(encoder: nn.Module, mapping=peer_key) -> nn.Module:
    """a copy of `encoder` holding the recipe's weights under the authors' keys, its GroupNorms replaced by
    BatchNorm2d (eval) with the recipe's statistics, as the authors' layers are."""
    encoder = copy.deepcopy(encoder).eval()
    state = encoder.state_dict()
    state |= {k: torch.from_numpy(recipe_value(mapping(k), tuple(v.shape))) for k, v in state.items() if mapping(k)}
    encoder.load_state_dict(state)
    for path, parent in list(encoder.named_modules()):
        for name, child in list(parent.named_children()):
            full = f"{path}.{name}" if path else name
            if isinstance(child, nn.GroupNorm) and mapping(full + ".weight"):
                bn = nn.BatchNorm2d(child.num_channels).eval()
                base = mapping(full + ".weight")[: -len("weight")]
                bn.load_state_dict(
                    {s: torch.from_numpy(recipe_value(base + s, tuple(t.shape))) for s, t in bn.state_dict().items()}
                )
                setattr(parent, name, bn)
    return encoder


def maps(encoder: nn.Module, image: torch.Tensor) -> dict[str, torch.Tensor]:
    """the authors' encoder outputs from our stages, on their input (RGB / 255, no normalisation)."""
    x = encoder.stages[0](F.max_pool2d(encoder.stem(image), 3, 2, 1))
    s16 = encoder.stages[2](encoder.stages[1](x))
    s32 = encoder.stages[3](s16)
    return {"s16": s16[0], "s32": s32[0], "pooled": s32[0].mean((1, 2))}


@pytest.fixture(scope="module")
def reference() -> dict[str, np.ndarray]:
    with np.load(REFERENCE) as data:
        return dict(data)


def worst(encoder: nn.Module, ref: dict[str, np.ndarray]) -> float:
    image = torch.from_numpy(ref["image"]).permute(2, 0, 1)[None].float() / 255.0
    with torch.no_grad():
        out = maps(encoder, image)
    return max(float(np.abs(out[k].numpy() - ref[k]).max() / np.abs(ref[k]).max()) for k in out)


@pytest.mark.parametrize("cls", [CorrI2PImageEncoder, DeepI2PImageEncoder])
def test_peer_reference_resnet34_equal_with_batchnorm(cls, reference):
    torch.manual_seed(0)
    assert worst(with_peer_weights(cls()), reference) < 1e-4


def test_peer_reference_resnet34_fails_on_a_wrong_mapping(reference):
    def swapped(key: str) -> str | None:  # conv1 and conv2 of one block exchanged: same shapes, another function
        mapped = peer_key(key)
        if mapped and "layer3.1.conv" in mapped:
            return mapped.replace("conv1", "convX").replace("conv2", "conv1").replace("convX", "conv2")
        return mapped

    assert worst(with_peer_weights(CorrI2PImageEncoder(), swapped), reference) > 1e-2
