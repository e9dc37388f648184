"""Entry point of the cofii2p plugin: the authors' CoFiI2P network as the `official` size of the `cofii2p` method
(method.py), with their loader's pixels and points and their solvePnPRansac.

The stages are registered by import path: their modules import torch, which `i2pbench plugins` and runs of other
stages never need.
"""

from __future__ import annotations

from i2pbench.api import Register, hookimpl

from .method import cofii2p


@hookimpl
def register_extractors_2d(register: Register) -> None:
    register("i2pbench_cofii2p.official.stages:OfficialGrid", name="cofii2p-official-grid")


@hookimpl
def register_extractors_3d(register: Register) -> None:
    register("i2pbench_cofii2p.official.stages:OfficialPoints", name="cofii2p-official-points")


@hookimpl
def register_matchers(register: Register) -> None:
    register("i2pbench_cofii2p.official.stages:OfficialCoFiI2P", name="cofii2p-official")


@hookimpl
def register_pose_solvers(register: Register) -> None:
    register("i2pbench_cofii2p.official.solver:OfficialPnP", name="cofii2p-official-pnp")


@hookimpl
def register_methods(register: Register) -> None:
    register(cofii2p())
