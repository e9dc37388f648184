"""The hooks a plugin implements. Each receives a `register` callback, so one plugin can offer many components.

A plugin is any module or object with functions decorated by `i2pbench.hookimpl`, exposed through the entry-point
group `i2pbench`. Built-in stages are registered this way too.

Components and datasets are registered as a class, `register(cls)`, or by import path and name,
`register("package.module:Class", name="x")`: then the class is imported only when a run uses it, so a plugin whose
modules import torch (or any heavy library) costs `i2pbench plugins` and other runs nothing. Either form takes
`aliases=("other-name",)`: more names users may type for the same component (rows and cache keys carry `name`).
"""

from __future__ import annotations

from collections.abc import Callable

import pluggy

hookspec = pluggy.HookspecMarker("i2pbench")
hookimpl = pluggy.HookimplMarker("i2pbench")  # what a plugin decorates its hooks with, beside what they implement
Register = Callable[..., None]


@hookspec
def register_datasets(register: Register) -> None:
    """Register `i2pbench.data.Dataset` subclasses: `register(DatasetClass)` (or by path), keyed by its `name`."""


@hookspec
def register_extractors_2d(register: Register) -> None:
    """Register `Extractor2D` subclasses (image keypoint / edge pixel selectors): `register(cls)`."""


@hookspec
def register_extractors_3d(register: Register) -> None:
    """Register `Extractor3D` subclasses (LiDAR keypoint / edge point selectors): `register(cls)`."""


@hookspec
def register_encoders_2d(register: Register) -> None:
    """Register `Encoder2D` subclasses, which describe image keypoints with [M x D] descriptors: `register(cls)`."""


@hookspec
def register_encoders_3d(register: Register) -> None:
    """Register `Encoder3D` subclasses, which describe LiDAR keypoints with [M x D] descriptors: `register(cls)`."""


@hookspec
def register_exchangers(register: Register) -> None:
    """Register `Exchanger` subclasses, which update 2D and 3D descriptors jointly: `register(cls)`."""


@hookspec
def register_matchers(register: Register) -> None:
    """Register `Matcher` subclasses, which pair 2D and 3D keypoints: `register(cls)`."""


@hookspec
def register_pose_solvers(register: Register) -> None:
    """Register `PoseSolver` subclasses, which turn matches into a camera <- LiDAR pose: `register(cls)`."""


@hookspec
def register_presets(register: Register) -> None:
    """Register named lists of stage combinations: `register(name, combinations, description)`.

    `combinations` is a list of dicts mapping stage kinds (e.g. "extractor2d") to component names; kinds left out take
    the default pipeline's choice. An entry may instead be another preset's name (a str): its rows, in place, so a
    comparison across several plugins' methods names their presets rather than copying them; or a
    `Row(size, swaps, method=NAME, confs=..., variant=...)`, a row of a registered method built from its
    declaration. The preset named "default" is what `i2pbench run` uses with no stage options.
    """


@hookspec
def register_methods(register: Register) -> None:
    """Register learned methods: `register(i2pbench.registry.methods.Method(...))`, one object naming a method's stage
    components, its sizes (named stage configs), its presets (rows built from a size, stages swapped) and its shipped
    checkpoints. Its presets and weights are registered with it: no `register_presets` needed."""


@hookspec
def register_corruptions(register: Register) -> None:
    """Register `i2pbench.api.Corruption` subclasses (sensor or calibration faults run with `--corruption NAME`):
    `register(cls)` or by path. A corruption changes what the stages see, never the ground truth."""


@hookspec
def register_metrics(register: Register) -> None:
    """Register `i2pbench.api.Metric`s: `register(Metric(...))`, a per-frame value stored in every record and its
    aggregate as a leaderboard column, read by `run`, `evaluate`, training validation and `compare`
    (`i2pbench.scoring.metrics` says how to declare one)."""


@hookspec
def register_protocols(register: Register) -> None:
    """Register protocol cards: `register(i2pbench.scoring.cards.ProtocolCard(...))`, a paper's test inputs and
    scoring rules, named and versioned, that `run --protocol NAME` runs under and `evaluate --rules NAME` scores by."""


HOOK_NAMES: tuple[str, ...] = (
    "register_datasets",
    "register_extractors_2d",
    "register_extractors_3d",
    "register_encoders_2d",
    "register_encoders_3d",
    "register_exchangers",
    "register_matchers",
    "register_pose_solvers",
    "register_presets",
    "register_methods",
    "register_corruptions",
    "register_protocols",
    "register_metrics",
)
