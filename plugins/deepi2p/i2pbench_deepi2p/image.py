"""DeepI2P's image branch (Li & Lee, CVPR 2021, Sec. 3.1): a ResNet on the resized image whose stride-16 and
stride-32 maps, read at each 2D keypoint (the grid cells' centres), and its global feature describe the image.

Each keypoint's descriptor is [local (D - G) | global (G)], the layout CorrI2P's encoders use (the fusion exchanger
reads the last G channels as the image's global feature): local is the stride-16 and stride-32 features sampled
bilinearly at the keypoint, projected to D - G channels (none when their widths add up to D - G), L2-normalised;
global is the average-pooled stride-32 map. The paper's ResNet-34 widths are the defaults (256 channels at stride 16,
512 at stride 32 and global).

Built from CorrI2P's residual blocks (`i2pbench.layers.resnet`) and the SuperPoint-style sampling and per-image
normalisation (`i2pbench.layers.sampling`). What differs from the paper, and why: no ImageNet initialisation (the
paper's ResNet-34 is pretrained); GroupNorm instead of BatchNorm (one-frame training steps); no crop, the whole
image is resized by `image_scale` (the paper crops KITTI's top 50 rows and takes 160 x 512 of the half-size image),
so any image size works and no part of the frame goes unseen.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, Encoder2D, Frame, Keypoints2D
from i2pbench.layers.resnet import coarse_mask, norm, stage
from i2pbench.layers.sampling import normalize_images, sample_descriptors


def resized(frame: Frame, kp2d: Keypoints2D, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(the frame's image resized by `scale`, OpenCV linear; the keypoints in its pixels, centres mapped as
    u' = (u + 0.5) w / W - 0.5)."""
    width, height = frame.image_size
    w, h = max(int(round(width * scale)), 1), max(int(round(height * scale)), 1)
    image = np.ascontiguousarray(frame.image)
    if (w, h) != (width, height):
        image = cv2.resize(image, (w, h), interpolation=cv2.INTER_LINEAR)
    ratio = np.array([w / width, h / height], np.float32)
    return np.ascontiguousarray(image), (np.asarray(kp2d.uv, np.float32).reshape(-1, 2) + 0.5) * ratio - 0.5


class DeepI2PImageEncoder(BatchedStage, Encoder2D):
    """Per-keypoint [local | global] descriptors from a ResNet's stride-16 and stride-32 maps."""

    name = "deepi2p-resnet"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 768,  # D: local (D - G) + global (G) channels per keypoint
        "global_dim": 512,  # G: the image's global feature (ResNet-34's 512-wide stride-32 map, average-pooled)
        "blocks": (3, 4, 6, 3),  # residual blocks per stage (ResNet-34, the paper's)
        "channels": (64, 128, 256, 512),  # stage widths at strides 4, 8, 16, 32
        "stem_channels": 64,  # the 7x7 stride-2 stem
        "image_scale": 0.5,  # resize before the CNN (the paper: half-size images)
        "groups": 8,  # GroupNorm groups
        "normalize_descriptors": True,  # L2-normalise the local part
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        c, g = self.conf, self.conf["groups"]
        local, widths = c["descriptor_dim"] - c["global_dim"], tuple(c["channels"])
        if local < 1 or len(widths) != 4 or len(c["blocks"]) != 4:
            raise ValueError(f"{self.label}: needs descriptor_dim > global_dim and 4 stages")
        stem = c["stem_channels"]
        self.stem = nn.Sequential(nn.Conv2d(3, stem, 7, 2, 3, bias=False), norm(stem, g), nn.ReLU(inplace=True))
        ins, strides = (stem, *widths[:3]), (1, 2, 2, 2)
        self.stages = nn.ModuleList(
            stage(i, o, n, s, g) for i, o, n, s in zip(ins, widths, c["blocks"], strides, strict=True)
        )
        sampled = widths[2] + widths[3]
        self.local_head = nn.Identity() if sampled == local else nn.Linear(sampled, local)
        self.global_head = nn.Identity() if widths[3] == c["global_dim"] else nn.Linear(widths[3], c["global_dim"])

    def compile_targets(self) -> list[nn.Module]:
        """the convolutions, over a fixed image size (the sampling stays eager)."""
        return [self.stem, *self.stages]

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, device: torch.device | str = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's inputs: the resized RGB image [3 x h x w] in [0, 1], its size [2] (h, w), and the keypoints
        [M x 2] in its pixels."""
        image, uv = resized(frame, kp2d, self.conf["image_scale"])
        rgb = torch.from_numpy(image).to(device=device, dtype=torch.float32)
        return {
            "image": rgb.permute(2, 0, 1) / 255.0,
            "size": torch.tensor(image.shape[:2], device=device),
            "uv": torch.from_numpy(np.ascontiguousarray(uv)).to(device),
        }

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """a batch of `prepare`d frames: image [B x 3 x h x w] (zero-padded to the largest), size [B x 2], uv
        [B x M x 2] -> descriptors [B x M x D], [local | global]."""
        x = self.stages[0](F.max_pool2d(self.stem(normalize_images(inputs["image"], inputs["size"])), 3, 2, 1))
        s16 = self.stages[2](self.stages[1](x))
        s32 = self.stages[3](s16)
        uv = inputs["uv"]
        local = self.local_head(torch.cat([sample_descriptors(s16, uv, 16), sample_descriptors(s32, uv, 32)], -1))
        if self.conf["normalize_descriptors"]:
            local = F.normalize(local, dim=-1)
        valid = coarse_mask(inputs["size"], s32.shape[-2:], 32)
        glob = self.global_head((s32 * valid).sum((2, 3)) / valid.sum((2, 3)).clamp(min=1))  # [B x G]
        return torch.cat([local, glob[:, None].expand(-1, local.shape[1], -1)], -1)
