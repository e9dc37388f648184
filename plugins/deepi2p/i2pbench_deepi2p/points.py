"""DeepI2P's point branch (Li & Lee, CVPR 2021, Sec. 3.1): two levels of 128 point nodes, features propagated back
to every classified point, and the cloud's global feature; [local (D - G) | global (G)] per 3D keypoint.

This is the network of CorrI2P's point encoder (`i2pbench.layers.global_pointnet2`: PointNet++ set abstraction at
DeepI2P's node counts and widths) under DeepI2P's name and input size: the paper's KITTI network takes
20,480 points (CorrI2P's 40,960). What differs from the paper, as there: set abstraction over ball neighbourhoods
instead of SO-Net's assignment of every point to its nearest node, no surface normals among the inputs (the frames
carry none), GroupNorm for one-frame steps.
"""

from __future__ import annotations

from typing import Any

from i2pbench.layers.global_pointnet2 import GlobalPointNet2Encoder


class DeepI2PPointEncoder(GlobalPointNet2Encoder):
    """Per-keypoint [local | global] descriptors from a two-level PointNet++ on the (sub-sampled) cloud."""

    name = "deepi2p-pointnet2"
    default_conf: dict[str, Any] = {
        **GlobalPointNet2Encoder.default_conf,
        "descriptor_dim": 768,  # D: local (D - G) + global (G) channels per keypoint, the image encoder's too
        "global_dim": 512,  # G: the cloud's global feature (the paper's 512)
        "num_points": 20480,  # cloud size (seeded random subset by frame id; the paper's 20,480)
        "sa1": {"npoint": 128, "radius": 0.1, "nsample": 64, "mlp": (32, 32, 64)},  # node level a: 128 nodes, 64 ch
        "sa2": {"npoint": 128, "radius": 0.3, "nsample": 16, "mlp": (256, 256)},  # node level b: 128 nodes, 256 ch
    }
