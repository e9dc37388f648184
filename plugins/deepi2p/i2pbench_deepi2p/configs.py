"""Stage configs of DeepI2P: the paper's size and a smaller one that trains on a CPU.

Keys are stage kinds, values config overrides for that stage's component (`{}`: its defaults, which are the paper's
size). From the paper and its code (kitti/options.py): ResNet-34 on the half-size image, a grid of 32 px cells of
that image (64 px of a full-size one), 20,480 input points, 128 + 128 point nodes (64- and 256-wide), 512-wide global
features, a 256-256 per-point head with dropout 0.5, and PnP in RANSAC with a 0.6-cell reprojection threshold. Our
choice: D = 768 per keypoint on both sides (256 local + 512 global), the width the fusion reads.
"""

from __future__ import annotations

from typing import Any

COMPONENTS = {
    "encoder2d": "deepi2p-resnet",
    "encoder3d": "deepi2p-pointnet2",
    "exchanger": "deepi2p-fusion",
    "matcher": "deepi2p-classifier",
}
EXTRACTORS = {"extractor2d": "deepi2p-cell-centres", "extractor3d": "random"}
SOLVER = {"solver": "epnp-ransac"}

CELL_PX = 64  # the paper's 32 px cells of its half-size input
PAPER_POINTS = 20480  # the paper classifies every one of its 20,480 input points
CPU_POINTS = 4096
# the paper code's cv2.solvePnPRansac threshold, 0.6 in cell units: a centre stands for any pixel of its cell
PNP = {"reprojection_error_px": 0.6 * CELL_PX}

PAPER: dict[str, dict[str, Any]] = {**{kind: {} for kind in COMPONENTS}, "solver": PNP}

CPU_WIDTH = {"descriptor_dim": 128, "global_dim": 64}  # 64 local + 64 global channels per keypoint
CPU: dict[str, dict[str, Any]] = {
    "encoder2d": {
        **CPU_WIDTH,
        "blocks": (1, 1, 1, 1),
        "channels": (32, 64, 96, 128),
        "stem_channels": 32,
        "image_scale": 0.25,
    },
    "encoder3d": {
        **CPU_WIDTH,
        # our addition, as CorrI2P's and EdgeRegNet's small sizes: without it the frustum head learned nothing in
        # 8,500 steps of 2 frames (85.8% accuracy, predicting "outside" gives 85.8%); docs/methods.md
        "canonical_yaw": True,
        "num_points": 8192,
        "sa1": {"npoint": 128, "radius": 0.1, "nsample": 32, "mlp": (32, 32, 64)},
        "sa2": {"npoint": 128, "radius": 0.3, "nsample": 16, "mlp": (64, 128)},
        "global_mlp": (128, 64),
        "fp_mlp": (128,),
        "head_mlp": (128,),
    },
    "exchanger": {**CPU_WIDTH, "attention_dim": 64, "node_mlp": (256, 128), "point_mlp": (128,)},
    "matcher": {"descriptor_dim": 128, "head_mlp": (128, 128), "cell_mlp": (64,)},
    "solver": PNP,
}
