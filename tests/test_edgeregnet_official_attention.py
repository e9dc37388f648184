"""The official exchanger's tied layer runs the 3D and 2D sides as one batch; that must be the authors' two separate
calls (cali_glue.py:112-114): the same updates in eval and in training, each side normalised by its own batch
statistics and the running statistics updated 3D first, with padded keys masked; the eval BatchNorm folded into
the Linear before it gives the norm's own outputs."""

import copy

import pytest
import torch
from i2pbench_edgeregnet.official.attention import AttentionalPropagation, batchnorm_mlp, run_mlp

from i2pbench.layers.attention import key_mask

DIM, HEADS, N = 16, 4, 12


def separate_calls(layer, d3, d2, cross, m3, m2):
    """the authors' order: the 3D side's update, then the 2D side's, each from the descriptors before the layer."""
    s3, s2, k3, k2 = (d2, d3, m2, m3) if cross else (d3, d2, m3, m2)
    return layer.update(d3, s3, k3), layer.update(d2, s2, k2)


@pytest.fixture
def layer():
    torch.manual_seed(0)
    module = AttentionalPropagation(DIM, HEADS)
    for norm in (m for m in module.modules() if isinstance(m, torch.nn.BatchNorm1d)):
        norm.running_mean.uniform_(-0.5, 0.5)
        norm.running_var.uniform_(0.5, 1.5)
        norm.weight.data.uniform_(0.5, 1.5)
        norm.bias.data.uniform_(-0.5, 0.5)
    return module


@pytest.mark.parametrize("cross", [False, True])
@pytest.mark.parametrize("train", [False, True])
def test_official_layer_batched_sides_equal_separate_calls(layer, cross, train):
    d3, d2 = torch.randn(2, N, DIM), torch.randn(2, N, DIM)
    padded = torch.ones(2, N, dtype=torch.bool)
    padded[1, 7:] = False  # the second frame's 3D side has 7 keypoints
    m3, m2 = key_mask(padded), None
    reference = copy.deepcopy(layer).train(train)
    layer.train(train)
    with torch.no_grad():
        ours = layer(d3, d2, cross, m3, m2)
        theirs = separate_calls(reference, d3, d2, cross, m3, m2)
    for a, b in zip(ours, theirs, strict=True):
        assert torch.allclose(a, b, atol=1e-5, rtol=1e-5)
    for (key, a), b in zip(layer.state_dict().items(), reference.state_dict().values(), strict=True):
        assert torch.allclose(a.float(), b.float(), atol=1e-6), key  # running statistics: per side, 3D first


def test_official_layer_batched_sides_ignore_padded_keys(layer):
    """a padded key's value does not reach any update."""
    layer.eval()
    d3, d2 = torch.randn(1, N, DIM), torch.randn(1, N, DIM)
    mask = torch.ones(1, N, dtype=torch.bool)
    mask[0, 9:] = False
    moved = d3.clone()
    moved[0, 9:] += 100.0
    with torch.no_grad():
        before = layer(d3, d2, True, key_mask(mask), None)[1]  # the 2D side attends to the 3D keys
        after = layer(moved, d2, True, key_mask(mask), None)[1]
    assert torch.allclose(before, after, atol=1e-5)


def channels_first(head: torch.nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """the MLP as the authors run it: eval BatchNorm1d on [B x C x N], each layer on its own."""
    for module in head:
        if isinstance(module, torch.nn.BatchNorm1d):
            x = torch.nn.functional.batch_norm(
                x.transpose(1, 2), module.running_mean, module.running_var, module.weight, module.bias, eps=module.eps
            ).transpose(1, 2)
        else:
            x = module(x)
    return x


def test_official_mlp_folded_norm_equals_the_norm():
    torch.manual_seed(1)
    head = batchnorm_mlp((DIM, 2 * DIM, 3 * DIM, DIM)).eval()
    for norm in (m for m in head.modules() if isinstance(m, torch.nn.BatchNorm1d)):
        norm.running_mean.uniform_(-1, 1)
        norm.running_var.uniform_(0.2, 2)
    x = torch.randn(3, N, DIM)
    with torch.no_grad():
        expected = channels_first(head, x)
        assert expected.abs().max() > 0.1  # the ReLUs leave something to compare
        assert torch.allclose(run_mlp(head, x), expected, atol=1e-5)  # norms folded into the Linears
        assert torch.allclose(head(x), expected, atol=1e-5)  # ChannelNorm's own eval path


@pytest.mark.parametrize("cross", [False, True])
def test_official_layer_eval_folds_the_merge_into_the_mlp(layer, cross):
    """eval: the stacked q/k/v products and the merge folded with the first Linear and its norm give the authors'
    steps one by one (separate projections, attention, merge, concatenation, the MLP with its own norm), float64."""
    layer = layer.double().eval()
    d3, d2 = torch.randn(1, N, DIM, dtype=torch.float64), torch.randn(1, N, DIM, dtype=torch.float64)
    source = d2 if cross else d3
    heads = [p(t).unflatten(-1, (HEADS, -1)).transpose(1, 2) for p, t in zip(
        (layer.q, layer.k, layer.v), (d3, source, source), strict=True)]  # fmt: skip
    message = torch.nn.functional.scaled_dot_product_attention(*heads).transpose(1, 2).flatten(2)
    with torch.no_grad():
        expected = channels_first(layer.mlp, torch.cat([d3, layer.merge(message)], -1))
        ours = layer.update(d3, source, None)
    assert expected.abs().max() > 0.1
    torch.testing.assert_close(ours, expected, rtol=1e-12, atol=1e-12)
