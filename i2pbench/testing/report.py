"""What the conformance kit returns: a list of problems, each naming its check, plus the latency it measured."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Problem:
    check: str  # declaration, construct, contract, declared inputs, side effects, determinism, empty/bad input
    message: str

    def __str__(self) -> str:
        return f"[{self.check}] {self.message}"


class ConformanceReport(list[Problem]):
    """The problems found (an empty report means the component conforms), and latency on the sample frame (ms).

    Latency is reported, never judged: `first_call_ms` includes one-off costs, `latency_ms` is the second call.
    """

    def __init__(self, component: str) -> None:
        super().__init__()
        self.component = component
        self.first_call_ms = float("nan")
        self.latency_ms = float("nan")

    def add(self, check: str, message: str) -> ConformanceReport:
        self.append(Problem(check, message))
        return self

    def checks_failed(self) -> set[str]:
        return {p.check for p in self}

    def __str__(self) -> str:
        timing = f"latency {self.latency_ms:.1f} ms (first call {self.first_call_ms:.1f} ms)"
        if not self:
            return f"{self.component} conforms; {timing}"
        lines = [f"{self.component}: {len(self)} conformance problem(s); {timing}"]
        return "\n".join(lines + [f"  - {p}" for p in self])
