"""i2pbench.layers.sparse and point_voxel compute torchsparse 2.0's function: on reference vectors torchsparse itself
produced (tools/reference/sparse.py; folder from I2PBENCH_SPARSE_REFERENCE, default tests/data/sparse_reference)
every coordinate set, corner link and voxel order is equal, and every feature tensor and every gradient (of a seeded
weighted sum of two outputs) agrees within 1e-4 of its largest value. Nothing here assumes the particular set (scan
patch, seed, salt)."""

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from i2pbench.layers.point_voxel import SparsePoints, initial_voxelize, point_to_voxel, voxel_to_point
from i2pbench.layers.sparse import SparseConv3d

FOLDER = Path(os.environ.get("I2PBENCH_SPARSE_REFERENCE") or Path(__file__).parent / "data" / "sparse_reference")
pytestmark = pytest.mark.skipif(
    not (FOLDER / "outputs.npz").is_file(), reason=f"no sparse-convolution reference vectors at {FOLDER}"
)
RELATIVE = 1e-4


def relative_error(ours: np.ndarray, ref: np.ndarray) -> float:
    """max |ours - ref| / max |ref|, shapes required equal."""
    assert ours.shape == ref.shape
    return float(np.abs(ours.astype(np.float64) - ref).max() / max(np.abs(ref).max(), 1e-30))


@pytest.fixture(scope="module")
def reference():
    return (
        dict(np.load(FOLDER / "inputs.npz")),
        dict(np.load(FOLDER / "outputs.npz")),
        json.loads((FOLDER / "meta.json").read_text()),
    )


def layers_of(inputs: dict, meta: dict) -> dict[str, SparseConv3d]:
    """the recorded layers with the recorded kernels, loaded through torchsparse's parameter names."""
    layers = {}
    for name, spec in meta["layers"].items():
        layer = SparseConv3d(spec["in"], spec["out"], spec["kernel"], spec["stride"], spec["bias"], spec["transposed"])
        state = {k.split(".", 1)[1]: torch.from_numpy(v) for k, v in inputs.items() if k.startswith(f"param_{name}.")}
        layer.load_state_dict(state)
        layers[name] = layer
    return layers


@pytest.fixture(scope="module")
def ours(reference):
    """the chain of tools/reference/sparse.py on i2pbench.layers, with the same names."""
    inputs, _, meta = reference
    torch.set_num_threads(1)
    layers = layers_of(inputs, meta)
    coords = torch.from_numpy(inputs["coords"])
    points, x0 = initial_voxelize(SparsePoints(torch.from_numpy(inputs["feats"]), coords), 0.05, 0.05)
    x0 = x0.with_feats(x0.feats.detach().requires_grad_(True))
    out = {"coords1": x0.coords, "voxel_rows1": points.links.voxel_rows[1][0], "voxelized": x0.feats}
    t, kept = x0, {}
    for name, layer in layers.items():
        t = kept[name] = layer(t)
        out[name], out[f"coords_{name}"] = t.feats, t.coords
    for stride, source in ((4, "point4"), (1, "up1")):
        out[f"points{stride}"] = voxel_to_point(kept[source], points).feats
        rows, weights = points.links.corners[stride]
        out[f"corner_rows{stride}"], out[f"corner_weights{stride}"] = rows.T, weights.T
    out["voxels2"] = point_to_voxel(kept["sub2"], points.with_feats(out["points4"][:, :8])).feats
    loss = sum((out[k] * torch.from_numpy(inputs[f"weight_{k}"])).sum() for k in ("points1", "voxels2"))
    loss.backward()
    out["grad_voxelized"] = x0.feats.grad
    for name, layer in layers.items():
        for key, param in layer.named_parameters():
            out[f"grad_{name}.{key}"] = param.grad
    return {k: v.detach().numpy() for k, v in out.items()}


def test_reference_records_every_tensor_we_compute(reference, ours):
    assert set(ours) == set(reference[1])


def test_reference_coordinates_and_links_are_equal(reference, ours):
    _, ref, _ = reference
    integers = [k for k in ref if np.issubdtype(ref[k].dtype, np.integer)]
    assert "coords1" in integers and "corner_rows4" in integers
    unequal = [k for k in integers if not np.array_equal(ours[k].astype(np.int64), ref[k].astype(np.int64))]
    assert not unequal


def test_reference_features_and_gradients_agree(reference, ours):
    _, ref, _ = reference
    floats = [k for k in ref if np.issubdtype(ref[k].dtype, np.floating)]
    assert "grad_sub1.kernel" in floats and "up1" in floats
    errors = {k: relative_error(ours[k], ref[k]) for k in floats}
    assert max(errors.values()) <= RELATIVE, {k: e for k, e in errors.items() if e > RELATIVE}


def test_reference_comparison_fails_on_an_altered_tensor(reference, ours):
    """the tolerance is tight enough: a thousandth of the largest value on one element of any tensor is caught,
    and so is one voxel out of order."""
    _, ref, _ = reference
    for key in ("voxelized", "sub2", "up1", "points1", "grad_down2.kernel"):
        altered = ref[key].copy()
        altered.flat[len(altered.flat) // 2] += 1e-3 * np.abs(ref[key]).max()
        assert relative_error(ours[key], altered) > RELATIVE, key
    swapped = ref["coords_down1"][[1, 0, *range(2, len(ref["coords_down1"]))]]
    assert not np.array_equal(ours["coords_down1"], swapped)
