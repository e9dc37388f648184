"""CorrI2P's image branch (half of the paper's "feature embedding" module): a ResNet encoder to stride 32 and a U-Net
decoder back to stride 4 of the resized image, sampled bilinearly at the keypoints, plus the image's global feature.

Each keypoint's descriptor is [local (D - G) | global (G)]: the last `global_dim` channels are the average-pooled
stride-32 map (the same for every keypoint of a frame), which the exchanger reads as this image's global feature.

Choices the paper leaves open or that differ from it, with reasons:
- GroupNorm instead of BatchNorm: training takes one frame (or a padded handful) per step, where batch statistics are
  noise; no ImageNet initialisation (the paper's encoder is trained from scratch too);
- the image is resized in `prepare` (OpenCV, linear, as the paper's loader) and normalised per image (zero mean, unit
  std over its own pixels), so padding in a batch never enters the statistics;
- upsampling goes to the skip connection's exact size, so any image size works (the paper's fixed 160 x 512 crop
  divides by 32); the stride-4 skip is the stride-4 map with the stem's stride-2 map resized onto it, as the paper's;
- keypoints are read off the stride-4 map with SuperPoint's mapping (cell centres at 4 j + 1.5 of the resized image,
  `i2pbench.layers.sampling.sample_descriptors`), from pixels of the original image.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, Encoder2D, Frame, Keypoints2D
from i2pbench.layers.resnet import BasicBlock, coarse_mask, norm, stage
from i2pbench.layers.sampling import normalize_images, sample_descriptors

STRIDE = 4  # of the decoded map, on the resized image


class UpBlock(nn.Module):
    """upsample to the skip's size, concatenate, two residual blocks (the paper's decoder step)."""

    def __init__(self, cin: int, cskip: int, cout: int, groups: int) -> None:
        super().__init__()
        self.blocks = nn.Sequential(BasicBlock(cin + cskip, cout, 1, groups), BasicBlock(cout, cout, 1, groups))

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        return self.blocks(torch.cat([x, skip], 1))


class CorrI2PImageEncoder(BatchedStage, Encoder2D):
    """Per-keypoint [local | global] descriptors from a ResNet encoder-decoder on the resized RGB image."""

    name = "corri2p-resnet"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 640,  # D: local (D - G) + global (G) channels per keypoint
        "global_dim": 512,  # G: the image's global feature (ResNet-34's 512-wide stride-32 map, average-pooled)
        "blocks": (3, 4, 6, 3),  # residual blocks per encoder stage (ResNet-34, the paper's)
        "channels": (64, 128, 256, 512),  # encoder stage widths at strides 4, 8, 16, 32
        "stem_channels": 64,  # the 7x7 stride-2 stem
        "decoder_channels": (256, 128, 64),  # decoder widths at strides 16, 8, 4 (the paper's)
        "image_scale": 0.5,  # resize before the CNN (the paper: half-size images; the map is then stride 8 px)
        "groups": 8,  # GroupNorm groups
        "normalize_descriptors": True,  # L2-normalise the local part
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        c, g = self.conf, self.conf["groups"]
        local = c["descriptor_dim"] - c["global_dim"]
        if local < 1 or len(c["channels"]) != 4 or len(c["blocks"]) != 4 or len(c["decoder_channels"]) != 3:
            raise ValueError(f"{self.label}: needs descriptor_dim > global_dim, 4 encoder and 3 decoder stages")
        stem, widths = c["stem_channels"], tuple(c["channels"])
        self.stem = nn.Sequential(nn.Conv2d(3, stem, 7, 2, 3, bias=False), norm(stem, g), nn.ReLU(inplace=True))
        ins, strides = (stem, *widths[:3]), (1, 2, 2, 2)
        self.stages = nn.ModuleList(
            stage(i, o, n, s, g) for i, o, n, s in zip(ins, widths, c["blocks"], strides, strict=True)
        )
        d16, d8, d4 = c["decoder_channels"]
        self.up = nn.ModuleList(
            [
                UpBlock(widths[3], widths[2], d16, g),
                UpBlock(d16, widths[1], d8, g),
                UpBlock(d8, widths[0] + stem, d4, g),
            ]
        )
        self.local_head = nn.Conv2d(d4, local, 1)
        self.global_head = nn.Identity() if widths[3] == c["global_dim"] else nn.Linear(widths[3], c["global_dim"])

    def compile_targets(self) -> list[nn.Module]:
        """the encoder stages and decoder: convolutions over a fixed image size (the sampling stays eager)."""
        return [self.stem, *self.stages, *self.up]

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, device: torch.device | str = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's inputs: the resized RGB image [3 x h x w] in [0, 1], its size [2] (h, w), and the keypoints
        [M x 2] in pixels of the resized image (pixel centres map as u' = (u + 0.5) w / W - 0.5)."""
        width, height = frame.image_size
        scale = self.conf["image_scale"]
        w, h = max(int(round(width * scale)), 1), max(int(round(height * scale)), 1)
        image = np.ascontiguousarray(frame.image)
        if (w, h) != (width, height):
            image = cv2.resize(image, (w, h), interpolation=cv2.INTER_LINEAR)
        rgb = torch.from_numpy(np.ascontiguousarray(image)).to(device=device, dtype=torch.float32)
        ratio = np.array([w / width, h / height], np.float32)
        uv = (np.asarray(kp2d.uv, np.float32).reshape(-1, 2) + 0.5) * ratio - 0.5
        return {
            "image": rgb.permute(2, 0, 1) / 255.0,
            "size": torch.tensor([h, w], device=device),
            "uv": torch.from_numpy(np.ascontiguousarray(uv)).to(device),
        }

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """a batch of `prepare`d frames: image [B x 3 x h x w] (zero-padded to the largest), size [B x 2], uv
        [B x M x 2] -> descriptors [B x M x D], [local | global]."""
        x = normalize_images(inputs["image"], inputs["size"])
        s2 = self.stem(x)
        s4 = self.stages[0](F.max_pool2d(s2, 3, 2, 1))
        s8 = self.stages[1](s4)
        s16 = self.stages[2](s8)
        s32 = self.stages[3](s16)
        s2_on_s4 = F.interpolate(s2, size=s4.shape[-2:], mode="bilinear", align_corners=False)
        x = self.up[2](self.up[1](self.up[0](s32, s16), s8), torch.cat([s4, s2_on_s4], 1))
        local = sample_descriptors(self.local_head(x), inputs["uv"], STRIDE)
        if self.conf["normalize_descriptors"]:
            local = F.normalize(local, dim=-1)
        valid = coarse_mask(inputs["size"], s32.shape[-2:], 32)
        pooled = (s32 * valid).sum((2, 3)) / valid.sum((2, 3)).clamp(min=1)
        glob = self.global_head(pooled)  # [B x G]
        return torch.cat([local, glob[:, None].expand(-1, local.shape[1], -1)], -1)
