"""Cross-validated scores with 95% intervals, resampling whole scenes (drives), not frames.

Frames of one drive share scenery, so they are not independent draws: an interval from resampling frames would be
too narrow where one drive gives many frames. The bootstrap here draws scenes with replacement and takes all of each
drawn scene's frames (a cluster bootstrap); the interval is the percentile interval of the statistic.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from ..scoring.installed import by_name
from ..scoring.metrics import BUILTIN
from ..scoring.protocol import Protocol
from .leaderboard import ACC_SKILL, TRUE_MATCHES

BOOTSTRAP_DRAWS = 2000


def scene_bootstrap(
    values: np.ndarray,
    scenes: Sequence[str],
    statistic: Callable[[np.ndarray], float],
    draws: int = BOOTSTRAP_DRAWS,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float, float]:
    """(estimate, low, high): `statistic` of per-frame `values` [F] and its percentile interval over `draws`
    resamples of whole scenes (each frame's scene in `scenes` [F]); seeded, so the same inputs give the same
    interval."""
    values = np.asarray(values, dtype=float)
    names, index = np.unique(np.asarray(scenes), return_inverse=True)
    members = [np.flatnonzero(index == i) for i in range(len(names))]
    rng = np.random.default_rng(seed)
    stats = np.empty(draws)
    for d in range(draws):
        picked = rng.integers(0, len(names), len(names))
        stats[d] = statistic(values[np.concatenate([members[i] for i in picked])])
    tail = (1 - level) / 2 * 100
    low, high = np.nanpercentile(stats, [tail, 100 - tail])
    return float(statistic(values)), float(low), float(high)


def registered(records: pd.DataFrame, protocol: Protocol) -> np.ndarray:
    """[F] 1.0 where a frame is registered with true matches, else 0.0: the per-frame values of the leaderboard's
    'Acc. with true matches' metric (scoring.metrics), not a second definition of it."""
    return by_name(BUILTIN)["skill_acc_pct"].per_frame(records, protocol)


def cross_validated(
    records: pd.DataFrame, scene_of: Callable[[str], str], protocol: Protocol | None = None, seed: int = 0
) -> pd.DataFrame:
    """One row per combination of pooled per-frame records (every fold's test frames, each fold with its own
    weights): Acc. with true matches and the median of true matches, each with its 95% scene-bootstrap interval."""
    protocol = protocol or Protocol()
    rows = []
    for combination, group in records.groupby("combination", sort=False):
        weights = " / ".join(dict.fromkeys(group["weights"].astype(str)))
        scenes = [scene_of(f) for f in group["frame_id"]]
        acc = scene_bootstrap(registered(group, protocol) * 100, scenes, np.mean, seed=seed)
        true = group["n_true_matches"].fillna(0).to_numpy(dtype=float)
        median = scene_bootstrap(true, scenes, np.median, seed=seed)
        rows.append(
            {
                "combination": combination,
                "weights": weights,
                "frames": len(group),
                "scenes": len(set(scenes)),
                ACC_SKILL: round(acc[0], 2),
                "Acc. 95% interval": f"[{acc[1]:.1f}, {acc[2]:.1f}]",
                TRUE_MATCHES: median[0],
                "true matches 95% interval": f"[{median[1]:g}, {median[2]:g}]",
            }
        )
    return pd.DataFrame(rows)
