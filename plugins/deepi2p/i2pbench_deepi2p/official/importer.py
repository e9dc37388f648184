"""`i2pbench weights import deepi2p-official FILE`: a state dict of the authors' `KeypointDetector` (lijx10/DeepI2P
saves `model.state_dict()`, `module.`-prefixed when wrapped in DataParallel) as the official size's weights.

weights.py maps it (prefixes stripped, the ResNet's ImageNet `fc` dropped) onto the one learned stage, the matcher,
whose network sits under `net.`; a key that does not fit, a missing key or a shape that differs is refused by name.
The official size runs the KITTI input (160 x 512, 80 cells): the authors' KITTI weights are lost (issue #2), so a
file of that shape is whatever the user trained with their code; their released Oxford RobotCar model (384 x 640,
240 cells) does not fit it and is refused, its fine head's shape named.
"""

from __future__ import annotations

from pathlib import Path

from i2pbench.api import ImportedWeights

from .weights import RELEASES, UNUSED, to_network

SIZE = "official"
STAGE = "matcher"
PREFIX = "net."
TRAINED_ON = (
    "user-supplied DeepI2P KeypointDetector state dict at the KITTI input (160 x 512); the authors' KITTI weights are "
    "lost (lijx10/DeepI2P issue #2), their one release is Oxford RobotCar at 384 x 640, which this size cannot run"
)


def import_official(path: Path) -> ImportedWeights:
    """a state dict of the authors' KeypointDetector as the official size's weights."""
    from .stages import OfficialDeepI2P

    stage = OfficialDeepI2P()
    state = ImportedWeights.read(path)
    network = to_network(state, stage.net.state_dict(), str(path))
    dropped = sorted(k.removeprefix("module.") for k in state if UNUSED.fullmatch(k.removeprefix("module.")))
    meta = {"format": "DeepI2P models.networks_united.KeypointDetector state dict", "dropped": dropped,
            "authors_training_at_this_size": RELEASES[(160, 512)]}  # fmt: skip
    return ImportedWeights(SIZE, {STAGE: {PREFIX + k: v for k, v in network.items()}}, {"release": TRAINED_ON}, meta)
