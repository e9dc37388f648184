"""CoFiI2P's official network computes its authors' function: every tensor a reference folder recorded from their
code (tools/reference/cofii2p.py: WHU-USI3DV/CoFiI2P's network with seeded weights and their own kernel
dispositions on a real KITTI frame, in 'val' and 'test' mode, with train.py's losses) is what our network computes
from the same inputs and weights, each within 1e-4 of the tensor's largest magnitude, integers exactly. The folder
comes from I2PBENCH_COFII2P_REFERENCE (default: the set committed in tests/data); nothing here assumes a particular
set, and a set with an altered tensor fails."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from i2pbench_cofii2p.official.importer import ours, split
from i2pbench_cofii2p.official.network import CoFiI2PNetwork
from i2pbench_cofii2p.official.reference import reference_forward

from i2pbench.testing.recipe import folder_state

DEFAULT = Path(__file__).parent / "data" / "reference" / "cofii2p"
RELATIVE = 1e-4  # of a tensor's largest magnitude: float32 rounding in another summation order stays ~1e-6 here
KERNELS = "kernel_points"


def reference_folder() -> Path:
    return Path(os.environ.get("I2PBENCH_COFII2P_REFERENCE", DEFAULT))


def load(folder: Path) -> tuple[dict, dict[str, np.ndarray], dict[str, np.ndarray]]:
    meta = json.loads((folder / "meta.json").read_text())
    with np.load(folder / "inputs.npz") as inputs, np.load(folder / "outputs.npz") as outputs:
        return meta, dict(inputs), dict(outputs)


def authors_state(folder: Path, inputs: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """the authors' whole state dict of the set: the recipe's learned tensors and the recorded kernel dispositions."""
    learned, _ = folder_state(folder)
    return learned | {k: torch.from_numpy(v) for k, v in inputs.items() if k.endswith(KERNELS)}


def as_recorded(tensors: dict[str, np.ndarray], meta: dict) -> dict[str, np.ndarray]:
    """our tensors as the set keeps them: those it sampled as every step-th flat value (after checking the shape)."""
    out = dict(tensors)
    for name, how in meta.get("sampled", {}).items():
        if name in out and list(out[name].shape) == how["shape"]:
            out[name] = out[name].reshape(-1)[:: how["step"]]
    return out


def differences(got: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> dict[str, float]:
    """per recorded tensor the largest |ours - ref| / max|ref| (integers: 0 or inf); inf for a tensor we lack or
    whose shape differs."""
    out = {}
    for name, want in ref.items():
        have = got.get(name)
        if have is None or np.shape(have) != want.shape:
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
        pytest.skip(f"no CoFiI2P reference set in {path} (I2PBENCH_COFII2P_REFERENCE)")
    return path


@pytest.fixture(scope="module")
def reference(folder) -> tuple[dict, dict[str, np.ndarray], dict[str, np.ndarray]]:
    return load(folder)


@pytest.fixture(scope="module")
def ours_outputs(folder, reference) -> dict[str, np.ndarray]:
    meta, inputs, _ = reference
    net = CoFiI2PNetwork().eval()
    state, _ = split(authors_state(folder, inputs))
    net.load_state_dict({k.removeprefix("net."): v for k, v in state.items()})
    return as_recorded(reference_forward(net, inputs), meta)


def test_reference_weights_are_the_recipe(folder):
    assert folder_state(folder)[1] == (folder / "weights.sha256").read_text().strip()


def test_reference_state_dict_maps_onto_ours_key_for_key(folder, reference):
    _, inputs, _ = reference
    theirs = authors_state(folder, inputs)
    mine = CoFiI2PNetwork().state_dict()
    kept = {ours(k): tuple(v.shape) for k, v in theirs.items() if ours(k) is not None}
    assert kept == {k: tuple(v.shape) for k, v in mine.items()}
    unused = ("img_encoder.backbone.fc.", "img_feature_layer.", "fine_img_pos_encoding.", "fine_pc_pos_encoding.")
    dropped = [k for k in theirs if ours(k) is None]
    assert all(k.startswith(unused) for k in dropped)
    assert {p for p in unused if any(k.startswith(p) for k in dropped)} == set(unused)


def test_reference_every_recorded_tensor_is_ours(reference, ours_outputs):
    _, _, ref = reference
    assert len(ref) >= 50  # every block's output, the transformer's 16 updates, outputs of both modes, losses
    assert failures(ours_outputs, ref) == []


def test_reference_integer_outputs_are_exact(reference, ours_outputs):
    _, _, ref = reference
    integers = {k for k, v in ref.items() if v.dtype.kind in "iu"}
    assert {"pc_inline_index", "coarse_pc_index"} <= integers  # the coarse selection and the fine points it picks
    for name in integers:
        np.testing.assert_array_equal(ours_outputs[name], ref[name])


def test_reference_selection_and_losses_are_not_vacuous(reference, ours_outputs):
    meta, _, ref = reference
    assert len(ref["pc_inline_index"]) >= 4  # PnP's minimum, which the authors' loop guarantees
    assert meta["num_kpt"] >= 1 and ref["correspondence_mask"].sum() > 0  # true coarse pairs: the loss has positives
    total = ours_outputs["loss_desc"] + ours_outputs["loss_coarse"] + ours_outputs["loss_fine"]
    assert abs(float(total) - float(ref["loss"])) <= RELATIVE * abs(float(ref["loss"]))


@pytest.mark.parametrize(
    ("name", "change"),
    [
        ("pc_encoder.encoder3_2", "nudge"),
        ("transformer.layers.5.points", "nudge"),
        ("fine_img_feature_patch", "nudge"),
        ("loss_fine", "nudge"),
        ("coarse_pc_index", "swap"),
        ("img_upsample_2", "drop"),
    ],
)
def test_reference_comparison_fails_on_an_altered_set(folder, reference, ours_outputs, tmp_path, name, change):
    altered = tmp_path / "altered"
    shutil.copytree(folder, altered, ignore=shutil.ignore_patterns("outputs.npz"))
    ref = dict(reference[2])
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
