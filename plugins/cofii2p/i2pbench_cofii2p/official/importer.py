"""`i2pbench weights import cofii2p-official FILE`: a state dict of the authors' `CoFiI2P` (train.py:334 saves
`model.state_dict()`; eval_all.py:252 loads the same; `module.`-prefixed keys when it was wrapped in DataParallel) as
the official size's weights: the matcher stage, whose network (`CoFiI2PNetwork`, the authors' module names) sits
under `net.`.

Four modules of theirs are built but never used by their forward, and are dropped with their keys (recorded in the
import's meta): the ResNet's ImageNet classifier `img_encoder.backbone.fc`, `img_feature_layer` (network.py:31, its
use commented out at :120), `fine_img_pos_encoding` and `fine_pc_pos_encoding` (network.py:36-37, never called).
Every KPConv's `kernel_points` buffer is kept: the disposition the weights were trained with. A key no rule maps, a
missing key or a shape that does not fit is refused by name (ImportedWeights.require_fit).

The authors release two files (README "Evaluation": OneDrive and Baidu Disk links): one trained on KITTI Odometry
(sequences 00-08, data/kitti.py) and one on nuScenes (v1.0 trainval, data/nuscenes.py). Both have the same keys and
shapes (no layer depends on the image size), so the file's name is all that tells them apart: the import records
the dataset its name says, or that it does not say.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import torch

from i2pbench.api import ImportedWeights

from .network import CoFiI2PNetwork

SIZE = "official"
STAGE = "matcher"
PREFIX = "net."
UNUSED = re.compile(r"(img_encoder\.backbone\.fc|img_feature_layer|fine_img_pos_encoding|fine_pc_pos_encoding)\..+")
RELEASES = {"kitti": "KITTI Odometry sequences 00-08", "nuscenes": "nuScenes v1.0 trainval"}


def ours(key: str) -> str | None:
    """an authors' key -> our network's key (their names, any `module.` prefix stripped); None for an unused one."""
    key = key.removeprefix("module.")
    return None if UNUSED.fullmatch(key) else key


def split(state: Mapping[str, torch.Tensor]) -> tuple[dict[str, torch.Tensor], list[str]]:
    """authors' state dict -> (the matcher stage's state dict, the unused keys dropped)."""
    kept, dropped = {}, []
    for key, value in state.items():
        target = ours(key)
        if target is None:
            dropped.append(key.removeprefix("module."))
        else:
            kept[PREFIX + target] = value
    return kept, sorted(dropped)


def trained_on(path: Path) -> dict[str, str]:
    """what the file's name says it was trained on (the two releases share every key and shape)."""
    name = path.name.lower()
    found = [dataset for key, dataset in RELEASES.items() if key in name]
    said = found[0] if len(found) == 1 else "not said by the file name (the authors release KITTI and nuScenes files)"
    return {"release": f"CoFiI2P authors' weights, user-supplied; trained on: {said}"}


def import_official(path: Path) -> ImportedWeights:
    """a state dict of the authors' CoFiI2P as the official size's weights."""
    path = Path(path)
    state, dropped = split(ImportedWeights.read(path))
    expected = {PREFIX + k: v for k, v in CoFiI2PNetwork().state_dict().items()}
    ImportedWeights.require_fit(state, expected, f"{path} is not a state dict of the authors' CoFiI2P network")
    meta = {"format": "CoFiI2P model/network.py CoFiI2P state dict", "dropped": dropped}
    return ImportedWeights(SIZE, {STAGE: state}, trained_on(path), meta)
