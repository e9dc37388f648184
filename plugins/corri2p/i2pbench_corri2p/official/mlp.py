"""The authors' shared per-point layers (layers_pc.py `EquivariantLayer`, `PointNet`, `MyConv2d`): a 1x1
convolution with bias, then BatchNorm and ReLU, the last layer optionally bare."""

from __future__ import annotations

from torch import nn


class ConvNormAct(nn.Sequential):
    """1x1 conv (with bias) -> BatchNorm -> ReLU over [B x C x N] (dims 1) or [B x C x M x K] (dims 2)."""

    def __init__(self, cin: int, cout: int, dims: int = 1, bare: bool = False) -> None:
        conv, norm = (nn.Conv1d, nn.BatchNorm1d) if dims == 1 else (nn.Conv2d, nn.BatchNorm2d)
        super().__init__(conv(cin, cout, 1), *(() if bare else (norm(cout), nn.ReLU())))


class PointMLP(nn.Sequential):
    """widths' 1x1 layers on [B x C x N]; `act_last=False` leaves the last one a bare convolution (the authors'
    `norm_act_at_last`)."""

    def __init__(self, cin: int, widths: tuple[int, ...], act_last: bool = True, dims: int = 1) -> None:
        cins = (cin, *widths[:-1])
        last = len(widths) - 1
        pairs = enumerate(zip(cins, widths, strict=True))
        super().__init__(*(ConvNormAct(i, o, dims, bare=n == last and not act_last) for n, (i, o) in pairs))


def conv_bn_relu_1x1(widths: tuple[int, ...], dims: int) -> nn.Sequential:
    """the heads' and image attentions' stacks (network.py): bias-free 1x1 convs, BatchNorm + ReLU between them,
    the last conv bare."""
    conv, norm = (nn.Conv1d, nn.BatchNorm1d) if dims == 1 else (nn.Conv2d, nn.BatchNorm2d)
    layers: list[nn.Module] = []
    for n, (cin, cout) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
        layers.append(conv(cin, cout, 1, bias=False))
        if n < len(widths) - 2:
            layers += [norm(cout), nn.ReLU()]
    return nn.Sequential(*layers)
