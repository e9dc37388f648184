"""CorrI2P's point branch (the other half of its feature embedding): PointNet++ on the cloud with the paper's two
levels of 128 nodes, feature propagation onto the 3D keypoints, plus the cloud's global feature.

Each keypoint's descriptor is [local (D - G) | global (G)]; the global feature is a shared MLP on the second level's
nodes ([position, features]) max-pooled over them, as the paper's final PointNet.

The network is `i2pbench.layers.global_pointnet2`, built from the PointNet++ blocks of `i2pbench.layers.pointnet2`
(farthest point sampling, ball query, set abstraction, 3-NN interpolation, the seeded cloud subset and the
transform-free grouping cache). What differs from the paper, and why:
- the paper's point encoder is DeepI2P's (SO-Net style: every point assigned to its nearest first-level node, k-NN
  from second-level nodes to first-level ones, with surface normals as inputs). Here it is PointNet++ set abstraction
  at the same node counts and widths (128 nodes of 64 channels, 128 of 256, a 512-wide global feature), on xyz and
  reflectance only: normals would need a neighbourhood estimate the benchmark's frames do not carry;
- the second level takes its 128 centroids among the first level's (the paper samples them from the cloud again);
- each keypoint's head also reads its offsets from its 3 nearest first-level nodes (in units of their radius), the
  fine geometry the paper's per-point PointNet takes relative to each point's node: interpolated node features and
  the cloud-normalised position alone differ by ~0.003 between points one stride-16 cell apart;
- GroupNorm in the set abstractions, and a head normalised over the frame's keypoints (layers/frame_norm.py), instead of
  BatchNorm, for one-frame steps;
- `canonical_yaw` (on in the CPU size, off at the paper's) expresses the cloud in its yaw-canonical frame
  (i2pbench/layers/canonical.py), so the encoder need not learn invariance to the protocol's random yaw from data.
"""

from __future__ import annotations

from i2pbench.layers.global_pointnet2 import GlobalPointNet2Encoder


class CorrI2PPointEncoder(GlobalPointNet2Encoder):
    """Per-keypoint [local | global] descriptors from a two-level PointNet++ on the (sub-sampled) cloud."""

    name = "corri2p-pointnet2"
