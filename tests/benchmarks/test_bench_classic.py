"""Latency of the classic stages on a full real KITTI scan (120k points) and image (1242 x 375).

The project's addopts carry --benchmark-disable, so a plain pytest run executes each benchmark once, untimed (a
smoke test). Time them with: pytest tests/benchmarks/test_bench_classic.py --benchmark-enable

Each extractor is timed beside its floor (benchmarks/extractor_floor.py: the same rule in bare library calls, which
is checked here to compute the extractor's selection), the two in one group: pytest-benchmark's table then shows the
extractor's times relative to the floor's, the ratio the project holds each extractor to (<= 1.3x, docs/performance.md).
benchmarks/extractor_floor.py measures the same ratio in alternating rounds, which a loaded machine disturbs less.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from conftest import SAMPLE_DATA, sample

from i2pbench.registry.build import default_registry
from i2pbench.scoring.protocol import Protocol
from i2pbench.types import Features

ROOT = Path(__file__).resolve().parents[2]
KITTI = SAMPLE_DATA / "kitti_odometry"
EXTRACTORS = [("extractor2d", name) for name in ("lsd", "canny", "sobel", "random")] + [
    ("extractor3d", name) for name in ("depth", "reflectance", "depth+reflectance", "random")
]


@pytest.fixture(scope="module")
def frame():
    sample("kitti_odometry")
    from i2pbench.data.kitti import KittiOdometry

    return Protocol().apply(KittiOdometry("all", {"root": str(KITTI)}).load("00/000000"))


@pytest.fixture(scope="module")
def floors(frame):
    """benchmarks/extractor_floor.py's floors for this frame (one definition for the script and the suite)"""
    spec = importlib.util.spec_from_file_location("extractor_floor", ROOT / "benchmarks" / "extractor_floor.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module, module.floors(frame)


def make(kind: str, name: str):
    return default_registry().component(kind, name)()


@pytest.mark.parametrize("side", ["extractor", "floor"])
@pytest.mark.parametrize("kind, name", EXTRACTORS, ids=[f"{kind}-{name}" for kind, name in EXTRACTORS])
def test_extractor_beside_its_floor(benchmark, frame, floors, kind, name, side):
    module, floor_of = floors
    benchmark.group = f"{kind} {name}: extractor / floor"
    if side == "floor":
        module.check_floor(kind, name, floor_of[kind, name], frame, default_registry())  # the same selection
        benchmark(floor_of[kind, name], frame)
        return
    kp = benchmark(make(kind, name), frame)
    assert (len(kp) == 3000) if kind == "extractor2d" else (0 < len(kp) <= 3000)


@pytest.mark.parametrize("name", ["epnp-ransac", "poselib"])
def test_solver_on_oracle_matches(benchmark, frame, name):
    kp2d, kp3d = make("extractor2d", "lsd")(frame), make("extractor3d", "depth+reflectance")(frame)
    matches = make("matcher", "oracle")(frame, kp2d, kp3d, Features(None, None))
    estimate = benchmark(make("solver", name), frame, kp2d, kp3d, matches)
    assert estimate.ok
