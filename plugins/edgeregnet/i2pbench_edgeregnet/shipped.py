"""The combination `i2pbench run` uses by default, and the checkpoints shipped with the package.

The shipped checkpoint was trained on this CPU, so it is the small variant (configs.SMALL); the default pipeline pins
exactly its stage configs, which is what lets `--weights auto` find it. The paper-size model has no shipped weights
and runs as `untrained` unless given a checkpoint.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .configs import COMPONENTS, FULL, FULL_KEYPOINTS, SMALL, SMALL_KEYPOINTS

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
EDGES = {"extractor2d": "lsd", "extractor3d": "depth+reflectance"}
SOLVER = {"solver": "epnp-ransac"}


def combination(confs: dict[str, dict[str, Any]], keypoints: int, variant: str, **stages: str) -> dict[str, Any]:
    """A preset row: EdgeRegNet's stages (overridable), the stage configs, and the extractors' keypoint cap."""
    names = {**EDGES, **COMPONENTS, **SOLVER, **stages}
    confs = {kind: conf for kind, conf in confs.items() if names[kind] == COMPONENTS[kind]}  # a swapped stage: own
    # a cap equal to the extractors' own default is not pinned, so classic rows built over this one stay plain
    caps = {kind: {"max_keypoints": keypoints} for kind in EDGES if keypoints != FULL_KEYPOINTS}
    return {**names, "confs": {**confs, **caps}, "variant": variant}


def small(**stages: str) -> dict[str, Any]:
    return combination(SMALL, SMALL_KEYPOINTS, "cpu-size", **stages)


def full(**stages: str) -> dict[str, Any]:
    return combination(FULL, FULL_KEYPOINTS, "", **stages)


def shipped_weights() -> list[Path]:
    return sorted(WEIGHTS_DIR.glob("*.pt"))
