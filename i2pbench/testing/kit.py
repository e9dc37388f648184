"""`check_component(cls)`: every way a component can break the pipeline, found before a benchmark run finds it.

Checks, in order (each problem names its check and what went wrong):
- declaration: subclasses a stage base, has a name, a dict `default_conf`, refuses unknown config keys, and its
  `consumes`/`provides` name known values that stages before its kind can provide (an extra value such as
  FRUSTUM_SCORES provided only by its kind, a matcher);
- contract: on a sample frame the output has the documented types, shapes, dtypes, ranges and finite values;
- declared inputs: a component that fails without T_gt but works with it reads ground truth it did not declare;
- no side effects: the frame's arrays are unchanged after the call;
- determinism: the same instance, called again on an equal frame, returns an identical output. Nothing is reseeded
  in between, as in a run: a draw from a global RNG would make results depend on which frames ran before;
- empty input: a blank image, an empty scan, zero keypoints, zero matches give a valid empty output (a solver given
  no matches must answer PoseEstimate.failed), never an exception;
- bad input (NaN points, a negative-stride image, coincident points): an exception with a message, or a valid
  output; never garbage and never a bare exception.
Every call is the pipeline's own (`i2pbench.stages.calling.call_stage`: the declared view, then the contract check),
so a contract problem reads as the error a run would record for that output. Latency on the sample frame is measured and
reported, never asserted.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import torch

from ..errors import StageError
from ..stages.calling import StageInputs, call_stage
from ..stages.components import EXTRA_VALUES, STAGE_BASES, STAGE_ORDER, Component
from ..stages.config import ConfigError
from ..stages.contracts import ContractError
from ..stages.learned import LearnedComponent
from ..stages.trace import StageRecord
from ..types import Frame
from .cases import Case, bad_cases, empty_cases
from .frames import synthetic_frame
from .inputs import descriptor_dim, ground_truth_inputs
from .outputs import changed_arrays, check_extras, difference, frame_arrays
from .report import ConformanceReport, Problem


def check_component(cls: type, conf: Mapping[str, Any] | None = None, frame: Frame | None = None) -> ConformanceReport:
    """Run every check on `cls` built with `conf`; returns the problems found (empty when it conforms)."""
    report = ConformanceReport(getattr(cls, "__name__", repr(cls)))
    report.extend(check_declaration(cls))
    component = None if report else _build(cls, conf, report)
    if component is None:
        return report
    frame = frame if frame is not None else synthetic_frame()
    inputs = ground_truth_inputs(frame, descriptor_dim(component))
    first = _check_sample(component, frame, inputs, report)
    if first is not None:
        _check_determinism(component, frame, inputs, first, report)
    for case in empty_cases(component.kind, frame, inputs, descriptor_dim(component)):
        _check_empty(component, case, report)
    for case in bad_cases(component.kind, frame, inputs):
        _check_bad(component, case, report)
    return report


def _build(cls: type[Component], conf: Mapping[str, Any] | None, report: ConformanceReport) -> Component | None:
    try:
        component = cls(dict(conf) if conf else None)
    except Exception as exc:
        report.add("construct", f"{cls.__name__}({conf}) raised {_describe(exc)}")
        return None
    if isinstance(component, LearnedComponent):
        component.eval()  # inference behaviour (no dropout), as the runner sets it
    report.component = component.label
    return component


def assert_conforms(cls: type, conf: Mapping[str, Any] | None = None, frame: Frame | None = None) -> None:
    """pytest-friendly: raise AssertionError listing every problem check_component finds."""
    report = check_component(cls, conf, frame)
    if report:
        raise AssertionError(str(report))


def check_declaration(cls: type) -> list[Problem]:
    """Problems in what the class declares, found without running it."""
    if not (isinstance(cls, type) and issubclass(cls, tuple(STAGE_BASES.values()))):
        bases = ", ".join(b.__name__ for b in STAGE_BASES.values())
        return [Problem("declaration", f"{cls!r} does not subclass a stage base ({bases})")]
    problems = []
    if not isinstance(cls.name, str) or not cls.name:
        problems.append(Problem("declaration", f"{cls.__name__} has no `name` (the name users pick it by)"))
    if not isinstance(cls.default_conf, dict):
        problems.append(Problem("declaration", f"default_conf must be a dict, got {type(cls.default_conf).__name__}"))
    problems += _check_values(cls)
    if not problems:
        problems += _check_unknown_key_refused(cls)
    return problems


def _check_values(cls: type[Component]) -> list[Problem]:
    """consumes/provides must name known values, only values available before this kind runs, and an extra value
    (EXTRA_VALUES, e.g. a matcher's frustum scores) only as a component of the kind that may provide it."""
    known = set().union(*(b.consumes | b.provides for b in STAGE_BASES.values()))
    known |= {"ground_truth"} | set(EXTRA_VALUES)
    available = {"image", "points", "ground_truth"}
    for kind in STAGE_ORDER[: STAGE_ORDER.index(cls.kind)]:
        available |= STAGE_BASES[kind].provides | {v for v, provider in EXTRA_VALUES.items() if provider == kind}
    problems = []
    for attr in ("consumes", "provides"):
        unknown = sorted(set(getattr(cls, attr)) - known)
        if unknown:
            problems.append(Problem("declaration", f"{attr} names unknown values {unknown}; known: {sorted(known)}"))
    late = sorted(set(cls.consumes) & known - available)
    if late:
        problems.append(Problem("declaration", f"consumes {late}, which no stage before the {cls.kind} provides"))
    misplaced = sorted(v for v in set(cls.provides) & set(EXTRA_VALUES) if EXTRA_VALUES[v] != cls.kind)
    if misplaced:
        kinds = ", ".join(f"{v} by a {EXTRA_VALUES[v]}" for v in misplaced)
        problems.append(Problem("declaration", f"provides {misplaced}, which only {kinds} can carry"))
    return problems


def _check_unknown_key_refused(cls: type[Component]) -> list[Problem]:
    key = "__conformance_unknown_key__"
    try:
        cls({key: 1})
    except (ConfigError, ValueError, KeyError, TypeError):
        return []
    except Exception as exc:  # refused, if clumsily; construction is checked properly later
        return [Problem("declaration", f"an unknown config key raised {_describe(exc)}; expected ConfigError")]
    return [Problem("declaration", f"accepted the unknown config key {key!r}: typos in user config would go unseen")]


def _check_sample(component: Component, frame: Frame, inputs: StageInputs, report: ConformanceReport) -> Any:
    """Run on the sample frame; check the contract, declared inputs and side effects. The output, or None."""
    before = frame_arrays(frame)
    try:
        out, report.first_call_ms = _timed(component, frame, inputs)
        check_extras(component, out, inputs)
    except Exception as exc:
        report.add(*_sample_failure(component, frame, inputs, exc))
        return None
    changed = changed_arrays(before, frame)
    if changed:
        report.add("side effects", f"wrote into the frame's {', '.join(changed)}; stages must not modify inputs")
    return out


def _sample_failure(component: Component, frame: Frame, inputs: StageInputs, exc: Exception) -> tuple[str, str]:
    """Tell a broken contract from a component that only works when it can see ground truth."""
    if isinstance(exc, StageError):
        return "contract", str(exc)
    if frame.T_gt is not None and "ground_truth" not in component.consumes:
        peeking = copy.copy(component)
        peeking.consumes = component.consumes | {"ground_truth"}
        try:
            check_extras(component, _call(peeking, frame, inputs).output, inputs)
        except Exception:
            pass
        else:
            return "declared inputs", (
                f"fails without frame.T_gt ({_describe(exc)}) but works with it: it reads ground truth; "
                "declare GROUND_TRUTH in `consumes` (the pipeline hides T_gt from stages that do not)"
            )
    return "contract", f"raised {_describe(exc)} on the sample frame"


def _check_determinism(
    component: Component, frame: Frame, inputs: StageInputs, first: Any, report: ConformanceReport
) -> None:
    try:
        again, report.latency_ms = _timed(component, copy.deepcopy(frame), copy.deepcopy(inputs))
    except Exception as exc:
        report.add("determinism", f"a second call on the same frame raised {_describe(exc)}")
        return
    where = difference(first, again)
    if where:
        report.add(
            "determinism",
            f"two calls on the same frame returned different {where}; seed any randomness "
            "from the frame (dataset, frame id) and conf, not from a global or unseeded generator",
        )


def _check_empty(component: Component, case: Case, report: ConformanceReport) -> None:
    try:
        out = _call(component, case.frame, case.inputs).output
        check_extras(component, out, case.inputs)
    except Exception as exc:
        report.add("empty input", f"on {case.what}: {_describe(exc)}; return a valid empty output instead")
        return
    if case.must_fail_pose and out.ok:
        report.add("empty input", f"on {case.what}: returned a pose; return PoseEstimate.failed(reason)")


def _check_bad(component: Component, case: Case, report: ConformanceReport) -> None:
    garbage = f"on {case.what}: returned garbage instead of raising a clear error"
    try:
        out = _call(component, case.frame, case.inputs).output
    except ContractError as exc:  # the call returned, and its output broke the contract
        report.add("bad input", f"{garbage}: {exc}")
        return
    except Exception as exc:
        if not str(exc).strip():
            report.add("bad input", f"on {case.what}: raised {type(exc).__name__} with no message; say what is wrong")
        return
    try:
        check_extras(component, out, case.inputs)
    except StageError as exc:
        report.add("bad input", f"{garbage}: {exc}")


def _call(component: Component, frame: Frame, inputs: StageInputs) -> StageRecord:
    """The component called as the pipeline calls its kind (`call_stage`), under torch.inference_mode as a run is."""
    with torch.inference_mode():
        return call_stage(component, frame, inputs)


def _timed(component: Component, frame: Frame, inputs: StageInputs) -> tuple[Any, float]:
    """The output and the milliseconds the call took."""
    record = _call(component, frame, inputs)
    return record.output, 1e3 * record.seconds


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
