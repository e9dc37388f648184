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
