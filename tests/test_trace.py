"""A frame takes one path: `Pipeline.run` returns each stage's checked output and seconds in order, and the failure;
the conformance kit, the training samples and the per-frame training fallback call stages through the same
`call_stage`, so they refuse a bad output with the same error."""

import numpy as np
import pytest
import torch
import toy_plugin

from i2pbench.api import Encoder2D, Extractor2D, Features, Keypoints2D, Matcher, Matches
from i2pbench.execution.isolation import isolated
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.calling import StageInputs, call_stage
from i2pbench.stages.contracts import ContractError
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.testing import check_component, synthetic_frame
from i2pbench.training.batching import BatchForward
from i2pbench.training.samples import TrainingSamples, collate_samples

TOY = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}


class Outside(Extractor2D):
    """Returns one keypoint left of and above the image: a contract violation."""

    name = "outside"

    def __call__(self, frame):
        return Keypoints2D(np.array([[-10.0, -10.0]], np.float32))


class OutOfRange(Matcher):
    """Pairs a 3D keypoint that does not exist."""

    name = "out-of-range"
    consumes = frozenset({"keypoints2d", "keypoints3d"})

    def __call__(self, frame, kp2d, kp3d, features):
        return Matches(np.array([0]), np.array([len(kp3d)]), np.array([1.0], np.float32))


class Short(Encoder2D):
    """One descriptor fewer than there are keypoints."""

    name = "short"

    def __call__(self, frame, kp2d):
        return torch.zeros(len(kp2d) - 1, 4)


def toy_frame(frame_id="a"):
    return Protocol().apply(toy_plugin.ToyDataset("test").load(frame_id))


def pipeline(**stages):
    """The toy combination with some stages replaced by instances, built directly (run in this process)."""
    default = {
        "extractor2d": toy_plugin.GridPixels(),
        "extractor3d": toy_plugin.FirstPoints(),
        "matcher": toy_plugin.TruthMatcher(),
        "solver": toy_plugin.GroundTruthSolver(),
    }
    chosen = {**default, **stages}
    return Pipeline(Combination({k: c.name for k, c in chosen.items()}), chosen, timeout_s=None)


def test_the_trace_holds_each_stage_s_output_and_seconds_in_data_flow_order():
    frame = toy_frame()
    outcome = pipeline(encoder2d=toy_plugin.ConstantEncoder()).run(frame)
    kinds = ["extractor2d", "extractor3d", "encoder2d", "matcher", "solver"]
    assert [r.kind for r in outcome.records] == kinds
    assert [r.component for r in outcome.records] == [
        "extractor2d 'grid'", "extractor3d 'first'", "encoder2d 'constant'", "matcher 'truth'", "solver 'truth'",
    ]  # fmt: skip
    assert list(outcome.timings) == kinds and outcome.timings == {r.kind: r.seconds for r in outcome.records}
    np.testing.assert_array_equal(outcome.kp2d.uv, [[1, 1], [2, 2]])
    np.testing.assert_array_equal(outcome.kp3d.index, [0, 1, 2])
    assert torch.equal(outcome.features.desc2d, torch.ones(2, 8)) and outcome.features.desc3d is None
    assert (outcome.matches.index2d.tolist(), outcome.matches.index3d.tolist()) == ([0], [0])
    np.testing.assert_array_equal(outcome.estimate.T, frame.T_gt)
    assert (outcome.n_kp2d, outcome.n_kp3d, outcome.n_matches, outcome.n_inliers) == (2, 3, 1, 1)
    np.testing.assert_array_equal(outcome.matched_uv, [[1, 1]])
    np.testing.assert_array_equal(outcome.matched_xyz, frame.points[[0], :3])
    assert outcome.failure is None and outcome.error == "" and outcome.failed_component == ""


def test_a_raising_stage_leaves_the_outputs_before_it_and_a_failure_naming_it():
    outcome = pipeline(extractor3d=toy_plugin.Boom()).run(toy_frame())
    assert [r.kind for r in outcome.records] == ["extractor2d"] and list(outcome.timings) == ["extractor2d"]
    assert outcome.failure.component == outcome.failed_component == "extractor3d 'boom'"
    assert outcome.failure.kind == "extractor3d"
    assert outcome.failure.message == outcome.error
    assert outcome.error.startswith("extractor3d 'boom': RuntimeError: exploded on purpose")
    assert not outcome.estimate.ok and outcome.n_kp2d == 2 and outcome.kp3d is None and outcome.upstream is None


def test_a_contract_violation_fails_the_stage_that_returned_it_after_the_stages_before():
    outcome = pipeline(matcher=OutOfRange()).run(toy_frame())
    assert [r.kind for r in outcome.records] == ["extractor2d", "extractor3d"]
    assert "matcher" not in outcome.timings  # it ran, but its output never entered the trace
    assert outcome.failure.component == "matcher 'out-of-range'" and outcome.failure.kind == "matcher"
    assert outcome.error == "matcher 'out-of-range': index3d out of range for 3 3D keypoints"


def test_a_resolve_replays_the_stored_upstream_untimed_and_times_the_solver():
    p, frame = pipeline(), toy_frame()
    whole = p.run(frame)
    resolved = p.resolve(frame, whole.upstream)
    assert [(r.kind, r.seconds is None) for r in resolved.records] == [
        ("extractor2d", True), ("extractor3d", True), ("matcher", True), ("solver", False),
    ]  # fmt: skip
    assert list(resolved.timings) == ["solver"]
    assert resolved.upstream == whole.upstream
    np.testing.assert_array_equal(resolved.estimate.T, whole.estimate.T)


def test_the_kit_and_the_pipeline_refuse_the_same_bad_output_with_the_same_error():
    frame = synthetic_frame()
    report = check_component(Outside, frame=frame)
    (contract,) = [p for p in report if p.check == "contract"]
    outcome = pipeline(extractor2d=Outside()).run(frame)
    assert contract.message == outcome.error == "extractor2d 'outside': 1 keypoints lie outside the 160x96 image"
    assert outcome.failed_component == "extractor2d 'outside'"


def test_call_stage_hides_what_a_component_does_not_declare():
    frame, seen = toy_frame(), {}

    class Spy(Matcher):
        name = "spy"
        consumes = frozenset({"keypoints2d", "keypoints3d", "features2d"})

        def __call__(self, frame, kp2d, kp3d, features):
            seen.update(t_gt=frame.T_gt, desc2d=features.desc2d, desc3d=features.desc3d)
            return Matches.empty()

    kp2d, kp3d = toy_plugin.GridPixels()(frame), toy_plugin.FirstPoints()(frame)
    inputs = StageInputs(kp2d, kp3d, Features(torch.ones(2, 4), torch.ones(3, 4)))
    record = call_stage(Spy(), frame, inputs)
    assert seen["t_gt"] is None and seen["desc3d"] is None and torch.equal(seen["desc2d"], torch.ones(2, 4))
    assert (record.kind, record.component, len(record.output)) == ("matcher", "matcher 'spy'", 0)


class OneFrame(toy_plugin.ToyDataset):
    def frame_ids(self):
        return ["a"]


def test_training_keypoints_go_through_the_contract_checks():
    extractors = {"extractor2d": toy_plugin.GridPixels(), "extractor3d": toy_plugin.FirstPoints()}
    good = TrainingSamples(extractors, OneFrame("test"), 0)
    kp2d, kp3d = good.keypoints(good.frame(0))
    np.testing.assert_array_equal(kp2d.uv, [[1, 1], [2, 2]])
    np.testing.assert_array_equal(kp3d.index, [0, 1, 2])
    bad = TrainingSamples({**extractors, "extractor2d": Outside()}, OneFrame("test"), 0)
    with pytest.raises(ContractError, match=r"^extractor2d 'outside': 1 keypoints lie outside the 8x8 image$"):
        bad.keypoints(bad.frame(0))
    assert bad[0]["error"] == "ContractError: extractor2d 'outside': 1 keypoints lie outside the 8x8 image"


def per_frame_batch(encoder):
    """A batch of the one toy frame for a per-frame encoder (no `prepare`) and the toy regression matcher."""
    stages = {
        "extractor2d": toy_plugin.GridPixels(),
        "extractor3d": toy_plugin.FirstPoints(),
        "encoder2d": encoder,
        "matcher": toy_plugin.RegressionMatcher(),
    }
    samples = TrainingSamples(stages, OneFrame("test"), 0)
    return stages, collate_samples([samples[0]])


def test_the_per_frame_training_fallback_calls_through_call_stage_with_gradients():
    encoder = toy_plugin.LinearEncoder()
    stages, batch = per_frame_batch(encoder)
    loss, terms = BatchForward(stages)(batch)
    loss.backward()
    assert terms["mse"] == pytest.approx(float(loss.detach()))
    assert encoder.layer.weight.grad is not None and bool(encoder.layer.weight.grad.abs().sum() > 0)


def test_the_per_frame_training_fallback_refuses_a_bad_output_naming_the_stage():
    stages, batch = per_frame_batch(Short())
    says = r"^encoder2d 'short': descriptors must be a \[2 x D\] tensor, got \(1, 4\)$"
    with pytest.raises(ContractError, match=says):
        BatchForward(stages)(batch)


def test_an_isolated_run_returns_the_same_trace():
    frame, here = toy_frame(), pipeline(encoder2d=toy_plugin.ConstantEncoder())
    there = isolated(Pipeline(here.combination, here.stages, timeout_s=None), "process")
    a, b = here.run(frame), there.run(frame)
    assert [(r.kind, r.component) for r in a.records] == [(r.kind, r.component) for r in b.records]
    assert list(b.timings) == list(a.timings)
    np.testing.assert_array_equal(b.kp2d.uv, a.kp2d.uv)
    np.testing.assert_array_equal(b.upstream.matches.index3d, a.upstream.matches.index3d)
    assert torch.equal(b.features.desc2d, a.features.desc2d)
