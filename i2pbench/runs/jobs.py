"""A job: one combination ready to run (its pipeline, weights loaded), and the cache keys of its frames.

A frame's key is a hash of everything its record depends on (dataset identity, frame, each stage's resolved config,
weights identity, protocol card, corruption), versioned by the state of the frame's files; its upstream's key is the
same less the solver, so every solver of a sweep shares it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from .. import layers
from ..data.base import Dataset
from ..execution.isolation import isolated
from ..registry.catalog import Registry
from ..scoring.protocol import Protocol
from ..stages.components import Component
from ..stages.pipeline import Combination, Pipeline, stage_classes
from ..weights.checkpoints import apply_checkpoint, select_checkpoint
from . import weights_choice
from .environment import sync_torch_threads
from .store import versioned_key
from .upstream import FORMAT

UNTRAINED_SEED = 0


@dataclass
class Job:
    """One combination ready to run: its pipeline (weights loaded) and identity."""

    combination: Combination
    pipeline: Pipeline
    device: str = "cpu"  # where the learned stages run

    @property
    def weights(self) -> str:
        return self.pipeline.weights_identity

    @property
    def label(self) -> str:
        """The combination's stages, variant and config overrides, so rows that differ only in config stay apart."""
        return self.combination.display

    def stages(self) -> dict[str, dict[str, Any]]:
        """Each stage's name, full config (defaults merged), revision and shared layers' revisions: a changed default
        or a bumped revision changes the cache key; revisions at 0 are left out, so keys made before revisions
        existed still match."""
        return {kind: _described(c) for kind, c in self.pipeline.stages.items()}

    def to(self, device: str) -> Job:
        """Move the learned stages to `device` (a worker's own), recording where they run."""
        self.pipeline.to(device)
        self.device = device
        return self


def _described(component: Component) -> dict[str, Any]:
    described: dict[str, Any] = {"name": component.name, "conf": component.conf}
    if component.revision:
        described["revision"] = component.revision
    used = layers.revisions(component)  # shared layers its code imports, at nonzero revisions (i2pbench.layers)
    return {**described, "layers": used} if used else described


def prepare(
    registry: Registry,
    combinations: Sequence[Combination],
    weights: str = "auto",
    device: str = "cpu",
    dataset: str | None = None,
) -> list[Job]:
    """Build every pipeline before any frame runs, so an incompatible combination is refused up front; `dataset`
    (a name) lets `--weights auto` prefer shipped weights trained on it."""
    shipped = list(registry.weights)
    jobs = []
    for combination in combinations:
        pipeline = _build(registry, combination)
        checkpoint = select_checkpoint(pipeline, weights, shipped, dataset)
        if checkpoint is not None:
            apply_checkpoint(pipeline, checkpoint)
        elif weights == "auto" and pipeline.learned_modules():  # say why, when only the extractors differ
            weights_choice.explain_untrained(pipeline, combination.label, shipped)
        jobs.append(Job(combination, pipeline.to(device).eval(), str(device)))
    weights_choice.refuse_unused(jobs, weights)
    return jobs


def _build(registry: Registry, combination: Combination) -> Pipeline:
    """Build with a fixed torch seed, so an `untrained` row means the same initial weights in every run. The stages'
    classes are imported first: a learned stage's module imports torch, which then gets the run's thread count before
    any torch work; a combination none of whose modules imports torch needs no seed."""
    stage_classes(registry, combination)
    sync_torch_threads()
    torch = sys.modules.get("torch")
    if torch is None:
        return isolated(Pipeline.build(registry, combination))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(UNTRAINED_SEED)
        return isolated(Pipeline.build(registry, combination))


def labels(job: Job) -> dict[str, str]:
    """The row's combination columns: the key holds resolved configs, so labels follow the job's spelling."""
    return {"combination": job.label, "combination_key": job.combination.key()}


def frame_key(dataset: Dataset, frame_id: str, job: Job, protocol: Protocol) -> str:
    """What is computed, versioned by the state of the frame's files: a repaired scan is recomputed, not reused."""
    return versioned_key(_key_parts(dataset, frame_id, job, protocol), dataset.fingerprint(frame_id))


def upstream_key(dataset: Dataset, frame_id: str, job: Job, protocol: Protocol) -> str:
    """`frame_key` less the solver: what the solver consumes, shared by every solver of a sweep."""
    parts = _key_parts(dataset, frame_id, job, protocol)
    parts["stages"] = {kind: stage for kind, stage in parts["stages"].items() if kind != "solver"}
    return versioned_key({**parts, "upstream": FORMAT}, dataset.fingerprint(frame_id))


def _key_parts(dataset: Dataset, frame_id: str, job: Job, protocol: Protocol) -> dict[str, Any]:
    parts = {
        "data": dataset.identity(),
        "frame": frame_id,
        "stages": job.stages(),
        "weights": job.weights,
        "protocol": protocol.card(),
    }
    corruption = protocol.component()
    if corruption is not None:  # its level and class too: an edited table recomputes (clean keys are unchanged)
        parts["corruption"] = corruption.describe(protocol.severity)
    return parts
