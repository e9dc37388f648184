"""Latency of the classic stages on a full real KITTI scan (120k points) and image (1242 x 375).

The project's addopts carry --benchmark-disable, so a plain pytest run executes each benchmark once, untimed (a
smoke test). Time them with: pytest tests/benchmarks/test_bench_classic.py --benchmark-enable
"""

from __future__ import annotations

from pathlib import Path

import pytest

from i2pbench.plugins import default_registry
from i2pbench.protocol import Protocol
from i2pbench.types import Features

KITTI = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "kitti_odometry"


@pytest.fixture(scope="module")
def frame():
    if not KITTI.is_dir():
        pytest.skip(f"{KITTI} is not present")
    from i2pbench.data.kitti import KittiOdometry

    return Protocol().apply(KittiOdometry("all", {"root": str(KITTI)}).load("00/000000"))


def make(kind: str, name: str):
    return default_registry().component(kind, name)()


@pytest.mark.parametrize("name", ["lsd", "canny", "sobel", "random"])
def test_extractor2d(benchmark, frame, name):
    kp = benchmark(make("extractor2d", name), frame)
    assert len(kp) == 3000


@pytest.mark.parametrize("name", ["depth", "reflectance", "depth+reflectance", "random"])
def test_extractor3d(benchmark, frame, name):
    kp = benchmark(make("extractor3d", name), frame)
    assert 0 < len(kp) <= 3000


@pytest.mark.parametrize("name", ["epnp-ransac", "poselib"])
def test_solver_on_oracle_matches(benchmark, frame, name):
    kp2d, kp3d = make("extractor2d", "lsd")(frame), make("extractor3d", "depth+reflectance")(frame)
    matches = make("matcher", "oracle")(frame, kp2d, kp3d, Features(None, None))
    estimate = benchmark(make("solver", name), frame, kp2d, kp3d, matches)
    assert estimate.ok
