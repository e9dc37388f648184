"""EdgeRegNet as one declared method: its stages, its three variants, the paper's ablations as presets, its weights.

The variants follow the scheme every method shares (docs/methods.md, "A method's variants"): `paper` (the paper's
widths, preset `edgeregnet-paper`), `cpu-size` (widths a CPU trains, preset `edgeregnet`) and `official` (the
authors' own network, preset `edgeregnet-official`, whose stages are other components, not other widths).

The shipped checkpoints were trained on this project's CPU, so they are the cpu-size variant (configs.CPU), which
the `edgeregnet` preset runs (the project's `default` too): its rows pin exactly the stage configs the weights were
trained with, which is what lets `--weights auto` find them. The paper variant has no shipped weights and runs
`untrained` unless given a checkpoint.

`--preset edge-ablation` reproduces Table III in one command: every row keeps the learned stages at the CPU size and
changes only the studied stage. Each row needs weights trained with its own extractors (a checkpoint belongs to the
stages it was trained with), so a row with none shipped runs and is labelled `untrained` rather than borrowing
another row's weights.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from i2pbench.api import Method, MethodPreset, Row, Size

from .configs import COMPONENTS, CPU, CPU_KEYPOINTS, OFFICIAL_KEYPOINTS, OFFICIAL_STAGES, PAPER

if TYPE_CHECKING:
    from i2pbench.api import LearnedComponent

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
EDGES = {"extractor2d": "lsd", "extractor3d": "depth+reflectance"}
SOLVER = {"solver": "epnp-ransac"}

PAPER_SIZE = Size("paper", PAPER, variant="", description="d=256, 6 blocks, 3000 + 3000 keypoints (the paper's)")
# the extractors' cap serves the learned stages whichever extractor an ablation row uses; the paper's 3000 is the
# extractors' own default, so it is not pinned and classic rows built over a paper-size row stay plain
CPU_SIZE = Size(
    "cpu-size",
    CPU,
    pins={kind: {"max_keypoints": CPU_KEYPOINTS} for kind in EDGES},
    description=f"d=128, 3 blocks, {CPU_KEYPOINTS} + {CPU_KEYPOINTS} keypoints, yaw-canonical 3D (shipped weights)",
)
# the authors' network (docs/edgeregnet.md: paper text vs authors' code vs i2pbench); its weights are theirs, imported
OFFICIAL = Size(
    "official",
    stages=OFFICIAL_STAGES,
    pins={kind: {"max_keypoints": OFFICIAL_KEYPOINTS} for kind in EDGES},
    description="the authors' code exactly (ESRSchao/EdgeRegNet): tied SuperGlue attention, 9,789,922 values; "
    "weights: i2pbench weights import edgeregnet-official KITTI.t7",
)

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

# the non-learned reference: the paper's edges under ground-truth matches
ORACLE = {**EDGES, "matcher": "oracle", **SOLVER, "confs": {k: {"max_keypoints": CPU_KEYPOINTS} for k in EDGES}}

PRESETS = (
    # the former names stay aliases: `default` is also what `i2pbench run` runs with no stage options, and committed
    # boards (paper-table-1) name the row by it
    MethodPreset(
        "edgeregnet",
        (Row("cpu-size"),),
        "EdgeRegNet (CPU-sized, shipped weights): lsd + depth+reflectance edges",
        aliases=("default",),
    ),
    MethodPreset(
        "edgeregnet-paper",
        (Row("paper"),),
        "EdgeRegNet at the paper's size (d=256, 6 blocks, 3000 + 3000 keypoints)",
        aliases=("edgeregnet-full",),
    ),
    MethodPreset(
        "edgeregnet-official",
        (Row("official"),),
        "EdgeRegNet as the authors' code computes it (run with --weights from `i2pbench weights import`)",
    ),
    MethodPreset(
        "edge-ablation",
        tuple(Row("cpu-size", {"extractor2d": e2, "extractor3d": e3}) for e3, e2 in EDGE_ROWS),
        "Table III: 2D x 3D edge extractors (random, canny, sobel, lsd x random, depth, reflectance, "
        "depth+reflectance) under EdgeRegNet's learned stages (CPU size)",
    ),
    MethodPreset(
        "exchange-ablation",
        tuple(Row("cpu-size", {"exchanger": exchanger}) for exchanger in EXCHANGERS),
        "Table IV: no feature exchanger vs attention, with lsd + depth+reflectance edges (CPU size)",
    ),
    MethodPreset(
        "baselines",
        (
            Row("cpu-size"),
            Row("cpu-size", {"exchanger": "none"}),
            Row("cpu-size", {"matcher": "cosine"}),
            Row("cpu-size", {"extractor2d": "random", "extractor3d": "random"}),
            ORACLE,
        ),
        "the reference pipeline beside no-exchange, cosine, random-edge and oracle rows",
    ),
)


def edgeregnet() -> Method:
    """The declaration, built when the plugin registers (the weights folder is listed then, nothing is loaded)."""
    return Method(
        "edgeregnet",
        {**EDGES, **COMPONENTS, **SOLVER},
        (PAPER_SIZE, CPU_SIZE, OFFICIAL),
        PRESETS,
        tuple(sorted(WEIGHTS_DIR.glob("*.pt"))),
        "edge pixels and points, CNN + PointNet++ encoders, attention exchange, optimal matching, EPnP",
        importers={"edgeregnet-official": "i2pbench_edgeregnet.official.importer:import_official"},
        title="EdgeRegNet",
    )


def official_stages() -> dict[str, LearnedComponent]:
    """the official size's four learned stages at their defaults, built directly (no registry)."""
    from .official.attention import OfficialAttention
    from .official.matching import OfficialMatcher
    from .official.pointnet2 import OfficialPointNet2
    from .official.superpoint import OfficialSuperPoint

    classes = (OfficialSuperPoint, OfficialPointNet2, OfficialAttention, OfficialMatcher)
    return {kind: cls() for kind, cls in zip(COMPONENTS, classes, strict=True)}
