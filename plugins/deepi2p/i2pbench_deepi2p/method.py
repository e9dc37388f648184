"""DeepI2P as one declared method: its stages, its three variants (paper, cpu-size and official, named as every
method's: docs/methods.md, "A method's variants"), its presets, its shipped weights.

Both sizes classify points into the same 64 px cells (the cell-centres extractor's default); the 3D keypoint cap is
a pin (it serves the learned stages whichever extractor a row uses). The presets run the two back-ends of the paper
on the same classifier: grid classification + PnP (`epnp-ransac` on cell-centre matches, the method's own solver)
and frustum classification + inverse camera projection (`deepi2p-frustum`, planar "2d" or 6-DoF "3d").

The `official` size is the authors' network (official/: lijx10/DeepI2P, proven on tensors their code computed,
tests/test_deepi2p_reference.py) with their pixels, points, inference and grid-classification + PnP solver
(official/stages.py): it runs untrained unless given weights from `i2pbench weights import deepi2p-official FILE`
(the authors' KITTI weights are lost; their Oxford release does not fit KITTI's input).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from i2pbench.api import Method, MethodPreset, Row, Size

from .configs import COMPONENTS, CPU, CPU_POINTS, EXTRACTORS, PAPER, PAPER_POINTS, SOLVER

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
FRUSTUM = {"solver": "deepi2p-frustum"}

PAPER_SIZE = Size(
    "paper",
    PAPER,
    pins={"extractor3d": {"max_keypoints": PAPER_POINTS}},
    variant="",
    description=f"ResNet-34 on the half-size image, 128 + 128 point nodes, D = 768, {PAPER_POINTS} points",
)
CPU_SIZE = Size(
    "cpu-size",
    CPU,
    pins={"extractor3d": {"max_keypoints": CPU_POINTS}},
    description=f"ResNet-10 at quarter size, 64 + 64 channels, {CPU_POINTS} points",
)

# the authors' network and inference (official/stages.py): their crop's 80 fine cells and 20,480 points, one learned
# stage, and registration_pnp.py's EPnP-RANSAC (500 iterations, 0.6 cell, the 14.14 m rejection)
OFFICIAL_STAGES = {
    "extractor2d": "deepi2p-official-grid",
    "extractor3d": "deepi2p-official-points",
    "encoder2d": "none",
    "encoder3d": "none",
    "exchanger": "none",
    "matcher": "deepi2p-official",
    "solver": "deepi2p-official-pnp",
}
OFFICIAL = Size(
    "official",
    stages=OFFICIAL_STAGES,
    description="the authors' code exactly (lijx10/DeepI2P): SO-Net nodes, attention over image cells, 2 coarse + "
    "80 fine classes; weights: i2pbench weights import deepi2p-official FILE (KITTI weights lost)",
)


def frustum_3d_row(method: Method) -> dict[str, Any]:
    """the CPU size with the 6-DoF inverse projection: a solver config no size carries, labelled apart from the
    planar row's so the two never share a leaderboard label."""
    row = method.row("cpu-size", **FRUSTUM)
    row["confs"]["solver"] = {"variant": "3d"}
    row["variant"] = "cpu-size, 3d"
    return row


def deepi2p() -> Method:
    """The declaration, built when the plugin registers (the weights folder is listed then, nothing is loaded)."""
    bare = Method(
        "deepi2p",
        {**EXTRACTORS, **COMPONENTS, **SOLVER},
        (PAPER_SIZE, CPU_SIZE, OFFICIAL),
        (),
        tuple(sorted(WEIGHTS_DIR.glob("*.pt"))),
        "grid-cell centres and random points, ResNet + PointNet++ encoders, attention fusion into the points, "
        "per-point frustum and grid-cell classification; PnP on cell centres or inverse camera projection",
        importers={"deepi2p-official": "i2pbench_deepi2p.official.importer:import_official"},
        title="DeepI2P",
    )
    presets = (
        MethodPreset("deepi2p", (Row("cpu-size"),), "DeepI2P (CPU size), grid classification + EPnP-RANSAC"),
        MethodPreset("deepi2p-paper", (Row("paper"),), "DeepI2P at the paper's size, grid classification + PnP"),
        MethodPreset(
            "deepi2p-official",
            (Row("official"),),
            "DeepI2P's authors' own network (lijx10/DeepI2P), not a look-alike, with their grid classification + PnP; "
            "untrained unless given --weights from `i2pbench weights import deepi2p-official`",
        ),
        MethodPreset(
            "deepi2p-frustum-2d",
            (Row("cpu-size", FRUSTUM),),
            "DeepI2P (CPU size), frustum classification + inverse camera projection (planar, the protocol's family)",
        ),
        MethodPreset(
            "deepi2p-frustum-3d",
            (frustum_3d_row(bare),),
            "DeepI2P (CPU size), frustum classification + inverse camera projection refined in 6 DoF",
        ),
    )
    return dataclasses.replace(bare, presets=presets)
