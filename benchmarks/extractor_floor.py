"""Each classic extractor against its floor: the same rule in bare library calls, timed in turn in one run.

The floor of an image extractor is its OpenCV call(s) on the grey image plus the candidates' coordinates
(`cv2.findNonZero`, the fastest way to list a mask's pixels): the extractor must return those coordinates, so no
wrapper can go below that. A LiDAR rule's floor is the rule in bare numpy on a scan already grouped by ring (KITTI's
is), down to the selected indices; a random extractor's is the draw itself (a generator seeded per frame, a subset,
sorted). What the extractor adds on top is its wrapping: dropping non-finite points, the seeded cap, checking and
packing the keypoints. The ratio extractor / floor says what that costs; the target is <= 1.3x.

    .venv/bin/python benchmarks/extractor_floor.py --rounds 30 --threads 1

Rounds alternate extractor and floor, so load on a shared machine hits both alike. The table prints the fastest
round of each (on a loaded machine the minimum is the least disturbed estimate of the work itself) and their ratio,
then the median of the per-round ratios. Before timing, each floor's output is checked against the extractor's (the
same candidates, or the same draw), so a floor cannot skip work the extractor must do.

For an edge extractor the last two columns price the cap apart: `cap ms` is the cap's own library calls (the seeded
draw of the kept positions, sorted, as the random floors make it) on that rule's number of candidates, timed in the
same rounds, and the last ratio is the extractor against floor + cap, i.e. what is left of the wrapping once the draw
itself is paid.
"""

from __future__ import annotations

import argparse
import hashlib
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from i2pbench.data.kitti import KittiOdometry
from i2pbench.registry.build import default_registry
from i2pbench.scoring.protocol import Protocol
from i2pbench.types import Frame

KITTI = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_odometry"
CAP = 3000


def grey(frame: Frame) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(frame.image), cv2.COLOR_RGB2GRAY)


def lsd_floor(frame: Frame) -> object:
    return cv2.createLineSegmentDetector().detect(grey(frame))  # segments: rasterising them is the rule's own work


def canny_floor(frame: Frame) -> object:
    return cv2.findNonZero(cv2.Canny(grey(frame), 50, 150))


def sobel_floor(frame: Frame) -> object:
    g = grey(frame)
    mask = cv2.magnitude(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)) > 150.0
    return cv2.findNonZero(mask.view(np.uint8))


def random_floor(count: int) -> Callable[[Frame], object]:
    """the seeded draw in its cheapest bare form, the one the cap makes: the sha256 words as a uint32 array
    (SeedSequence takes an array 4x faster than a list, to the same state), no shuffle of the drawn values where
    numpy's Floyd branch keeps the same set without it, and the sort as a scatter into a mask (few candidates per kept
    one) or on int32 keys (2x an int64 sort)."""
    floyd = count <= 10_000 or CAP <= count // 50

    def draw(frame: Frame) -> np.ndarray:
        seed = np.frombuffer(hashlib.sha256(f"0\x00{frame.dataset}\x00{frame.frame_id}".encode()).digest(), np.uint32)
        keep = np.random.default_rng(seed).choice(count, CAP, replace=False, shuffle=not floyd)
        if count <= 32 * CAP:
            mask = np.zeros(count, bool)
            mask[keep] = True
            return np.flatnonzero(mask)
        return np.sort(keep.astype(np.int32))

    return draw


def scanline_floor(eps_depth: float | None, eps_reflectance: float | None) -> Callable[[Frame], object]:
    """the paper's rule in bare numpy on a scan grouped by ring (KITTI's is): relative range change in float64 (NaN
    where r_i <= 0: no return), absolute reflectance change, rise selects i-1, drop selects i+1, along a ring only."""

    def rule(frame: Frame) -> np.ndarray:
        same = frame.ring[1:] == frame.ring[:-1]
        selected = np.zeros(len(frame.ring), bool)
        changes = []
        if eps_depth is not None:
            r = frame.ranges.astype(np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                change = np.diff(r) / r[:-1]
            change[r[:-1] <= 0] = np.nan  # a masked store: ~1.5x faster than np.where(r > 0, change, nan)
            changes.append((change, eps_depth))
        if eps_reflectance is not None:
            refl = frame.points[:, 3].astype(np.float64)
            refl = refl / refl.max() if refl.max() > 1 else np.clip(refl, 0, 1)  # a sensor's own scale -> [0, 1]
            changes.append((np.diff(refl), eps_reflectance))
        for change, eps in changes:
            selected[1:] |= same & (change < -eps)
            selected[:-2] |= same[1:] & same[:-1] & (change[1:] > eps)
        return np.flatnonzero(selected)

    return rule


def floors(frame: Frame) -> dict[tuple[str, str], Callable[[Frame], object]]:
    width, height = frame.image_size
    return {
        ("extractor2d", "lsd"): lsd_floor,
        ("extractor2d", "canny"): canny_floor,
        ("extractor2d", "sobel"): sobel_floor,
        ("extractor2d", "random"): random_floor(width * height),
        ("extractor3d", "depth"): scanline_floor(0.1, None),
        ("extractor3d", "reflectance"): scanline_floor(None, 0.2),
        ("extractor3d", "depth+reflectance"): scanline_floor(0.1, 0.2),
        ("extractor3d", "random"): random_floor(len(frame.points)),
    }


def seconds(fn: Callable[[Frame], object], frame: Frame) -> float:
    start = time.perf_counter()
    fn(frame)
    return time.perf_counter() - start


def check_floor(kind: str, name: str, floor: Callable[[Frame], object], frame: Frame, registry: object) -> int | None:
    """Raise ValueError unless the floor computes what the extractor must return (its candidates before the cap for an
    edge rule, the capped draw for a random one): a floor that skipped part of the work would flatter every extractor.
    Returns how many candidates an edge rule caps (None for a random extractor, whose floor is the draw)."""
    random = name == "random"
    got = registry.component(kind, name)({"max_keypoints": CAP if random else None})(frame)
    ours = got.uv if kind == "extractor2d" else got.index
    if name == "lsd":  # the floor stops at the detector's segments: rasterising them is the rule's own work
        return len(ours)
    bare = np.asarray(floor(frame))
    if kind == "extractor2d":
        width = frame.image_size[0]
        bare = np.stack([bare % width, bare // width], axis=1) if random else bare.reshape(-1, 2)
    if not np.array_equal(ours, bare):
        raise ValueError(f"{kind} {name}: the floor does not compute the extractor's selection")
    return None if random else len(ours)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=100)
    parser.add_argument("--threads", type=int, default=1, help="OpenCV threads (both sides alike)")
    args = parser.parse_args()
    cv2.setNumThreads(args.threads)
    frame = Protocol().apply(KittiOdometry("all", {"root": str(KITTI)}).load("00/000000"))
    registry = default_registry()
    print(f"real KITTI 00/000000: {frame.image_size[0]} x {frame.image_size[1]} image, {len(frame.points)} points")
    print(
        f"{'extractor':<32} {'extractor ms':>12} {'floor ms':>9} {'ratio':>7} {'median of ratios':>17} "
        f"{'cap ms':>7} {'ratio to floor + cap':>21}"
    )
    for (kind, name), floor in floors(frame).items():
        try:
            candidates = check_floor(kind, name, floor, frame, registry)
        except ValueError as error:
            raise SystemExit(str(error)) from None
        extractor = registry.component(kind, name)({"max_keypoints": CAP})
        timed = [extractor, floor]
        if candidates is not None and candidates > CAP:
            timed.append(random_floor(candidates))  # the cap's own library calls: the seeded draw, sorted
        for fn in timed:
            fn(frame)  # warm-up: OpenCV allocations, page faults
        ours, bare, *cap = np.array([[seconds(fn, frame) for fn in timed] for _ in range(args.rounds)]).T
        line = (
            f"{kind + ' ' + name:<32} {ours.min() * 1e3:>12.3f} {bare.min() * 1e3:>9.3f} "
            f"{ours.min() / bare.min():>6.2f}x {np.median(ours / bare):>16.2f}x"
        )
        if cap:
            line += f" {cap[0].min() * 1e3:>7.3f} {ours.min() / (bare + cap[0]).min():>20.2f}x"
        print(line)


if __name__ == "__main__":
    main()
