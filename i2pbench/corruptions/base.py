"""Corruptions: robustness measured under the one protocol (ImageNet-C / KITTI-C style), for every method alike.

A corruption changes what the sensors delivered, before the protocol moves the cloud: the image (kind "image"), the
scan ("lidar"), or the geometry ("geometry": the K the stages are told, or a rigid motion of the cloud). It never
touches the ground truth. The protocol takes T_gt from the dataset's true T_cam_lidar whatever a corruption returns,
and when K is corrupted the true K travels with the ground truth as `Frame.K_gt` (hidden from the stages like T_gt):
true matches, the oracle and the metrics use the camera that formed the image, while extractors, matchers and solvers
work with the wrong one, as they would with a bad calibration.

A corruption that `moves_cloud` (a tilted mount) returns a rigid motion M of the scan from `motion` instead of
changing the frame: the protocol composes it into its own random transform, T = T_rand @ M, so the ground truth stays
the truth, T_gt = T_cam_lidar @ inv(T). A corruption that `needs` an optional field of the frame (the ego motion) does
not apply to a frame without it: `i2pbench.runs.grid.protocols` leaves it out of `all` for such data and refuses it by
name, before any frame runs, and a frame that still meets it stops the run (`NotApplicable`), so it never becomes a
0 % row.

Severity 0 is the identity; severities 1..len(levels) pick the corruption's parameter from its table `levels`
(docs/robustness.md lists every table). The randomness comes from the protocol's generator for (seed, dataset, frame
id, corruption, severity), so a corrupted frame never depends on run order or on the other severities run.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar

from ..errors import I2PBenchError, PluginError

if TYPE_CHECKING:  # numpy and the frame are imported where frames are checked: listing plugins needs neither
    import numpy as np

    from ..data.base import Dataset
    from ..types import SensorFrame

KINDS = ("image", "lidar", "geometry")
CHANGES = {"image": {"image"}, "lidar": {"points", "ring"}, "geometry": {"K"}}  # what each kind may change
CHECKED = ("image", "points", "ring", "K", "ego_motion")  # the fields a corruption is checked not to change unasked
OPTIONAL = {"ego_motion": "the LiDAR's ego motion, which KITTI gives where <root>/poses/<sequence>.txt exists and "
            "nuScenes from its ego poses (docs/datasets.md)"}  # fmt: skip  # what `needs` may name, and where from
ROTATION_TOL = 1e-9  # |R^T R - I| and |det R - 1| of a corruption's motion: it is computed, not read from a file
MIN_LEVELS, MAX_LEVELS = 3, 5


class CorruptionError(I2PBenchError):
    """A corruption failed or broke its contract: the run stops, since a failed row would blame the method."""


class NotApplicable(CorruptionError):
    """A frame lacks what the corruption needs: it has no result under it (a failed row would blame the method)."""


class Corruption:
    """Base of every corruption: `corrupt` one sensor frame at one level of the table `levels` (or, one that
    `moves_cloud`, give the rigid `motion` the protocol composes into its random transform)."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = ""  # one of KINDS: which part of the frame it changes
    meaning: ClassVar[str] = ""  # the physical effect it models, one sentence
    parameter: ClassVar[str] = ""  # what `levels` holds, with its unit
    levels: ClassVar[tuple[Any, ...]] = ()  # the parameter at severity 1, 2, ... (3 to 5 of them)
    moves_cloud: ClassVar[bool] = False  # True: `motion` moves the scan rigidly; the protocol composes it into T_gt
    needs: ClassVar[tuple[str, ...]] = ()  # optional SensorFrame fields it needs (of OPTIONAL); else it does not apply

    @property
    def severities(self) -> range:
        return range(1, len(self.levels) + 1)

    def level(self, severity: int) -> Any:
        if severity not in self.severities:
            raise PluginError(f"corruption {self.name!r} has severities 1..{len(self.levels)}, not {severity}")
        return self.levels[severity - 1]

    def applies(self, sensor: SensorFrame) -> bool:
        """Whether the frame has everything the corruption `needs` (a frame without its ego motion cannot be shifted
        in time)."""
        return all(getattr(sensor, name, None) is not None for name in self.needs)

    def apply(self, sensor: SensorFrame, severity: int, rng: np.random.Generator) -> SensorFrame:
        """The frame as the corrupted sensors would have delivered it; `sensor` itself at severity 0."""
        if severity == 0:
            return sensor
        out = self._call(self.corrupt, sensor, severity, rng)
        check_corrupted(sensor, out, self)
        return out

    def displacement(self, sensor: SensorFrame, severity: int, rng: np.random.Generator) -> np.ndarray | None:
        """The checked rigid motion [4 x 4] of the scan (LiDAR frame) that the protocol composes into T_rand and so
        into T_gt; None at severity 0 or for a corruption that does not `moves_cloud`."""
        if severity == 0 or not self.moves_cloud:
            return None
        import numpy as np

        motion = self._call(self.motion, sensor, severity, rng)
        check_motion(sensor, motion, self)
        return np.asarray(motion, dtype=np.float64)

    def _call(self, method: Callable[..., Any], sensor: SensorFrame, severity: int, rng: np.random.Generator) -> Any:
        """`method(sensor, level, rng)`, refused on a frame it does not apply to; a failure names the corruption."""
        level = self.level(severity)
        if not self.applies(sensor):
            raise NotApplicable(f"corruption {self.name!r} does not apply to {sensor.dataset} frame {sensor.frame_id}: "
                                f"{missing(self, sensor)}")  # fmt: skip
        try:
            return method(sensor, level, rng)
        except CorruptionError:
            raise
        except Exception as exc:  # a broken corruption names itself, not the dataset or a stage
            raise CorruptionError(
                f"corruption {self.name!r} severity {severity} failed on {sensor.dataset} frame {sensor.frame_id}: "
                f"{type(exc).__name__}: {exc}"
            ) from exc

    def corrupt(self, sensor: SensorFrame, level: Any, rng: np.random.Generator) -> SensorFrame:
        """`sensor` corrupted at `level` (an entry of `levels`); subclasses implement it, without mutating input.
        One that only `moves_cloud` changes nothing the sensors delivered: `sensor` itself."""
        if self.moves_cloud:
            return sensor
        raise NotImplementedError

    def motion(self, sensor: SensorFrame, level: Any, rng: np.random.Generator) -> np.ndarray:
        """[4 x 4] rigid motion of the scan in the LiDAR frame at `level`, for a corruption that `moves_cloud`."""
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


def missing(corruption: Corruption, sensor: SensorFrame) -> str:
    """What the frame lacks of what the corruption needs, in words ("" when nothing)."""
    absent = [name for name in corruption.needs if getattr(sensor, name, None) is None]
    return "; ".join(f"it needs {OPTIONAL.get(name, name)}, and this frame has none" for name in absent)


def check_class(cls: type[Corruption], plugin: str) -> None:
    """Refuse, naming the plugin, a corruption class the protocol could not use consistently."""
    if cls.kind not in KINDS:
        raise PluginError(f"plugin {plugin!r} registered corruption {cls.name!r} of kind {cls.kind!r}; kinds: {KINDS}")
    if not MIN_LEVELS <= len(cls.levels) <= MAX_LEVELS:
        raise PluginError(
            f"plugin {plugin!r} registered corruption {cls.name!r} with {len(cls.levels)} levels; it needs "
            f"{MIN_LEVELS} to {MAX_LEVELS}, so means over severities stay comparable"
        )
    unknown = sorted(set(cls.needs) - set(OPTIONAL))
    if unknown:
        raise PluginError(f"plugin {plugin!r} registered corruption {cls.name!r} needing {unknown}; a corruption may "
                          f"need only optional frame fields: {sorted(OPTIONAL)}")  # fmt: skip
    if cls.moves_cloud and cls.motion is Corruption.motion:
        raise PluginError(f"plugin {plugin!r} registered corruption {cls.name!r} that moves_cloud without a motion")


def check_corrupted(before: SensorFrame, after: object, corruption: Corruption) -> None:
    """The corrupted frame is the same frame, changed only where its kind allows, with valid arrays."""
    import numpy as np

    from ..types import SensorFrame

    where = f"corruption {corruption.name!r} on {before.dataset} frame {before.frame_id}"
    if not isinstance(after, SensorFrame):
        raise CorruptionError(f"{where} returned {type(after).__name__}, expected SensorFrame")
    if not np.array_equal(after.T_cam_lidar, before.T_cam_lidar) or after.match_radius_px != before.match_radius_px:
        raise CorruptionError(f"{where} changed the ground truth (T_cam_lidar or eps_c); no corruption may")
    changed = {f for f in CHECKED if not _same(getattr(before, f), getattr(after, f))}
    if (after.dataset, after.frame_id) != (before.dataset, before.frame_id) or changed - CHANGES[corruption.kind]:
        raise CorruptionError(f"{where} changed {sorted(changed)}; a {corruption.kind} corruption may change only "
                              f"{sorted(CHANGES[corruption.kind])}")  # fmt: skip
    problem = _invalid(before, after)
    if problem:
        raise CorruptionError(f"{where}: {problem}")


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    import numpy as np

    if a is None or b is None:
        return a is b
    return a is b or (a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b))


def check_motion(sensor: SensorFrame, motion: object, corruption: Corruption) -> None:
    """A corruption's motion is a finite rigid transform: the protocol composes it into the ground truth."""
    import numpy as np

    where = f"corruption {corruption.name!r} on {sensor.dataset} frame {sensor.frame_id}"
    M = np.asarray(motion, dtype=np.float64) if isinstance(motion, np.ndarray) else None
    if M is None or M.shape != (4, 4) or not np.isfinite(M).all():
        raise CorruptionError(f"{where}: its motion must be a finite 4 x 4 array, got {type(motion).__name__}")
    R = M[:3, :3]
    off = max(float(np.abs(R.T @ R - np.eye(3)).max()), abs(float(np.linalg.det(R)) - 1.0))
    if off > ROTATION_TOL or not np.array_equal(M[3], [0.0, 0.0, 0.0, 1.0]):
        raise CorruptionError(f"{where}: its motion is not a rigid transform (rotation off by {off:.3g}, last row "
                              f"{M[3].tolist()})")  # fmt: skip


def _invalid(before: SensorFrame, after: SensorFrame) -> str:
    import numpy as np

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


def unavailable(corruption: Corruption, dataset: Dataset, frame_ids: Sequence[str]) -> str:
    """Why `corruption` cannot run on these frames ("" when it can). Only a corruption that `needs` something loads
    them (once, before the run); a frame that does not load is left to the run, which records it failed."""
    if not corruption.needs:
        return ""
    from ..errors import DataError

    lacking: list[tuple[str, str]] = []
    for frame_id in frame_ids:
        try:
            sensor = dataset.load(frame_id)
        except DataError:
            continue
        if not corruption.applies(sensor):
            lacking.append((frame_id, missing(corruption, sensor)))
    if not lacking:
        return ""
    first, why = lacking[0]
    return f"{len(lacking)} of the {len(frame_ids)} {dataset.name} frames (the first {first}) cannot take it: {why}"
