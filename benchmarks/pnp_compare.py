"""Compare the epnp-ransac and poselib solvers on the real KITTI frames, fed by the oracle matcher.

Oracle matches are all within eps_c of the truth, which flatters any solver; `--outliers` therefore also replaces a
share of each frame's matches by random 2D-3D pairs (seeded), the situation a learned matcher leaves a solver in.
Prints per-setting median latency, RRE/RTE and success, and the poselib / epnp-ransac ratios.

    .venv/bin/python benchmarks/pnp_compare.py [--root ../shared/data/kitti_odometry] [--repeat 20]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from i2pbench.data.kitti import KittiOdometry
from i2pbench.registry.build import default_registry
from i2pbench.scoring.pose import pose_errors
from i2pbench.scoring.protocol import Protocol
from i2pbench.types import Features, Matches

SOLVERS = ("epnp-ransac", "poselib")
DEFAULT_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_odometry"


def make(kind: str, name: str):
    return default_registry().component(kind, name)()


def contaminate(matches: Matches, n2d: int, n3d: int, share: float, rng: np.random.Generator) -> Matches:
    """Replace `share` of the matches by uniformly random (2D, 3D) pairs."""
    bad = rng.random(len(matches)) < share
    index2d, index3d = matches.index2d.copy(), matches.index3d.copy()
    index2d[bad] = rng.integers(0, n2d, int(bad.sum()))
    index3d[bad] = rng.integers(0, n3d, int(bad.sum()))
    return Matches(index2d, index3d, matches.score)


def median_ms(fn, repeat: int) -> tuple[object, float]:
    times, out = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return out, 1e3 * float(np.median(times))


def rows_for_frame(frame, outliers: list[float], repeat: int) -> list[dict]:
    kp2d, kp3d = make("extractor2d", "lsd")(frame), make("extractor3d", "depth+reflectance")(frame)
    clean = make("matcher", "oracle")(frame, kp2d, kp3d, Features(None, None))
    rows = []
    for share in outliers:
        matches = contaminate(clean, len(kp2d), len(kp3d), share, Protocol().rng(frame.dataset, frame.frame_id))
        for name in SOLVERS:
            solver = make("solver", name)
            estimate, ms = median_ms(lambda s=solver, m=matches: s(frame, kp2d, kp3d, m), repeat)
            err = pose_errors(estimate.T, frame.T_gt)
            rows.append(
                {
                    "frame_id": frame.frame_id,
                    "outliers": share,
                    "solver": name,
                    "matches": len(matches),
                    "ms": ms,
                    "rre_deg": err.rre_deg,
                    "rte_m": err.rte_m,
                    "ok": err.rre_deg < 5 and err.rte_m < 2,
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=DEFAULT_ROOT)
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--outliers", type=float, nargs="+", default=[0.0, 0.5, 0.8, 0.9])
    args = parser.parse_args()
    dataset = KittiOdometry("all", {"root": str(args.root)})
    frames = [Protocol().apply(dataset.load(i)) for i in dataset.frame_ids()]
    rows = pd.DataFrame([r for f in frames for r in rows_for_frame(f, args.outliers, args.repeat)])
    pd.set_option("display.width", 160)
    print(rows.round(4).to_string(index=False))
    summary = rows.groupby(["outliers", "solver"]).agg(
        ms=("ms", "median"), rre_deg=("rre_deg", "median"), rte_m=("rte_m", "median"), success=("ok", "mean")
    )
    print("\nmedian over frames\n" + summary.round(4).to_string())
    print("\nposelib / epnp-ransac (latency over all frames; errors over frames both solve)")
    print(ratios(rows).to_string())


def ratios(rows: pd.DataFrame) -> pd.DataFrame:
    """Median per-frame ratio poselib / epnp-ransac for each outlier share."""
    wide = rows.pivot_table(index=["outliers", "frame_id"], columns="solver", values=["ms", "rre_deg", "rte_m", "ok"])
    both = wide["ok"].all(axis=1)
    out = {}
    for share, group in wide.groupby(level="outliers"):
        solved = group[both.loc[group.index]]
        ratio = {m: (solved[m]["poselib"] / solved[m]["epnp-ransac"]).median() for m in ("rre_deg", "rte_m")}
        out[share] = {
            "ms": (group["ms"]["poselib"] / group["ms"]["epnp-ransac"]).median(),
            **ratio,
            "frames_both_ok": int(len(solved)),
        }
    return pd.DataFrame(out).T.round(3)


if __name__ == "__main__":
    main()
