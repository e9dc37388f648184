"""Reading the authors' VP2P-Match checkpoint: the plain state dict of `VP2PMatchNet` that their `run_kitti.py`
loads (`model.load_state_dict(torch.load(args.load_ckpt))`, line 410).

The official modules keep the authors' key names and shapes, torchsparse's `[K^3 x C_in x C_out]` kernels included
(layers.sparse uses torchsparse's kernel-offset order), so nothing is renamed or transposed: a file loads when its keys
and shapes are exactly the network's, and is refused with the misfitting keys named otherwise. What a run records of
the file: its sha256 and where it comes from. `import_official` is the `vp2p-match` method's `vp2p-match-official`
importer (`i2pbench weights import vp2p-match-official FILE`): the state goes, keys unchanged, under the official
matcher stage's `net.`.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import torch

from i2pbench.api import ImportedWeights

from .network import VP2PMatchNet

RELEASE = "authors' release (KITTI)"
FORMAT = "VP2P-Match VP2PMatchNet state dict"
SIZE, STAGE, PREFIX = "official", "matcher", "net."  # the size and stage the network runs in (stages.py)


def checked_state(path: Path, net: VP2PMatchNet) -> dict[str, torch.Tensor]:
    """the file's state dict, refused with the misfitting keys named unless it is exactly `net`'s."""
    state = ImportedWeights.read(path)
    ImportedWeights.require_fit(state, net.state_dict(), f"{path} is not the authors' VP2PMatchNet state dict")
    return state


def load_official(path: Path) -> tuple[VP2PMatchNet, dict[str, str]]:
    """the official network with the file's weights, and what identifies them (sha256, release, format)."""
    net = VP2PMatchNet()
    net.load_state_dict(checked_state(path, net))
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return net, {"sha256": digest, "release": RELEASE, "format": FORMAT}


def import_official(path: Path) -> ImportedWeights:
    """the authors' checkpoint as the official size's weights (`import_weights` records its sha256)."""
    state = checked_state(path, VP2PMatchNet())
    return ImportedWeights(SIZE, {STAGE: {PREFIX + k: v for k, v in state.items()}}, {"release": RELEASE},
                           {"format": FORMAT})  # fmt: skip
