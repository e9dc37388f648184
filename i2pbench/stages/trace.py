"""A frame's trace: what each stage of one run returned and how long it took, in order, and what stopped it.

Every stage call goes through `calling.call_stage`, and `Pipeline.run` returns no more than this, so a benchmark
record, a stored upstream, `viz`'s panels and training validation read the same values instead of calling stages
again. A record holds a stage's output after its contract check (`calling`); a failed frame keeps the records of the
stages that finished before the failure.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..types import Features, Keypoints2D, Keypoints3D, Matches, PoseEstimate
from .components import STAGES
from .inputs import StageInputs


@dataclass(frozen=True)
class StageRecord:
    """One stage of one frame: its kind, its component's label, its checked output and the seconds its call took
    (None: replayed from a stored upstream, not run)."""

    kind: str
    component: str
    output: Any
    seconds: float | None


@dataclass(frozen=True)
class Failure:
    """What stopped a frame: the component blamed, the stage kind running then ("" when none was), the message."""

    component: str
    kind: str
    message: str


@dataclass(frozen=True)
class Upstream:
    """What the solver consumes, as the stages before it produced it: stored, it lets another solver run alone.

    `matches` carries the matcher's frustum scores when it gives them (`Matches.frustum`), so a frustum solver
    re-runs from the store as any other."""

    kp2d: Keypoints2D
    kp3d: Keypoints3D
    matches: Matches


@dataclass(frozen=True)
class FrameOutcome:
    """A frame's trace (`records`, `failure`) and what a benchmark record reads from it, built once by `of`.

    `estimate`, `timings`, `error` and `failed_component` are fields so that a frame that never reached the
    pipeline (a dataset error) can be described without records, and a resolve can merge stored timings in.
    """

    estimate: PoseEstimate
    timings: dict[str, float]  # seconds per stage kind that ran (a replayed stage did not)
    error: str = ""
    failed_component: str = ""
    records: tuple[StageRecord, ...] = ()  # the stages that finished, in data-flow order
    failure: Failure | None = None

    @classmethod
    def of(cls, records: Sequence[StageRecord], failure: Failure | None = None) -> FrameOutcome:
        """The outcome of a frame whose stages left `records`: failed by `failure`, else the solver's estimate."""
        records = tuple(records)
        timings = {r.kind: r.seconds for r in records if r.seconds is not None}
        if failure is not None:
            estimate = PoseEstimate.failed(failure.message)
            return cls(estimate, timings, failure.message, failure.component, records, failure)
        estimate = records[-1].output
        return cls(estimate, timings, "" if estimate.ok else estimate.message, "", records)

    @property
    def produced(self) -> StageInputs:
        """What the finished stages produced, each output where the stages after it read it (`StageKind.put`):
        the descriptors as the exchanger left them, a side None where no encoder ran. A stage sees only the sides it
        declares (`calling.declared_view`)."""
        produced = StageInputs()
        for record in self.records:
            produced = STAGES[record.kind].put(produced, record.output)
        return produced

    @property
    def kp2d(self) -> Keypoints2D | None:
        return self.produced.kp2d

    @property
    def kp3d(self) -> Keypoints3D | None:
        return self.produced.kp3d

    @property
    def features(self) -> Features:
        return self.produced.features

    @property
    def matches(self) -> Matches | None:
        return self.produced.matches

    @property
    def upstream(self) -> Upstream | None:
        """The solver's inputs (None: the matcher did not finish)."""
        kp2d, kp3d, matches = self.kp2d, self.kp3d, self.matches
        return None if matches is None else Upstream(kp2d, kp3d, matches)

    @property
    def n_kp2d(self) -> int:
        return 0 if self.kp2d is None else len(self.kp2d)

    @property
    def n_kp3d(self) -> int:
        return 0 if self.kp3d is None else len(self.kp3d)

    @property
    def n_matches(self) -> int:
        return 0 if self.matches is None else len(self.matches)

    @property
    def n_inliers(self) -> int:
        return int(len(self.estimate.inliers))

    @property
    def matched_uv(self) -> np.ndarray | None:
        """[K x 2] pixels of the matcher's pairs (None: the matcher did not run)."""
        return None if self.matches is None else self.kp2d.uv[self.matches.index2d]

    @property
    def matched_xyz(self) -> np.ndarray | None:
        """[K x 3] LiDAR points of the same pairs, for the metrics' inlier ratio."""
        return None if self.matches is None else self.kp3d.xyz[self.matches.index3d]
