"""Stage base classes: what each kind of component takes, returns, and declares.

A component is a small class with `default_conf` (user config merges over it; unknown keys are refused) and the
names of the values it `consumes` and `provides`, so an incompatible combination is refused before a run starts.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

from .errors import PluginError

if TYPE_CHECKING:  # torch is imported where a learned stage is built, not by every command that names stages
    import torch

    from .types import Features, Frame, Keypoints2D, Keypoints3D, Matches, PoseEstimate

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


class ConfigError(PluginError, ValueError):
    """A component was given a configuration it does not understand."""


def merge_conf(defaults: Mapping[str, Any], overrides: Mapping[str, Any] | None, owner: str) -> dict[str, Any]:
    """`overrides` merged over a copy of `defaults` at every depth: a mapping given for a mapping default changes
    only the keys it names (`{"sa1": {"radius": 0.2}}` keeps sa1's other keys). A key the defaults lack, at any
    depth, is a ConfigError naming its dotted path and the closest valid one; an empty mapping default (nothing to
    check against) takes a mapping whole."""
    return _merged(defaults, overrides or {}, owner, "")


def _merged(defaults: Mapping[str, Any], overrides: Mapping[str, Any], owner: str, path: str) -> dict[str, Any]:
    conf = copy.deepcopy(dict(defaults))
    for key, value in overrides.items():
        where = f"{path}{key}"
        if key not in conf:
            raise ConfigError(_unknown_key(owner, path, str(key), conf))
        check_kind(owner, where, conf[key], value)
        nested = isinstance(conf[key], Mapping) and bool(conf[key]) and isinstance(value, Mapping)
        conf[key] = _merged(conf[key], value, owner, f"{where}.") if nested else value
    return conf


def overlay(base: Mapping[str, Any], more: Mapping[str, Any]) -> dict[str, Any]:
    """`more` over `base`, nested mappings merged rather than replaced and nothing checked: overrides from several
    places (a preset's pins, a grid file, --conf) combined before `merge_conf` checks them against the defaults."""
    out = dict(base)
    for key, value in more.items():
        both = isinstance(out.get(key), Mapping) and isinstance(value, Mapping)
        out[key] = overlay(out[key], value) if both else value
    return out


def _unknown_key(owner: str, path: str, key: str, known: Mapping[str, Any]) -> str:
    import difflib  # only to suggest a key: a valid config never needs it

    names = [str(k) for k in known]
    close = difflib.get_close_matches(key, names, n=1, cutoff=0.5)
    hint = f"; did you mean {path + close[0]!r}?" if close else ""
    where = f" under {path[:-1]!r}" if path else ""
    return f"{owner}: unknown config key {path + key!r}{hint} (known keys{where}: {', '.join(names)})"


LENGTHS = ("radius_px", "reproj")  # keys that are pixel lengths (match radii, reprojection error bounds): above 0


def _kind(value: Any) -> str | None:
    """the kind of value a config key holds, for the check below; None: any value goes (a None default, or None)."""
    if value is None:
        return None
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list | tuple):
        return "a list"
    return "a mapping" if isinstance(value, Mapping) else None


def check_kind(owner: str, key: str, default: Any, value: Any) -> None:
    """Refuse a value of another kind than its default (a string where a list goes would be read as its
    characters). A None default or value, and ints for floats, go through."""
    want, got = _kind(default), _kind(value)
    if want is not None and got is not None and want != got:
        raise ConfigError(f"{owner}: config {key} = {value!r} is {got}, but {key} takes {want} (default {default!r})")
    if got != "a number":
        return
    if math.isnan(value):
        raise ConfigError(f"{owner}: config {key} = nan is no number to compare with; give a number")
    lengths = any(word in key for word in LENGTHS) and isinstance(default, int | float) and default > 0
    if lengths and not (math.isfinite(value) and value > 0):  # a radius of 0 or -3 px matches nothing, silently
        raise ConfigError(f"{owner}: config {key} = {value!r}: a radius or error bound is a finite positive number")


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


@dataclass(frozen=True)
class StageKind:
    """One stage kind as the whole core reads it: registry, hooks, command line, calls, trace and contract checks.
    Adding a kind is one entry in STAGES (in data-flow order), its base class above, its hookspec and its contract."""

    base: type[Component]  # what its components subclass; `base.kind` names the kind
    hook: str  # the hookspec (i2pbench.registry.hookspecs) its components are registered through
    options: tuple[str, ...]  # its command-line options (run, train, viz)
    inputs: tuple[str, ...]  # what it is called with after the frame, fields of `trace.StageInputs`, in order
    output: str  # the `StageInputs` field its output becomes ("features.desc2d": one side; "": none reads it)
    contract: str  # the function of i2pbench.contracts that checks its output before anything reads it
    required: bool = False  # a combination without it is refused
    learnable: bool = False  # its components may hold trained parameters (`learned.LearnedComponent`)

    @property
    def kind(self) -> str:
        return self.base.kind


STAGES: dict[str, StageKind] = {
    spec.kind: spec
    for spec in (
        StageKind(Extractor2D, "register_extractors_2d", ("--extractor", "--extractor2d"), (), "kp2d", "keypoints2d",
                  required=True),
        StageKind(Extractor3D, "register_extractors_3d", ("--extractor3d",), (), "kp3d", "keypoints3d", required=True),
        StageKind(Encoder2D, "register_encoders_2d", ("--encoder2d",), ("kp2d",), "features.desc2d", "descriptors2d",
                  learnable=True),
        StageKind(Encoder3D, "register_encoders_3d", ("--encoder3d",), ("kp3d",), "features.desc3d", "descriptors3d",
                  learnable=True),
        StageKind(Exchanger, "register_exchangers", ("--exchanger",), ("kp2d", "kp3d", "features"), "features",
                  "features", learnable=True),
        StageKind(Matcher, "register_matchers", ("--matcher",), ("kp2d", "kp3d", "features"), "matches", "matches",
                  required=True, learnable=True),
        StageKind(PoseSolver, "register_pose_solvers", ("--solver",), ("kp2d", "kp3d", "matches"), "", "estimate",
                  required=True),
    )
}  # fmt: skip
STAGE_BASES: dict[str, type[Component]] = {kind: spec.base for kind, spec in STAGES.items()}
STAGE_ORDER: tuple[str, ...] = tuple(STAGES)
LEARNABLE_KINDS: tuple[str, ...] = tuple(kind for kind, spec in STAGES.items() if spec.learnable)
