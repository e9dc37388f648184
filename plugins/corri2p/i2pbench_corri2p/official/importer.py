"""`i2pbench weights import corri2p-official FILE`: a state dict of the authors' `CorrI2P` (train.py:277-292 saves
`model.state_dict()`; `module.`-prefixed keys when it was wrapped in DataParallel) as the official size's weights.

Every key goes through checkpoint.py's mapping onto the one learned stage (the matcher, whose network sits under
`net.`); the ResNet's ImageNet `fc` is dropped. A key the mapping does not know, a missing key or a shape that does
not fit is refused by name. The authors released no weights (rsy6318/CorrI2P issues #7, #13): a file is whatever
the user trained with their code, recorded as user-supplied with the file's sha256
(i2pbench.weights.checkpoints.import_weights).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch

from i2pbench.api import ImportedWeights

from .checkpoint import dropped, ours

SIZE = "official"
STAGE = "matcher"
PREFIX = "net."
TRAINED_ON = "user-supplied CorrI2P state dict (the authors released no weights; their train.py trains on KITTI 00-08)"


def expected() -> dict[str, torch.Tensor]:
    """the official stage's state dict (what an import must fill exactly)."""
    from .stages import OfficialCorrI2P

    return OfficialCorrI2P().state_dict()


def split(state: Mapping[str, torch.Tensor]) -> tuple[dict[str, torch.Tensor], list[str], list[str]]:
    """authors' state dict -> (our stage's state dict, keys no rule maps, keys dropped on purpose)."""
    mapped, unknown, left = {}, [], []
    for key, value in state.items():
        if dropped(key):
            left.append(key)
        elif (target := ours(key)) is None:
            unknown.append(key)
        else:
            mapped[PREFIX + target] = value
    return mapped, unknown, left


def check(state: Mapping[str, torch.Tensor], unknown: list[str], source: str) -> None:
    """refuse, naming the keys, a state whose keys or shapes are not the official size's (a key no rule maps is
    kept under its own name, so it is named as unexpected)."""
    ImportedWeights.require_fit({**state, **dict.fromkeys(unknown, torch.empty(0))}, expected(),
                                f"{source} is not a state dict of the authors' CorrI2P network")  # fmt: skip


def import_official(path: Path) -> ImportedWeights:
    """a state dict of the authors' CorrI2P as the official size's weights."""
    state, unknown, left = split(ImportedWeights.read(path))
    check(state, unknown, str(path))
    meta = {"format": "CorrI2P network.CorrI2P state dict", "dropped": sorted(k.removeprefix("module.") for k in left)}
    return ImportedWeights(SIZE, {STAGE: state}, {"release": TRAINED_ON}, meta)
