"""Stage configs of EdgeRegNet's three variants (docs/methods.md, "A method's variants"): `PAPER`, the paper's
widths (the components' defaults); `CPU`, narrower ones that train on a CPU (the shipped weights'); and
`OFFICIAL_STAGES`, the components of the authors' own network (official/), which differ in kind, not in width.

The CPU variant also turns on the yaw-canonical frame for 3D inputs (layers/canonical.py), our addition: without it
the encoders must learn invariance to the protocol's random yaw from augmentation alone, which a CPU cannot afford.

Keys are stage kinds, values config overrides for that stage's component (`{}`: its defaults, the paper's widths).
The CPU variant also expects the extractors capped at `CPU_KEYPOINTS` edge pixels and edge points.
"""

from __future__ import annotations

from typing import Any

COMPONENTS = {"encoder2d": "superpoint-cnn", "encoder3d": "pointnet2", "exchanger": "attention", "matcher": "lightglue"}
PAPER_KEYPOINTS = 3000
CPU_KEYPOINTS = 2048  # attention cost grows with the square of this; 2048 keeps a CPU training step near 2 s and
# gives ~4x the ground-truth pairs of 1024 (about 50 per synthetic frame: only ~12% of a scan's edge points are in view)

# the authors' network (official/): other components, not other widths; 3000 edge pixels and points (test.py)
OFFICIAL_STAGES = {
    "encoder2d": "superpoint-official",
    "encoder3d": "pointnet2-official",
    "exchanger": "attention-official",
    "matcher": "match-assignment-official",
}
OFFICIAL_KEYPOINTS = 3000

PAPER: dict[str, dict[str, Any]] = {kind: {} for kind in COMPONENTS}

CPU: dict[str, dict[str, Any]] = {
    "encoder2d": {"descriptor_dim": 128, "channels": (32, 32, 64, 64), "head_channels": 128},
    "encoder3d": {
        "descriptor_dim": 128,
        "num_points": 8192,
        "sa1": {"npoint": 2048, "radius": 0.1, "nsample": 32, "mlp": (64, 64, 128)},
        "sa2": {"npoint": 512, "radius": 0.2, "nsample": 32, "mlp": (128, 128, 128)},
        "fp_mlp": (128, 128),
        "head_mlp": (128,),
        "canonical_yaw": True,
    },
    "exchanger": {"descriptor_dim": 128, "num_blocks": 3, "canonical_yaw": True},
    # the fov filter off at inference: chosen on the synthetic val split (Acc. 40% without it, 20% with it)
    "matcher": {"descriptor_dim": 128, "fov_filter": False},
}
