"""Entry point of the edgeregnet plugin: EdgeRegNet's encoders, attention exchanger and matcher, and the method
that binds them to their sizes, presets and shipped weights (method.py).

The learned stages are registered by import path: their modules import torch, which `i2pbench plugins` and runs of
the classic stages never need.
"""

from __future__ import annotations

from i2pbench.api import Register, hookimpl

from .method import edgeregnet


@hookimpl
def register_encoders_2d(register: Register) -> None:
    register("i2pbench_edgeregnet.superpoint:SuperPointEncoder", name="superpoint-cnn")
    register("i2pbench_edgeregnet.official.superpoint:OfficialSuperPoint", name="superpoint-official")


@hookimpl
def register_encoders_3d(register: Register) -> None:
    register("i2pbench_edgeregnet.pointnet2:PointNet2Encoder", name="pointnet2")
    register("i2pbench_edgeregnet.official.pointnet2:OfficialPointNet2", name="pointnet2-official")


@hookimpl
def register_exchangers(register: Register) -> None:
    register("i2pbench_edgeregnet.attention:AttentionExchanger", name="attention")
    register("i2pbench_edgeregnet.official.attention:OfficialAttention", name="attention-official")


@hookimpl
def register_matchers(register: Register) -> None:
    # the shipped weights and committed leaderboards name it `lightglue`; what it is: the optimal matching layer
    register("i2pbench_edgeregnet.matching:OptimalMatcher", name="lightglue", aliases=("optimal-matching",))
    register("i2pbench_edgeregnet.official.matching:OfficialMatcher", name="match-assignment-official")


@hookimpl
def register_methods(register: Register) -> None:
    register(edgeregnet())
