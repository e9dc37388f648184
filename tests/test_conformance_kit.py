"""The conformance kit catches planted faults with messages that name them, and passes a clean component."""

import numpy as np
import pytest
import torch

from i2pbench.api import (
    Encoder2D,
    Encoder3D,
    Extractor2D,
    Extractor3D,
    Keypoints2D,
    Keypoints3D,
    Matcher,
    Matches,
    PoseEstimate,
    PoseSolver,
    hookimpl,
)
from i2pbench.geometry.transforms import in_image, project
from i2pbench.testing import assert_conforms, check_component, registered_components, synthetic_frame


class Corners(Extractor2D):
    """A clean extractor: up to max_keypoints Shi-Tomasi-free 'corners' (pixels brighter than their right neighbour)."""

    name = "clean"
    default_conf = {"max_keypoints": 50}

    def __call__(self, frame):
        grey = frame.image[..., 0].astype(np.int16)
        rows, cols = np.nonzero(grey[:, :-1] - grey[:, 1:] > 20)
        keep = slice(0, self.conf["max_keypoints"])
        return Keypoints2D(np.stack([cols[keep], rows[keep]], axis=1).astype(np.float32).reshape(-1, 2))


class WrongShape(Corners):
    name = "wrong-shape"

    def __call__(self, frame):
        return Keypoints2D(np.zeros((5, 3), np.float32))


class WrongDtype(Corners):
    name = "wrong-dtype"

    def __call__(self, frame):
        return Keypoints2D(super().__call__(frame).uv.astype(np.float64))


class CoinFlip(Corners):
    """Draws from the global RNG: the output depends on what ran before."""

    name = "coin-flip"

    def __call__(self, frame):
        uv = super().__call__(frame).uv
        return Keypoints2D(uv[np.random.rand(len(uv)) < 0.5])


class FarthestPoint(Extractor3D):
    """Crashes on an empty scan: argmax of nothing."""

    name = "farthest"

    def __call__(self, frame):
        return Keypoints3D.from_index(frame, np.array([np.argmax(frame.ranges)]))


class Scribbler(Extractor3D):
    """Writes into its input."""

    name = "scribbler"

    def __call__(self, frame):
        frame.points[:, 3] = 0.0
        return Keypoints3D.from_index(frame, np.arange(min(3, len(frame.points))))


class EveryPoint(Extractor3D):
    """Passes a corrupt scan's NaN points straight on."""

    name = "every-point"

    def __call__(self, frame):
        return Keypoints3D.from_index(frame, np.arange(len(frame.points)))


class StrictNaN(Encoder3D):
    """Refuses NaN with a bare exception: an error nobody can act on."""

    name = "strict"

    def __call__(self, frame, kp3d):
        if not np.isfinite(frame.points).all():
            raise ValueError
        return torch.zeros(len(kp3d), 8)


class Silent(Encoder2D):
    """Declares it provides features2d but returns None."""

    name = "silent"

    def __call__(self, frame, kp2d):
        return None


class Peeker(Matcher):
    """Reads ground truth without declaring it."""

    name = "peeker"
    consumes = frozenset({"keypoints2d", "keypoints3d"})

    def __call__(self, frame, kp2d, kp3d, features):
        uv, front = project(frame.K, frame.T_gt, kp3d.xyz.astype(np.float64))
        rows = np.flatnonzero(in_image(uv, front, frame.image_size))[: len(kp2d)]
        return Matches(np.zeros(len(rows), np.int64), rows.astype(np.int64), np.ones(len(rows), np.float32))


class Confident(PoseSolver):
    """Answers the identity whatever it is given, even with no matches."""

    name = "confident"

    def __call__(self, frame, kp2d, kp3d, matches):
        return PoseEstimate(np.eye(4), np.arange(len(matches)))


class TakesAnything(Corners):
    """Swallows unknown config keys, so a typo in user config goes unnoticed."""

    name = "takes-anything"

    def __init__(self, conf=None):
        self.conf = {**self.default_conf, **(conf or {})}


class TimeTraveller(Extractor2D):
    """An image extractor that claims to need LiDAR keypoints, which no earlier stage provides."""

    name = "time-traveller"
    consumes = frozenset({"image", "keypoints3d"})


def _messages(report, check):
    return [p.message for p in report if p.check == check]


def test_a_clean_component_conforms_and_latency_is_reported():
    report = check_component(Corners)
    assert list(report) == [], str(report)
    assert report.latency_ms >= 0 and report.first_call_ms >= 0
    assert "extractor2d 'clean' conforms; latency" in str(report)
    assert_conforms(Corners, {"max_keypoints": 5})


def test_wrong_shape_is_named_with_the_shape_it_returned():
    (message,) = _messages(check_component(WrongShape), "contract")
    assert "uv must be [M x 2], got (5, 3)" in message


def test_wrong_dtype_is_named():
    (message,) = _messages(check_component(WrongDtype), "contract")
    assert "Keypoints2D.uv must be float32, got float64" in message


def test_nondeterminism_is_caught_and_names_the_field_that_differs():
    (message,) = _messages(check_component(CoinFlip), "determinism")
    assert "two calls on the same frame returned different output.uv" in message


def test_a_crash_on_an_empty_scan_is_caught_naming_the_input_and_the_error():
    (message,) = _messages(check_component(FarthestPoint), "empty input")
    assert message.startswith("on a scan with 0 points: ValueError: attempt to get argmax of an empty sequence")


def test_writing_into_the_frame_is_caught():
    (message,) = _messages(check_component(Scribbler), "side effects")
    assert "wrote into the frame's points" in message


def test_a_bare_exception_on_bad_input_is_caught():
    (message,) = _messages(check_component(StrictNaN), "bad input")
    assert message == "on a scan with NaN in 1 of 7 points: raised ValueError with no message; say what is wrong"


def test_garbage_on_bad_input_is_caught():
    (message,) = _messages(check_component(EveryPoint), "bad input")
    assert message.startswith("on a scan with NaN in 1 of 7 points: returned garbage instead of raising a clear error")
    assert message.endswith("xyz contains NaN or inf")


def test_a_conf_the_component_refuses_is_reported():
    (message,) = _messages(check_component(Corners, {"max_keypoint": 5}), "construct")
    assert "unknown config key 'max_keypoint'" in message


def test_missing_descriptors_from_an_encoder_that_provides_them_is_caught():
    (message,) = _messages(check_component(Silent), "contract")
    assert "returned no descriptors although it declares it provides features2d" in message


def test_reading_undeclared_ground_truth_is_caught():
    (message,) = _messages(check_component(Peeker), "declared inputs")
    assert "fails without frame.T_gt" in message and "declare GROUND_TRUTH" in message


def test_a_pose_from_zero_matches_is_caught():
    assert "on 0 matches: returned a pose; return PoseEstimate.failed(reason)" in _messages(
        check_component(Confident), "empty input"
    )


@pytest.mark.parametrize(
    ("cls", "fragment"),
    [
        (TakesAnything, "accepted the unknown config key"),
        (TimeTraveller, "consumes ['keypoints3d'], which no stage before the extractor2d provides"),
        (dict, "does not subclass a stage base"),
    ],
)
def test_declaration_problems_are_found_without_running(cls, fragment):
    assert any(fragment in m for m in _messages(check_component(cls), "declaration"))


def test_assert_conforms_lists_every_problem():
    with pytest.raises(AssertionError) as info:
        assert_conforms(Scribbler)
    assert "extractor3d 'scribbler'" in str(info.value) and "[side effects]" in str(info.value)


def test_registered_components_reads_a_plugins_hooks_as_the_registry_calls_them():
    class Plugin:
        @hookimpl
        def register_extractors_2d(self, register):
            register(Corners)

        @hookimpl
        def register_pose_solvers(self, register):
            register(Confident)

        def register_matchers(self, register):  # no @hookimpl: pluggy, and so the registry, never calls it
            register(Confident)

    assert registered_components(Plugin()) == [Corners, Confident]


def test_the_synthetic_frame_is_a_consistent_registration_problem():
    frame = synthetic_frame(3)
    again = synthetic_frame(3)
    assert np.array_equal(frame.points, again.points) and np.array_equal(frame.image, again.image)
    assert frame.image.shape == (96, 160, 3) and frame.image.dtype == np.uint8
    assert frame.points.dtype == np.float32 and np.all(np.diff(frame.ring) >= 0)
    assert frame.ranges.min() > 3.9 and frame.T_gt is not None  # no wall nearer than 4 m
    uv, front = project(frame.K, frame.T_gt, frame.points[:, :3].astype(np.float64))
    assert in_image(uv, front, frame.image_size).sum() > 1000  # the camera sees a good part of the scan
