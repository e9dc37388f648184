"""Per-frame results, one small Parquet file per finished frame, written atomically.

Each file is named by the frame's cache key, `<slot>-<version>`: the slot hashes what is computed (dataset, frame,
component configs, weights and protocol), the version the state of the frame's files. A frame whose files changed
gets a new key, so it is recomputed, and storing the new version deletes the old one: the store never holds two
results of one slot.

A file appears only once complete: it is written to a temp file named after the writing process, then renamed over
the final name. A run killed at any point (SIGKILL included) therefore leaves finished frames intact and at most one
stray temp file, which readers ignore and the next store opening removes once its writer is dead. No fsync: a killed
process loses nothing the kernel already holds; only a power cut could, and then the unreadable file is detected on
read, reported by path, set aside and recomputed. So is a readable file that is not a result (missing or mistyped
columns, not one row): it would otherwise become a bogus leaderboard row.

Beside the records, `frames/<key>.npz` files hold what each frame's solver consumed (keypoints and matches, see
`runs.upstream`), keyed by the stages before the solver, so a solver sweep can reuse them; they are written,
superseded and set aside the same way. A store without them (written before they existed) still reads as before.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

TEMP_SUFFIX = ".tmp"
CORRUPT_SUFFIX = ".corrupt"
VERSION_SEP = "-"
RECORD_SUFFIX, UPSTREAM_SUFFIX = ".parquet", ".npz"
T = TypeVar("T")


def _text(t: pa.DataType) -> bool:
    return pa.types.is_string(t) or pa.types.is_large_string(t)


def _number(t: pa.DataType) -> bool:
    return pa.types.is_floating(t) or pa.types.is_integer(t)


# The columns every reader of the store relies on (the leaderboard groups and scores by them), each with its type.
REQUIRED: dict[str, Callable[[pa.DataType], bool]] = {
    **dict.fromkeys(("dataset", "split", "frame_id", "combination", "weights", "status", "failed_component"), _text),
    **dict.fromkeys(("rte_m", "rre_deg", "geodesic_deg", "model_size_mb", "t_total_s"), _number),
}


class SchemaError(ValueError):
    """A readable Parquet file that is not a frame's result."""


def cache_key(parts: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:24]


def versioned_key(parts: dict[str, Any], version: Any) -> str:
    """`<slot>-<version>`: `parts` say what is computed, `version` (e.g. file stamps) what it was computed from."""
    return f"{cache_key(parts)}{VERSION_SEP}{cache_key({'version': version})[:12]}"


def check_result(table: pa.Table) -> None:
    """Raise SchemaError naming what makes a table other than one frame's result: missing or mistyped columns, or
    a row count other than one."""
    schema = table.schema
    missing = [name for name in REQUIRED if name not in schema.names]
    wrong = [
        f"{name} is {schema.field(name).type}"
        for name, ok in REQUIRED.items()
        if name in schema.names and not ok(schema.field(name).type)
    ]
    rows = [] if table.num_rows == 1 else [f"{table.num_rows} rows, not 1"]
    if not rows:
        rows = _pose_problems(table)
    if missing or wrong or rows:
        problems = ([f"no column {', '.join(missing)}"] if missing else []) + wrong + rows
        raise SchemaError(f"not a frame result: {'; '.join(problems)}")


def _pose_problems(table: pa.Table) -> list[str]:
    """the stored poses (`evaluate` and `report` rebuild 4 x 4 matrices from them) must hold 16 numbers or none."""
    frame = table.column("frame_id")[0].as_py() if "frame_id" in table.schema.names else "?"
    problems = []
    for name in ("T_pred", "T_gt"):
        if name not in table.schema.names:
            continue
        values = table.column(name)[0].as_py()
        if values is not None and (not isinstance(values, list) or len(values) != 16):
            size = len(values) if isinstance(values, list) else type(values).__name__
            problems.append(f"frame {frame}'s {name} holds {size} values, not the 16 of a 4 x 4 pose")
    return problems


class ResultsStore:
    """A directory of `frames/<key>.parquet` files, plus `invocations/` (see `runs.invocation`)."""

    def __init__(self, root: str | Path, read_only: bool = False) -> None:
        """`read_only`: for readers (`evaluate`) that must leave the store as they found it: nothing is made,
        swept or set aside; an unreadable result is reported and skipped."""
        self.root = Path(root)
        self.frames_dir = self.root / "frames"
        self.read_only = read_only
        self._versions: dict[str, dict[str, set[str]]] = {}  # suffix -> slot -> stored keys, listed on the first put
        if not read_only:
            self.frames_dir.mkdir(parents=True, exist_ok=True)
            self._sweep_dead_temps()

    def path(self, key: str) -> Path:
        return self.frames_dir / f"{key}{RECORD_SUFFIX}"

    def put(self, key: str, record: dict[str, Any]) -> None:
        """Store one frame's record: pyarrow directly, uncompressed, as pandas' writer costs ~5x more per frame."""
        table = pa.Table.from_pylist([record])
        tmp = self.frames_dir / f".{key}.{os.getpid()}{TEMP_SUFFIX}"
        try:
            pq.write_table(table, tmp, compression="none", write_statistics=False)  # one row: nothing to gain
            os.replace(tmp, self.path(key))
        finally:
            tmp.unlink(missing_ok=True)
        self._supersede(key, RECORD_SUFFIX)

    def upstream_path(self, key: str) -> Path:
        return self.frames_dir / f"{key}{UPSTREAM_SUFFIX}"

    def put_upstream(self, key: str, arrays: Mapping[str, np.ndarray]) -> None:
        """Store what one frame's solver consumed, as arrays, atomically like a record (uncompressed: float32 edge
        coordinates gain little from it)."""
        tmp = self.frames_dir / f".{key}{UPSTREAM_SUFFIX}.{os.getpid()}{TEMP_SUFFIX}"
        try:
            with open(tmp, "wb") as file:  # a file object: given a path, numpy would append its own .npz
                np.savez(file, **arrays)
            os.replace(tmp, self.upstream_path(key))
        finally:
            tmp.unlink(missing_ok=True)
        self._supersede(key, UPSTREAM_SUFFIX)

    def get_upstream(self, key: str, decode: Callable[[Mapping[str, np.ndarray]], T]) -> T | None:
        """`decode` of the stored arrays, or None when absent, unreadable or refused by `decode` (then reported and
        set aside: the frame is run whole again)."""
        path = self.upstream_path(key)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as arrays:
                return decode(arrays)
        except FileNotFoundError:
            return None
        except Exception as exc:  # zipfile, numpy and decode's ValueError all mean: compute it again
            self._set_aside(path, exc)
            return None

    def _supersede(self, key: str, suffix: str) -> None:
        """Delete the other versions of the key's slot (results of data that has changed since), so that readers of
        the whole store (`load()`, reports) see one result per slot."""
        slot, sep, _ = key.partition(VERSION_SEP)
        if not sep:
            return
        versions = self._versions.get(suffix)
        if versions is None:  # listed once per store: a directory scan per frame would grow with the store
            versions = self._versions[suffix] = {}
            for path in self.frames_dir.glob(f"*{suffix}"):
                versions.setdefault(path.stem.partition(VERSION_SEP)[0], set()).add(path.stem)
        for old in versions.get(slot, set()) - {key}:
            (self.frames_dir / f"{old}{suffix}").unlink(missing_ok=True)
        versions[slot] = {key}

    def get(self, key: str) -> dict[str, Any] | None:
        """The stored record, or None when absent, unreadable or not a result (then reported and set aside for
        recomputing)."""
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            table = pq.read_table(path)
            check_result(table)
            return table.to_pylist()[0]
        except FileNotFoundError:  # removed between the check and the read
            return None
        except Exception as exc:  # pyarrow raises several types for a damaged file; any of them means recompute
            self._set_aside(path, exc)
            return None

    def keys(self) -> list[str]:
        """The keys of the stored records, sorted (not temps, set-asides or upstreams); none for a store not made."""
        return sorted(p.stem for p in self.frames_dir.glob(f"*{RECORD_SUFFIX}"))

    def load(self, keys: list[str] | None = None) -> pd.DataFrame:
        """All records (or those with the given keys that exist and are readable), one row per frame: the reader
        of the whole store for everyone (evaluate, board tracing, scripts), each record checked as `get` does."""
        keys = self.keys() if keys is None else keys
        return pd.DataFrame([r for r in (self.get(k) for k in keys) if r is not None])

    def _set_aside(self, path: Path, exc: Exception) -> None:
        aside = path.with_name(path.name + CORRUPT_SUFFIX)
        what = "malformed" if isinstance(exc, SchemaError) else "unreadable"
        if self.read_only:
            print(f"i2pbench: warning: {what} result {path} ({type(exc).__name__}: {exc}); skipped, left as it is "
                  "(a run sets it aside and computes the frame again)", file=sys.stderr)  # fmt: skip
            return
        print(
            f"i2pbench: warning: {what} result {path} ({type(exc).__name__}: {exc}); "
            f"moved to {aside.name}, it will be recomputed",
            file=sys.stderr,
        )
        os.replace(path, aside)

    def _sweep_dead_temps(self) -> None:
        """Remove temp files left by writers that no longer run (a killed run's last, unfinished frame)."""
        for tmp in self.frames_dir.glob(f".*{TEMP_SUFFIX}"):
            pid = tmp.name.removesuffix(TEMP_SUFFIX).rsplit(".", 1)[-1]
            if pid.isdigit() and not _alive(int(pid)):
                tmp.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True
