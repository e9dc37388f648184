"""The authors' image branch (model/imagenet.py): a ResNet-34 whose every normalisation is a parameter-free
InstanceNorm (their `ResNet` defaults `norm_layer` to `nn.InstanceNorm2d` and `resnet34` keeps it), returning the
maps at strides 2 to 32 and the pooled stride-32 map; and the decoder's `ResidualConv` / `ImageUpSample` (BatchNorm).
Module names are theirs (`backbone.layerN.i.conv1`, `conv.j.conv_skip.0`), so their state dict loads as it is; the
ImageNet classifier `backbone.fc` is left out (their forward never uses it; official/importer.py drops its keys)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def conv3x3(cin: int, cout: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, stride, 1, bias=False)


class BasicBlock(nn.Module):
    """two 3x3 convolutions, each instance-normalised, with an identity or strided 1x1 (normalised) shortcut."""

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1, self.bn1 = conv3x3(cin, cout, stride), nn.InstanceNorm2d(cout)
        self.conv2, self.bn2 = conv3x3(cout, cout), nn.InstanceNorm2d(cout)
        self.downsample = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.InstanceNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.bn2(self.conv2(F.relu(self.bn1(self.conv1(x)))))
        return F.relu(out + (x if self.downsample is None else self.downsample(x)))


class ResNet34(nn.Module):
    """image [B x 3 x H x W] -> [s2, s4, s8, s16, s32 maps, pooled s32 [B x 512 x 1 x 1]]."""

    def __init__(self) -> None:
        super().__init__()
        self.conv1, self.bn1 = nn.Conv2d(3, 64, 7, 2, 3, bias=False), nn.InstanceNorm2d(64)
        cin = 64
        for n, (count, width) in enumerate(zip((3, 4, 6, 3), (64, 128, 256, 512), strict=True)):
            blocks = [BasicBlock(cin, width, 1 if n == 0 else 2)] + [BasicBlock(width, width) for _ in range(count - 1)]
            self.add_module(f"layer{n + 1}", nn.Sequential(*blocks))
            cin = width

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = F.relu(self.bn1(self.conv1(x)))
        maps = [x]
        x = F.max_pool2d(x, 3, 2, 1)
        for n in range(1, 5):
            x = getattr(self, f"layer{n}")(x)
            maps.append(x)
        return [*maps, F.adaptive_avg_pool2d(x, 1)]


class ImageEncoder(nn.Module):
    """the authors' wrapper: the ResNet under `backbone`."""

    def __init__(self) -> None:
        super().__init__()
        self.backbone = ResNet34()

    def forward(self, image: torch.Tensor) -> list[torch.Tensor]:
        return self.backbone(image)


class ResidualConv(nn.Module):
    """two 3x3 conv + BatchNorm with a 3x3 conv + BatchNorm shortcut (`kernel_1` off, stride 1, as used)."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.conv1, self.bn1 = conv3x3(cin, cout), nn.BatchNorm2d(cout)
        self.conv2, self.bn2 = conv3x3(cout, cout), nn.BatchNorm2d(cout)
        self.conv_skip = nn.Sequential(conv3x3(cin, cout), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.bn2(self.conv2(F.relu(self.bn1(self.conv1(x)))))
        return F.relu(out + self.conv_skip(x))


class ImageUpSample(nn.Module):
    """bilinear x2 of the coarse map (align_corners off), concatenated before the skip map, two residual blocks."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.conv = nn.Sequential(ResidualConv(cin, cout), ResidualConv(cout, cout))

    def forward(self, coarse: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        up = F.interpolate(coarse, scale_factor=2, mode="bilinear", align_corners=False)
        return self.conv(torch.cat([up, skip], 1))
