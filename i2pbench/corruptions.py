"""Corruptions: robustness measured under the one protocol (ImageNet-C / KITTI-C style), for every method alike.

A corruption changes what the sensors delivered, before the protocol moves the cloud: the image (kind "image"), the
scan ("lidar"), or the calibration the stages are told ("geometry": K). It never touches the ground truth. The
protocol takes T_gt from the dataset's true T_cam_lidar whatever a corruption returns, and when K is corrupted the
true K travels with the ground truth as `Frame.K_gt` (hidden from the stages like T_gt): true matches, the oracle and
the metrics use the camera that formed the image, while extractors, matchers and solvers work with the wrong one, as
they would with a bad calibration.

Severity 0 is the identity; severities 1..len(levels) pick the corruption's parameter from its table `levels`
(docs/robustness.md lists every table). The randomness comes from the protocol's generator for (seed, dataset, frame
id, corruption, severity), so a corrupted frame never depends on run order or on the other severities run.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from .errors import I2PBenchError, PluginError
from .types import SensorFrame

if TYPE_CHECKING:
    from .plugins import Registry
    from .protocol import Protocol

KINDS = ("image", "lidar", "geometry")
CHANGES = {"image": {"image"}, "lidar": {"points", "ring"}, "geometry": {"K"}}  # what each kind may change
MIN_LEVELS, MAX_LEVELS = 3, 5
CLEAN, ALL = "clean", "all"  # --corruption words: the uncorrupted protocol, every registered corruption


class CorruptionError(I2PBenchError):
    """A corruption failed or broke its contract: the run stops, since a failed row would blame the method."""


class Corruption:
    """Base of every corruption: `corrupt` one sensor frame at one level of the table `levels`."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = ""  # one of KINDS: which part of the frame it changes
    meaning: ClassVar[str] = ""  # the physical effect it models, one sentence
    parameter: ClassVar[str] = ""  # what `levels` holds, with its unit
    levels: ClassVar[tuple[Any, ...]] = ()  # the parameter at severity 1, 2, ... (3 to 5 of them)

    @property
    def severities(self) -> range:
        return range(1, len(self.levels) + 1)

    def level(self, severity: int) -> Any:
        if severity not in self.severities:
            raise PluginError(f"corruption {self.name!r} has severities 1..{len(self.levels)}, not {severity}")
        return self.levels[severity - 1]

    def apply(self, sensor: SensorFrame, severity: int, rng: np.random.Generator) -> SensorFrame:
        """The frame as the corrupted sensors would have delivered it; `sensor` itself at severity 0."""
        if severity == 0:
            return sensor
        level = self.level(severity)
        try:
            out = self.corrupt(sensor, level, rng)
        except CorruptionError:
            raise
        except Exception as exc:  # a broken corruption names itself, not the dataset or a stage
            raise CorruptionError(
                f"corruption {self.name!r} severity {severity} failed on {sensor.dataset} frame {sensor.frame_id}: "
                f"{type(exc).__name__}: {exc}"
            ) from exc
        check_corrupted(sensor, out, self)
        return out

    def corrupt(self, sensor: SensorFrame, level: Any, rng: np.random.Generator) -> SensorFrame:
        """`sensor` corrupted at `level` (an entry of `levels`); subclasses implement it, without mutating input."""
        raise NotImplementedError

    def describe(self, severity: int) -> dict[str, Any]:
        """What a corrupted result depends on, for its cache key: a changed table recomputes, not reuses."""
        cls = type(self)
        return {
            "name": self.name,
            "kind": self.kind,
            "severity": severity,
            "level": _plain(self.level(severity)),
            "class": f"{cls.__module__}:{cls.__qualname__}",
        }


def _plain(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


def check_class(cls: type[Corruption], plugin: str) -> None:
    """Refuse, naming the plugin, a corruption class the protocol could not use consistently."""
    if cls.kind not in KINDS:
        raise PluginError(f"plugin {plugin!r} registered corruption {cls.name!r} of kind {cls.kind!r}; kinds: {KINDS}")
    if not MIN_LEVELS <= len(cls.levels) <= MAX_LEVELS:
        raise PluginError(
            f"plugin {plugin!r} registered corruption {cls.name!r} with {len(cls.levels)} levels; it needs "
            f"{MIN_LEVELS} to {MAX_LEVELS}, so means over severities stay comparable"
        )


def check_corrupted(before: SensorFrame, after: object, corruption: Corruption) -> None:
    """The corrupted frame is the same frame, changed only where its kind allows, with valid arrays."""
    where = f"corruption {corruption.name!r} on {before.dataset} frame {before.frame_id}"
    if not isinstance(after, SensorFrame):
        raise CorruptionError(f"{where} returned {type(after).__name__}, expected SensorFrame")
    if not np.array_equal(after.T_cam_lidar, before.T_cam_lidar) or after.match_radius_px != before.match_radius_px:
        raise CorruptionError(f"{where} changed the ground truth (T_cam_lidar or eps_c); no corruption may")
    changed = {f for f in ("image", "points", "ring", "K") if not _same(getattr(before, f), getattr(after, f))}
    if (after.dataset, after.frame_id) != (before.dataset, before.frame_id) or changed - CHANGES[corruption.kind]:
        raise CorruptionError(f"{where} changed {sorted(changed)}; a {corruption.kind} corruption may change only "
                              f"{sorted(CHANGES[corruption.kind])}")  # fmt: skip
    problem = _invalid(before, after)
    if problem:
        raise CorruptionError(f"{where}: {problem}")


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a is b or (a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b))


def _invalid(before: SensorFrame, after: SensorFrame) -> str:
    image, points, ring, K = after.image, after.points, after.ring, after.K
    if image.shape != before.image.shape or image.dtype != np.uint8:
        return f"image must stay {before.image.shape} uint8, got {image.shape} {image.dtype}"
    if points.ndim != 2 or points.shape[1] != 4 or points.dtype != np.float32 or not np.isfinite(points).all():
        return f"points must be finite [N x 4] float32, got {points.shape} {points.dtype}"
    if ring.shape != (len(points),) or ring.dtype != before.ring.dtype:
        return f"ring must be [{len(points)}] {before.ring.dtype}, got {ring.shape} {ring.dtype}"
    if K.shape != (3, 3) or not np.isfinite(K).all():
        return f"K must be a finite 3 x 3 matrix, got {K.shape}"
    return ""


def with_points(sensor: SensorFrame, keep: np.ndarray) -> SensorFrame:
    """The frame keeping the returns where `keep` ([N] bool) is set, in scan order."""
    return dataclasses.replace(sensor, points=sensor.points[keep], ring=sensor.ring[keep])


def protocols(
    registry: Registry, base: Protocol, specs: Sequence[str], severities: Sequence[int] | None = None
) -> list[Protocol]:
    """The protocols `--corruption` names, in order, each once: `clean`, `NAME` (every severity, or `severities`),
    `NAME:S`, or `all` (every registered corruption, as NAME)."""
    out: list[Protocol] = []
    for spec in specs:
        name, sep, severity = spec.partition(":")
        if name == CLEAN:
            chosen = [base]
        else:
            names = sorted(registry.corruptions) if name == ALL else [name]
            chosen = [p for n in names for p in _of(registry, base, n, severity if sep else None, severities)]
        out += [p for p in chosen if p not in out]
    return out


def _of(
    registry: Registry, base: Protocol, name: str, severity: str | None, severities: Sequence[int] | None
) -> list[Protocol]:
    corruption = registry.corruption(name)()
    if severity is not None:
        if not severity.isdigit():
            raise PluginError(
                f"--corruption {name}:{severity}: the severity must be a number 1..{len(corruption.levels)}"
            )
        chosen: Sequence[int] = [int(severity)]
    else:
        chosen = [s for s in corruption.severities if severities is None or s in severities]
    return [base.corrupted(corruption, s) for s in chosen]
