"""The seeded weight recipe of the official reference sets (../shared/data/edgeregnet_reference/README.md,
'Weights'): every tensor drawn from numpy's generator seeded by `crc32(key + salt)`, so the authors' network and
ours load the same weights from a list of keys and shapes, and a set records only that list and a sha256. One recipe
for every method's set (EdgeRegNet, CorrI2P, DeepI2P, VP2P-Match), its tests, tools/reference/ and the benchmarks.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch


def recipe_value(key: str, shape: tuple[int, ...], salt: str = "") -> np.ndarray:
    """one tensor of the recipe, float32 (int64 zeros for `num_batches_tracked`)."""
    rng = np.random.default_rng(zlib.crc32((key + salt).encode()))
    if key.endswith("num_batches_tracked"):
        return np.zeros(shape, np.int64)
    if key.endswith("running_mean"):
        value = 0.1 * rng.standard_normal(shape)
    elif key.endswith("running_var"):
        value = 0.5 + rng.random(shape)
    elif key.endswith("weight") and len(shape) == 1:
        value = 1 + 0.1 * rng.standard_normal(shape)
    elif key.endswith("bias"):
        value = 0.05 * rng.standard_normal(shape)
    elif key.endswith("kernel"):  # torchsparse's [K^3 x C_in x C_out] (or [C_in x C_out]): fan-in before the last
        value = rng.standard_normal(shape) / np.sqrt(np.prod(shape[:-1]))
    else:
        value = rng.standard_normal(shape) / np.sqrt(np.prod(shape[1:]))
    return value.astype(np.float32)


def recipe_state(shapes: Mapping[str, Sequence[int]], salt: str = "") -> tuple[dict[str, torch.Tensor], str]:
    """the state dict of `shapes` (key -> shape, in order) by the recipe, and the sha256 of its tensors'
    little-endian bytes in that order."""
    digest, state = hashlib.sha256(), {}
    for key, shape in shapes.items():
        value = recipe_value(key, tuple(shape), salt)
        digest.update(value.astype(value.dtype.newbyteorder("<")).tobytes())
        state[key] = torch.from_numpy(value)
    return state, digest.hexdigest()


def folder_state(folder: Path) -> tuple[dict[str, torch.Tensor], str]:
    """a reference set's state dict, regenerated from its `state_dict_shapes.json` and the salt in `meta.json`."""
    shapes = json.loads((folder / "state_dict_shapes.json").read_text())
    return recipe_state(shapes, json.loads((folder / "meta.json").read_text()).get("salt", ""))
