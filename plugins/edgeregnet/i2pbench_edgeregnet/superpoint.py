"""SuperPoint-style VGG encoder: a stride-8 descriptor map sampled bilinearly at the 2D edge pixels.

Coordinate mapping: pixel centres sit at integer (u, v) (the convention of LSD and of `Keypoints2D`). Descriptor cell
(i, j) pools pixels [8j, 8j + 8) x [8i, 8i + 8), so its centre is at u = 8j + 3.5, v = 8i + 3.5. A pixel therefore
lies at cell coordinate x = (u - 3.5) / 8, which `grid_sample(align_corners=True)` reads at 2x / (Wc - 1) - 1;
pixels beyond the outer cell centres take the border cell's value. With `image_scale` s the image is resized first
(pixel centres map as u' = (u + 0.5) s - 0.5), which is the same mapping with stride 8 / s.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, Encoder2D, Frame, Keypoints2D
from i2pbench.layers.sampling import normalize_images, sample_descriptors

GREY_WEIGHTS = (0.299, 0.587, 0.114)  # ITU-R BT.601, as cv2.cvtColor(RGB2GRAY)


def to_grey(image: np.ndarray, device: torch.device | str = "cpu") -> torch.Tensor:
    """rgb uint8 [H x W x 3] -> grey float [1 x H x W] in [0, 1]."""
    rgb = torch.from_numpy(np.ascontiguousarray(image)).to(device=device, dtype=torch.float32)
    grey = rgb @ torch.tensor(GREY_WEIGHTS, device=device) / 255.0
    return grey[None]


def conv(cin: int, cout: int, kernel: int = 3) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, kernel, padding=kernel // 2)


class SuperPointEncoder(BatchedStage, Encoder2D):
    """Descriptors of image edge pixels from a VGG backbone on the grayscale image."""

    name = "superpoint-cnn"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 256,  # D, the output width
        "channels": (64, 64, 128, 128),  # widths of the four VGG stages (pooling after the first three: stride 8)
        "head_channels": 256,  # the 3x3 conv of the descriptor head, before the 1x1 conv to D
        "image_scale": 1.0,  # resize the image before the CNN: 0.5 quarters its cost (descriptor stride 16 px)
        "normalize_image": True,  # zero mean / unit std per image (robust to exposure); False: grey in [0, 1]
        "normalize_descriptors": True,  # L2-normalise sampled descriptors, as SuperPoint and SuperGlue's input
    }
    stride = 8

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        c1, c2, c3, c4 = self.conf["channels"]
        layers: list[nn.Module] = []
        cin = 1
        for i, c in enumerate((c1, c2, c3, c4)):
            layers += [conv(cin, c), nn.ReLU(inplace=True), conv(c, c), nn.ReLU(inplace=True)]
            layers += [nn.MaxPool2d(2, 2)] if i < 3 else []
            cin = c
        self.backbone = nn.Sequential(*layers)
        head = self.conf["head_channels"]
        self.head = nn.Sequential(conv(c4, head), nn.ReLU(inplace=True), conv(head, self.conf["descriptor_dim"], 1))
        # channels-last (NHWC) weights make oneDNN keep every activation in NHWC: no layout reorder around each conv,
        # pooling vectorised over channels; 1.6-1.8x faster on this CPU, outputs equal to ~1e-8
        # (tests/test_edgeregnet_layouts.py)
        self.to(memory_format=torch.channels_last)

    def compile_targets(self) -> list[nn.Module]:
        """the VGG backbone and descriptor head: convolutions over a fixed image size (the sampling is left eager)."""
        return [self.backbone, self.head]

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, device: torch.device | str = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's network inputs: grey image [1 x H x W], its size [2] (H, W) and the edge pixels [M x 2]."""
        grey = to_grey(frame.image, device)
        uv = torch.from_numpy(np.asarray(kp2d.uv, np.float32)).to(device)
        return {"grey": grey, "size": torch.tensor(grey.shape[1:], device=device), "uv": uv}

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """a batch of `prepare`d frames: grey [B x 1 x H x W] in [0, 1] (zero-padded to the largest), size [B x 2],
        uv [B x M x 2] pixels -> descriptors [B x M x D]. Frames of one size are exact; a smaller frame in a batch of
        larger ones sees padding instead of its border beyond the first layer's receptive field."""
        grey, size, scale = inputs["grey"], inputs["size"], self.conf["image_scale"]
        if scale != 1.0:
            grey = F.interpolate(grey, scale_factor=scale, mode="bilinear", antialias=True)
            size = (size * scale).floor().long()
        if self.conf["normalize_image"]:
            grey = normalize_images(grey, size)
        fmap = self.head(self.backbone(grey))
        desc = sample_descriptors(fmap, inputs["uv"], self.stride / scale)
        return F.normalize(desc, dim=-1) if self.conf["normalize_descriptors"] else desc
