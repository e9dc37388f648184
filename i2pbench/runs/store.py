"""Per-frame results, one small Parquet file per finished frame, written atomically.

Each file is named by the frame's cache key (a hash of dataset, frame, component configs, weights and protocol) and
appears only once complete: it is written to a temp file named after the writing process, then renamed over the
final name. A run killed at any point (SIGKILL included) therefore leaves finished frames intact and at most one
stray temp file, which readers ignore and the next store opening removes once its writer is dead. No fsync: a killed
process loses nothing the kernel already holds; only a power cut could, and then the unreadable file is detected on
read, reported by path, set aside and recomputed.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

TEMP_SUFFIX = ".tmp"
CORRUPT_SUFFIX = ".corrupt"


def cache_key(parts: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:24]


class ResultsStore:
    """A directory of `frames/<key>.parquet` files, plus `invocations/` (see `runs.invocation`)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.frames_dir = self.root / "frames"
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        self._sweep_dead_temps()

    def path(self, key: str) -> Path:
        return self.frames_dir / f"{key}.parquet"

    def put(self, key: str, record: dict[str, Any]) -> None:
        """Store one frame's record: pyarrow directly, uncompressed, as pandas' writer costs ~5x more per frame."""
        table = pa.Table.from_pylist([record])
        tmp = self.frames_dir / f".{key}.{os.getpid()}{TEMP_SUFFIX}"
        try:
            pq.write_table(table, tmp, compression="none", write_statistics=False)  # one row: nothing to gain
            os.replace(tmp, self.path(key))
        finally:
            tmp.unlink(missing_ok=True)

    def get(self, key: str) -> dict[str, Any] | None:
        """The stored record, or None when absent or unreadable (then reported and set aside for recomputing)."""
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            return pq.read_table(path).to_pylist()[0]
        except FileNotFoundError:  # removed between the check and the read
            return None
        except Exception as exc:  # pyarrow raises several types for a damaged file; any of them means recompute
            self._set_aside(path, exc)
            return None

    def load(self, keys: list[str] | None = None) -> pd.DataFrame:
        """All records (or those with the given keys that exist and are readable), one row per frame."""
        if keys is None:
            keys = sorted(p.stem for p in self.frames_dir.glob("*.parquet"))  # not temps (.tmp), set-asides (.corrupt)
        return pd.DataFrame([r for r in (self.get(k) for k in keys) if r is not None])

    def _set_aside(self, path: Path, exc: Exception) -> None:
        aside = path.with_name(path.name + CORRUPT_SUFFIX)
        print(
            f"i2pbench: warning: unreadable result {path} ({type(exc).__name__}: {exc}); "
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
