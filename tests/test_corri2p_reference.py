"""CorrI2P's official size computes its authors' function: every tensor a reference folder recorded from their code
(tools/reference/corri2p.py: rsy6318/CorrI2P's network with seeded weights on a real KITTI frame) is what our
network computes from the same inputs and weights, each within 1e-4 of the tensor's largest magnitude, integers
exactly. The folder comes from I2PBENCH_CORRI2P_REFERENCE (default: the set committed in tests/data); nothing here
assumes a particular set, and a set with an altered tensor fails."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import require
from i2pbench_corri2p.official.checkpoint import dropped, ours
from i2pbench_corri2p.official.network import CorrI2PNet
from i2pbench_corri2p.official.reference import reference_forward

from i2pbench.testing.recipe import folder_state

DEFAULT = Path(__file__).parent / "data" / "reference" / "corri2p"
RELATIVE = 1e-4  # of a tensor's largest magnitude: float32 rounding in another summation order stays ~1e-6 here


def reference_folder() -> Path:
    return Path(os.environ.get("I2PBENCH_CORRI2P_REFERENCE", DEFAULT))


def load(folder: Path) -> tuple[dict, dict[str, np.ndarray], dict[str, np.ndarray]]:
    meta = json.loads((folder / "meta.json").read_text())
    with np.load(folder / "inputs.npz") as inputs, np.load(folder / "outputs.npz") as outputs:
        return meta, dict(inputs), dict(outputs)


def network_for(meta: dict, inputs: dict[str, np.ndarray]) -> CorrI2PNet:
    return CorrI2PNet(meta["nodes"], tuple(inputs["image"].shape[:2])).eval()


def ours_on(folder: Path, theirs: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    meta, inputs, _ = load(folder)
    net = network_for(meta, inputs)
    net.load_state_dict({ours(k): v for k, v in theirs.items() if not dropped(k)})
    return reference_forward(net, inputs)


def differences(got: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> dict[str, float]:
    """per recorded tensor the largest |ours - ref| / max|ref| (integers: 0 or inf); inf for a tensor we lack or
    whose shape differs."""
    out = {}
    for name, want in ref.items():
        have = got.get(name)
        if have is None or have.shape != want.shape:
            out[name] = float("inf")
        elif want.dtype.kind in "iub":
            out[name] = 0.0 if np.array_equal(have, want) else float("inf")
        else:
            scale = max(float(np.abs(want).max()), np.finfo(np.float32).tiny)
            out[name] = float(np.abs(have.astype(np.float64) - want).max()) / scale
    return out


def failures(got: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> list[str]:
    return [f"{k}: {v:.3g}" for k, v in differences(got, ref).items() if not v <= RELATIVE]


@pytest.fixture(scope="module")
def folder() -> Path:
    path = reference_folder()
    if not (path / "outputs.npz").exists():
        pytest.skip(f"no CorrI2P reference set in {path} (I2PBENCH_CORRI2P_REFERENCE)")
    return path


@pytest.fixture(scope="module")
def recipe(folder) -> tuple[dict[str, torch.Tensor], str]:
    return folder_state(folder)


@pytest.fixture(scope="module")
def ours_outputs(folder, recipe) -> dict[str, np.ndarray]:
    return ours_on(folder, recipe[0])


def test_reference_weights_are_the_recipe(folder, recipe):
    _, sha = recipe
    assert sha == (folder / "weights.sha256").read_text().strip()


def test_reference_state_dict_maps_onto_ours_key_for_key(folder, recipe):
    meta, inputs, _ = load(folder)
    theirs, _ = recipe
    mine = network_for(meta, inputs).state_dict()
    kept = {ours(k): tuple(v.shape) for k, v in theirs.items() if not dropped(k)}
    assert None not in kept, "an authors' key maps to nothing"
    assert kept == {k: tuple(v.shape) for k, v in mine.items()}
    assert sorted(k for k in theirs if dropped(k)) == ["img_encoder.backbone.fc.bias", "img_encoder.backbone.fc.weight"]


def test_reference_every_recorded_tensor_is_ours(folder, ours_outputs):
    _, _, ref = load(folder)
    assert len(ref) >= 20  # every module's output, the four outputs and the losses
    assert failures(ours_outputs, ref) == []


def test_reference_integer_outputs_are_exact(folder, ours_outputs):
    _, _, ref = load(folder)
    integers = [k for k, v in ref.items() if v.dtype.kind in "iu"]
    assert integers  # the nodes each point joins
    for name in integers:
        np.testing.assert_array_equal(ours_outputs[name], ref[name])


def test_reference_losses_are_train_py_terms(folder, ours_outputs):
    _, _, ref = load(folder)
    total = ours_outputs["loss_desc"] + 0.5 * ours_outputs["loss_det"]
    assert abs(float(total) - float(ref["loss"])) <= RELATIVE * abs(float(ref["loss"]))
    assert ref["correspondence_mask"].sum() > 0  # the frame has true pairs: the circle loss is not vacuous


@pytest.mark.parametrize(
    ("name", "change"),
    [
        ("pc_feature", "nudge"),
        ("up4", "nudge"),
        ("pc_point_node_a", "swap"),
        ("loss", "nudge"),
        ("node_b_up", "drop"),
    ],
)
def test_reference_comparison_fails_on_an_altered_set(folder, ours_outputs, tmp_path, name, change):
    altered = tmp_path / "altered"
    shutil.copytree(folder, altered, ignore=shutil.ignore_patterns("outputs.npz"))
    _, _, ref = load(folder)
    value = ref[name].copy()
    if change == "nudge":  # 1e-3 of the largest magnitude on one element: ten times the tolerance
        value.reshape(-1)[value.size // 2] += 1e-3 * np.abs(value).max()
        ref[name] = value
    elif change == "swap":
        value.reshape(-1)[[0, 1]] = value.reshape(-1)[[1, 0]] + 1
        ref[name] = value
    else:
        ref[name + "_renamed"] = ref.pop(name)
    np.savez(altered / "outputs.npz", **ref)
    _, _, reread = load(altered)
    problems = failures(ours_outputs, reread)
    assert problems and all(p.startswith(name) for p in problems)


def test_reference_image_is_the_official_stages_crop(folder, shared_data):
    """the official size prepares the frame's image as the authors' loader (the reference script) did."""
    from i2pbench_corri2p.official.stages import CROP, network_image

    from i2pbench.data.kitti import KittiOdometry

    meta, inputs, _ = load(folder)
    sequences = shared_data / meta["frame"]
    require(sequences)
    frame = KittiOdometry("all", {"root": str(sequences.parent.parent)}).load(
        f"{sequences.name}/{meta['frame_index']:06d}"
    )
    np.testing.assert_array_equal(network_image(frame.image, CROP), inputs["image"])
