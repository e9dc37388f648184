"""CorrI2P as one declared method: its stages, its three variants (paper, cpu-size and official, named as every
method's: docs/methods.md, "A method's variants"), its presets, its shipped weights.

The paper's size (configs.PAPER: the components' defaults) takes the dense stride-8 grid of a full-size image and
40,960 random points, as the paper matches among all its pixels and points; the CPU size takes a stride-16 grid
capped at 2,048 pixels and 4,096 points. The 3D cap is a pin (it serves the learned stages whichever extractor a
row uses); the grid's stride and cap are configs of the method's own extractor, dropped where a row swaps it (a
pin on extractor2d would replace them, not merge with them).

The `official` size is the authors' network (official/: rsy6318/CorrI2P, proven on tensors their code computed,
tests/test_corri2p_reference.py) with their pixels, points and inference (official/stages.py): it runs untrained
unless given weights from `i2pbench weights import corri2p-official FILE` (the authors released none).
"""

from __future__ import annotations

from pathlib import Path

from i2pbench.api import Method, MethodPreset, Row, Size

from .configs import COMPONENTS, CPU, CPU_PIXELS, CPU_POINTS, EXTRACTORS, PAPER, PAPER_POINTS

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
SOLVER = {"solver": "epnp-ransac"}
ORACLE = {"encoder2d": "none", "encoder3d": "none", "exchanger": "none", "matcher": "oracle"}  # no learned stage

PAPER_SIZE = Size(
    "paper",
    PAPER,
    pins={"extractor3d": {"max_keypoints": PAPER_POINTS}},
    variant="",
    description=f"ResNet-34, 128 + 128 point nodes, d = 64, dense stride-8 grid + {PAPER_POINTS} points (the paper's)",
)
CPU_SIZE = Size(
    "cpu-size",
    CPU,
    pins={"extractor3d": {"max_keypoints": CPU_POINTS}},
    description=f"ResNet-10 at quarter size, 64 + 64 channels, stride-16 grid <= {CPU_PIXELS} + {CPU_POINTS} points",
)

# the authors' network and inference (official/stages.py): their crop's stride-4 cells and 40,960 voxel points, one
# learned stage, EPnP in RANSAC with their 500 iterations and 1 px at 1/4 of the half-size crop (8 px here)
OFFICIAL_STAGES = {
    "extractor2d": "corri2p-official-grid",
    "extractor3d": "corri2p-official-points",
    "encoder2d": "none",
    "encoder3d": "none",
    "exchanger": "none",
    "matcher": "corri2p-official",
}
OFFICIAL_SOLVER = {"iterations": 500, "reprojection_error_px": 8.0}  # cal_error_all.py:90-93, in full-size pixels
OFFICIAL = Size(
    "official",
    pins={"solver": OFFICIAL_SOLVER},
    stages=OFFICIAL_STAGES,
    description="the authors' code exactly (rsy6318/CorrI2P): SO-Net nodes, two-way attention, 36,381,392 values; "
    "weights: i2pbench weights import corri2p-official FILE (none released)",
)

PRESETS = (
    MethodPreset("corri2p", (Row("cpu-size"),), "CorrI2P at the CPU size: grid pixels, random points, EPnP-RANSAC"),
    MethodPreset("corri2p-paper", (Row("paper"),), "CorrI2P at the paper's size (ResNet-34, 40,960 points)"),
    MethodPreset(
        "corri2p-official",
        (Row("official"),),
        "CorrI2P's authors' own network (rsy6318/CorrI2P), not a look-alike; untrained unless given --weights from "
        "`i2pbench weights import corri2p-official`",
    ),
    MethodPreset(
        "corri2p-ablation",
        (Row("cpu-size"), Row("cpu-size", {"exchanger": "none"}), Row("cpu-size", ORACLE)),
        "CorrI2P (CPU size) beside no feature exchange, and ground-truth matches on its keypoints (the ceiling)",
    ),
)


def corri2p() -> Method:
    """The declaration, built when the plugin registers (the weights folder is listed then, nothing is loaded)."""
    return Method(
        "corri2p",
        {**EXTRACTORS, **COMPONENTS, **SOLVER},
        (PAPER_SIZE, CPU_SIZE, OFFICIAL),
        PRESETS,
        tuple(sorted(WEIGHTS_DIR.glob("*.pt"))),
        "dense grid pixels and points, ResNet + PointNet++ encoders, global-feature exchange, overlap scores, "
        "similarity matching, EPnP",
        importers={"corri2p-official": "i2pbench_corri2p.official.importer:import_official"},
        title="CorrI2P",
    )
