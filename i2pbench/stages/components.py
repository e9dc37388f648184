"""Stage base classes: what each kind of component takes, returns, and declares.

A component is a small class with `default_conf` (user config merges over it; unknown keys are refused) and the
names of the values it `consumes` and `provides`, so an incompatible combination is refused before a run starts.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

from .config import merge_conf

if TYPE_CHECKING:  # torch is imported where a learned stage is built, not by every command that names stages
    import torch

    from ..types import Features, Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate
    from .inputs import StageInputs

# The values that can flow between stages; a frame always provides "image" and "points".
IMAGE, POINTS, GROUND_TRUTH = "image", "points", "ground_truth"
KEYPOINTS2D, KEYPOINTS3D = "keypoints2d", "keypoints3d"
FEATURES2D, FEATURES3D = "features2d", "features3d"
MATCHES = "matches"
# per-3D-keypoint probabilities of lying in the camera frustum, carried by `Matches.frustum` (DeepI2P's classifier
# provides them, its inverse-projection solver consumes them)
FRUSTUM_SCORES = "frustum_scores"
# values beyond those of the stage bases, each with the one stage kind that may provide it: a component declares one
# in `provides` explicitly, and a stage consuming it needs a component that does
EXTRA_VALUES: dict[str, str] = {FRUSTUM_SCORES: "matcher"}


class Component:
    """Base of every stage implementation."""

    kind: ClassVar[str] = ""
    name: ClassVar[str] = ""  # set by the registry to the registered name
    default_conf: ClassVar[dict[str, Any]] = {}
    consumes: ClassVar[frozenset[str]] = frozenset()
    provides: ClassVar[frozenset[str]] = frozenset()
    learned: ClassVar[bool] = False  # True for components whose parameters come from a checkpoint
    # bump when the outputs change for the same name, config and weights (a fixed bug, a new field): results cached
    # by the old code are then recomputed instead of reused (0 adds nothing to the cache key)
    revision: ClassVar[int] = 0

    def __init__(self, conf: Mapping[str, Any] | None = None) -> None:
        self.conf = merge_conf(self.default_conf, conf, f"{self.kind} {self.name!r}")

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        """Return why this component cannot follow `upstream` (kind -> component), or None if it can.

        The default accepts anything whose declared inputs are provided; override for finer checks, e.g. a
        descriptor dimension that must agree with the encoders'.
        """
        return None

    @property
    def label(self) -> str:
        return f"{self.kind} {self.name!r}"

    def __repr__(self) -> str:
        return f"<{self.label} {self.conf}>"


class Extractor2D(Component):
    """Selects image keypoints (edge pixels)."""

    kind = "extractor2d"
    consumes = frozenset({IMAGE})
    provides = frozenset({KEYPOINTS2D})

    def __call__(self, frame: Frame) -> Keypoints2D:
        raise NotImplementedError


class Extractor3D(Component):
    """Selects LiDAR keypoints (edge points)."""

    kind = "extractor3d"
    consumes = frozenset({POINTS})
    provides = frozenset({KEYPOINTS3D})

    def __call__(self, frame: Frame) -> Keypoints3D:
        raise NotImplementedError


class Encoder2D(Component):
    """Describes image keypoints: returns [M2 x D] descriptors."""

    kind = "encoder2d"
    consumes = frozenset({IMAGE, KEYPOINTS2D})
    provides = frozenset({FEATURES2D})

    def __call__(self, frame: Frame, kp2d: Keypoints2D) -> torch.Tensor | None:
        raise NotImplementedError


class Encoder3D(Component):
    """Describes LiDAR keypoints: returns [M3 x D] descriptors."""

    kind = "encoder3d"
    consumes = frozenset({POINTS, KEYPOINTS3D})
    provides = frozenset({FEATURES3D})

    def __call__(self, frame: Frame, kp3d: Keypoints3D) -> torch.Tensor | None:
        raise NotImplementedError


class Exchanger(Component):
    """Updates both descriptor sets jointly (e.g. self/cross attention); shapes are kept."""

    kind = "exchanger"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, FEATURES2D, FEATURES3D})
    provides = frozenset({FEATURES2D, FEATURES3D})

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Features:
        raise NotImplementedError


class Matcher(Component):
    """Pairs image keypoints with LiDAR keypoints."""

    kind = "matcher"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, FEATURES2D, FEATURES3D})
    provides = frozenset({MATCHES})

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        raise NotImplementedError


@runtime_checkable
class TrainableMatcher(Protocol):
    """A matcher that can supervise training: `i2pbench train` minimises its `loss` through every learned stage.

    `frame` carries T_gt. Returns the scalar loss tensor and its named terms (floats) for progress reporting.
    """

    def loss(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features
    ) -> tuple[torch.Tensor, dict[str, float]]: ...


class PoseSolver(Component):
    """Estimates the camera <- LiDAR transform from matches."""

    kind = "solver"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, MATCHES})
    provides = frozenset()

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches) -> PoseEstimate:
        raise NotImplementedError


# What a stage of each kind is called with after the frame (`features`: the descriptor sides it declares) ...
def _no_inputs(inputs: StageInputs, features: Features) -> tuple[Any, ...]:
    return ()


def _kp2d(inputs: StageInputs, features: Features) -> tuple[Any, ...]:
    return (inputs.kp2d,)


def _kp3d(inputs: StageInputs, features: Features) -> tuple[Any, ...]:
    return (inputs.kp3d,)


def _keypoints_and_features(inputs: StageInputs, features: Features) -> tuple[Any, ...]:
    return inputs.kp2d, inputs.kp3d, features


def _keypoints_and_matches(inputs: StageInputs, features: Features) -> tuple[Any, ...]:
    return inputs.kp2d, inputs.kp3d, inputs.matches


# ... and where its output goes for the stages after it.
def _as_kp2d(inputs: StageInputs, out: Keypoints2D) -> StageInputs:
    return replace(inputs, kp2d=out)


def _as_kp3d(inputs: StageInputs, out: Keypoints3D) -> StageInputs:
    return replace(inputs, kp3d=out)


def _as_desc2d(inputs: StageInputs, out: torch.Tensor | None) -> StageInputs:
    return replace(inputs, features=replace(inputs.features, desc2d=out))


def _as_desc3d(inputs: StageInputs, out: torch.Tensor | None) -> StageInputs:
    return replace(inputs, features=replace(inputs.features, desc3d=out))


def _as_features(inputs: StageInputs, out: Features) -> StageInputs:
    return replace(inputs, features=out)


def _as_matches(inputs: StageInputs, out: Matches) -> StageInputs:
    return replace(inputs, matches=out)


def _unread(inputs: StageInputs, out: PoseEstimate) -> StageInputs:
    return inputs  # the solver's estimate ends the frame: no stage reads it


@dataclass(frozen=True)
class StageKind:
    """One stage kind as the whole core reads it: registry, hooks, command line, calls, trace and contract checks.
    Adding a kind is one entry in STAGES (in data-flow order), its base class above, its hookspec and its contract."""

    base: type[Component]  # what its components subclass; `base.kind` names the kind
    hook: str  # the hookspec (i2pbench.registry.hookspecs) its components are registered through
    options: tuple[str, ...]  # its command-line options (run, train, viz)
    arguments: Callable[[StageInputs, Features], tuple[Any, ...]]  # what it is called with after the frame
    put: Callable[[StageInputs, Any], StageInputs]  # the inputs with its output where the stages after it read it
    contract: str  # the function of i2pbench.stages.contracts that checks its output before anything reads it
    required: bool = False  # a combination without it is refused
    learnable: bool = False  # its components may hold trained parameters (`learned.LearnedComponent`)

    @property
    def kind(self) -> str:
        return self.base.kind


STAGES: dict[str, StageKind] = {
    spec.kind: spec
    for spec in (
        StageKind(Extractor2D, "register_extractors_2d", ("--extractor", "--extractor2d"), _no_inputs, _as_kp2d,
                  "keypoints2d", required=True),
        StageKind(Extractor3D, "register_extractors_3d", ("--extractor3d",), _no_inputs, _as_kp3d, "keypoints3d",
                  required=True),
        StageKind(Encoder2D, "register_encoders_2d", ("--encoder2d",), _kp2d, _as_desc2d, "descriptors2d",
                  learnable=True),
        StageKind(Encoder3D, "register_encoders_3d", ("--encoder3d",), _kp3d, _as_desc3d, "descriptors3d",
                  learnable=True),
        StageKind(Exchanger, "register_exchangers", ("--exchanger",), _keypoints_and_features, _as_features,
                  "features", learnable=True),
        StageKind(Matcher, "register_matchers", ("--matcher",), _keypoints_and_features, _as_matches, "matches",
                  required=True, learnable=True),
        StageKind(PoseSolver, "register_pose_solvers", ("--solver",), _keypoints_and_matches, _unread, "estimate",
                  required=True),
    )
}  # fmt: skip
STAGE_BASES: dict[str, type[Component]] = {kind: spec.base for kind, spec in STAGES.items()}
STAGE_ORDER: tuple[str, ...] = tuple(STAGES)
LEARNABLE_KINDS: tuple[str, ...] = tuple(kind for kind, spec in STAGES.items() if spec.learnable)
