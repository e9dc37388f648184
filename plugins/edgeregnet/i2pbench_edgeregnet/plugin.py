"""Entry point of the edgeregnet plugins: EdgeRegNet's encoders, attention exchanger and matcher."""

from __future__ import annotations

from i2pbench.api import hookimpl
from i2pbench.hookspecs import Register

from .attention import AttentionExchanger
from .matching import LightGlueMatcher
from .pointnet2 import PointNet2Encoder
from .presets import register_presets  # noqa: F401
from .shipped import shipped_weights
from .superpoint import SuperPointEncoder


@hookimpl
def register_encoders_2d(register: Register) -> None:
    register(SuperPointEncoder)


@hookimpl
def register_encoders_3d(register: Register) -> None:
    register(PointNet2Encoder)


@hookimpl
def register_exchangers(register: Register) -> None:
    register(AttentionExchanger)


@hookimpl
def register_matchers(register: Register) -> None:
    register(LightGlueMatcher)


@hookimpl
def register_weights(register: Register) -> None:
    for path in shipped_weights():
        register(path)
