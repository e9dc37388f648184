"""Entry point of the classic plugins: edge, random and grid extractors, cosine and oracle matchers, PnP solvers,
and their preset.

Components are registered by import path, so listing plugins imports none of OpenCV, PoseLib or torch (the cosine
matcher's), and a run imports only the modules of the stages it uses.
"""

from __future__ import annotations

from i2pbench.api import Register, hookimpl


@hookimpl
def register_extractors_2d(register: Register) -> None:
    register("i2pbench_classic.extract2d:LSDExtractor", name="lsd")
    register("i2pbench_classic.extract2d:CannyExtractor", name="canny")
    register("i2pbench_classic.extract2d:SobelExtractor", name="sobel")
    register("i2pbench_classic.extract2d:RandomExtractor2D", name="random")
    register("i2pbench_classic.extract2d:GridExtractor2D", name="grid")


@hookimpl
def register_extractors_3d(register: Register) -> None:
    register("i2pbench_classic.extract3d:DepthExtractor", name="depth")
    register("i2pbench_classic.extract3d:ReflectanceExtractor", name="reflectance")
    register("i2pbench_classic.extract3d:DepthReflectanceExtractor", name="depth+reflectance")
    register("i2pbench_classic.extract3d:RandomExtractor3D", name="random")


@hookimpl
def register_matchers(register: Register) -> None:
    register("i2pbench_classic.matchers:CosineMatcher", name="cosine")
    register("i2pbench_classic.matchers:OracleMatcher", name="oracle")


@hookimpl
def register_pose_solvers(register: Register) -> None:
    register("i2pbench_classic.solvers:EPnPRansacSolver", name="epnp-ransac")
    register("i2pbench_classic.solvers:PoseLibSolver", name="poselib")


@hookimpl
def register_presets(register: Register) -> None:
    register(
        "classic-oracle",
        [{"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle", "solver": "epnp-ransac"}],
        "the paper's edge extractors with ground-truth matches and EPnP-RANSAC: the upper bound of the classic stages",
    )
