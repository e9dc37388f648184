"""Entry point of the classic plugins: edge extractors, cosine and oracle matchers, PnP solvers, and their preset."""

from __future__ import annotations

from i2pbench.api import hookimpl
from i2pbench.hookspecs import Register

from .extract2d import CannyExtractor, LSDExtractor, RandomExtractor2D, SobelExtractor
from .extract3d import DepthExtractor, DepthReflectanceExtractor, RandomExtractor3D, ReflectanceExtractor
from .matchers import CosineMatcher, OracleMatcher
from .solvers import EPnPRansacSolver, PoseLibSolver


@hookimpl
def register_extractors_2d(register: Register) -> None:
    for cls in (LSDExtractor, CannyExtractor, SobelExtractor, RandomExtractor2D):
        register(cls)


@hookimpl
def register_extractors_3d(register: Register) -> None:
    for cls in (DepthExtractor, ReflectanceExtractor, DepthReflectanceExtractor, RandomExtractor3D):
        register(cls)


@hookimpl
def register_matchers(register: Register) -> None:
    register(CosineMatcher)
    register(OracleMatcher)


@hookimpl
def register_pose_solvers(register: Register) -> None:
    register(EPnPRansacSolver)
    register(PoseLibSolver)


@hookimpl
def register_presets(register: Register) -> None:
    register(
        "classic-oracle",
        [{"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle", "solver": "epnp-ransac"}],
        "the paper's edge extractors with ground-truth matches and EPnP-RANSAC: the upper bound of the classic stages",
    )
