"""A chosen combination of components, checked before any frame runs, and run one frame at a time.

Each stage is timed on its own; an exception, a contract violation or a stage running past its time limit (see
`i2pbench.timeout`) becomes a failed outcome that names the component, so one bad frame or plugin never sinks a run.
That includes plugin code calling sys.exit or raising KeyboardInterrupt; only the user's own Ctrl-C stops a run
(`i2pbench.interrupts` tells the two apart). Untrusted plugins can run in a child process instead
(`i2pbench.isolation`), which a time limit can kill even when the stage holds the GIL.
"""

from __future__ import annotations

import functools
import hashlib
import json
import time
import traceback
from collections.abc import Callable, Generator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from . import contracts, interrupts
from .components import (
    FEATURES2D,
    FEATURES3D,
    GROUND_TRUTH,
    IMAGE,
    KEYPOINTS2D,
    KEYPOINTS3D,
    MATCHES,
    POINTS,
    STAGE_ORDER,
    Component,
    LearnedComponent,
)
from .errors import PluginError, StageError
from .isolation import IsolationError, ProcessIsolation, isolation_from_env
from .plugins import Registry
from .timeout import StageTimeout, TimeLimiter, timeout_from_env
from .types import Features, Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate

NONE = "none"  # a stage set to "none" is skipped
REQUIRED_STAGES = ("extractor2d", "extractor3d", "matcher", "solver")
# what a solver may read to run alone on a stored upstream: no pixels, no points (they are not stored)
RESOLVABLE = frozenset({KEYPOINTS2D, KEYPOINTS3D, MATCHES, GROUND_TRUTH})
Stages = Generator[tuple[str, Any], None, "Upstream"]


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


@dataclass(frozen=True)
class Upstream:
    """What the solver consumes, as the stages before it produced it: stored, it lets another solver run alone."""

    kp2d: Keypoints2D
    kp3d: Keypoints3D
    matches: Matches


@dataclass
class FrameOutcome:
    """What running a pipeline on one frame produced."""

    estimate: PoseEstimate
    timings: dict[str, float]  # seconds per stage kind that ran
    n_kp2d: int = 0
    n_kp3d: int = 0
    n_matches: int = 0
    error: str = ""
    failed_component: str = ""
    matched_uv: np.ndarray | None = None  # [K x 2] pixels of the matcher's pairs (None: the matcher did not run)
    matched_xyz: np.ndarray | None = None  # [K x 3] LiDAR points of the same pairs, for the metrics' inlier ratio
    upstream: Upstream | None = None  # the solver's inputs (None: the matcher did not finish)

    @property
    def n_inliers(self) -> int:
        return int(len(self.estimate.inliers))


@dataclass
class _FrameState:
    """How far one frame has got: the stage running, seconds per finished stage, counts; `on_stage` hears starts."""

    on_stage: Callable[[_FrameState], None] | None = None
    stage: str = ""
    timings: dict[str, float] = field(default_factory=dict)
    counts: dict[str, Any] = field(default_factory=lambda: {"n_kp2d": 0, "n_kp3d": 0, "n_matches": 0})

    def enter(self, kind: str) -> None:
        self.stage = kind
        if self.on_stage is not None:
            self.on_stage(self)


class Pipeline:
    """Instantiated components for every stage kind, in data-flow order."""

    def __init__(
        self,
        combination: Combination,
        stages: Mapping[str, Component],
        timeout_s: float | None | str = "env",
        isolate: str = "thread",
    ) -> None:
        """`timeout_s`: seconds one frame may take; None disables; "env" reads I2PBENCH_STAGE_TIMEOUT_S.

        `isolate`: "thread" (stages run in this process) or "process" (in a child process); "env" reads
        I2PBENCH_ISOLATE. Only `build` reads it by default: a pipeline of wrapped stages whose side effects must
        stay in this process (a report's recording trace) is built directly.
        """
        self.combination = combination
        self.stages = {k: stages[k] for k in STAGE_ORDER if k in stages}
        self.limiter = TimeLimiter(timeout_from_env() if timeout_s == "env" else timeout_s)
        mode = isolation_from_env() if isolate == "env" else isolate
        self.isolation = ProcessIsolation(self.limiter.timeout_s) if mode == "process" else None
        self.weights_identity = "none" if not self.learned_modules() else "untrained"
        self.weights_meta: dict[str, Any] = {}
        _check_compatibility(self.stages)

    @classmethod
    def build(
        cls, registry: Registry, combination: Combination, timeout_s: float | None | str = "env", isolate: str = "env"
    ) -> Pipeline:
        missing = [k for k in REQUIRED_STAGES if combination.name(k) == NONE]
        if missing:
            raise PluginError(f"combination {combination.label!r} has no {', '.join(missing)}")
        stages = {}
        for kind in STAGE_ORDER:
            if combination.name(kind) != NONE:
                component_cls = registry.component(kind, combination.name(kind))
                stages[kind] = component_cls(combination.confs.get(kind))
        return cls(combination, stages, timeout_s, isolate)

    def learned_modules(self) -> dict[str, LearnedComponent]:
        return {k: c for k, c in self.stages.items() if isinstance(c, LearnedComponent)}

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
        ground truth, and runs in this process (an isolated child is handed whole frames only)."""
        return self.isolation is None and self.stages["solver"].consumes <= RESOLVABLE

    def resolve(self, frame: Frame, upstream: Upstream) -> FrameOutcome:
        """Run the solver alone on a stored upstream, with `run`'s checks, time limit, timing and failure handling.

        `frame` needs only what a resolvable solver reads: intrinsics, image size, ground truth (see `resolvable`).
        """
        if not self.resolvable:
            raise PluginError(f"{self.stages['solver'].label} cannot run alone on a stored upstream")
        return self.run_here(frame, self.limiter, upstream=upstream)

    def run(self, frame: Frame) -> FrameOutcome:
        """Run every stage on one frame; never raises for a stage's failure, only for the user's Ctrl-C.

        The whole frame runs under the time limiter (one thread hand-off per frame, not per stage), or in the child
        process when isolated; a frame that overruns is failed in the name of the stage that was running.
        """
        if self.isolation is not None:
            return self.isolation.run(self, frame)
        return self.run_here(frame, self.limiter)

    def run_here(
        self,
        frame: Frame,
        limiter: TimeLimiter | None = None,
        on_stage: Callable[[_FrameState], None] | None = None,
        upstream: Upstream | None = None,
    ) -> FrameOutcome:
        """Run the stages in this process (under `limiter` if given); `on_stage` hears each stage as it starts; from
        the solver on when given a stored `upstream`."""
        state = _FrameState(on_stage)
        work = functools.partial(self._run_stages, frame, state, upstream)
        mark = interrupts.watch()
        try:
            estimate = work() if limiter is None else limiter.call(work)
            return FrameOutcome(estimate, state.timings, **state.counts, error="" if estimate.ok else estimate.message)
        except BaseException as exc:  # SystemExit, KeyboardInterrupt... from a plugin are its failure, not the run's
            if interrupts.stops_run(exc, mark):  # the user's Ctrl-C: stop, keeping the frames finished
                if isinstance(exc, KeyboardInterrupt):
                    raise
                raise KeyboardInterrupt from exc
            return self.failed(exc, state.stage, state.timings, state.counts)

    def failed(
        self, exc: BaseException, kind: str, timings: Mapping[str, float], counts: Mapping[str, Any]
    ) -> FrameOutcome:
        """The failed outcome of a frame that raised `exc` while stage `kind` ran, naming its component."""
        if isinstance(exc, StageError):
            component, message = exc.component, str(exc)
        else:
            component = self.stages[kind].label if kind in self.stages else "pipeline"
            plain = isinstance(exc, StageTimeout | IsolationError)
            message = f"{component}: {exc}" if plain else f"{component}: {_describe(exc)}"
        return FrameOutcome(
            PoseEstimate.failed(message), dict(timings), **dict(counts), error=message, failed_component=component
        )

    def _run_stages(self, frame: Frame, state: _FrameState, upstream: Upstream | None = None) -> PoseEstimate:
        """Run the stages, filling `state.counts` with keypoint and match counts, the matched pairs' coordinates and
        the solver's inputs."""
        kept: dict[str, Any] = {}
        counts = state.counts
        with torch.inference_mode():
            for kind, result in self._stages(frame, state, upstream):
                _count(kind, result, counts)
                kept[kind] = result
                if kind == "matcher":
                    counts["matched_uv"] = kept["extractor2d"].uv[result.index2d]
                    counts["matched_xyz"] = kept["extractor3d"].xyz[result.index3d]
                    counts["upstream"] = Upstream(kept["extractor2d"], kept["extractor3d"], result)
        return result

    def _stages(self, frame: Frame, state: _FrameState, upstream: Upstream | None = None):
        """Yield (kind, output) for each stage in order, timing each one and checking its output; the stages before
        the solver replay `upstream` when given one."""
        hidden = frame.without_ground_truth()

        def call(kind: str, *args: Any) -> Any:
            component = self.stages[kind]
            state.enter(kind)
            view = frame if GROUND_TRUTH in component.consumes else hidden
            out, state.timings[kind] = _timed(component, view, *args)
            return out

        up = yield from (self._upstream(call, frame) if upstream is None else self._replay(upstream))
        solver = self.stages["solver"].label
        yield "solver", contracts.check_estimate(call("solver", up.kp2d, up.kp3d, up.matches), solver)

    def _upstream(self, call: Callable[..., Any], frame: Frame) -> Stages:
        """Run the stages before the solver, yielding each output; returns what the solver consumes."""
        s = self.stages
        kp2d = contracts.check_keypoints2d(call("extractor2d"), frame, s["extractor2d"].label)
        yield "extractor2d", kp2d
        kp3d = contracts.check_keypoints3d(call("extractor3d"), frame, s["extractor3d"].label)
        yield "extractor3d", kp3d
        features = self._features(call, kp2d, kp3d)
        matches = contracts.check_matches(
            call("matcher", kp2d, kp3d, features), len(kp2d), len(kp3d), s["matcher"].label
        )
        yield "matcher", matches
        return Upstream(kp2d, kp3d, matches)

    def _replay(self, upstream: Upstream) -> Stages:
        """Yield a stored upstream's outputs as if its stages had run (untimed), its matches checked again."""
        kp2d, kp3d = upstream.kp2d, upstream.kp3d
        contracts.check_matches(upstream.matches, len(kp2d), len(kp3d), self.stages["matcher"].label)
        yield "extractor2d", kp2d
        yield "extractor3d", kp3d
        yield "matcher", upstream.matches
        return upstream

    def _features(self, call: Any, kp2d: Keypoints2D, kp3d: Keypoints3D) -> Features:
        s = self.stages
        d2 = call("encoder2d", kp2d) if "encoder2d" in s else None
        d3 = call("encoder3d", kp3d) if "encoder3d" in s else None
        d2 = contracts.check_descriptors(d2, len(kp2d), s["encoder2d"].label) if "encoder2d" in s else None
        d3 = contracts.check_descriptors(d3, len(kp3d), s["encoder3d"].label) if "encoder3d" in s else None
        features = Features(d2, d3)
        if "exchanger" in s:
            features = contracts.check_features(
                call("exchanger", kp2d, kp3d, features), len(kp2d), len(kp3d), s["exchanger"].label
            )
        return features


def _timed(component: Component, *args: Any) -> tuple[Any, float]:
    """(output, seconds) of one stage, timed around the call only."""
    start = time.perf_counter()
    out = component(*args)
    _synchronize()
    return out, time.perf_counter() - start


def _count(kind: str, result: Any, counts: dict[str, Any]) -> None:
    key = {"extractor2d": "n_kp2d", "extractor3d": "n_kp3d", "matcher": "n_matches"}.get(kind)
    if key:
        counts[key] = len(result)


def _describe(exc: BaseException) -> str:
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    loc = f" (at {where.filename.rsplit('/', 1)[-1]}:{where.lineno})" if where else ""
    if isinstance(exc, SystemExit):  # its str() is the bare exit code, or nothing
        return f"called sys.exit({exc.code!r}){loc}"
    return f"{type(exc).__name__}: {exc}{loc}" if str(exc) else f"{type(exc).__name__}{loc}"


def _synchronize() -> None:
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()


# Which stage kind normally provides each value, for error messages.
_PROVIDER = {KEYPOINTS2D: "extractor2d", KEYPOINTS3D: "extractor3d", FEATURES2D: "encoder2d", FEATURES3D: "encoder3d"}


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
