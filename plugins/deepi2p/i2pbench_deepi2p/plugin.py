"""Entry point of the deepi2p plugin: DeepI2P's cell-centres extractor, encoders, fusion, per-point classifier and
frustum solver, the official size's stages (the authors' network, pixels, points and PnP: official/stages.py), and
the method that binds them to the classic `random` points and EPnP in RANSAC (method.py).

Everything is registered by import path: the learned stages' modules import torch, which `i2pbench plugins` and
runs of other stages never need.
"""

from __future__ import annotations

from i2pbench.api import Register, hookimpl

from .method import deepi2p


@hookimpl
def register_extractors_2d(register: Register) -> None:
    register("i2pbench_deepi2p.extract:CellCentresExtractor", name="deepi2p-cell-centres")
    register("i2pbench_deepi2p.official.stages:OfficialCells", name="deepi2p-official-grid")


@hookimpl
def register_extractors_3d(register: Register) -> None:
    register("i2pbench_deepi2p.official.stages:OfficialPoints", name="deepi2p-official-points")


@hookimpl
def register_encoders_2d(register: Register) -> None:
    register("i2pbench_deepi2p.image:DeepI2PImageEncoder", name="deepi2p-resnet")


@hookimpl
def register_encoders_3d(register: Register) -> None:
    register("i2pbench_deepi2p.points:DeepI2PPointEncoder", name="deepi2p-pointnet2")


@hookimpl
def register_exchangers(register: Register) -> None:
    register("i2pbench_deepi2p.fusion:DeepI2PFusion", name="deepi2p-fusion")


@hookimpl
def register_matchers(register: Register) -> None:
    register("i2pbench_deepi2p.classifier:DeepI2PClassifier", name="deepi2p-classifier")
    register("i2pbench_deepi2p.official.stages:OfficialDeepI2P", name="deepi2p-official")


@hookimpl
def register_pose_solvers(register: Register) -> None:
    register("i2pbench_deepi2p.solver:FrustumSolver", name="deepi2p-frustum")
    register("i2pbench_deepi2p.official.stages:OfficialPnP", name="deepi2p-official-pnp")
    register("i2pbench_deepi2p.official.stages:OfficialFrustum", name="deepi2p-official-frustum")


@hookimpl
def register_methods(register: Register) -> None:
    register(deepi2p())
