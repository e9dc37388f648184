"""The awkward inputs each stage kind must survive: empty ones (a valid empty output is the only right answer) and bad
ones (a clear exception or a valid output; never garbage)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..types import Frame, Keypoints2D, Matches
from . import frames
from .inputs import StageInputs, empty_inputs, ground_truth_inputs, without_2d


@dataclasses.dataclass(frozen=True)
class Case:
    what: str  # names the input in problem messages, e.g. "a scan with 0 points"
    frame: Frame
    inputs: StageInputs
    must_fail_pose: bool = False  # a solver must answer PoseEstimate.failed, not a pose from nothing


def empty_cases(kind: str, frame: Frame, inputs: StageInputs, dim: int) -> list[Case]:
    """Inputs with nothing (or almost nothing) in them, for a stage of `kind`."""
    empty = empty_inputs(dim)
    if kind == "extractor2d":
        return [
            Case("a blank (uniform grey) image", frames.blank_image(frame), empty),
            Case("an 8x8 image", frames.tiny_image(frame), empty),
        ]
    if kind == "extractor3d":
        return [
            Case("a scan with 0 points", frames.with_points(frame, 0), empty),
            Case("a scan with 3 points", frames.with_points(frame, 3), empty),
        ]
    if kind == "encoder2d":
        return [
            Case("0 keypoints", frame, empty),
            Case("keypoints on the image corners", frame, _corners(frame, inputs)),
        ]
    if kind == "encoder3d":
        small = frames.with_points(frame, inputs.kp3d.index[:3])
        return [
            Case("0 keypoints", frame, empty),
            Case("a scan of 3 points, all keypoints", small, ground_truth_inputs(small, dim)),
        ]
    if kind in ("exchanger", "matcher"):
        return [
            Case("0 keypoints on both sides", frame, empty),
            Case("0 image keypoints (3D side kept)", frame, without_2d(inputs)),
        ]
    if kind == "solver":
        three = dataclasses.replace(inputs, matches=_first_matches(inputs.matches, 3))
        return [Case("0 matches", frame, empty, must_fail_pose=True), Case("3 matches", frame, three)]
    return []


def bad_cases(kind: str, frame: Frame, inputs: StageInputs) -> list[Case]:
    """Inputs a careful stage refuses clearly or copes with."""
    cases = []
    if kind in ("extractor2d", "encoder2d"):
        cases.append(Case("a mirrored (negative-stride) image view", frames.flipped_image(frame), inputs))
    if kind not in ("extractor2d", "encoder2d"):
        rows = np.setdiff1d(np.arange(0, len(frame.points), 7), inputs.kp3d.index)
        cases.append(Case("a scan with NaN in 1 of 7 points", frames.with_nan_points(frame, rows), inputs))
    if kind == "solver":
        cases.append(Case("matches whose 3D points all coincide", frame, _coincident(inputs)))
    return cases


def _corners(frame: Frame, inputs: StageInputs) -> StageInputs:
    width, height = frame.image_size
    uv = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], np.float32)
    return dataclasses.replace(inputs, kp2d=Keypoints2D(uv), matches=Matches.empty())


def _first_matches(matches: Matches, count: int) -> Matches:
    return Matches(matches.index2d[:count], matches.index3d[:count], matches.score[:count])


def _coincident(inputs: StageInputs) -> StageInputs:
    m = inputs.matches
    return dataclasses.replace(inputs, matches=Matches(m.index2d, np.zeros_like(m.index3d), m.score))
