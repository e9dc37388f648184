"""`cluster_max` gives what SO-Net's index_max kernel lets DeepI2P's and CorrI2P's encoders gather: per cluster and
channel, the largest member value (negative ones included), and 0 for a cluster without members."""

import torch

from i2pbench.layers.cluster_max import cluster_max


def test_channel_maxima_per_cluster_by_hand():
    features = torch.tensor([[[1.0, -5.0, 3.0, -2.0], [-1.0, -4.0, -3.0, 7.0]]])  # B=1, C=2, N=4
    cluster = torch.tensor([[0, 0, 2, 0]])  # cluster 1 is empty
    out = cluster_max(features, cluster, 3)
    assert out.tolist() == [[[1.0, 0.0, 3.0], [7.0, 0.0, -3.0]]]


def test_batches_are_independent():
    features = torch.tensor([[[2.0, 9.0]], [[-6.0, -8.0]]])  # B=2, C=1, N=2
    cluster = torch.tensor([[1, 0], [0, 0]])
    assert cluster_max(features, cluster, 2).tolist() == [[[9.0, 2.0]], [[-6.0, 0.0]]]
