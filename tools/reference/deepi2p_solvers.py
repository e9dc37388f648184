"""Poses DeepI2P's own solvers reach from given classifier outputs, recorded beside a reference set.

    python tools/reference/deepi2p_solvers.py /path/to/DeepI2P SET_DIR [--frustum-module DIR] [--seed N]

Classifier outputs: what a classifier that is right on 90% of the points gives on the set's frame (labels from the
set's P and K, 5% of the coarse labels flipped, 10% of the inside points given a random cell; seeded), so the
solvers have a pose to find. Then:
- `solve_PnP` of evaluation/registration_pnp.py, imported from the checkout and called as its __main__ does;
- `get_initial_guess` of evaluation/registration_lsq.py, then its `solver_wrapper` (Ceres, frustum_reg) from each of
  the recorded perturbed starts, 2D and 3D, the lowest cost kept as `solve_P_random_perturb` does. Their function
  draws the starts with `random` inside 8 processes; here they are drawn once (numpy, seeded) and recorded, so
  another solver can be run from the same starts.
`FrustumRegistration` is their frustum_reg/src/registration.cpp compiled here (Ceres 2.1, pybind11 2.13; their
bundled pybind11 2.3 does not build for Python 3.11): pass its folder with --frustum-module. Built here with

    apt-get install libceres-dev && pip install --target /tmp/pb11 pybind11
    g++ -O2 -shared -fPIC -std=c++17 DeepI2P/evaluation/frustum_reg/src/registration.cpp -I/tmp/pb11/pybind11/include \
        -I/usr/include/eigen3 $(python3-config --includes) -lceres -lglog \
        -o DIR/FrustumRegistration$(python3-config --extension-suffix)

Writes SET_DIR/solvers.npz.
"""

from __future__ import annotations

import argparse
import math
import sys
import types
from pathlib import Path

import numpy as np
import torch

STUBS = ("torchvision", "torchvision.models", "torchvision.transforms", "torch.utils.tensorboard")


def import_authors(checkout: Path, frustum_module: Path):
    """their registration_pnp and registration_lsq modules (headless: no Tk, no torchvision, no tensorboard)."""
    import matplotlib

    matplotlib.use = lambda *a, **k: None  # their modules ask for TkAgg; this machine has no display
    np.float, np.int = float, int  # removed from numpy 2; their solvers cast with them
    for name in STUBS:
        sys.modules.setdefault(name, types.ModuleType(name))
    sys.modules["torchvision.models.utils"] = types.SimpleNamespace(load_state_dict_from_url=None)
    sys.modules["torch.utils.tensorboard"].SummaryWriter = None
    sys.modules["torchvision"].transforms = sys.modules["torchvision.transforms"]
    sys.modules["index_max"] = types.ModuleType("index_max")
    sys.path[:0] = [str(frustum_module), str(checkout), str(checkout / "evaluation")]
    import registration_lsq
    import registration_pnp

    return registration_pnp, registration_lsq


def classifier_outputs(inputs: dict, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """coarse [N] and fine [N] predictions right on ~90% of the points (see the docstring)."""
    pc, P, K = inputs["pc"].astype(np.float64), inputs["P"].astype(np.float64), inputs["K"].astype(np.float64)
    h, w = inputs["img"].shape[1:]
    cam = P[:, :3] @ pc + P[:, 3:]
    xy = (K @ cam)[:2] / (K @ cam)[2]
    inside = (xy[0] >= 0) & (xy[0] <= w - 1) & (xy[1] >= 0) & (xy[1] <= h - 1) & (cam[2] > 0.1)
    fine = (np.floor(xy[0] / 32) + np.floor(xy[1] / 32) * (w // 32)).astype(np.int64)
    fine[~inside] = 0
    coarse = inside.astype(np.int64)
    flip = rng.random(len(coarse)) < 0.05
    coarse[flip] = 1 - coarse[flip]
    wrong = rng.random(len(fine)) < 0.1
    fine[wrong] = rng.integers(0, (h // 32) * (w // 32), wrong.sum())
    return coarse, fine


def frustum(lsq, pc, coarse, K, hw, starts, is_2d):
    """their initial guess, then their solver_wrapper from each start; the best of them."""
    _, yaw, pc_front, coarse_front = lsq.get_initial_guess(pc, coarse)
    best = {"P": None, "cost": 1e20, "residuals": None}
    for ry, tz in starts:
        lsq.solver_wrapper(pc_front, coarse_front, K, ry, np.array([0, 0, tz]), hw[0], hw[1],
                           [-5, -0.1, -10], [5, 0.1, 10], 500, False, is_2d, best)  # fmt: skip
    return yaw, best["P"], best["cost"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkout", type=Path)
    parser.add_argument("set", type=Path)
    parser.add_argument("--frustum-module", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=20261204)
    parser.add_argument("--restarts", type=int, default=60)
    args = parser.parse_args()
    pnp, lsq = import_authors(args.checkout.resolve(), args.frustum_module.resolve())
    inputs = dict(np.load(args.set / "inputs.npz"))
    outputs = dict(np.load(args.set / "outputs.npz"))
    rng = np.random.default_rng(args.seed)
    coarse, fine = classifier_outputs(inputs, rng)
    pc, K, hw = inputs["pc"].astype(np.float64), inputs["K"].astype(np.float64), inputs["img"].shape[1:]
    record = {"coarse_predictions": coarse, "fine_predictions": fine}
    record["pnp_pose"], record["pnp_outlier_ratio"] = pnp.solve_PnP(pc, coarse, fine, K, hw[0], hw[1], 1 / 32.0, 500, 1)
    net_coarse = torch.from_numpy(outputs["coarse_scores"]).argmax(0).numpy()
    net_fine = torch.from_numpy(outputs["fine_scores"]).argmax(0).numpy()
    net_pose, net_ratio = pnp.solve_PnP(pc, net_coarse, net_fine, K, hw[0], hw[1], 1 / 32.0, 500, 1)
    record |= {"network_pnp_pose": net_pose, "network_pnp_outlier_ratio": net_ratio}
    _, yaw, _, _ = lsq.get_initial_guess(pc, coarse)
    starts = [(yaw + rng.normal(0, 10 * math.pi / 180), rng.uniform(-10, 10)) for _ in range(args.restarts)]
    record["starts"] = np.array(starts)
    for variant, is_2d in (("2d", True), ("3d", False)):
        record["initial_yaw"], record[f"frustum{variant}_pose"], record[f"frustum{variant}_cost"] = frustum(
            lsq, pc, coarse, K, hw, starts, is_2d
        )
    np.savez_compressed(args.set / "solvers.npz", **{k: np.asarray(v) for k, v in record.items()})


if __name__ == "__main__":
    main()
