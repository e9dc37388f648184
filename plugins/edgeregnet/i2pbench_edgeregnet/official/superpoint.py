"""The authors' 2D branch (ESRSchao/EdgeRegNet, models/superpoint.py): SuperPoint's VGG on a fixed grey canvas, its
descriptor head L2-normalised, sampled at the edge pixels as SuperGlue's `sample_descriptors` and normalised again.

Preprocessing is the authors' data loader (KITTI_bin.py:104-110): the image turned grey as PIL's `convert("L")`
(integer BT.601 weights, rounded), pasted at the top-left of a black 1250 x 376 canvas (a larger image is cropped),
then `(x / 255 - 0.485) / 0.229`. The detector head (convPa, convPb) is kept so the authors' state dict and Magic
Leap's `superpoint_v1.pth` load whole; the authors' forward computes keypoints from it that nothing reads, so it is
not run here.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, Encoder2D, Frame, Keypoints2D

VGG = (("conv1a", 1, 64), ("conv1b", 64, 64), ("conv2a", 64, 64), ("conv2b", 64, 64))
VGG += (("conv3a", 64, 128), ("conv3b", 128, 128), ("conv4a", 128, 128), ("conv4b", 128, 128))
HEADS = (("convPa", 128, 256, 3), ("convPb", 256, 65, 1), ("convDa", 128, 256, 3), ("convDb", 256, 256, 1))
STRIP_ROWS = 32  # even (the 2x2 pool's rows stay paired); 16 here gave other roundings, 32-96 the same values
PIL_GREY = (19595, 38470, 7471)  # PIL's fixed-point BT.601 weights (x 2^16) of convert("L")


def pil_grey(image: np.ndarray) -> np.ndarray:
    """rgb uint8 [H x W x 3] -> grey uint8 [H x W], exactly as PIL's `Image.convert("L")`."""
    rgb = image.astype(np.uint32)
    r, g, b = PIL_GREY
    return ((rgb[..., 0] * r + rgb[..., 1] * g + rgb[..., 2] * b + 0x8000) >> 16).astype(np.uint8)


def canvas(grey: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """grey uint8 [H x W] pasted at the top-left of a black canvas of size (W, H), cropped where larger."""
    width, height = size
    out = np.zeros((height, width), np.uint8)
    h, w = min(height, grey.shape[0]), min(width, grey.shape[1])
    out[:h, :w] = grey[:h, :w]
    return out


def sample_descriptors(fmap: torch.Tensor, uv: torch.Tensor, s: int = 8) -> torch.Tensor:
    """SuperGlue's lookup of fmap [B x D x Hc x Wc] at pixels uv [B x M x 2] -> L2-normalised [B x M x D].

    Its mapping is kept as written: pixel x to (x - s/2 + 0.5) / (Wc s - s/2 - 0.5) * 2 - 1 with align_corners=True
    and zero padding (not the cell-centre mapping of superpoint.py)."""
    _, _, h, w = fmap.shape
    scale = uv.new_tensor([w * s - s / 2 - 0.5, h * s - s / 2 - 0.5])
    grid = (uv - s / 2 + 0.5) / scale * 2 - 1
    out = F.grid_sample(fmap, grid[:, None], mode="bilinear", align_corners=True)[:, :, 0]
    return F.normalize(out, p=2, dim=1).transpose(1, 2)


class OfficialSuperPoint(BatchedStage, Encoder2D):
    """The authors' SuperPoint descriptors of edge pixels (module docstring)."""

    name = "superpoint-official"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 256,  # D (fixed by SuperPoint's head; declared for the compatibility check)
        "canvas": (1250, 376),  # (W, H) of the black canvas the grey image is pasted on (KITTI_bin.py:106)
        "mean": 0.485,  # transforms.Normalize (KITTI_bin.py:73)
        "std": 0.229,
    }
    stride = 8

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        for name, cin, cout in VGG:
            setattr(self, name, nn.Conv2d(cin, cout, 3, padding=1))
        for name, cin, cout, k in HEADS:
            setattr(self, name, nn.Conv2d(cin, cout, k, padding=k // 2))
        self.to(memory_format=torch.channels_last)  # oneDNN then keeps activations NHWC (superpoint.py says why)

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, device: torch.device | str = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's network inputs: the normalised canvas [1 x H x W] and the edge pixels [M x 2]."""
        grey = canvas(pil_grey(frame.image), tuple(self.conf["canvas"]))
        image = (torch.from_numpy(grey).float() / 255 - self.conf["mean"]) / self.conf["std"]
        uv = torch.from_numpy(np.asarray(kp2d.uv, np.float32))
        return {"image": image[None].to(device), "uv": uv.to(device)}

    def dense(self, image: torch.Tensor) -> torch.Tensor:
        """image [B x 1 x H x W] -> the descriptor map [B x D x H/8 x W/8], L2-normalised (superpoint.py:148-193)."""
        x = self.full_resolution(image)
        for i, (name, _, _) in enumerate(VGG[2:], start=2):
            x = F.relu(getattr(self, name)(x))
            if i in (3, 5):
                x = F.max_pool2d(x, 2, 2)
        return F.normalize(self.convDb(F.relu(self.convDa(x))), p=2, dim=1)

    def full_resolution(self, image: torch.Tensor) -> torch.Tensor:
        """conv1a and conv1b (3x3 + ReLU each) and the first 2x2 max pool of image [B x 1 x H x W], STRIP_ROWS
        output rows at a time.

        Whole, each of the two 64-channel activations is a [B x 64 x H x W] tensor (120 MB at 1250 x 376), too large
        for the allocator to keep, so every frame writes it to fresh pages: 635 ms of CPU for this block here, 363
        in strips (the same values: each strip's rows are computed from the rows around them, zeros beyond the
        image as the convolutions' padding)."""
        height, strips = image.shape[2], []
        pooled = height - height % 2  # the pool drops an odd last row: no strip computes it
        for top in range(0, pooled, STRIP_ROWS):
            bottom = min(pooled, top + STRIP_ROWS)
            first = max(top - 2, 0)  # conv1a's rows top - 1 .. bottom are conv1b's input; they read one more
            x = F.relu_(self.conv1a(image[:, :, first : min(bottom + 2, height)]))
            x = x[:, :, max(top - 1, 0) - first : min(bottom + 1, height) - first]
            if top == 0 or bottom == height:  # conv1b's zero padding at the image's top and bottom rows
                x = F.pad(x, (0, 0, int(top == 0), int(bottom == height)))
            x = F.relu_(F.conv2d(x, self.conv1b.weight, self.conv1b.bias, padding=(0, 1)))
            strips.append(F.max_pool2d(x, 2, 2))
        return torch.cat(strips, 2)

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """`prepare`d frames: image [B x 1 x H x W], uv [B x M x 2] -> descriptors [B x M x D]."""
        return sample_descriptors(self.dense(inputs["image"]), inputs["uv"], self.stride)
