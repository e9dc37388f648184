"""A chosen combination of components, checked before any frame runs, and run one frame at a time.

`Pipeline.run` calls a frame's stages, each through `i2pbench.stages.calling.call_stage` (declared view, timed call,
contract check; the one caller, which the batched training path and the conformance kit use too), and returns the
frame's trace (`i2pbench.stages.trace.FrameOutcome`): each stage's checked output and seconds, in order, and the
failure if any; runs, viz and training read that trace. An exception, a contract violation or
a stage running past its time limit (see `i2pbench.execution.timeout`) becomes a failed outcome that names the
component, so one bad frame or plugin never sinks a run. That includes plugin code calling sys.exit or raising
KeyboardInterrupt; only the user's own Ctrl-C stops a run (`i2pbench.execution.interrupts` tells the two apart).
Untrusted plugins can run in a child process instead: `i2pbench.execution.isolation` wraps a pipeline so that its frames
run there, where a time limit can kill a stage even when it holds the GIL.
"""

from __future__ import annotations

import functools
import hashlib
import json
import sys
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ..errors import IsolationError, PluginError, StageError
from ..execution import interrupts
from ..execution.timeout import StageTimeout, TimeLimiter, timeout_from_env
from ..registry.catalog import Registry
from ..types import Frame, Keypoints2D, Keypoints3D
from . import contracts
from .calling import StageInputs, call_stage
from .components import (
    EXTRA_VALUES,
    FRUSTUM_SCORES,
    GROUND_TRUTH,
    IMAGE,
    KEYPOINTS2D,
    KEYPOINTS3D,
    MATCHES,
    POINTS,
    STAGE_BASES,
    STAGE_ORDER,
    STAGES,
    Component,
)
from .trace import Failure, FrameOutcome, StageRecord, Upstream

if TYPE_CHECKING:  # a pipeline of classic stages runs without torch; learned stages bring it
    import torch

    from .learned import LearnedComponent

NONE = "none"  # a stage set to "none" is skipped
REQUIRED_STAGES = tuple(kind for kind, spec in STAGES.items() if spec.required)
# what a solver may read to run alone on a stored upstream: no pixels, no points (they are not stored)
RESOLVABLE = frozenset({KEYPOINTS2D, KEYPOINTS3D, MATCHES, FRUSTUM_SCORES, GROUND_TRUTH})


@dataclass(frozen=True)
class Combination:
    """Which component runs at each stage (or "none"), with config overrides.

    `variant` names a set of configs a preset pins (e.g. "cpu" for EdgeRegNet's CPU-trained size) so labels stay
    short; `shown` are the overrides a label spells out (None: all of `confs`). Neither enters the cache key.
    """

    names: Mapping[str, str]
    confs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    variant: str = field(default="", compare=False)
    shown: Mapping[str, Mapping[str, Any]] | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        unknown = set(self.names) - set(STAGE_ORDER)
        if unknown:
            raise PluginError(f"unknown stage kind(s) {sorted(unknown)}; kinds are {list(STAGE_ORDER)}")

    def name(self, kind: str) -> str:
        return self.names.get(kind, NONE)

    @property
    def label(self) -> str:
        return " > ".join(self.name(k) for k in STAGE_ORDER if self.name(k) != NONE)

    @property
    def display(self) -> str:
        """The label with the variant and the spelled-out overrides, so rows differing only in config stay apart."""
        shown = self.confs if self.shown is None else self.shown
        confs = [f"{kind}.{k}={v}" for kind, conf in sorted(shown.items()) for k, v in conf.items()]
        variant = f" ({self.variant})" if self.variant else ""
        return self.label + variant + (f" [{', '.join(confs)}]" if confs else "")

    def describe(self) -> dict[str, Any]:
        return {k: {"name": self.name(k), "conf": dict(self.confs.get(k, {}))} for k in STAGE_ORDER}

    def key(self) -> str:
        return hashlib.sha256(json.dumps(self.describe(), sort_keys=True, default=str).encode()).hexdigest()[:16]


class _Progress:
    """A frame's records as its stages finish, and the kind last started: read by whoever gives up on the frame
    before it ends (the time limiter's caller; an isolated child's parent, told by `listener` at each start)."""

    def __init__(self, listener: Callable[[_Progress], None] | None = None) -> None:
        self.records: list[StageRecord] = []
        self.running = ""
        self.listener = listener

    def start(self, kind: str) -> None:
        self.running = kind
        if self.listener is not None:
            self.listener(self)


def pretrained_sources(learned: Mapping[str, Any]) -> list[str]:
    """`kind: identity` of each learned stage that starts from pretrained weights (its `pretrained_identity`, e.g.
    `encoder2d: aliked-n16@1a2b3c4d`)."""
    return [f"{kind}: {c.pretrained_identity}" for kind, c in learned.items() if c.pretrained_identity]


def untrained_identity(learned: Mapping[str, Any]) -> str:
    """`untrained`, plus the pretrained weights its learned stages start from, so a row without a checkpoint still
    names every weight it ran with."""
    pretrained = pretrained_sources(learned)
    return "untrained" + (f" ({', '.join(pretrained)})" if pretrained else "")


class Pipeline:
    """Instantiated components for every stage kind, in data-flow order."""

    def __init__(
        self,
        combination: Combination,
        stages: Mapping[str, Component],
        timeout_s: float | None | str = "env",
    ) -> None:
        """`timeout_s`: seconds one frame may take; None disables; "env" reads I2PBENCH_STAGE_TIMEOUT_S. Stages run in
        this process (`i2pbench.execution.isolation.isolated` gives a pipeline whose frames run in a child process)."""
        self.combination = combination
        self.stages = {k: stages[k] for k in STAGE_ORDER if k in stages}
        self.limiter = TimeLimiter(timeout_from_env() if timeout_s == "env" else timeout_s)
        self.weights_identity = "none" if not self.learned_modules() else untrained_identity(self.learned_modules())
        self.weights_meta: dict[str, Any] = {}
        _check_compatibility(self.stages)

    @classmethod
    def build(cls, registry: Registry, combination: Combination, timeout_s: float | None | str = "env") -> Pipeline:
        classes = stage_classes(registry, combination)
        stages = {kind: component_cls(combination.confs.get(kind)) for kind, component_cls in classes.items()}
        return cls(combination, stages, timeout_s)

    def learned_modules(self) -> dict[str, LearnedComponent]:
        # a learned stage's class subclasses it, so it is loaded then
        learned = sys.modules.get("i2pbench.stages.learned")
        if learned is None:
            return {}
        return {k: c for k, c in self.stages.items() if isinstance(c, learned.LearnedComponent)}

    def model_size_mb(self) -> float:
        """Size of all learned parameters stored as float32."""
        n = sum(p.numel() for m in self.learned_modules().values() for p in m.parameters())
        return n * 4 / 2**20

    def to(self, device: str | torch.device) -> Pipeline:
        for module in self.learned_modules().values():
            module.to(device)
        return self

    def eval(self) -> Pipeline:
        for module in self.learned_modules().values():
            module.eval()
        return self

    @property
    def resolvable(self) -> bool:
        """Whether the solver can run alone on a stored upstream: it declares no input beyond keypoints, matches and
        ground truth."""
        return self.stages["solver"].consumes <= RESOLVABLE

    def resolve(self, frame: Frame, upstream: Upstream) -> FrameOutcome:
        """Run the solver alone on a stored upstream, with `run`'s checks, time limit, timing and failure handling.

        `frame` needs only what a resolvable solver reads: intrinsics, image size, ground truth (see `resolvable`).
        """
        if not self.resolvable:
            raise PluginError(f"{self.stages['solver'].label} cannot run alone on a stored upstream")
        return self.run_here(frame, self.limiter, upstream=upstream)

    def run(self, frame: Frame) -> FrameOutcome:
        """Run every stage on one frame; never raises for a stage's failure, only for the user's Ctrl-C.

        The whole frame runs under the time limiter (one thread hand-off per frame, not per stage); a frame that
        overruns is failed in the name of the stage that was running.
        """
        return self.run_here(frame, self.limiter)

    def run_here(
        self,
        frame: Frame,
        limiter: TimeLimiter | None = None,
        listener: Callable[[_Progress], None] | None = None,
        upstream: Upstream | None = None,
    ) -> FrameOutcome:
        """Run the stages in this process (under `limiter` if given), as a benchmark does (under
        torch.inference_mode once any stage has loaded torch); `listener` hears each stage as it starts; from the
        solver on when given a stored `upstream`."""
        progress = _Progress(listener)
        work = functools.partial(self._inference, frame, progress, upstream)
        mark = interrupts.watch()
        try:
            work() if limiter is None else limiter.call(work)
            return FrameOutcome.of(progress.records)
        except BaseException as exc:  # SystemExit, KeyboardInterrupt... from a plugin are its failure, not the run's
            if interrupts.stops_run(exc, mark):  # the user's Ctrl-C: stop, keeping the frames finished
                if isinstance(exc, KeyboardInterrupt):
                    raise
                raise KeyboardInterrupt from exc
            return self.failed(exc, progress.running, progress.records)

    def failed(self, exc: BaseException, kind: str, records: Sequence[StageRecord] = ()) -> FrameOutcome:
        """The failed outcome of a frame that raised `exc` while stage `kind` ran, after `records`; it names the
        component at fault."""
        if isinstance(exc, StageError):
            component, message = exc.component, str(exc)
        else:
            component = self.stages[kind].label if kind in self.stages else "pipeline"
            plain = isinstance(exc, StageTimeout | IsolationError)
            message = f"{component}: {exc}" if plain else f"{component}: {_describe(exc)}"
        return FrameOutcome.of(tuple(records), Failure(component, kind, message))

    def _inference(self, frame: Frame, progress: _Progress, upstream: Upstream | None) -> None:
        torch = sys.modules.get("torch")
        if torch is None:  # no stage has loaded torch (a classic pipeline): there is no autograd to turn off
            _walk(self.stages, frame, progress, upstream)
            return
        with torch.inference_mode():
            _walk(self.stages, frame, progress, upstream)


def stage_classes(registry: Registry, combination: Combination) -> dict[str, type[Component]]:
    """The component class of each stage the combination names, in data-flow order (imported now: a learned
    stage's module imports torch); refuses a combination without every required stage."""
    missing = [k for k in REQUIRED_STAGES if combination.name(k) == NONE]
    if missing:
        raise PluginError(f"combination {combination.label!r} has no {', '.join(missing)}")
    named = [kind for kind in STAGE_ORDER if combination.name(kind) != NONE]
    return {kind: registry.component(kind, combination.name(kind)) for kind in named}


def _walk(
    stages: Mapping[str, Component],
    frame: Frame,
    progress: _Progress,
    upstream: Upstream | None = None,
    until: str = "solver",
) -> None:
    """Call the stages in data-flow order up to `until`, each through `call_stage`, adding each record to
    `progress`; raises what a stage raises. Given a stored `upstream`, it stands in for the stages before the solver."""
    inputs = StageInputs() if upstream is None else _replay(stages, upstream, progress)
    for kind in STAGE_ORDER[: STAGE_ORDER.index(until) + 1]:
        if kind in stages and (upstream is None or kind == "solver"):
            progress.start(kind)
            record = call_stage(stages[kind], frame, inputs)
            progress.records.append(record)
            inputs = STAGES[kind].put(inputs, record.output)


def extract(stages: Mapping[str, Component], frame: Frame) -> tuple[Keypoints2D, Keypoints3D]:
    """The extractors' keypoints of `frame`, through the path a run takes (declared view, contract checks) but with
    autograd as the caller has it and failures raised (a StageError naming the component), for training samples."""
    progress = _Progress()
    _walk(stages, frame, progress, until="extractor3d")
    kp2d, kp3d = (r.output for r in progress.records)
    return kp2d, kp3d


def _replay(stages: Mapping[str, Component], upstream: Upstream, progress: _Progress) -> StageInputs:
    """A stored upstream's outputs recorded as if its stages had run (untimed), its matches checked again."""
    kp2d, kp3d, matches = upstream.kp2d, upstream.kp3d, upstream.matches
    contracts.check_matches(matches, len(kp2d), len(kp3d), stages["matcher"].label)
    for kind, out in (("extractor2d", kp2d), ("extractor3d", kp3d), ("matcher", matches)):
        progress.records.append(StageRecord(kind, stages[kind].label, out, None))
    return StageInputs(kp2d, kp3d, matches=matches)


def _describe(exc: BaseException) -> str:
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    loc = f" (at {where.filename.rsplit('/', 1)[-1]}:{where.lineno})" if where else ""
    if isinstance(exc, SystemExit):  # its str() is the bare exit code, or nothing
        return f"called sys.exit({exc.code!r}){loc}"
    return f"{type(exc).__name__}: {exc}{loc}" if str(exc) else f"{type(exc).__name__}{loc}"


# Which stage kind first provides each value, for error messages (features2d: the encoder2d, not the exchanger).
_PROVIDER = {value: kind for kind, base in reversed(STAGE_BASES.items()) for value in base.provides} | EXTRA_VALUES


def _check_compatibility(stages: Mapping[str, Component]) -> None:
    """Refuse a combination whose stages' declared inputs are not provided upstream, naming both components."""
    available = {IMAGE, POINTS, GROUND_TRUTH}
    upstream: dict[str, Component] = {}
    for kind, component in stages.items():
        for need in sorted(component.consumes - available):
            provider = _PROVIDER.get(need, "an earlier stage")
            chosen = f"{provider} {stages[provider].name!r}" if provider in stages else f"{provider} 'none'"
            raise PluginError(f"{component.label} needs {need}, but {chosen} does not provide it")
        reason = component.check_compatible(upstream)
        if reason:
            raise PluginError(f"{component.label} cannot follow this combination: {reason}")
        upstream[kind] = component
        available |= component.provides
