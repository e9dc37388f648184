"""DeepI2P's image branch: a ResNet-34 (the authors' `models/resnet.py`, torchvision's layout and key names) whose
1/16 and 1/32 maps and global average the network reads. The authors' unused ImageNet `fc` head is left out; their
checkpoints' `fc.*` keys are dropped on import.
"""

from __future__ import annotations

import torch
from torch import nn


class BasicBlock(nn.Module):
    """two 3x3 convolutions with BatchNorm, an identity or strided 1x1 `downsample` shortcut."""

    def __init__(self, cin: int, cout: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU()
        shortcut = stride != 1 or cin != cout
        self.downsample = (
            nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout)) if shortcut else None
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.bn2(self.conv2(self.relu(self.bn1(self.conv1(x)))))
        return self.relu(y + (x if self.downsample is None else self.downsample(x)))


class ResNet34(nn.Module):
    """[B x 3 x H x W] (pixel values 0-255, as the authors feed it) -> (1/16 map, 1/32 map, [B x 512 x 1 x 1])."""

    def __init__(self, blocks: tuple[int, ...] = (3, 4, 6, 3), widths: tuple[int, ...] = (64, 128, 256, 512)) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(3, 64, 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU()
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        cin = 64
        for n, (count, width) in enumerate(zip(blocks, widths, strict=True)):
            stride = 1 if n == 0 else 2
            stage = [BasicBlock(cin if b == 0 else width, width, stride if b == 0 else 1) for b in range(count)]
            self.add_module(f"layer{n + 1}", nn.Sequential(*stage))
            cin = width

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.layer1(self.maxpool(self.relu(self.bn1(self.conv1(image)))))
        s16 = self.layer3(self.layer2(x))
        s32 = self.layer4(s16)
        return s16, s32, s32.mean(dim=(2, 3), keepdim=True)
