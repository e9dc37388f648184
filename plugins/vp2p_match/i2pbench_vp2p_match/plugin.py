"""Entry point of the vp2p_match plugin: the authors' VP2P-Match network as the `official` size of the `vp2p-match`
method (method.py).

The stages are registered by import path: their modules import torch, which `i2pbench plugins` and runs of other
stages never need.
"""

from __future__ import annotations

from i2pbench.api import Register, hookimpl

from .method import vp2p_match


@hookimpl
def register_extractors_2d(register: Register) -> None:
    register("i2pbench_vp2p_match.official.stages:OfficialGrid", name="vp2p-match-official-grid")


@hookimpl
def register_extractors_3d(register: Register) -> None:
    register("i2pbench_vp2p_match.official.stages:OfficialPoints", name="vp2p-match-official-points")


@hookimpl
def register_matchers(register: Register) -> None:
    register("i2pbench_vp2p_match.official.stages:OfficialVP2PMatch", name="vp2p-match-official")


@hookimpl
def register_methods(register: Register) -> None:
    register(vp2p_match())
