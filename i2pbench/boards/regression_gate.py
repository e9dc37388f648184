"""The regression gate: compare a new leaderboard with a baseline under explicit per-metric tolerances.

Rows are matched by dataset, split, combination and weights. A row regresses when a checked metric moves the wrong
way by more than its tolerance, when it becomes NaN where the baseline had a value (e.g. no frame passes the RTE/RRE
filter any more), or when its frame count changes; a baseline row missing from the new leaderboard is a failure too.
Tolerances are absolute for accuracy metrics (`acc=-2`: at most 2 points lower) and ratios for latency
(`latency=x1.5`: at most 1.5 times slower), because seconds mean nothing across machines. A metric a plugin
registers (`scoring.metrics`) is checked under its name.

When both boards keep per-frame values of a row on the same frames (`uncertainty`), every checked metric that moved
is tested paired: McNemar's exact test for Acc., a paired bootstrap for RTE and RRE, and the report says whether the
move is significant. With `alpha` a move beyond tolerance that is not significant at that level is reported as
noise instead of failing. The golden gate does not pass it: its pipelines are deterministic, so any frame that
changes is a real change of the code, and on its 6 frames McNemar's test cannot call fewer than 6 frames lost in one
direction significant (5 of 5: p = 2 / 2^5 = 0.0625), so a significance-gated gate there would pass nearly anything.

A table the gate cannot trust is an error, not a verdict: an empty, header-only, binary or ragged file would
otherwise pass vacuously (no baseline row to fail) or compare misaligned columns.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ..errors import I2PBenchError
from ..scoring import installed as installed_metrics
from ..scoring import metrics as metric_registry
from ..stages.components import STAGE_ORDER
from . import uncertainty
from .leaderboard import (
    ACC,
    GROUP,
    LATENCY_MEDIAN,
    LATENCY_P90,
    MODEL_SIZE,
    RRE_MEAN,
    RTE_MEAN,
    read,
    stage_latency,
)
from .stats import Paired

DEFAULT_TOLERANCE = "acc=-2,rte=+0.05,rre=+0.2"
# metric -> (leaderboard column, higher is better)
METRICS: dict[str, tuple[str, bool]] = {
    "acc": (ACC, True),
    "rte": (RTE_MEAN, False),
    "rre": (RRE_MEAN, False),
    "failures": ("failures", False),
    "kept": ("kept", True),
    "size": (MODEL_SIZE, False),
    "latency": (LATENCY_MEDIAN, False),
    "latency_p90": (LATENCY_P90, False),
    **{f"latency.{kind}": (stage_latency(kind, "median"), False) for kind in STAGE_ORDER},
}


def known() -> dict[str, tuple[str, bool]]:
    """METRICS and the metrics plugins register (under their names)."""
    plugins = installed_metrics.active()[len(metric_registry.BUILTIN) :]
    return {**METRICS, **{m.name: (m.column, bool(m.higher_is_better)) for m in plugins if m.column}}


@dataclass(frozen=True)
class Tolerance:
    """How far one metric may move in its worse direction: `slack` units, or a factor of `ratio`."""

    metric: str
    slack: float = 0.0
    ratio: float | None = None

    @property
    def column(self) -> str:
        return known()[self.metric][0]

    @property
    def higher_is_better(self) -> bool:
        return known()[self.metric][1]

    def limit(self, base: float) -> float:
        """The worst value still accepted, given the baseline's."""
        if self.ratio is not None:
            return base / self.ratio if self.higher_is_better else base * self.ratio
        return base - self.slack if self.higher_is_better else base + self.slack

    def regressed(self, new: float, base: float) -> bool:
        if math.isnan(base):
            return False  # nothing to fall from
        if math.isnan(new):
            return True
        eps = 1e-9 * max(1.0, abs(base))  # CSV round trips and summation order are not bit-exact
        return new < self.limit(base) - eps if self.higher_is_better else new > self.limit(base) + eps

    def __str__(self) -> str:
        if self.ratio is not None:
            return f"{self.metric}=x{self.ratio:g}"
        return f"{self.metric}={'-' if self.higher_is_better else '+'}{self.slack:g}"


def parse_tolerances(text: str) -> list[Tolerance]:
    """`"acc=-2,rte=+0.05,rre=+0.2,latency=x1.5"` -> tolerances, refusing unknown metrics and wrong-way signs."""
    tolerances = [_parse_one(item.strip()) for item in text.split(",") if item.strip()]
    metrics = [t.metric for t in tolerances]
    twice = sorted({m for m in metrics if metrics.count(m) > 1})
    if twice:  # the last one silently won
        raise I2PBenchError(f"tolerance {text!r}: {', '.join(twice)} given twice; give each metric once")
    return tolerances


def _parse_one(item: str) -> Tolerance:
    metric, sep, value = item.partition("=")
    metric, value = metric.strip(), value.strip()
    if not sep or metric not in known():
        raise I2PBenchError(f"tolerance {item!r}: expected METRIC=VALUE with METRIC one of {', '.join(known())}")
    if value.startswith("x"):
        ratio = _number(item, value[1:])
        if ratio < 1:
            raise I2PBenchError(f"tolerance {item!r}: a ratio is at least x1 (x1.5 allows 1.5 times worse)")
        return Tolerance(metric, ratio=ratio)
    if metric.startswith("latency"):
        raise I2PBenchError(f"tolerance {item!r}: latency tolerances are ratios such as {metric}=x1.5, not times")
    slack = _number(item, value)
    worse = "-" if known()[metric][1] else "+"
    if value[0] in "+-" and value[0] != worse and slack != 0:
        hint = f"{metric}={worse}{abs(slack):g}"
        raise I2PBenchError(f"tolerance {item!r}: {metric} gets worse as it goes {worse}; write {hint}")
    return Tolerance(metric, slack=abs(slack))


def _number(item: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise I2PBenchError(f"tolerance {item!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise I2PBenchError(f"tolerance {item!r}: {text!r} is not finite")
    return value


@dataclass(frozen=True)
class Finding:
    """One failed check: a metric beyond tolerance, a changed frame count, or a missing row."""

    row: tuple
    what: str  # a metric name, "frames" or "missing"
    base: float = math.nan
    new: float = math.nan
    limit: float = math.nan
    test: Paired | None = None  # the paired test of the move, when both boards keep the row's per-frame values


@dataclass
class Report:
    findings: list[Finding] = field(default_factory=list)
    compared: int = 0
    added: list[tuple] = field(default_factory=list)  # rows only in the new leaderboard (reported, not checked)
    tolerances: list[Tolerance] = field(default_factory=list)
    moves: list[Finding] = field(default_factory=list)  # tested moves within tolerance, or dismissed as noise
    alpha: float | None = None  # beyond tolerance but not significant at alpha: a move, not a finding

    @property
    def ok(self) -> bool:
        return not self.findings


def read_board(path: str | Path, role: str = "leaderboard") -> pd.DataFrame:
    """A leaderboard file (.csv or .parquet), refusing one that cannot be read as a table; errors start with
    `role` (e.g. "baseline") and the path, then say what is wrong."""
    path = Path(path)
    try:
        return _read_checked(path)
    except I2PBenchError as exc:
        raise I2PBenchError(f"{role} {exc}") from None


def _read_checked(path: Path) -> pd.DataFrame:
    if path.suffix not in (".csv", ".parquet"):
        what = f"a {path.suffix} file" if path.suffix else "a file without extension"
        raise I2PBenchError(f"{path}: {what}; this takes a leaderboard's .csv or .parquet (written beside its .md)")
    if not path.is_file():
        raise I2PBenchError(f"{path}: no such leaderboard file")
    if path.stat().st_size == 0:
        raise I2PBenchError(f"{path}: empty file (0 bytes), not a leaderboard")
    if path.suffix != ".parquet":
        _check_csv(path)
    try:
        board = read(path)
    except Exception as exc:  # pandas and pyarrow raise many types for a damaged file
        kind = "Parquet" if path.suffix == ".parquet" else "CSV"
        raise I2PBenchError(f"{path}: not a readable {kind} leaderboard ({type(exc).__name__}: {exc})") from None
    if "combination" not in board:  # the row label every reader looks rows up by: refused here, not mid-way
        raise I2PBenchError(f"{path}: not a leaderboard (no column combination)")
    return board


def _check_csv(path: Path) -> None:
    """Text, a header, and every row as wide as the header: pandas pads a short row with NaN and takes an extra
    leading field as the index, so a ragged file would compare misaligned cells without a word."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise I2PBenchError(f"{path}: binary, not a CSV leaderboard (byte {exc.start} is not UTF-8 text)") from None
    if "\0" in text:  # valid UTF-8, yet in no text file
        raise I2PBenchError(f"{path}: binary, not a CSV leaderboard (character {text.index(chr(0))} is NUL)")
    reader = csv.reader(io.StringIO(text))
    try:
        rows = [(reader.line_num, len(row)) for row in reader if row]  # blank lines skipped, as pandas does
    except csv.Error as exc:
        raise I2PBenchError(f"{path}: line {reader.line_num}: not CSV ({exc})") from None
    if not rows:
        raise I2PBenchError(f"{path}: no header line, not a leaderboard")
    width = rows[0][1]
    for line, fields in rows[1:]:
        if fields != width:
            raise I2PBenchError(f"{path}: line {line} has {fields} fields, the header {width}")


def _indexed(board: pd.DataFrame, name: str) -> pd.DataFrame:
    missing = [c for c in GROUP if c not in board]
    if missing:
        raise I2PBenchError(f"{name}: not a leaderboard (no column {', '.join(missing)})")
    if board.empty:
        raise I2PBenchError(f"{name}: no rows (a header only), so nothing to compare")
    keys = board[GROUP].astype(str)
    duplicated = keys[keys.duplicated()]
    if len(duplicated):
        raise I2PBenchError(f"{name}: row {' / '.join(duplicated.iloc[0])} appears more than once")
    return board.set_index(pd.MultiIndex.from_frame(keys))


def _value(row: pd.Series, column: str) -> float:
    """The cell as a float; absent, empty or non-numeric cells are NaN."""
    try:
        return float(row.get(column, math.nan))
    except (TypeError, ValueError):
        return math.nan


def compare(
    new: pd.DataFrame,
    base: pd.DataFrame,
    tolerances: list[Tolerance],
    names: tuple[str, str] = ("new leaderboard", "baseline"),
    alpha: float | None = None,
) -> Report:
    """Check every baseline row against the new leaderboard; `names` say which table an error is about. With
    `alpha`, a move beyond tolerance whose paired test is not significant at `alpha` does not fail."""
    new, base = _indexed(new, names[0]), _indexed(base, names[1])
    for tol in tolerances:
        if tol.column not in base:
            raise I2PBenchError(f"tolerance {tol}: {names[1]} has no column {tol.column!r}")
    report = Report(added=[k for k in new.index if k not in base.index], tolerances=list(tolerances), alpha=alpha)
    for key, b in base.iterrows():
        if key not in new.index:
            report.findings.append(Finding(key, "missing"))
            continue
        report.compared += 1
        for finding, beyond in _check_row(key, new.loc[key], b, tolerances):
            noise = alpha is not None and finding.test is not None and finding.test.p >= alpha
            (report.findings if beyond and not noise else report.moves).append(finding)
    return report


def _check_row(key: tuple, new: pd.Series, base: pd.Series, tolerances: list[Tolerance]) -> list[tuple[Finding, bool]]:
    """(finding, beyond tolerance) for a changed frame count and for every checked metric that moved and could be
    tested paired, or moved beyond its tolerance."""
    findings = []
    if "frames" in base and _value(new, "frames") != _value(base, "frames"):
        findings.append((Finding(key, "frames", _value(base, "frames"), _value(new, "frames")), True))
    tested = {m.column: m for m in uncertainty.with_interval(installed_metrics.active())}
    for tol in tolerances:
        b, n = _value(base, tol.column), _value(new, tol.column)
        test = uncertainty.paired(new, base, tested[tol.column]) if tol.column in tested else None
        beyond = tol.regressed(n, b)
        if beyond or (test is not None and not _same(n, b)):
            findings.append((Finding(key, tol.metric, b, n, tol.limit(b), test), beyond))
    return findings


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or abs(a - b) <= 1e-9 * max(1.0, abs(b))


def format_report(report: Report) -> str:
    """A readable diff: each failing row, what moved and the limit it crossed, and whether the move is significant
    where both boards keep per-frame values; moves within tolerance (or dismissed as noise); a one-line verdict."""
    lines = [f"tolerances: {', '.join(str(t) for t in report.tolerances) or 'none'}"]
    if report.alpha is not None:
        lines[0] += f"; a move beyond tolerance fails only when significant (p < {report.alpha:g})"
    for key in dict.fromkeys(f.row for f in report.findings):
        lines.append(f"FAIL  {' / '.join(key)}")
        lines += [f"        {_describe(f)}" for f in report.findings if f.row == key]
    for key in dict.fromkeys(f.row for f in report.moves):
        lines.append(f"moved {' / '.join(key)}")
        lines += [f"        {_describe(f)}" for f in report.moves if f.row == key]
    lines += [f"new   {' / '.join(key)} (not in the baseline; not checked)" for key in report.added]
    missing = sum(f.what == "missing" for f in report.findings)
    regressed = len({f.row for f in report.findings}) - missing
    verdict = "FAIL" if report.findings else "OK"
    lines.append(
        f"{verdict}: {report.compared} rows compared, {regressed} regressed, {missing} missing, {len(report.added)} new"
    )
    return "\n".join(lines)


def _describe(f: Finding) -> str:
    if f.what == "missing":
        return "missing: in the baseline, not in the new leaderboard"
    if f.what == "frames":
        return f"frames: {f.base:g} -> {f.new:g} (results over different frames are not comparable)"
    if math.isnan(f.new):
        return f"{f.what}: {f.base:.4g} -> NaN (no value where the baseline had one)"
    test = f"; {f.test}" if f.test is not None else ""
    return f"{f.what}: {f.base:.4g} -> {f.new:.4g} ({f.new - f.base:+.4g}; limit {f.limit:.4g}{test})"
