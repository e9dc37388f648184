"""The authors' point branch (model/kpconv/kp_backbone.py `KPConvFPN`, modules.py), GeoTransformer's KPConv-FPN:
five stages of KPConv residual blocks on the pyramid of `pc_data_dict` (each stage half the points of the one
before), then a nearest-upsampling decoder back to stage 2. Module names are theirs (`encoder2_1.KPConv.weights`,
`decoder4.norm.norm.weight`). Normalisation is GroupNorm over a stage's points (options.py `norm = 'gn'`, 32 groups,
both datasets); their `get_norm` also offers 'bn' and 'ln', which no released option uses and this module leaves out.
"""

from __future__ import annotations

import torch
from torch import nn

from i2pbench.layers.kpconv import KPConv, nearest_upsample, neighbour_maxpool

GROUPS = 32  # options.py group_norm


class PointGroupNorm(nn.Module):
    """GroupNorm over the channels of a stage's points [N x C] (their `GroupNorm` wrapper: the nn module as `norm`)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.norm = nn.GroupNorm(GROUPS, channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.norm(x.T[None])[0].T


class UnaryBlock(nn.Module):
    """Linear, GroupNorm and (unless `relu` is off) LeakyReLU(0.1)."""

    def __init__(self, cin: int, cout: int, relu: bool = True) -> None:
        super().__init__()
        self.mlp, self.norm = nn.Linear(cin, cout), PointGroupNorm(cout)
        self.relu = relu

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.norm(self.mlp(x))
        return nn.functional.leaky_relu(x, 0.1) if self.relu else x


class LastUnaryBlock(nn.Module):
    """a plain Linear (the decoder's last layer)."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.mlp = nn.Linear(cin, cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.mlp(x)


class ConvBlock(nn.Module):
    """KPConv, GroupNorm, LeakyReLU(0.1): the first layer."""

    def __init__(self, cin: int, cout: int, radius: float, sigma: float, seed: int) -> None:
        super().__init__()
        self.KPConv = KPConv(cin, cout, KERNEL_SIZE, radius, sigma, seed)
        self.norm = PointGroupNorm(cout)

    def forward(self, feats, queries, support, neighbours) -> torch.Tensor:
        return nn.functional.leaky_relu(self.norm(self.KPConv(feats, queries, support, neighbours)), 0.1)


class ResidualBlock(nn.Module):
    """bottleneck: unary to out/4 channels (skipped when the input already has them), KPConv, GroupNorm, LeakyReLU,
    unary to `cout`; plus the input (max-pooled over the neighbour lists when `strided`, projected when the widths
    differ); LeakyReLU(0.1)."""

    def __init__(self, cin: int, cout: int, radius: float, sigma: float, seed: int, strided: bool = False) -> None:
        super().__init__()
        mid = cout // 4
        self.strided = strided
        self.unary1 = UnaryBlock(cin, mid) if cin != mid else nn.Identity()
        self.KPConv = KPConv(mid, mid, KERNEL_SIZE, radius, sigma, seed)
        self.norm_conv = PointGroupNorm(mid)
        self.unary2 = UnaryBlock(mid, cout, relu=False)
        self.unary_shortcut = UnaryBlock(cin, cout, relu=False) if cin != cout else nn.Identity()

    def forward(self, feats, queries, support, neighbours) -> torch.Tensor:
        x = self.KPConv(self.unary1(feats), queries, support, neighbours)
        x = self.unary2(nn.functional.leaky_relu(self.norm_conv(x), 0.1))
        shortcut = neighbour_maxpool(feats, neighbours) if self.strided else feats
        return nn.functional.leaky_relu(x + self.unary_shortcut(shortcut), 0.1)


KERNEL_SIZE = 15  # network.py: KPConvFPN(kernel_size=15, ...)
INIT_RADIUS, INIT_SIGMA = 4.25 * 0.1, 2 * 0.1  # network.py: init_radius, init_sigma (0.1 m voxels)
# (block, input width, output width, radius and sigma as multiples of the initial ones, strided): kp_backbone.py:11-77
STAGES = (
    ("encoder1_2", 1, 2, 1, False),
    ("encoder2_1", 2, 2, 1, True), ("encoder2_2", 2, 4, 2, False), ("encoder2_3", 4, 4, 2, False),
    ("encoder3_1", 4, 4, 2, True), ("encoder3_2", 4, 8, 4, False), ("encoder3_3", 8, 8, 4, False),
    ("encoder4_1", 8, 8, 4, True), ("encoder4_2", 8, 16, 8, False), ("encoder4_3", 16, 16, 8, False),
    ("encoder5_1", 16, 16, 8, True), ("encoder5_2", 16, 32, 16, False), ("encoder5_3", 32, 32, 16, False),
)  # fmt: skip


class KPConvFPN(nn.Module):
    """pc_data_dict (module docstring of network.py) -> [stage-2 features [N2 x 64], stage-3 [N3 x 512], stage-4
    [N4 x 1024], stage-5 [N5 x 2048]] (theirs, in that order). `seed` draws the kernel dispositions of a network
    built without a checkpoint (block i: seed + i); `trace` receives every block's output by its module name."""

    def __init__(self, cin: int = 4, cout: int = 64, width: int = 64, seed: int = 0) -> None:
        super().__init__()
        self.encoder1_1 = ConvBlock(cin, width, INIT_RADIUS, INIT_SIGMA, seed)
        for i, (name, a, b, scale, strided) in enumerate(STAGES, start=1):
            block = ResidualBlock(a * width, b * width, INIT_RADIUS * scale, INIT_SIGMA * scale, seed + i, strided)
            self.add_module(name, block)
        self.decoder4 = UnaryBlock(48 * width, 16 * width)
        self.decoder3 = UnaryBlock(24 * width, 8 * width)
        self.decoder2 = LastUnaryBlock(12 * width, cout)

    def forward(self, data: dict, trace: dict | None = None) -> list[torch.Tensor]:
        trace = {} if trace is None else trace
        points, neighbours = data["points"], data["neighbors"]
        x = trace["pc_encoder.encoder1_1"] = self.encoder1_1(data["feats"], points[0], points[0], neighbours[0])
        stages = []
        for name, *_, strided in STAGES:
            level = int(name[7]) - 1
            if strided:
                stages.append(x)
                args = (points[level], points[level - 1], data["subsampling"][level - 1])
            else:
                args = (points[level], points[level], neighbours[level])
            x = trace[f"pc_encoder.{name}"] = getattr(self, name)(x, *args)
        latent = x
        outputs = [latent]
        for level, decoder in ((3, self.decoder4), (2, self.decoder3), (1, self.decoder2)):
            up = nearest_upsample(latent, data["upsampling"][level])
            latent = trace[f"pc_encoder.decoder{level + 1}"] = decoder(torch.cat([up, stages[level]], 1))
            outputs.append(latent)
        return outputs[::-1]
