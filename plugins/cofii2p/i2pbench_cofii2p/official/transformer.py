"""The authors' coarse transformer (model/transformer/transformer.py `LocalFeatureTransformer` with full attention,
LoFTR's encoder layer as CoFiI2P changed it) and the sine position encoding of coordinates (position_encoding.py
`PositionEmbeddingCoordsSine`). Module names are theirs (`layers.i.q_proj`, `layers.i.mlp.0`, `layers.i.norm1`)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


class EncoderLayer(nn.Module):
    """one attention layer: multi-head attention of x over source, the projected queries L2-normalised over the
    token axis (their `F.normalize` of the [B x L x H x D] view takes its default dim 1: kept as written), softmax
    over the source at temperature sqrt(D); merge, LayerNorm; an MLP on [x, message], LayerNorm; plus x."""

    def __init__(self, d_model: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.q_proj, self.k_proj, self.v_proj, self.merge = (nn.Linear(d_model, d_model, bias=False) for _ in range(4))
        self.mlp = nn.Sequential(
            nn.Linear(2 * d_model, 2 * d_model, bias=False), nn.ReLU(), nn.Linear(2 * d_model, d_model, bias=False)
        )
        self.norm1, self.norm2 = nn.LayerNorm(d_model), nn.LayerNorm(d_model)

    def forward(self, x: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
        b, d = x.shape[0], x.shape[2] // self.heads
        query = F.normalize(self.q_proj(x).view(b, -1, self.heads, d), dim=1)
        key = self.k_proj(source).view(b, -1, self.heads, d)
        value = self.v_proj(source).view(b, -1, self.heads, d)
        logits = torch.einsum("blhd,bshd->bhls", query, key) / math.sqrt(d)
        message = torch.einsum("bhls,bshd->blhd", logits.softmax(-1), value).reshape(b, -1, self.heads * d)
        message = self.norm1(self.merge(message))
        return x + self.norm2(self.mlp(torch.cat([x, message], 2)))


class LocalFeatureTransformer(nn.Module):
    """(image tokens [B x L x C], point tokens [B x S x C]) through `names` layers: 'self' updates each from itself,
    'cross' updates the image from the points, then the points from the updated image (their order)."""

    def __init__(self, d_model: int = 128, heads: int = 4, names: tuple[str, ...] = ("self", "cross") * 4) -> None:
        super().__init__()
        self.names = names
        self.layers = nn.ModuleList(EncoderLayer(d_model, heads) for _ in names)

    def forward(self, image: torch.Tensor, points: torch.Tensor, trace: dict | None = None):
        trace = {} if trace is None else trace
        for i, (layer, name) in enumerate(zip(self.layers, self.names, strict=True)):
            image = layer(image, image if name == "self" else points)
            points = layer(points, points if name == "self" else image)
            trace[f"transformer.layers.{i}.image"], trace[f"transformer.layers.{i}.points"] = image, points
        return image, points


class PositionEmbeddingCoordsSine(nn.Module):
    """coordinates [... x n] -> [... x d_model]: per axis, sin and cos of coordinate * 2 pi / 10000^(2 floor(i/2)/f)
    interleaved (f = d_model // n // 2 * 2 features an axis), zeros padding the rest; no parameters."""

    def __init__(self, n_dim: int, d_model: int, temperature: float = 10000.0) -> None:
        super().__init__()
        self.n_dim, self.temperature = n_dim, temperature
        self.features = d_model // n_dim // 2 * 2
        self.padding = d_model - self.features * n_dim

    def forward(self, xyz: torch.Tensor) -> torch.Tensor:
        pairs = torch.arange(self.features, dtype=torch.float32, device=xyz.device).div(2, rounding_mode="floor")
        scale = self.temperature ** (2 * pairs / self.features)
        angles = (xyz * (2 * math.pi)).unsqueeze(-1) / scale
        encoded = torch.stack([angles[..., 0::2].sin(), angles[..., 1::2].cos()], -1).reshape(*xyz.shape[:-1], -1)
        return F.pad(encoded, (0, self.padding))
