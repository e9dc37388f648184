"""VP2P-Match's official modules compute the authors' function: on reference vectors their code produced on CPU
(tools/reference/vp2p.py; folder from I2PBENCH_VP2P_REFERENCE, default tests/data/vp2p_reference), with the seeded
weights loaded under the authors' state dict keys, every recorded tensor agrees within 1e-4 of its largest value.
Today the folder covers the voxel branch (SPVCNN). Nothing here assumes the particular set (frame, n, seed, salt)."""

import json
import os
from pathlib import Path

import numpy as np
import pytest
from i2pbench_vp2p_match.official.spvcnn import SPVCNN
from i2pbench_vp2p_match.reference import folder_state, voxel_branch_forward

FOLDER = Path(os.environ.get("I2PBENCH_VP2P_REFERENCE") or Path(__file__).parent / "data" / "vp2p_reference")
pytestmark = pytest.mark.skipif(
    not (FOLDER / "outputs.npz").is_file(), reason=f"no VP2P-Match reference vectors at {FOLDER}"
)
RELATIVE = 1e-4


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
    return voxel_branch_forward(state, reference[0])


def test_reference_state_dict_keys_and_shapes_are_the_authors(state):
    branch = SPVCNN().state_dict()
    ours = {f"voxel_branch.{k}": list(v.shape) for k, v in branch.items()}
    theirs = {k: v for k, v in json.loads((FOLDER / "state_dict_shapes.json").read_text()).items()}
    assert {k: v for k, v in theirs.items() if k.startswith("voxel_branch.")} == ours


def test_reference_parameter_count_is_the_authors():
    meta = json.loads((FOLDER / "meta.json").read_text())
    assert sum(p.numel() for p in SPVCNN().parameters()) == meta["parameters"]["voxel_branch"]


def test_reference_voxel_branch_agrees(reference, ours):
    ref = {k: v for k, v in reference[1].items() if k.startswith("voxel_branch.")}
    assert "voxel_branch.pointwise" in ref and set(ours) == set(ref)
    errors = {k: relative_error(ours[k], ref[k]) for k in ref}
    assert max(errors.values()) <= RELATIVE, {k: e for k, e in errors.items() if e > RELATIVE}


def test_reference_voxel_branch_fails_on_altered_tensors(reference, ours):
    for key in ("voxel_branch.x0", "voxel_branch.y4", "voxel_branch.pointwise"):
        altered = reference[1][key].copy()
        altered.flat[len(altered.flat) // 3] += 1e-3 * np.abs(altered).max()
        assert relative_error(ours[key], altered) > RELATIVE, key
