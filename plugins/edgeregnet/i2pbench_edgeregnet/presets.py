"""The paper's ablations as presets: `i2pbench run --preset edge-ablation` reproduces Table III in one command.

Every row keeps EdgeRegNet's learned stages at the CPU-trainable size of the shipped weights (configs.SMALL); only
the studied stage changes. Each row needs weights trained with
its own extractors (a checkpoint belongs to the stages it was trained with), so a row with none shipped runs and is
labelled `untrained` in the leaderboard rather than borrowing another row's weights.
"""

from __future__ import annotations

from typing import Any

from i2pbench.api import hookimpl
from i2pbench.hookspecs import Register

from .configs import SMALL_KEYPOINTS
from .shipped import EDGES, SOLVER, full, small

# Table III: (3D extractor, 2D extractor), in the paper's row order.
EDGE_ROWS = (
    ("random", "random"),
    ("depth+reflectance", "canny"),
    ("depth+reflectance", "sobel"),
    ("reflectance", "lsd"),
    ("depth", "lsd"),
    ("depth+reflectance", "lsd"),
)

# Table IV: without and with the attention exchanger, on the paper's edges.
EXCHANGERS = ("none", "attention")


def edge_ablation(size=small) -> list[dict[str, Any]]:
    return [size(extractor2d=e2, extractor3d=e3) for e3, e2 in EDGE_ROWS]


def exchange_ablation(size=small) -> list[dict[str, Any]]:
    return [size(exchanger=exchanger) for exchanger in EXCHANGERS]


def baselines() -> list[dict[str, Any]]:
    """Non-learned and partly learned references around the reference pipeline."""
    return [
        small(),
        small(exchanger="none"),
        small(matcher="cosine"),
        small(extractor2d="random", extractor3d="random"),
        {**EDGES, "matcher": "oracle", **SOLVER, "confs": {k: {"max_keypoints": SMALL_KEYPOINTS} for k in EDGES}},
    ]


@hookimpl
def register_presets(register: Register) -> None:
    register("default", [small()], "EdgeRegNet (CPU-sized, shipped weights): lsd + depth+reflectance edges")
    register("edgeregnet-full", [full()], "EdgeRegNet at the paper's size (d=256, 6 blocks, 3000 + 3000 keypoints)")
    register(
        "edge-ablation",
        edge_ablation(),
        "Table III: 2D x 3D edge extractors (random, canny, sobel, lsd x random, depth, reflectance, "
        "depth+reflectance) under EdgeRegNet's learned stages (CPU size)",
    )
    register(
        "exchange-ablation",
        exchange_ablation(),
        "Table IV: no feature exchanger vs attention, with lsd + depth+reflectance edges (CPU size)",
    )
    register("baselines", baselines(), "the reference pipeline beside no-exchange, cosine, random-edge and oracle rows")
