"""What a checkpoint was trained on: the training data's identity, recorded in the checkpoint's metadata, and the
lineage of earlier phases on other data that a fine-tuning run continues from (see `Checkpoint.lineage`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict
from typing import Any

from ..data.base import Dataset
from .config import TrainConfig
from .mix import MixedSource


def data_identity(train_set: Dataset, mix: Sequence[MixedSource] = ()) -> dict[str, Any]:
    """the training data's identity: the main dataset's, and under "mix" each mixed-in source's with its share."""
    identity = {**train_set.identity(), "frames": len(train_set.frame_ids())}
    return {**identity, "mix": [m.identity() for m in mix]} if mix else identity


def data_of(identity: dict[str, Any]) -> dict[str, Any]:
    """what names the training data (dataset, split, root, a non-default style; each mixed-in source's and its
    share), without counts or configs; an unmixed run's is what it was before mixes existed, so its checkpoints
    resume as one phase."""
    named = {k: identity.get(k) for k in ("dataset", "split", "root")}
    if identity.get("release"):  # imported weights (`weights import`): who trained them, on what
        named["release"] = identity["release"]
    if identity.get("style"):  # a synthetic set in another style is other data (absent for the default style)
        named["style"] = identity["style"]
    if identity.get("mix"):
        named["mix"] = [{**data_of(m), "share": m.get("share")} for m in identity["mix"]]
    return named


def continued(
    lineage: list[dict[str, Any]], before: dict[str, Any], now: dict[str, Any], step: int
) -> tuple[list[dict[str, Any]], bool]:
    """the lineage of a run resumed at `step` from a checkpoint trained on `before`, now training on `now`, and
    whether this starts a new phase (other data: the earlier phase joins the lineage)."""
    if before and data_of(before) != data_of(now):
        return [*lineage, {**data_of(before), "steps": step}], True
    return lineage, False


def training_meta(
    train_set: Dataset, config: TrainConfig, world: int = 1, mix: Sequence[MixedSource] = ()
) -> dict[str, Any]:
    """the checkpoint metadata naming the run: its data and its settings (ranks and effective batch included)."""
    trained_on = data_identity(train_set, mix)
    effective = world * config.accumulate * config.batch_size
    return {"trained_on": trained_on, "train_config": {**asdict(config), "ranks": world, "effective_batch": effective}}
