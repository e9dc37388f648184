"""What one `i2pbench run` works with, made once before its store and handed down whole: the registry its
combinations were chosen from, the combinations, the dataset and its frames, the protocols (the clean one, or one per
corruption and severity), the thread count, the store and the options. One value in place of chains of eight to ten
positional arguments, so a step's signature says which run it serves, not how the run was assembled."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..data.base import Dataset
    from ..registry.catalog import Registry
    from ..scoring.protocol import Protocol
    from ..stages.pipeline import Combination
    from .store import ResultsStore


@dataclass(frozen=True)
class RunContext:
    """A run checked and ready: everything but the store is known before any file is written (`with_store`)."""

    registry: Registry
    combinations: tuple[Combination, ...]
    dataset: Dataset
    frame_ids: tuple[str, ...]
    protocols: tuple[Protocol, ...]  # the first is the run's own card (the clean one, or the first corruption's)
    threads: int
    options: argparse.Namespace  # the parsed `run` options (executor, weights, device, overwrite, chunk size, ...)
    store: ResultsStore | None = None

    @property
    def protocol(self) -> Protocol:
        return self.protocols[0]

    @property
    def board_name(self) -> str:
        """the store's and the board's name: dataset and split (a fold's board is its own)"""
        return f"{self.dataset.name}-{self.dataset.split}{getattr(self.dataset, 'board_suffix', '')}"

    def with_store(self, store: ResultsStore) -> RunContext:
        return dataclasses.replace(self, store=store)

    def frames_in_all(self) -> int:
        """frames to run (cached ones included) over every combination and protocol"""
        return len(self.frame_ids) * len(self.combinations) * len(self.protocols)
