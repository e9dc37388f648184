"""The paper's ablations as presets: `i2pbench run --preset edge-ablation` reproduces Table III in one command.

Every row keeps EdgeRegNet's learned stages; only the studied stage changes. Each row needs weights trained with
its own extractors (a checkpoint belongs to the stages it was trained with), so a row with none shipped runs and is
labelled `untrained` in the leaderboard rather than borrowing another row's weights.
"""

from __future__ import annotations

from i2pbench.api import hookimpl
from i2pbench.hookspecs import Register

LEARNED = {
    "encoder2d": "superpoint-cnn",
    "encoder3d": "pointnet2",
    "exchanger": "attention",
    "matcher": "lightglue",
    "solver": "epnp-ransac",
}

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


def edge_ablation() -> list[dict[str, str]]:
    return [{"extractor2d": e2, "extractor3d": e3, **LEARNED} for e3, e2 in EDGE_ROWS]


def exchange_ablation() -> list[dict[str, str]]:
    edges = {"extractor2d": "lsd", "extractor3d": "depth+reflectance"}
    return [{**edges, **LEARNED, "exchanger": exchanger} for exchanger in EXCHANGERS]


@hookimpl
def register_presets(register: Register) -> None:
    register(
        "edge-ablation",
        edge_ablation(),
        "Table III: 2D x 3D edge extractors (random, canny, sobel, lsd x random, depth, reflectance, "
        "depth+reflectance) under EdgeRegNet's learned stages",
    )
    register(
        "exchange-ablation",
        exchange_ablation(),
        "Table IV: no feature exchanger vs attention, with lsd + depth+reflectance edges",
    )
