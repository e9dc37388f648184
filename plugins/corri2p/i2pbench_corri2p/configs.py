"""Stage configs of CorrI2P's learned stages: the paper's size and a smaller one that trains on a CPU.

Keys are stage kinds, values config overrides for that stage's component (`{}`: its defaults, which are the paper's
size). Widths the paper gives: ResNet-34 image encoder (3-4-6-3 blocks, 64-128-256-512), decoder 256-128-64 up to
stride 4 of the half-size image, 512-wide global features on both sides, 128 + 128 point nodes with 64- and 256-wide
features, 40,960 input points, 64-wide matching descriptors, a 0.9 overlap-score threshold, the circle loss's margins
0.2 / 1.8 and scale 10 over 512 in-view anchors, the overlap loss weighted 0.5. Widths we chose (the paper's
per-keypoint width before the exchange has no counterpart in its layout): 128 local channels per keypoint.
The CPU size also turns on the yaw-canonical frame for the point encoder (our addition, as EdgeRegNet's small size:
without it the invariance to the protocol's random yaw must be learnt from augmentation, which a CPU cannot afford).
"""

from __future__ import annotations

from typing import Any

COMPONENTS = {
    "encoder2d": "corri2p-resnet",
    "encoder3d": "corri2p-pointnet2",
    "exchanger": "corri2p-exchange",
    "matcher": "corri2p-overlap",
}
EXTRACTORS = {"extractor2d": "grid", "extractor3d": "random"}

PAPER_POINTS = 40960  # the paper matches among all of its 40,960 input points
CPU_POINTS = 4096
CPU_PIXELS = 2048  # cap on the grid; a full-size KITTI image at stride 16 has 77 x 23 = 1,771 cells, under it

PAPER: dict[str, dict[str, Any]] = {kind: {} for kind in COMPONENTS}

CPU_WIDTH = {"descriptor_dim": 128, "global_dim": 64}  # 64 local + 64 global channels per keypoint
CPU: dict[str, dict[str, Any]] = {
    # one keypoint per cell of the quarter-size image's stride-4 map; the cap is here rather than a pin because a
    # size's pin for a kind replaces (does not merge with) its conf for that kind, which would drop the stride
    "extractor2d": {"stride": 16, "max_keypoints": CPU_PIXELS},
    "encoder2d": {
        **CPU_WIDTH,
        "blocks": (1, 1, 1, 1),
        "channels": (32, 64, 96, 128),
        "stem_channels": 32,
        "decoder_channels": (96, 64, 32),
        "image_scale": 0.25,
    },
    "encoder3d": {
        **CPU_WIDTH,
        "canonical_yaw": True,  # our addition, as EdgeRegNet's small size: no yaw invariance to learn from data
        "num_points": 8192,
        "sa1": {"npoint": 128, "radius": 0.1, "nsample": 32, "mlp": (32, 32, 64)},
        "sa2": {"npoint": 128, "radius": 0.3, "nsample": 16, "mlp": (64, 128)},
        "global_mlp": (128, 64),
        "fp_mlp": (128,),
        "head_mlp": (128,),
    },
    "exchanger": {**CPU_WIDTH, "attention_dim": 64, "fusion_mlp": (128,)},
    # one cell of the stride-16 grid: the paper's one-cell pair radius and in-cell overlap label
    "matcher": {"descriptor_dim": 128, "head_mlp": (64,), "pair_radius_px": 16.0, "overlap_window_px": 8.0},
}
