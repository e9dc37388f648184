"""Entry point of the corri2p plugin: CorrI2P's encoders, feature exchange and overlap matcher, and the method that
binds them to the classic `grid` and `random` extractors, EPnP in RANSAC, and two sizes (method.py).

The learned stages are registered by import path: their modules import torch, which `i2pbench plugins` and runs of
other stages never need.
"""

from __future__ import annotations

from i2pbench.api import Register, hookimpl

from .method import corri2p


@hookimpl
def register_extractors_2d(register: Register) -> None:
    register("i2pbench_corri2p.official.stages:OfficialGrid", name="corri2p-official-grid")


@hookimpl
def register_extractors_3d(register: Register) -> None:
    register("i2pbench_corri2p.official.stages:OfficialPoints", name="corri2p-official-points")


@hookimpl
def register_encoders_2d(register: Register) -> None:
    register("i2pbench_corri2p.image:CorrI2PImageEncoder", name="corri2p-resnet")


@hookimpl
def register_encoders_3d(register: Register) -> None:
    register("i2pbench_corri2p.points:CorrI2PPointEncoder", name="corri2p-pointnet2")


@hookimpl
def register_exchangers(register: Register) -> None:
    register("i2pbench_corri2p.exchange:CorrI2PExchanger", name="corri2p-exchange")


@hookimpl
def register_matchers(register: Register) -> None:
    register("i2pbench_corri2p.overlap:CorrI2PMatcher", name="corri2p-overlap")
    register("i2pbench_corri2p.official.stages:OfficialCorrI2P", name="corri2p-official")


@hookimpl
def register_methods(register: Register) -> None:
    register(corri2p())
