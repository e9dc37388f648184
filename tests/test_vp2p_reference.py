"""VP2P-Match's official modules compute the authors' function: on reference vectors their code produced on CPU
(tools/reference/vp2p.py; folder from I2PBENCH_VP2P_REFERENCE, default tests/data/vp2p_reference), with the seeded
weights loaded under the authors' state dict keys, every recorded tensor agrees within 1e-4 of its largest value.
The folder covers the three branches, image (Image_ResNet), point (Point Transformer) and voxel (SPVCNN), and the
whole network's outputs (VP2PMatchNet: fusion and heads).
Nothing here assumes the particular set (frame, n, seed, salt)."""

import json
import os
from pathlib import Path

import numpy as np
import pytest
from i2pbench_vp2p_match.official.image import ImageResNet
from i2pbench_vp2p_match.official.network import VP2PMatchNet
from i2pbench_vp2p_match.official.points import PointsEncoder
from i2pbench_vp2p_match.official.reference import (
    image_branch_forward,
    network_forward,
    point_branch_forward,
    voxel_branch_forward,
)
from i2pbench_vp2p_match.official.spvcnn import SPVCNN

from i2pbench.testing.recipe import folder_state

FOLDER = Path(os.environ.get("I2PBENCH_VP2P_REFERENCE") or Path(__file__).parent / "data" / "vp2p_reference")
pytestmark = pytest.mark.skipif(
    not (FOLDER / "outputs.npz").is_file(), reason=f"no VP2P-Match reference vectors at {FOLDER}"
)
RELATIVE = 1e-4
BRANCHES = {  # ours, the authors' prefix
    "image_branch": (ImageResNet, "resnet."),
    "point_branch": (PointsEncoder, "point_transformer."),
    "voxel_branch": (SPVCNN, "voxel_branch."),
    "network": (VP2PMatchNet, ""),
}
FORWARDS = (image_branch_forward, point_branch_forward, voxel_branch_forward, network_forward)
GLOBAL = {"network": "network.pc_score"}  # a tensor each part's set must hold


def relative_error(ours: np.ndarray, ref: np.ndarray) -> float:
    assert ours.shape == ref.shape
    return float(np.abs(ours.astype(np.float64) - ref).max() / max(np.abs(ref).max(), 1e-30))


@pytest.fixture(scope="module")
def reference():
    return dict(np.load(FOLDER / "inputs.npz")), dict(np.load(FOLDER / "outputs.npz"))


@pytest.fixture(scope="module")
def state():
    state, digest = folder_state(FOLDER)
    assert digest == (FOLDER / "weights.sha256").read_text().split()[0]
    return state


@pytest.fixture(scope="module")
def ours(reference, state):
    return {k: v for forward in FORWARDS for k, v in forward(state, reference[0]).items()}


@pytest.mark.parametrize("branch", BRANCHES)
def test_reference_state_dict_keys_and_shapes_are_the_authors(branch):
    module, prefix = BRANCHES[branch]
    ours = {prefix + k: list(v.shape) for k, v in module().state_dict().items()}
    theirs = json.loads((FOLDER / "state_dict_shapes.json").read_text())
    assert {k: v for k, v in theirs.items() if k.startswith(prefix)} == ours


@pytest.mark.parametrize("branch", BRANCHES)
def test_reference_parameter_count_is_the_authors(branch):
    meta = json.loads((FOLDER / "meta.json").read_text())
    assert sum(p.numel() for p in BRANCHES[branch][0]().parameters()) == meta["parameters"][branch]


@pytest.mark.parametrize("branch", BRANCHES)
def test_reference_branch_agrees(reference, ours, branch):
    ref = {k: v for k, v in reference[1].items() if k.startswith(branch + ".")}
    assert GLOBAL.get(branch, f"{branch}.global") in ref and set(ref) == {k for k in ours if k.startswith(branch + ".")}
    errors = {k: relative_error(ours[k], ref[k]) for k in ref}
    assert max(errors.values()) <= RELATIVE, {k: e for k, e in errors.items() if e > RELATIVE}


def test_reference_fails_on_altered_tensors(reference, ours):
    keys = ("image_branch.mid", "image_branch.global", "point_branch.l1_up", "point_branch.pointwise")
    for key in (*keys, "voxel_branch.x0", "voxel_branch.pointwise", "network.point_feat", "network.img_score"):
        altered = reference[1][key].copy()
        altered.flat[len(altered.flat) // 3] += 1e-3 * np.abs(altered).max()
        assert relative_error(ours[key], altered) > RELATIVE, key
