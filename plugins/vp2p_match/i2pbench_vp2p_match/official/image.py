"""VP2P-Match's image branch (`Image_ResNet`): a ResNet-34 in torchvision's layout returning the maps of every
stride, then three upsampling stages back to a quarter of the input's resolution.

The encoder's maps after the stem (/2), each stage (/4 ... /32) and the global average pool; the decoder upsamples
the /32 map bilinearly, concatenates the /16 one and runs two residual blocks whose shortcut is a 3x3 convolution
(`ResidualConv`), then the same with /8, then with /4 beside the stem's map halved by nearest sampling. Module names
are the authors' (`encoder.backbone.layer3.5.conv2.weight`, `up_conv2.conv.1.conv_skip.0.weight`, ...); the
backbone's unused classifier `fc` is kept so their state dict loads strictly.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

STAGES = ((64, 3, 1), (128, 4, 2), (256, 6, 2), (512, 3, 2))  # ResNet-34: (width, blocks, stride) per stage


def conv3x3(c_in: int, c_out: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(c_in, c_out, 3, stride, padding=1, bias=False)


class BasicBlock(nn.Module):
    """torchvision's ResNet basic block: two 3x3 convolutions beside an identity (or 1x1 projection) shortcut."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1, self.bn1 = conv3x3(c_in, c_out, stride), nn.BatchNorm2d(c_out)
        self.conv2, self.bn2 = conv3x3(c_out, c_out), nn.BatchNorm2d(c_out)
        self.relu = nn.ReLU()
        self.downsample = None
        if stride != 1 or c_in != c_out:
            self.downsample = nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride, bias=False), nn.BatchNorm2d(c_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.bn2(self.conv2(self.relu(self.bn1(self.conv1(x)))))
        return self.relu(out + (x if self.downsample is None else self.downsample(x)))


class ResNet34(nn.Module):
    """[B x 3 x H x W] -> the maps at /2, /4, /8, /16, /32 and the [B x 512 x 1 x 1] average."""

    def __init__(self) -> None:
        super().__init__()
        self.conv1, self.bn1 = nn.Conv2d(3, 64, 7, 2, padding=3, bias=False), nn.BatchNorm2d(64)
        self.relu, self.maxpool = nn.ReLU(), nn.MaxPool2d(3, 2, padding=1)
        c_in = 64
        for i, (width, blocks, stride) in enumerate(STAGES, start=1):
            layers = [BasicBlock(c_in, width, stride)] + [BasicBlock(width, width) for _ in range(blocks - 1)]
            setattr(self, f"layer{i}", nn.Sequential(*layers))
            c_in = width
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        self.fc = nn.Linear(512, 1000)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        maps = [self.relu(self.bn1(self.conv1(x)))]
        x = self.maxpool(maps[0])
        for layer in (self.layer1, self.layer2, self.layer3, self.layer4):
            x = layer(x)
            maps.append(x)
        return [*maps, self.avgpool(x)]


class Encoder(nn.Module):
    """the backbone under `backbone`, as the authors' ImageEncoder holds it."""

    def __init__(self) -> None:
        super().__init__()
        self.backbone = ResNet34()

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        return self.backbone(x)


class ResidualConv(nn.Module):
    """two 3x3 convolutions beside a 3x3 convolution shortcut."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.conv1, self.bn1 = conv3x3(c_in, c_out), nn.BatchNorm2d(c_out)
        self.conv2, self.bn2 = conv3x3(c_out, c_out), nn.BatchNorm2d(c_out)
        self.relu = nn.ReLU()
        self.conv_skip = nn.Sequential(conv3x3(c_in, c_out), nn.BatchNorm2d(c_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.bn2(self.conv2(self.relu(self.bn1(self.conv1(x)))))
        return self.relu(out + self.conv_skip(x))


class UpSample(nn.Module):
    """the coarse map doubled bilinearly, the finer one beside it, two residual blocks."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.conv = nn.Sequential(ResidualConv(c_in, c_out), ResidualConv(c_out, c_out))

    def forward(self, coarse: torch.Tensor, fine: torch.Tensor) -> torch.Tensor:
        up = F.interpolate(coarse, scale_factor=2, mode="bilinear", align_corners=False)
        return self.conv(torch.cat([up, fine], dim=1))


class ImageResNet(nn.Module):
    """[B x 3 x H x W] -> global [B x 512], per-pixel [B x 64 x H/4 x W/4]."""

    def __init__(self) -> None:
        super().__init__()
        self.encoder = Encoder()
        self.up_conv1 = UpSample(512 + 256, 256)
        self.up_conv2 = UpSample(256 + 128, 128)
        self.up_conv3 = UpSample(128 + 64 + 64, 64)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        trace = self.trace(image)
        return trace["global"], trace["mid"]

    def trace(self, image: torch.Tensor) -> dict[str, torch.Tensor]:
        """the global feature, the /32 map and each upsampling stage's output (`f16`, `f8`, `mid`)."""
        s2, s4, s8, s16, s32, pooled = self.encoder(image)
        f16 = self.up_conv1(s32, s16)
        f8 = self.up_conv2(f16, s8)
        mid = self.up_conv3(f8, torch.cat([s4, F.interpolate(s2, scale_factor=0.5)], dim=1))
        return {"global": pooled.flatten(1), "s32": s32, "f16": f16, "f8": f8, "mid": mid}
