"""Each stage kind is declared once (`components.STAGES`); the hooks, the command line, the calls, the trace and the
contract checks read that declaration, so every part of it must name something that exists."""

import argparse
import dataclasses

import numpy as np

from i2pbench.commands.options import add_stage_options, stage_choices
from i2pbench.registry import hookspecs
from i2pbench.stages import contracts
from i2pbench.stages.components import STAGE_BASES, STAGE_ORDER, STAGES, Component
from i2pbench.stages.inputs import StageInputs
from i2pbench.stages.pipeline import REQUIRED_STAGES
from i2pbench.stages.trace import Failure, FrameOutcome, StageRecord, Upstream
from i2pbench.types import Features, Keypoints2D, Keypoints3D, Matches, PoseEstimate


def test_every_kind_names_a_hookspec_and_a_contract_that_exist():
    for kind, spec in STAGES.items():
        assert spec.kind == kind and issubclass(spec.base, Component)
        assert spec.hook in hookspecs.HOOK_NAMES and hasattr(getattr(hookspecs, spec.hook), "i2pbench_spec")
        assert callable(getattr(contracts, spec.contract))
    assert STAGE_ORDER == tuple(STAGES) and set(STAGE_BASES) == set(STAGES)
    assert REQUIRED_STAGES == ("extractor2d", "extractor3d", "matcher", "solver")


def test_the_options_are_one_per_kind_and_parse_to_its_name():
    flags = [flag for spec in STAGES.values() for flag in spec.options]
    assert len(flags) == len(set(flags))
    parser = argparse.ArgumentParser()
    add_stage_options(parser, "{kind}")
    args = parser.parse_args(["--extractor", "lsd,canny", "--solver", "epnp-ransac"])
    assert stage_choices(args) == {"extractor2d": ["lsd", "canny"], "solver": ["epnp-ransac"]}


def test_the_solver_is_called_with_what_an_upstream_stores():
    upstream = Upstream("kp2d", "kp3d", "matches")
    inputs = StageInputs(upstream.kp2d, upstream.kp3d, Features("d2", "d3"), upstream.matches)
    assert STAGES["solver"].arguments(inputs, Features(None, None)) == dataclasses.astuple(upstream)


def _records():
    kp2d = Keypoints2D(np.zeros((2, 2), np.float32))
    kp3d = Keypoints3D(np.arange(3), np.zeros((3, 3), np.float32), np.zeros(3, np.float32))
    matches = Matches(np.array([0]), np.array([2]), np.ones(1, np.float32))
    outputs = {"extractor2d": kp2d, "extractor3d": kp3d, "encoder2d": "d2", "encoder3d": "d3", "matcher": matches}
    records = [StageRecord(kind, kind, out, 0.0) for kind, out in outputs.items()]
    return [*records, StageRecord("solver", "solver", PoseEstimate.failed("no pose"), 0.0)]


def test_each_output_goes_where_the_stages_after_it_read_it():
    records = _records()
    produced = StageInputs()
    for record in records:
        produced = STAGES[record.kind].put(produced, record.output)
    assert produced.features == Features("d2", "d3") and produced.matches is records[4].output
    shown = Features(None, "d3")  # a matcher declaring only 3D descriptors
    assert STAGES["extractor3d"].arguments(produced, shown) == ()
    assert STAGES["encoder2d"].arguments(produced, shown) == (records[0].output,)
    assert STAGES["encoder3d"].arguments(produced, shown) == (records[1].output,)
    assert STAGES["matcher"].arguments(produced, shown) == (records[0].output, records[1].output, shown)
    assert STAGES["solver"].arguments(produced, shown) == (records[0].output, records[1].output, records[4].output)
    exchanged = STAGES["exchanger"].put(produced, Features("e2", "e3"))
    assert exchanged.features == Features("e2", "e3")
    assert STAGES["solver"].put(exchanged, records[5].output) == exchanged  # the solver's estimate goes nowhere


def test_a_trace_reads_its_values_through_the_same_declaration():
    records = _records()
    outcome = FrameOutcome.of(records)
    assert (outcome.kp2d, outcome.kp3d, outcome.matches) == (records[0].output, records[1].output, records[4].output)
    assert outcome.features == Features("d2", "d3") and outcome.upstream.matches is records[4].output
    failed = FrameOutcome.of(records[:2], Failure("encoder2d 'x'", "encoder2d", "it broke"))
    assert failed.features == Features(None, None) and failed.upstream is None and failed.kp3d is records[1].output
