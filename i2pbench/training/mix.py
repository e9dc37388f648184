"""Several datasets in one training run: which source each training sample comes from.

`--mix DATASET:SPLIT[@ROOT]=SHARE` adds a source: sample i comes from it with probability SHARE, the rest from the
main `--dataset/--split`. The choice is a pure function of (seed, i), drawn from a generator of its own (salted
apart from the one that picks the frame), so resume, worker counts and DDP ranks see the same sequence, and a run
without a mix draws exactly the frames it drew before mixes existed. A spec is checked whole (dataset, split, share,
frames on disk) before any work, and every error names the option and what is wrong.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.base import Dataset
from ..errors import I2PBenchError

MIX_SALT = 1_000_211  # the source draw's own stream: the frame draw (seed, index) stays as it was without a mix


@dataclass(frozen=True)
class SourceSpec:
    """`DATASET:SPLIT[@ROOT][=SHARE]` parsed; `share` is None where the option takes none (`--val-dataset`)."""

    dataset: str
    split: str
    root: str | None = None
    share: float | None = None


@dataclass(frozen=True)
class MixedSource:
    """an opened dataset split and the share of training samples it supplies."""

    dataset: Dataset
    share: float

    def identity(self) -> dict[str, Any]:
        """what the checkpoint records of it: the dataset identity, its frame count and its share."""
        return {**self.dataset.identity(), "frames": len(self.dataset.frame_ids()), "share": self.share}


def parse_source(text: str, option: str, with_share: bool) -> SourceSpec:
    """`kitti:train@/data/kitti=0.5` -> SourceSpec("kitti", "train", "/data/kitti", 0.5); a malformed spec is an
    I2PBenchError naming `option`."""
    form = "DATASET:SPLIT[@ROOT]=SHARE" if with_share else "DATASET:SPLIT[@ROOT]"
    body, share = text, None
    if with_share:
        body, sep, share_text = text.rpartition("=")
        if not sep:
            raise I2PBenchError(f"{option} {text!r}: no share; expected {form}")
        share = _share(share_text, text, option)
    name, sep, rest = body.partition(":")
    split, _, root = rest.partition("@")
    if not sep or not name or not split:
        raise I2PBenchError(f"{option} {text!r}: expected {form} (dataset and split both named)")
    return SourceSpec(name, split, root or None, share)


def _share(text: str, spec: str, option: str) -> float:
    try:
        share = float(text)
    except ValueError:
        raise I2PBenchError(f"{option} {spec!r}: share {text!r} is not a number") from None
    if not 0.0 < share < 1.0:
        raise I2PBenchError(f"{option} {spec!r}: share {share:g} is outside (0, 1)")
    return share


def check_mix(main: SourceSpec, specs: Sequence[SourceSpec], option: str = "--mix") -> None:
    """the mixed-in shares must leave the main dataset some samples, and no source may be named twice."""
    total = sum(s.share or 0.0 for s in specs)
    if total >= 1.0 - 1e-9:
        raise I2PBenchError(f"{option}: the shares sum to {total:g}; they must sum to under 1 (the rest is --dataset)")
    named = [(s.dataset, s.split, s.root) for s in (main, *specs)]
    for i, key in enumerate(named[1:], 1):
        if key in named[:i]:
            raise I2PBenchError(f"{option}: {key[0]}:{key[1]} is named twice (as --dataset or in another --mix)")


def open_source(registry: Any, spec: SourceSpec, option: str) -> Dataset:
    """the dataset split a spec names, its frames listed now, so a wrong name, split or root stops the run before
    any work; the root is the spec's, else the dataset's I2PBENCH_<NAME>_ROOT."""
    try:
        dataset = registry.dataset(spec.dataset)(spec.split, {"root": spec.root} if spec.root else None)
        dataset.frame_ids()
    except I2PBenchError as exc:
        raise I2PBenchError(f"{option} {spec.dataset}:{spec.split}: {exc}") from None
    return dataset


def choose_source(shares: Sequence[float], seed: int, index: int) -> int:
    """sample index's source: k (1-based) is mixed source k, drawn with probability shares[k - 1]; 0 is the main
    dataset. A pure function of (seed, index)."""
    if not shares:
        return 0
    u = np.random.default_rng([seed, index, MIX_SALT]).random()
    k = int(np.searchsorted(np.cumsum(shares), u, side="right"))
    return k + 1 if k < len(shares) else 0
