"""How a stage is called: the one function `Pipeline.run`, the conformance kit and the per-frame training fallback
all go through, so what a component sees and what it must return are the same wherever it runs.

A component sees the frame with its ground truth hidden unless it declares GROUND_TRUTH, and descriptors only on the
sides it declares (FEATURES2D, FEATURES3D); its output is checked against its kind's contract
(`contracts`) before anything reads it. Gradients are the caller's choice: a benchmark run calls under
torch.inference_mode, training with autograd on.
"""

from __future__ import annotations

import sys
import time

from ..types import Features, Frame
from . import contracts
from .components import FEATURES2D, FEATURES3D, GROUND_TRUTH, STAGES, Component
from .inputs import StageInputs
from .trace import StageRecord


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
    args = STAGES[component.kind].arguments(inputs, features)
    start = time.perf_counter()
    out = component(view, *args)
    _synchronize()
    seconds = time.perf_counter() - start
    n2d = len(inputs.kp2d) if inputs.kp2d is not None else 0
    n3d = len(inputs.kp3d) if inputs.kp3d is not None else 0
    handed = contracts.Handed(frame, n2d, n3d, component.label, component.provides)
    return StageRecord(component.kind, component.label, contracts.check_output(component.kind, out, handed), seconds)


def _synchronize() -> None:
    """Wait for queued GPU work, so a stage's seconds include the kernels it launched (none unless torch is loaded:
    a classic stage never imports it)."""
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()
