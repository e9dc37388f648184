"""How a stage is called: the one function `Pipeline.run`, the conformance kit and the per-frame training fallback
all go through, so what a component sees and what it must return are the same wherever it runs.

A component sees the frame with its ground truth hidden unless it declares GROUND_TRUTH, and descriptors only on the
sides it declares (FEATURES2D, FEATURES3D); its output is checked against its kind's contract
(`i2pbench.contracts`) before anything reads it. Gradients are the caller's choice: a benchmark run calls under
torch.inference_mode, training with autograd on.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable
from typing import Any

from . import contracts
from .components import FEATURES2D, FEATURES3D, GROUND_TRUTH, Component
from .trace import StageRecord
from .types import Features, Frame, Keypoints2D, Keypoints3D, Matches


@dataclasses.dataclass(frozen=True)
class StageInputs:
    """What the stages before one have produced so far: the values a stage of any kind may be handed."""

    kp2d: Keypoints2D | None = None
    kp3d: Keypoints3D | None = None
    features: Features = dataclasses.field(default_factory=lambda: Features(None, None))
    matches: Matches | None = None

    def after(self, record: StageRecord) -> StageInputs:
        """These inputs with a finished stage's output put where the stages after it read it."""
        out, f = record.output, self.features
        if record.kind == "encoder2d":
            return dataclasses.replace(self, features=Features(out, f.desc3d))
        if record.kind == "encoder3d":
            return dataclasses.replace(self, features=Features(f.desc2d, out))
        field = _FEEDS.get(record.kind)  # None for the solver: nothing reads its output
        return self if field is None else dataclasses.replace(self, **{field: out})


_FEEDS = {"extractor2d": "kp2d", "extractor3d": "kp3d", "exchanger": "features", "matcher": "matches"}

# the arguments after the frame that a stage of each kind is called with, from its inputs and declared features
_ARGUMENTS: dict[str, Callable[[StageInputs, Features], tuple[Any, ...]]] = {
    "extractor2d": lambda i, f: (),
    "extractor3d": lambda i, f: (),
    "encoder2d": lambda i, f: (i.kp2d,),
    "encoder3d": lambda i, f: (i.kp3d,),
    "exchanger": lambda i, f: (i.kp2d, i.kp3d, f),
    "matcher": lambda i, f: (i.kp2d, i.kp3d, f),
    "solver": lambda i, f: (i.kp2d, i.kp3d, i.matches),
}


def declared_view(component: Component, frame: Frame, features: Features) -> tuple[Frame, Features]:
    """The frame and features a component is handed, given what it declares it consumes."""
    view = frame if GROUND_TRUTH in component.consumes else frame.without_ground_truth()
    shown = Features(
        features.desc2d if FEATURES2D in component.consumes else None,
        features.desc3d if FEATURES3D in component.consumes else None,
    )
    return view, shown


def call_stage(component: Component, frame: Frame, inputs: StageInputs) -> StageRecord:
    """Call `component` as a stage of its kind: the declared view, then the call (timed alone), then the contract
    check of its output (a `contracts.ContractError` naming it)."""
    view, features = declared_view(component, frame, inputs.features)
    args = _ARGUMENTS[component.kind](inputs, features)
    start = time.perf_counter()
    out = component(view, *args)
    _synchronize()
    seconds = time.perf_counter() - start
    n2d = len(inputs.kp2d) if inputs.kp2d is not None else 0
    n3d = len(inputs.kp3d) if inputs.kp3d is not None else 0
    checked = contracts.check_output(component.kind, out, frame, n2d, n3d, component.label, component.provides)
    return StageRecord(component.kind, component.label, checked, seconds)


def _synchronize() -> None:
    """Wait for queued GPU work, so a stage's seconds include the kernels it launched (none unless torch is loaded:
    a classic stage never imports it)."""
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()
