"""What `--weights` did to a run, said where it would otherwise surprise (issue 31).

Weights belong to the learned stages and the extractors they were trained with (DESIGN principle 4): a network
trained on LSD's keypoints was trained on another input than Canny's. So `--weights auto` picks a shipped checkpoint
only for exactly its stages and extractors, and a default pipeline with another extractor runs untrained. That is
deliberate, but silent it reads as a bug: the run says so, naming the checkpoint and the extractor it expects, and
how to use it anyway (`--weights PATH` loads it whatever the extractors). A checkpoint passed to a run with no
learned stage at all would be ignored: that is refused.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import WeightsError
from ..weights.checkpoints import EXTRACTOR_KINDS, load_checkpoint, mismatch, stage_signature

_SAID: set[str] = set()  # a run prepares its grid once per protocol: each note once


def explain_untrained(pipeline: Any, label: str, shipped: Sequence[str]) -> None:
    """After `--weights auto` found no checkpoint for a learned pipeline: a note when a shipped one fits it but for
    its extractors."""
    if label in _SAID:
        return
    _SAID.add(label)
    for path in shipped:
        checkpoint = load_checkpoint(path)
        if mismatch(checkpoint, pipeline, strict_extractors=False) is not None:
            continue
        want, have = stage_signature(pipeline), checkpoint.meta["stages"]
        other = [f"{k} {_name(have.get(k))} (this row: {_name(want.get(k))})" for k in EXTRACTOR_KINDS
                 if want.get(k) != have.get(k)]  # fmt: skip
        print(
            f"i2pbench: note: --weights auto: {label} runs untrained: the shipped {Path(path).name} fits its learned "
            f"stages but was trained with {', '.join(other)}, and auto picks weights only for the extractors they "
            f"were trained with; --weights {path} uses them anyway",
            file=sys.stderr,
        )
        return


def _name(signature: dict[str, Any] | None) -> str:
    return "none" if signature is None else repr(signature["name"])


def refuse_unused(jobs: Sequence[Any], choice: str) -> None:
    """A checkpoint named for a run none of whose combinations has a learned stage would be ignored: refused."""
    if choice in ("auto", "untrained") or any(job.pipeline.learned_modules() for job in jobs):
        return
    rows = ", ".join(job.label for job in jobs)
    raise WeightsError(
        f"--weights {choice}: no combination of this run has a learned stage ({rows}), so the checkpoint would be "
        "ignored; drop --weights, or run the learned stages it was trained with"
    )
