"""CorrI2P as one declared method: its stages, the paper's size and a CPU size, its presets, its shipped weights.

The paper's size (configs.PAPER: the components' defaults) takes the dense stride-8 grid of a full-size image and
40,960 random points, as the paper matches among all its pixels and points; the CPU size takes a stride-16 grid
capped at 2,048 pixels and 4,096 points. The 3D cap is a pin (it serves the learned stages whichever extractor a
row uses); the grid's stride and cap are configs of the method's own extractor, dropped where a row swaps it (a
pin on extractor2d would replace them, not merge with them).
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

PRESETS = (
    MethodPreset("corri2p", (Row("cpu-size"),), "CorrI2P at the CPU size: grid pixels, random points, EPnP-RANSAC"),
    MethodPreset("corri2p-paper", (Row("paper"),), "CorrI2P at the paper's size (ResNet-34, 40,960 points)"),
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
        (PAPER_SIZE, CPU_SIZE),
        PRESETS,
        tuple(sorted(WEIGHTS_DIR.glob("*.pt"))),
        "dense grid pixels and points, ResNet + PointNet++ encoders, global-feature exchange, overlap scores, "
        "similarity matching, EPnP",
        title="CorrI2P",
    )
