"""Per-frame results, one small Parquet file per finished frame, written atomically.

Each file is named by the frame's cache key (a hash of dataset, frame, component configs, weights and protocol) and
appears only once complete (written to a temp file, then renamed), so a run killed at any point resumes without
losing or corrupting a finished frame, and a rerun skips what is done.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import pandas as pd


def cache_key(parts: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:24]


class ResultsStore:
    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.frames_dir = self.root / "frames"
        self.frames_dir.mkdir(parents=True, exist_ok=True)

    def path(self, key: str) -> Path:
        return self.frames_dir / f"{key}.parquet"

    def has(self, key: str) -> bool:
        return self.path(key).is_file()

    def put(self, key: str, record: dict[str, Any]) -> None:
        frame = pd.DataFrame([record])
        fd, tmp = tempfile.mkstemp(dir=self.frames_dir, prefix=".", suffix=".tmp")
        os.close(fd)
        try:
            frame.to_parquet(tmp, index=False)
            os.replace(tmp, self.path(key))
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)

    def load(self, keys: list[str] | None = None) -> pd.DataFrame:
        """All records (or those with the given keys that exist), one row per frame and combination."""
        paths = sorted(self.frames_dir.glob("*.parquet")) if keys is None else [self.path(k) for k in keys]
        tables = [pd.read_parquet(p) for p in paths if p.is_file()]
        return pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()

    def write_meta(self, meta: dict[str, Any]) -> None:
        fd, tmp = tempfile.mkstemp(dir=self.root, prefix=".", suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(meta, f, indent=2, default=str)
        os.replace(tmp, self.root / "run.json")
