"""A tiny plugin used by the core tests: deterministic toy stages, plus deliberately broken ones."""

import numpy as np
import torch

from i2pbench.api import (
    FEATURES2D,
    GROUND_TRUTH,
    KEYPOINTS2D,
    KEYPOINTS3D,
    DataError,
    Dataset,
    Encoder2D,
    Extractor2D,
    Extractor3D,
    Keypoints2D,
    Keypoints3D,
    LearnedComponent,
    Matcher,
    Matches,
    PoseEstimate,
    PoseSolver,
    SensorFrame,
    hookimpl,
)


class GridPixels(Extractor2D):
    name = "grid"

    def __call__(self, frame):
        return Keypoints2D(np.array([[1.0, 1.0], [2.0, 2.0]], np.float32))


class FirstPoints(Extractor3D):
    name = "first"

    def __call__(self, frame):
        return Keypoints3D.from_index(frame, np.arange(3))


class Boom(Extractor3D):
    name = "boom"

    def __call__(self, frame):
        raise RuntimeError("exploded on purpose")


class WrongShape(Extractor2D):
    name = "wrong-shape"

    def __call__(self, frame):
        return Keypoints2D(np.zeros((5, 3), np.float32))


class ConstantEncoder(Encoder2D):
    name = "constant"

    def __call__(self, frame, kp2d):
        return torch.ones(len(kp2d), 8)


class TruthMatcher(Matcher):
    """Pretends to match; reads ground truth, which it declares."""

    name = "truth"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, GROUND_TRUTH})

    def __call__(self, frame, kp2d, kp3d, features):
        assert frame.T_gt is not None
        return Matches(np.array([0]), np.array([0]), np.array([1.0], np.float32))


class PeekingMatcher(Matcher):
    """Does not declare ground truth; must never see it."""

    name = "peek"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D})

    def __call__(self, frame, kp2d, kp3d, features):
        if frame.T_gt is not None:
            raise AssertionError("ground truth leaked")
        return Matches.empty()


class GroundTruthSolver(PoseSolver):
    """Returns the truth when it sees it (declared), to test the flow end to end."""

    name = "truth"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, GROUND_TRUTH})

    def __call__(self, frame, kp2d, kp3d, matches):
        return PoseEstimate(frame.T_gt.copy(), np.arange(len(matches)))


@hookimpl
def register_extractors_2d(register):
    register(GridPixels)
    register(WrongShape)


@hookimpl
def register_extractors_3d(register):
    register(FirstPoints)
    register(Boom)


@hookimpl
def register_encoders_2d(register):
    register(ConstantEncoder)
    register(LinearEncoder)


@hookimpl
def register_matchers(register):
    register(TruthMatcher)
    register(PeekingMatcher)
    register(RegressionMatcher)


@hookimpl
def register_pose_solvers(register):
    register(GroundTruthSolver)


@hookimpl
def register_presets(register):
    register("default", [{"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}])


class ToyDataset(Dataset):
    """Three tiny frames; frame "bad" raises a DataError like a corrupt file would."""

    name = "toy"
    splits = ("test",)

    def frame_ids(self):
        return ["a", "bad", "c"]

    def load(self, frame_id):
        if frame_id == "bad":
            raise DataError("/data/toy/bad.bin: size 13 is not a multiple of 16 bytes")
        rng = np.random.default_rng(0)
        points = np.c_[rng.uniform(-5, 5, (10, 3)), rng.uniform(0, 1, 10)].astype(np.float32)
        return SensorFrame(
            "toy", frame_id, np.zeros((8, 8, 3), np.uint8), points, np.zeros(10, np.int16), np.eye(3), np.eye(4)
        )


@hookimpl
def register_datasets(register):
    register(ToyDataset)


class LinearEncoder(LearnedComponent, Encoder2D):
    """A learned toy encoder: one linear layer on pixel coordinates."""

    name = "linear"
    default_conf = {"dim": 4}

    def __init__(self, conf=None):
        super().__init__(conf)
        self.layer = torch.nn.Linear(2, self.conf["dim"])

    def __call__(self, frame, kp2d):
        return self.layer(torch.from_numpy(kp2d.uv))


class RegressionMatcher(Matcher):
    """A trainable toy matcher: its loss pulls every 2D descriptor towards 1."""

    name = "regress"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, FEATURES2D})

    def __call__(self, frame, kp2d, kp3d, features):
        return Matches(np.array([0]), np.array([0]), np.array([1.0], np.float32))

    def loss(self, frame, kp2d, kp3d, features):
        loss = ((features.desc2d - 1.0) ** 2).mean()
        return loss, {"mse": float(loss.detach())}
