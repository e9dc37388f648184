"""`aliked`: an encoder2d over ALIKED's pretrained network (real outdoor photos, MegaDepth), its deformable
descriptor head sampled at the 2D edge pixels; frozen (the default) or fine-tuned with the method's other stages."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, ConfigError, Encoder2D, Frame, Keypoints2D

from .aliked_net import CONFIGS, AlikedNet
from .weights import sha256, weight_file


class AlikedEncoder(BatchedStage, Encoder2D):
    """Descriptors of image keypoints from ALIKED's pretrained feature map and SDDH head; a learned linear map to
    `descriptor_dim` where that differs from the network's width."""

    name = "aliked"
    default_conf: ClassVar[dict[str, Any]] = {
        "network": "aliked-n16",  # aliked-n16, aliked-n16rot, aliked-n32 (128-d) or aliked-t16 (64-d)
        "descriptor_dim": 128,  # D, the output; another width than the network's adds a learned linear map
        "train_backbone": False,  # False: the pretrained network is frozen (BatchNorm in eval); True: fine-tuned
        "image_scale": 1.0,  # resize the image before the network (0.5 quarters its cost)
        "weights_sha256": None,  # the .pth file's sha256; None: filled in from the file (a different file is refused)
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        network = self.conf["network"]
        if network not in CONFIGS:
            raise ConfigError(f"{self.label}: unknown network {network!r}; choose one of {sorted(CONFIGS)}")
        path = weight_file(f"{network}.pth")
        digest = sha256(path)
        if self.conf["weights_sha256"] not in (None, digest):
            raise ConfigError(f"{self.label}: {path} has sha256 {digest}, not the {self.conf['weights_sha256']} asked")
        self.conf["weights_sha256"] = digest
        self.pretrained_identity = f"{network}@{digest[:8]}"  # on the rows (Pipeline.weights_identity)
        self.net = AlikedNet(network)
        state = torch.load(path, map_location="cpu", weights_only=True)
        self.net.load_state_dict({k: v for k, v in state.items() if not k.startswith("score_head.")}, strict=True)
        dim = self.conf["descriptor_dim"]
        self.project = nn.Linear(self.net.dim, dim) if dim != self.net.dim else None
        self.net.requires_grad_(bool(self.conf["train_backbone"]))
        self.net.eval()

    def train(self, mode: bool = True) -> AlikedEncoder:
        """a frozen network stays in eval mode (its BatchNorm statistics are the pretrained ones)."""
        super().train(mode)
        self.net.train(mode and bool(self.conf["train_backbone"]))
        return self

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, device: torch.device | str = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's network inputs: rgb [3 x H x W] in [0, 1], its size [2] (H, W), the edge pixels [M x 2]."""
        rgb = torch.from_numpy(np.ascontiguousarray(frame.image)).to(device=device, dtype=torch.float32)
        uv = torch.from_numpy(np.asarray(kp2d.uv, np.float32)).to(device)
        return {"rgb": rgb.permute(2, 0, 1) / 255.0, "size": torch.tensor(rgb.shape[:2], device=device), "uv": uv}

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """a batch of `prepare`d frames (rgb [B x 3 x H x W] zero-padded, size [B x 2], uv [B x M x 2]) ->
        descriptors [B x M x D]; each image runs at its own size, so a batch equals its frames one by one."""
        out = [self._one(rgb[:, : int(h), : int(w)], uv) for rgb, (h, w), uv in zip(*self._parts(inputs), strict=True)]
        return torch.stack(out)

    def _parts(self, inputs: dict[str, torch.Tensor]) -> tuple:
        return inputs["rgb"], inputs["size"].tolist(), inputs["uv"]

    def _one(self, rgb: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        scale = self.conf["image_scale"]
        if scale != 1.0:
            rgb = F.interpolate(rgb[None], scale_factor=scale, mode="bilinear", antialias=True)[0]
            uv = (uv + 0.5) * scale - 0.5  # pixel centres, as the resize maps them
        if len(uv) == 0:
            return torch.zeros(0, self.conf["descriptor_dim"], device=rgb.device)
        uv = uv.clamp(min=0).minimum(torch.tensor([rgb.shape[2] - 1, rgb.shape[1] - 1], device=uv.device))
        with torch.set_grad_enabled(torch.is_grad_enabled() and bool(self.conf["train_backbone"])):
            desc = self.net(rgb[None], uv)
        return desc if self.project is None else F.normalize(self.project(desc), dim=-1)
