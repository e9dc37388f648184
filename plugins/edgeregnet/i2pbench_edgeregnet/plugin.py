"""Entry point of the edgeregnet plugins: EdgeRegNet's encoders, attention exchanger and matcher.

The learned stages are registered by import path: their modules import torch, which `i2pbench plugins` and runs of
the classic stages never need.
"""

from __future__ import annotations

from i2pbench.api import hookimpl
from i2pbench.hookspecs import Register

from .presets import register_presets  # noqa: F401
from .shipped import shipped_weights


@hookimpl
def register_encoders_2d(register: Register) -> None:
    register("i2pbench_edgeregnet.superpoint:SuperPointEncoder", name="superpoint-cnn")


@hookimpl
def register_encoders_3d(register: Register) -> None:
    register("i2pbench_edgeregnet.pointnet2:PointNet2Encoder", name="pointnet2")


@hookimpl
def register_exchangers(register: Register) -> None:
    register("i2pbench_edgeregnet.attention:AttentionExchanger", name="attention")


@hookimpl
def register_matchers(register: Register) -> None:
    register("i2pbench_edgeregnet.matching:LightGlueMatcher", name="lightglue")


@hookimpl
def register_weights(register: Register) -> None:
    for path in shipped_weights():
        register(path)
