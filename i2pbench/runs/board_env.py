"""Which software made a leaderboard, kept beside it as `<stem>.env.json`, and how two boards' versions differ.

A board's rows come from the invocations whose frames it holds (a rerun reuses cached frames), so the record lists
each of them: its id, environment (package versions, python, git commit, machine) and dataset identity (a synthetic
one names its generator_version). A board written before these records existed is traced to its run's store when it
sits where `i2pbench run` puts it by default (`<runs>/leaderboards/<name>[-<what was run>].csv` beside
`<runs>/<name>/`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pandas as pd

from ..boards.leaderboard import GROUP
from .invocation import history
from .store import ResultsStore

SUFFIX = ".env.json"
GENERATOR = "generator_version"  # of the synthetic dataset, in its identity


def record(store_root: str | Path, invocation_ids: Iterable[str]) -> dict[str, Any]:
    """The environment and dataset identity of each named invocation the store recorded, oldest first."""
    ids = set(invocation_ids)
    runs = [m for m in history(store_root) if m.get("id") in ids]
    keep = ("id", "environment", "dataset")
    return {"store": str(store_root), "invocations": [{k: m.get(k, {}) for k in keep} for m in runs]}


def path_for(board: str | Path) -> Path:
    """The record's file beside a board file or stem (`x.csv`, `x.parquet` and `x` all give `x.env.json`)."""
    board = Path(board)
    stem = board.stem if board.suffix in (".csv", ".parquet") else board.name
    return board.with_name(stem + SUFFIX)


def write(stem: str | Path, store_root: str | Path, records: pd.DataFrame) -> Path:
    """`<stem>.env.json` for a board built from `records`, written atomically."""
    ids = records["invocation"].dropna().unique() if "invocation" in records else []
    path = path_for(stem)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(record(store_root, ids), indent=2, default=str) + "\n")
    os.replace(tmp, path)
    return path


class MalformedRecord(ValueError):
    """A board's `.env.json` that is not JSON, or JSON of another shape than `record` writes."""


def read(board_path: str | Path, board: pd.DataFrame) -> dict[str, Any] | None:
    """The board's record: its `.env.json` file, else its run's store in the default layout, else None; a file
    that is not a record of this shape raises MalformedRecord naming it and what is wrong."""
    board_path = Path(board_path)
    sidecar = path_for(board_path)
    if sidecar.is_file():
        try:
            found = json.loads(sidecar.read_text())
        except (OSError, ValueError) as exc:
            raise MalformedRecord(f"{sidecar} is not JSON ({type(exc).__name__}: {exc})") from None
        problem = _shape_problem(found)
        if problem:
            raise MalformedRecord(f"{sidecar} is not an environment record: {problem}")
        return found
    store = _store_of(board_path)
    if store is None:
        return None
    found = record(store, _invocations_of(store, board))
    return found if found["invocations"] else None


def _shape_problem(rec: Any) -> str | None:
    """what in a parsed record is not of the shape `record` writes (None: all is), so reading it never fails."""
    if not isinstance(rec, dict):
        return f"a JSON {_json_type(rec)}, not an object"
    invocations = rec.get("invocations", [])
    if not isinstance(invocations, list):
        return f"'invocations' is a {_json_type(invocations)}, not an array"
    for i, inv in enumerate(invocations):
        if not isinstance(inv, dict):
            return f"invocations[{i}] is a {_json_type(inv)}, not an object"
        for field in ("environment", "dataset"):
            if not isinstance(inv.get(field) or {}, dict):
                return f"invocations[{i}].{field} is a {_json_type(inv[field])}, not an object"
        if not isinstance((inv.get("environment") or {}).get("packages") or {}, dict):
            return f"invocations[{i}].environment.packages is not an object"
    return None


def _json_type(value: Any) -> str:
    names = {dict: "object", list: "array", str: "string", bool: "boolean", int: "number", float: "number"}
    return names.get(type(value), "null")


def _store_of(board_path: Path) -> Path | None:
    """The run's store of a board in the default layout: `<runs>/<name>/` for `<runs>/leaderboards/<name>[-<what was
    run>].csv` (the longest such name that is a store)."""
    if board_path.parent.name != "leaderboards":
        return None
    parts = board_path.stem.split("-")
    for n in range(len(parts), 0, -1):
        store = board_path.parent.parent / "-".join(parts[:n])
        if (store / "invocations").is_dir():
            return store
    return None


def _invocations_of(store: Path, board: pd.DataFrame) -> set[str]:
    """The invocations that computed the store's records of the board's rows, read without touching the store."""
    if not set(GROUP) <= set(board):
        return set()
    records = ResultsStore(store, read_only=True).load()
    if "invocation" not in records:  # records written before they named their invocation: nothing to trace
        return set()
    wanted = set(board[GROUP].astype(str).itertuples(index=False, name=None))
    rows = records[[*GROUP, "invocation"]].itertuples(index=False, name=None)
    return {inv for *group, inv in rows if isinstance(inv, str) and inv and tuple(map(str, group)) in wanted}


def versions(rec: dict[str, Any]) -> dict[str, set[str]]:
    """name -> the versions of it that the record's invocations ran: each package, python, the generator."""
    found: dict[str, set[str]] = {}
    for inv in rec.get("invocations", []):
        env, dataset = inv.get("environment") or {}, inv.get("dataset") or {}
        named = {**(env.get("packages") or {}), "python": env.get("python"), GENERATOR: dataset.get(GENERATOR)}
        for name, version in named.items():
            if version is not None:
                found.setdefault(name, set()).add(str(version))
    return found


def differences(new: dict[str, Any], base: dict[str, Any]) -> list[tuple[str, set[str], set[str]]]:
    """(name, new versions, baseline versions) for everything both records name at other versions."""
    a, b = versions(new), versions(base)
    return [(name, a[name], b[name]) for name in a if name in b and a[name] != b[name]]


def warnings(new: tuple[str | Path, pd.DataFrame], base: tuple[str | Path, pd.DataFrame]) -> list[str]:
    """Lines for `i2pbench compare`: each version that differs between the boards, or whose records are missing."""
    return board_warnings({"new leaderboard": new, "baseline": base}, {"new leaderboard": "new"})


def board_warnings(
    boards: dict[str, tuple[str | Path, pd.DataFrame]], short: dict[str, str] | None = None
) -> list[str]:
    """Lines for a command reading several boards (by role: `compare`'s new and baseline, `table`'s column groups):
    each board whose record is missing or malformed, else each version in which a board differs from the first."""
    short = short or {}
    records, unknown = {}, []
    for role, (path, board) in boards.items():
        try:
            records[role] = read(path, board)
        except MalformedRecord as exc:
            unknown.append(f"{role} {path}: its environment record {exc}; its package and generator versions are "
                           "unknown, so a difference in them would go unnoticed")  # fmt: skip
            continue
        if records[role] is None:
            unknown.append(
                f"{role} {path} has no environment record ({path_for(path).name} beside it, or its run's store): its "
                "package and generator versions are unknown, so a difference in them would go unnoticed"
            )
    if unknown:
        return unknown
    first, *others = boards
    return [
        f"the boards come from different {_what(name)}: {_shown(a)} ({short.get(first, first)}) vs {_shown(b)} "
        f"({short.get(other, other)}); a difference in results may come from it, not from the code"
        for other in others
        for name, a, b in differences(records[first], records[other])
    ]


def _what(name: str) -> str:
    if name == GENERATOR:
        return f"synthetic generator versions ({GENERATOR})"
    return "python versions" if name == "python" else f"{name} versions"


def _shown(values: set[str]) -> str:
    return ", ".join(sorted(values))
