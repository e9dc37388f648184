"""Import of the authors' checkpoint (ESRSchao/EdgeRegNet `ck/KITTI.t7`: a state dict of `AttentionModule`,
models/cali_glue.py:177-204) onto the official size's four learned stages, and of Magic Leap's `superpoint_v1.pth`
onto its 2D branch.

The mapping, done here once:
- `superpoint.*` -> encoder2d; `sa1.*`, `sa2.*`, `fp.*` -> encoder3d, names unchanged;
- `kenc2d.encoder2d.*`, `kenc3d.encoder3d.*`, `gnn.layers.L.*` -> the exchanger's `kenc2d.*`, `kenc3d.*`,
  `layers.L.*`, the attention's `proj.0/1/2` and `merge` as `q`, `k`, `v`, `merge`, with the heads regrouped: their
  Conv1d channel d * heads + h becomes our channel h * (D / heads) + d (rows of q, k, v; columns of merge);
- `feature_layer.*`, `pc_score_layer.*`, `log_assignment.final_proj.*`, `log_assignment.matchability.*` -> the
  matcher's `feature_layer.*`, `pc_score_layer.*`, `final_proj.*`, `matchability.*`;
- 1x1 Conv1d weights [out x in x 1] -> Linear weights [out x in] wherever our layer is a Linear.
A file whose keys or shapes do not fit is refused with the keys named.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import torch

from i2pbench.api import ImportedWeights

SIZE = "official"
TRAINED_ON = "authors' release (KITTI 00-08)"
HEADS = 4  # cali_glue.py:104
RENAMES = (  # official key pattern -> (stage kind, our key)
    (r"superpoint\.(.*)", "encoder2d", r"\1"),
    (r"((?:sa1|sa2|fp)\..*)", "encoder3d", r"\1"),
    (r"kenc2d\.encoder2d\.(.*)", "exchanger", r"kenc2d.\1"),
    (r"kenc3d\.encoder3d\.(.*)", "exchanger", r"kenc3d.\1"),
    (r"gnn\.layers\.(\d+)\.attn\.proj\.0\.(.*)", "exchanger", r"layers.\1.q.\2"),
    (r"gnn\.layers\.(\d+)\.attn\.proj\.1\.(.*)", "exchanger", r"layers.\1.k.\2"),
    (r"gnn\.layers\.(\d+)\.attn\.proj\.2\.(.*)", "exchanger", r"layers.\1.v.\2"),
    (r"gnn\.layers\.(\d+)\.attn\.merge\.(.*)", "exchanger", r"layers.\1.merge.\2"),
    (r"gnn\.layers\.(\d+)\.mlp\.(.*)", "exchanger", r"layers.\1.mlp.\2"),
    (r"((?:feature_layer|pc_score_layer)\..*)", "matcher", r"\1"),
    (r"log_assignment\.(.*)", "matcher", r"\1"),
)


def head_order(dim: int, heads: int = HEADS) -> torch.Tensor:
    """our channel c' = h * (dim / heads) + d -> the authors' channel d * heads + h."""
    return torch.arange(dim).view(dim // heads, heads).t().reshape(-1)


def convert(key: str, value: torch.Tensor, ours: str, heads: int = HEADS) -> torch.Tensor:
    """one official tensor in our layout: heads regrouped, 1x1 Conv1d kernels squeezed where ours is a Linear."""
    if re.search(r"\.(q|k|v)\.(weight|bias)$", ours):
        value = value[head_order(value.shape[0], heads)]
    elif ours.endswith(".merge.weight"):
        value = value[:, head_order(value.shape[1], heads)]
    return value[..., 0] if value.dim() == 3 and not key.startswith("fp.") else value


def split(state: Mapping[str, torch.Tensor], heads: int = HEADS) -> tuple[dict[str, dict[str, torch.Tensor]], list]:
    """official state dict -> ({stage kind: our state dict}, official keys no rule maps)."""
    out: dict[str, dict[str, torch.Tensor]] = {"encoder2d": {}, "encoder3d": {}, "exchanger": {}, "matcher": {}}
    unknown = []
    for key, value in state.items():
        for pattern, kind, target in RENAMES:
            if re.fullmatch(pattern, key):
                ours = re.sub(pattern, target, key)
                out[kind][ours] = convert(key, value, ours, heads)
                break
        else:
            unknown.append(key)
    return out, unknown


def expected() -> dict[str, dict[str, torch.Tensor]]:
    """the official size's state dicts, by stage kind (what an import must fill exactly)."""
    from ..method import official_stages

    return {kind: module.state_dict() for kind, module in official_stages().items()}


def check(state: Mapping[str, Mapping[str, torch.Tensor]], unknown: list[str], source: str) -> None:
    """refuse, naming the keys (as `<stage kind>.<key>`), a state whose keys or shapes are not the official size's."""
    flat = {f"{kind}.{k}": v for kind, stage in state.items() for k, v in stage.items()}
    want = {f"{kind}.{k}": v for kind, stage in expected().items() for k, v in stage.items()}
    ImportedWeights.require_fit({**flat, **dict.fromkeys(unknown, torch.empty(0))}, want,
                                f"{source} is not the authors' AttentionModule state dict")  # fmt: skip


def import_official(path: Path) -> ImportedWeights:
    """the authors' `KITTI.t7` (or any state dict of their AttentionModule) as the official size's weights."""
    state, unknown = split(ImportedWeights.read(path))  # tensors only, string keys
    check(state, unknown, str(path))
    return ImportedWeights(SIZE, state, {"release": TRAINED_ON}, {"format": "EdgeRegNet AttentionModule state dict"})
