"""EdgeRegNet's faster layouts (channels-last image CNN, shared MLPs as matrix products) compute what the plain
layouts computed, with the shipped weights, on real KITTI inputs (speed: benchmarks/roofline.py)."""

import copy
from pathlib import Path

import i2pbench_edgeregnet
import numpy as np
import pytest
import torch
from i2pbench_edgeregnet import configs
from i2pbench_edgeregnet.pointnet2 import PointNet2Encoder
from i2pbench_edgeregnet.superpoint import SuperPointEncoder

from i2pbench.data.images import read_image
from i2pbench.layers.pointnet2 import SharedMLP

SHIPPED = Path(i2pbench_edgeregnet.__file__).parent / "weights" / "edgeregnet-cpu-synthetic.pt"


def shipped_state(kind: str) -> dict[str, torch.Tensor]:
    return torch.load(SHIPPED, map_location="cpu", weights_only=True)["state"][kind]


def test_the_image_cnn_runs_channels_last_and_gives_the_plain_layouts_descriptors(shared_data):
    encoder = SuperPointEncoder(configs.CPU["encoder2d"]).eval()
    encoder.load_state_dict(shipped_state("encoder2d"))  # saved from plain (NCHW) weights: loads into NHWC ones
    assert all(m.weight.is_contiguous(memory_format=torch.channels_last) for m in encoder.backbone[::5])
    plain = copy.deepcopy(encoder).to(memory_format=torch.contiguous_format)
    assert not plain.backbone[2].weight.is_contiguous(memory_format=torch.channels_last)
    image = read_image(shared_data / "kitti_real" / "sequences" / "26" / "image_2" / "000000.png")
    grey = torch.from_numpy(image.astype(np.float32) @ np.float32([0.299, 0.587, 0.114]) / 255)[None, None]
    uv = torch.from_numpy(np.random.default_rng(0).uniform([0, 0], grey.shape[:1:-1], (500, 2)).astype(np.float32))
    inputs = {"grey": grey, "size": torch.tensor([grey.shape[-2:]]), "uv": uv[None]}
    with torch.no_grad():
        fast, reference = encoder.forward(inputs), plain.forward(inputs)
    torch.testing.assert_close(fast, reference, rtol=0, atol=1e-5)
    assert fast.abs().max() > 0.1  # real descriptors (unit-norm rows), not zeros


@pytest.mark.parametrize("layer", ["sa1", "sa2"])
def test_shared_mlps_as_matrix_products_equal_the_1x1_convolutions_forward_and_backward(layer):
    encoder = PointNet2Encoder(configs.CPU["encoder3d"])
    encoder.load_state_dict(shipped_state("encoder3d"))
    mlp = getattr(encoder, layer).mlp
    assert isinstance(mlp, SharedMLP)
    grouped = torch.randn(2, 300, 32, mlp[0].in_channels, generator=torch.Generator().manual_seed(1))  # [B x S x k x C]
    with torch.no_grad():  # float32, as run: the same up to the order of the sums
        plain = torch.nn.Sequential(*copy.deepcopy(list(mlp)))
        fast, reference = mlp(grouped.permute(0, 3, 1, 2)), plain(grouped.permute(0, 3, 1, 2).contiguous())
        # 3.6e-5 at most measured, on outputs up to ~6; exactness is the float64 check below, so this margin only
        # has to clear float32 rounding on any thread count
        torch.testing.assert_close(fast, reference, rtol=1e-4, atol=5e-4)
    # float64 for gradients: float32 rounding can flip a ReLU near 0 and route a gradient elsewhere
    mlp, plain = mlp.double(), plain.double()
    fast_in = grouped.double().permute(0, 3, 1, 2).requires_grad_()  # channels-last, as SetAbstraction builds it
    plain_in = grouped.double().permute(0, 3, 1, 2).contiguous().requires_grad_()
    fast, reference = mlp(fast_in), plain(plain_in)
    torch.testing.assert_close(fast, reference, rtol=1e-10, atol=1e-10)
    weights = torch.randn(reference.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    (fast * weights).sum().backward()
    (reference * weights).sum().backward()
    torch.testing.assert_close(fast_in.grad, plain_in.grad, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(mlp[0].weight.grad, plain[0].weight.grad, rtol=1e-9, atol=1e-9)


def official_set_abstraction(cin: int, mlp: tuple[int, ...]) -> torch.nn.Module:
    """the official size's SA in eval mode with float64 weights and batch-norm statistics away from identity."""
    from i2pbench_edgeregnet.official.pointnet2 import SetAbstraction

    sa = SetAbstraction(cin, mlp).double().eval()
    g = torch.Generator().manual_seed(3)
    for bn in sa.mlp_bns:
        for tensor in (bn.weight, bn.bias, bn.running_mean):
            tensor.data.copy_(torch.randn(tensor.shape, generator=g, dtype=torch.float64))
        bn.running_var.copy_(torch.rand(bn.running_var.shape, generator=g, dtype=torch.float64) + 0.5)
    return sa


@pytest.mark.parametrize("cin, mlp", [(4, (16, 16, 24)), (21, (8, 16, 24))], ids=["grouped-input", "per-point"])
def test_official_set_abstraction_on_each_balls_own_points_gives_the_dense_max(cin, mlp):
    """eval: the MLP on each ball's own points (repeats left out), balls of like size in blocks (CHUNK_ROWS patched
    small: many blocks), folded norms, gives the authors' dense [B x S x k] computation; with features wider than
    the first layer (SA2's case), that layer runs per point and per centre."""
    from i2pbench_edgeregnet.official import pointnet2 as official_pointnet2

    from i2pbench.layers.pointnet2 import ball_query_torch

    g = torch.Generator().manual_seed(4)
    xyz = torch.rand(2, 400, 3, generator=g, dtype=torch.float64)
    feats = torch.cat([xyz, torch.rand(2, 400, cin - 3, generator=g, dtype=torch.float64)], -1)
    centres = torch.stack([torch.randperm(400, generator=g)[:60] for _ in range(2)])
    balls = ball_query_torch(xyz, torch.stack([xyz[b, centres[b]] for b in range(2)]), 0.3, 32)
    counts = [len(set(row)) for row in balls.flatten(0, 1).tolist()]
    assert min(counts) < 16 and max(counts) == 32  # short balls (padded with repeats) and full ones
    sa = official_set_abstraction(cin, mlp)
    with torch.no_grad(), pytest.MonkeyPatch.context() as patch:
        patch.setattr(official_pointnet2, "CHUNK_ROWS", 100)
        centroids, ragged = sa(xyz, feats, centres, balls)
        dense_centroids, dense = sa.dense(xyz, feats, centres, balls)
    assert torch.equal(centroids, dense_centroids)
    torch.testing.assert_close(ragged, dense, rtol=1e-12, atol=1e-12)
    assert ragged.shape == (2, 60, 24) and (ragged > 0).any() and (ragged == 0).any()  # ReLU'd maxima, not zeros


def test_official_set_abstraction_trains_on_every_slot():
    """with batch statistics the repeats of a short ball count in the norm (as in the authors' code): training
    takes the dense path, and its output differs from the eval path's."""
    g = torch.Generator().manual_seed(5)
    xyz = torch.rand(1, 50, 3, generator=g, dtype=torch.float64)
    balls = torch.tensor([[[0, 3, 7, 0], [1, 1, 1, 1], [2, 9, 11, 20]]])
    sa = official_set_abstraction(3, (8,)).train()
    trained = sa(xyz, xyz, balls[..., 0], balls)[1]
    torch.testing.assert_close(trained, sa.dense(xyz, xyz, balls[..., 0], balls)[1], rtol=0, atol=0)
    assert not torch.allclose(trained, sa.eval()(xyz, xyz, balls[..., 0], balls)[1])


@pytest.mark.parametrize("height", [64, 77, 100, 33])
def test_official_image_cnn_in_strips_gives_the_whole_image_layers(height):
    """the official SuperPoint's full-resolution block in strips of STRIP_ROWS rows gives the layers run on the
    whole image one after the other (the authors' forward), at heights that are and are not multiples of the strip,
    odd ones included (the pool drops the last row)."""
    import torch.nn.functional as F
    from i2pbench_edgeregnet.official.superpoint import STRIP_ROWS, VGG, OfficialSuperPoint

    encoder = OfficialSuperPoint().eval()
    image = torch.randn(2, 1, height, 72, generator=torch.Generator().manual_seed(6))
    with torch.no_grad():
        x = image
        for i, (name, _, _) in enumerate(VGG):
            x = F.relu(getattr(encoder, name)(x))
            if i in (1, 3, 5):
                x = F.max_pool2d(x, 2, 2)
        expected = F.normalize(encoder.convDb(F.relu(encoder.convDa(x))), p=2, dim=1)
        ours = encoder.dense(image)
    assert height > STRIP_ROWS and ours.shape == expected.shape == (2, 256, height // 8, 9)
    torch.testing.assert_close(ours, expected, rtol=0, atol=1e-6)


def test_official_log_assignment_in_blocks_gives_the_whole_matrix_form():
    """without gradients the official log assignment is written block by block (BLOCK patched small: blocks of
    whole columns, then of whole rows, and a remainder); it gives the authors' whole-matrix expression, dustbins and
    corner included; with gradients the whole-matrix form runs and the gradient reaches sim."""
    from i2pbench_edgeregnet.official import matching as official_matching

    g = torch.Generator().manual_seed(7)
    sim = torch.randn(2, 45, 38, generator=g) * 6
    z3d, z2d = torch.randn(2, 45, generator=g), torch.randn(2, 38, generator=g)
    expected = official_matching.whole_log_assignment(sim, z3d, z2d)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(official_matching, "BLOCK", 16)
        ours = official_matching.log_assignment(sim, z3d, z2d)
        torch.testing.assert_close(ours, expected, rtol=0, atol=1e-5)
        assert ours[:, -1, -1].eq(0).all() and ours[:, :-1, :-1].exp().sum() > 1  # corner; a real assignment
        trained = sim.clone().requires_grad_()
        official_matching.log_assignment(trained, z3d, z2d)[:, :-1, :-1].sum().backward()
    assert trained.grad is not None and trained.grad.abs().sum() > 0
