"""What a frame's solver consumed, stored beside its record so another solver can run on it alone.

An upstream holds the 2D and 3D keypoints and the matches, the seconds each stage before the solver took, and what
a solver and the metrics read from a Frame besides pixels and points: intrinsics, image size, ground truth, eps_c.
It is stored as arrays (`.npz`, uncompressed): float32 coordinates and scores, int32 indices when they fit, and the
dtypes a stage returned when narrowing them would change a value, so a re-run solver sees exactly what the first one
saw. `decode` checks every shape and index, so a damaged or foreign file is refused rather than solved. The matches'
frustum scores (`Matches.frustum`) are stored when the matcher gave them and absent otherwise, so files without them
(every matcher but a frustum classifier's, and every file written before they existed) read back as None; so does
a matcher's own true-match radius (`Matches.radius_px`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..stages.components import STAGE_ORDER
from ..stages.pipeline import FrameOutcome, Upstream
from ..types import Frame, Keypoints2D, Keypoints3D, Matches

FORMAT = 1  # part of the upstream key: a new layout never meets files of an old one
UPSTREAM_KINDS = tuple(k for k in STAGE_ORDER if k != "solver")
ARRAYS = ("uv", "kp3d_index", "xyz", "reflectance", "index2d", "index3d", "score", "timings", "K", "image_size")


@dataclass(frozen=True)
class StoredUpstream:
    """A frame's upstream with the frame's calibration and the upstream stages' timings (seconds; NaN: not run)."""

    upstream: Upstream
    timings: dict[str, float]
    dataset: str
    frame_id: str
    K: np.ndarray  # [3 x 3] float64
    image_size: tuple[int, int]  # (width, height)
    T_gt: np.ndarray | None  # [4 x 4] float64
    T_init: np.ndarray | None  # [4 x 4] float64
    match_radius_px: float
    K_gt: np.ndarray | None = None  # [3 x 3] float64 true intrinsics when K is a corrupted calibration

    @classmethod
    def of(cls, frame: Frame, outcome: FrameOutcome) -> StoredUpstream | None:
        """The upstream of a frame that ran through the pipeline; None when its matcher did not finish."""
        if outcome.upstream is None:
            return None
        timings = {kind: outcome.timings.get(kind, math.nan) for kind in UPSTREAM_KINDS}
        return cls(
            outcome.upstream, timings, frame.dataset, frame.frame_id, frame.K, frame.image_size, frame.T_gt,
            frame.T_init, frame.match_radius_px, frame.K_gt,
        )  # fmt: skip

    def solver_frame(self) -> Frame:
        """The frame a re-run solver sees: calibration and ground truth, no pixels and no points.

        The image is [H x W x 0], so `image_size` holds while any read of a pixel fails loudly instead of seeing
        zeros; only solvers that declare no image or point input are re-run (`Pipeline.resolvable`).
        """
        width, height = self.image_size
        return Frame(
            dataset=self.dataset,
            frame_id=self.frame_id,
            image=np.zeros((height, width, 0), np.uint8),
            points=np.zeros((0, 4), np.float32),
            ring=np.zeros(0, np.int16),
            ranges=np.zeros(0, np.float32),
            K=self.K,
            T_gt=self.T_gt,
            match_radius_px=self.match_radius_px,
            T_init=self.T_init,
            K_gt=self.K_gt,
        )

    def encode(self) -> dict[str, np.ndarray]:
        up = self.upstream
        arrays = {
            "uv": _narrow(up.kp2d.uv),
            "kp3d_index": _narrow(up.kp3d.index),
            "xyz": _narrow(up.kp3d.xyz),
            "reflectance": _narrow(up.kp3d.reflectance),
            "index2d": _narrow(up.matches.index2d),
            "index3d": _narrow(up.matches.index3d),
            "score": _narrow(up.matches.score),
            "timings": np.array([self.timings[k] for k in UPSTREAM_KINDS], np.float64),
            "K": np.asarray(self.K, np.float64),
            "image_size": np.array(self.image_size, np.int64),
            "match_radius_px": np.float64(self.match_radius_px),
            "frame": np.array([self.dataset, self.frame_id]),
        }
        for name, T in (("T_gt", self.T_gt), ("T_init", self.T_init), ("K_gt", self.K_gt)):
            if T is not None:  # absent rather than NaN: decoding gives back None
                arrays[name] = np.asarray(T, np.float64)
        if up.matches.frustum is not None:
            arrays["frustum"] = _narrow(up.matches.frustum)
        if up.matches.radius_px is not None:
            arrays["matches_radius_px"] = np.float64(up.matches.radius_px)
        return arrays

    @classmethod
    def decode(cls, arrays: Mapping[str, np.ndarray]) -> StoredUpstream:
        """The stored upstream; ValueError naming what is wrong with a file that is not one."""
        a = _checked({name: arrays[name] for name in arrays})  # read every array before the file closes
        upstream = Upstream(
            Keypoints2D(a["uv"]),
            Keypoints3D(a["kp3d_index"].astype(np.int64), a["xyz"], a["reflectance"]),
            Matches(
                a["index2d"].astype(np.int64),
                a["index3d"].astype(np.int64),
                a["score"],
                a.get("frustum"),
                float(a["matches_radius_px"]) if "matches_radius_px" in a else None,
            ),
        )
        width, height = (int(v) for v in a["image_size"])
        return cls(
            upstream=upstream,
            timings=dict(zip(UPSTREAM_KINDS, a["timings"].tolist(), strict=True)),
            dataset=str(a["frame"][0]),
            frame_id=str(a["frame"][1]),
            K=a["K"],
            image_size=(width, height),
            T_gt=a.get("T_gt"),
            T_init=a.get("T_init"),
            match_radius_px=float(a["match_radius_px"]),
            K_gt=a.get("K_gt"),
        )


def _narrow(array: np.ndarray) -> np.ndarray:
    """float32 / int32 when that keeps every value, else the array as it is."""
    array = np.asarray(array)
    kind = array.dtype.kind
    narrow = np.float32 if kind == "f" else np.int32 if kind in "iu" else None
    if narrow is None or array.dtype.itemsize <= 4:
        return array
    small = array.astype(narrow)
    return small if np.array_equal(small, array, equal_nan=kind == "f") else array


def _checked(a: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The arrays, once every one an upstream needs is there with its shape, and the match indices in range."""
    missing = [name for name in (*ARRAYS, "match_radius_px", "frame") if name not in a]
    if missing:
        raise ValueError(f"not an upstream: no {', '.join(missing)}")
    m2, m3, k = len(a["uv"]), len(a["kp3d_index"]), len(a["index2d"])
    shapes = {"uv": (m2, 2), "xyz": (m3, 3), "reflectance": (m3,), "index3d": (k,), "score": (k,), "K": (3, 3)}
    shapes |= {"timings": (len(UPSTREAM_KINDS),), "image_size": (2,), "frame": (2,), "T_gt": (4, 4), "T_init": (4, 4)}
    shapes |= {"K_gt": (3, 3), "frustum": (m3,), "matches_radius_px": ()}
    wrong = [
        f"{name} is {a[name].shape}, not {shape}"
        for name, shape in shapes.items()
        if a.get(name, np.zeros(shape)).shape != shape
    ]
    wrong += [
        f"{name} is {a[name].dtype}" for name in ("kp3d_index", "index2d", "index3d") if a[name].dtype.kind not in "iu"
    ]
    if not wrong and not (_within(a["index2d"], m2) and _within(a["index3d"], m3)):
        wrong.append(f"match indices out of range of {m2} 2D and {m3} 3D keypoints")
    if wrong:
        raise ValueError(f"not an upstream: {'; '.join(wrong)}")
    return a


def _within(index: np.ndarray, n: int) -> bool:
    return index.size == 0 or (0 <= int(index.min()) and int(index.max()) < n)
