"""What `i2pbench run` says after its board: why frames failed, counted by reason, and which reused frames were timed
at other thread counts (the board shows counts and latencies; these lines say what lies behind them); and what it
says when Ctrl-C stopped it."""

from __future__ import annotations

import argparse
import re
from typing import Any


def failure_reasons(records, most: int = 10) -> list[str]:
    """Failed frames counted by (combination, reason), most first: a reason is the error with its frame, paths and
    numbers masked, so frames that fail the same way count together (the board counts failures, not why)."""
    failed = records[records["status"] != "ok"]
    if failed.empty:
        return []
    failed = failed.assign(reason=failed["error"].fillna("").map(_reason))
    groups = failed.groupby(["combination", "reason"], sort=False)["frame_id"].agg(["size", "first"])
    groups = groups.sort_values("size", ascending=False, kind="stable")
    lines = [f"{len(failed)} of {len(records)} frames failed; by reason (count x combination: reason, e.g. a frame):"]
    lines += [
        f"  {n} x {combination}: {why} (e.g. {example})"
        for (combination, why), (n, example) in groups.head(most).iterrows()
    ]
    return lines + ([f"  ... and {len(groups) - most} more reasons"] if len(groups) > most else [])


def _reason(error: str) -> str:
    error = re.sub(r"frame '[^']*'", "frame <id>", error)
    error = re.sub(r"(?<![\w.])/[^\s,;()]+", "<file>", error)
    error = re.sub(r"(?<![\w.-])\d+(\.\d+)?(e[-+]?\d+)?", "N", error)  # not UTF-8's
    return error if len(error) <= 200 else error[:197] + "..."


def latency_reused(records, invocation: str, threads: int, args: argparse.Namespace) -> list[str]:
    """A note when frames reused from the cache were timed at other thread counts than this run's: their latency
    is on the board, and says nothing of this run's settings."""
    if "threads" not in records:
        return []
    computed = records["invocation"] == invocation
    serial = args.executor == "local" and (args.workers or 1) <= 1  # else workers run at --threads-per-worker
    own = set(records.loc[computed, "threads"]) or {threads if serial else args.threads_per_worker}
    other = records[~computed & ~records["threads"].isin(own)]
    if other.empty:
        return []
    at = ", ".join(str(int(t)) for t in sorted(set(other["threads"])))
    return [
        f"note: the latency of {len(other)} frame(s) reused from the cache was measured at {at} thread(s), not "
        f"this run's {', '.join(str(int(t)) for t in sorted(own))}; --overwrite measures them again"
    ]


def stopped(exc: KeyboardInterrupt, store: Any, invocation: Any, protocol: Any) -> int:
    """After Ctrl-C or SIGTERM in `run`: mark the invocation failed, print the board of the frames that finished
    (this invocation's, and the stored ones the grid in progress reused) and one line saying what was kept; returns
    the exit status (130 for Ctrl-C, 143 for SIGTERM)."""
    import sys

    import pandas as pd

    from ..boards import leaderboard
    from ..execution.interrupts import stopped_by

    what, status = stopped_by()
    records = _finished(getattr(exc, "records", []), store, invocation.id)
    meta = invocation.meta
    total = len(meta.get("frames", [])) * len(meta.get("combinations", [])) * len(meta.get("protocols", [0]))
    invocation.fail(f"interrupted by {what} after {len(records)} of {total} frames")
    if len(records):
        print(leaderboard.to_markdown(leaderboard.build(pd.DataFrame(records), protocol)))
    mine = int((records["invocation"] == invocation.id).sum()) if "invocation" in records else 0
    kept = f"all kept in {store.frames_dir}; the board above is of those" if len(records) else "nothing to keep"
    print(
        f"i2pbench: interrupted ({what}): workers stopped; {len(records)} of {total} frames finished ({mine} computed "
        f"by this run), {kept}; the same command resumes",
        file=sys.stderr,
    )
    return status


def _finished(records: list[dict[str, Any]], store: Any, invocation: str):
    """The grid's finished records, with those this invocation stored that never reached the driver (a worker's
    last frames, an earlier protocol's grid), each (frame, row, protocol) once."""
    import pandas as pd

    from ..runs.store import ResultsStore

    stored = ResultsStore(store.root).load()  # opening it sweeps the temp file of a frame a worker was writing
    stored = stored[stored["invocation"] == invocation] if "invocation" in stored else stored.iloc[:0]
    both = pd.concat([pd.DataFrame(records), stored], ignore_index=True)
    if both.empty:
        return both
    keys = [c for c in ("frame_id", "combination", "weights", "protocol") if c in both]
    return both.drop_duplicates(subset=keys).reset_index(drop=True)
