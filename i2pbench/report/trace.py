"""One pipeline run that also keeps each stage's output (keypoints, matches), for the edge and match panels.

The pipeline's own `run` is reused unchanged (error handling, timings, contract checks): each component is wrapped
in a recorder that forwards everything and notes what the component returned, so nothing of the data flow is
duplicated here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..components import Component
from ..pipeline import FrameOutcome, Pipeline
from ..types import Frame, Keypoints2D, Keypoints3D, Matches


class _Recorder:
    """Stands in for a component: same attributes, and each call's output is stored under the component's kind."""

    def __init__(self, component: Component, outputs: dict[str, Any]) -> None:
        self._component, self._outputs = component, outputs

    def __getattr__(self, name: str) -> Any:
        return getattr(self._component, name)

    def __call__(self, *args: Any) -> Any:
        out = self._component(*args)
        self._outputs[self._component.kind] = out
        return out


@dataclass
class Trace:
    """A frame's outcome plus the intermediate outputs of the stages that ran (missing after a failure)."""

    outcome: FrameOutcome
    outputs: dict[str, Any] = field(default_factory=dict)

    @property
    def kp2d(self) -> Keypoints2D | None:
        return self.outputs.get("extractor2d")

    @property
    def kp3d(self) -> Keypoints3D | None:
        return self.outputs.get("extractor3d")

    @property
    def matches(self) -> Matches | None:
        return self.outputs.get("matcher")


def trace(pipeline: Pipeline, frame: Frame) -> Trace:
    """Run the pipeline on one frame, keeping every stage's output."""
    outputs: dict[str, Any] = {}
    recorded = {kind: _Recorder(component, outputs) for kind, component in pipeline.stages.items()}
    twin = Pipeline(pipeline.combination, recorded, timeout_s=pipeline.limiter.timeout_s)
    return Trace(twin.run(frame), outputs)
