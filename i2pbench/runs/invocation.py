"""One JSON file per run invocation under `<store>/invocations/`, so a store keeps its whole history.

Each rerun into the same store (a resume, an `--overwrite`, a wider grid) adds a file rather than replacing the
last one; every per-frame record names the invocation that computed it, so a leaderboard can be traced to the
code, machine and thread count behind each of its frames.
"""

from __future__ import annotations

import datetime
import json
import os
from pathlib import Path
from typing import Any


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.UTC)


class Invocation:
    """A run's metadata file: written when the run starts, completed when it ends."""

    def __init__(self, store_root: str | Path, meta: dict[str, Any]) -> None:
        started = _now()
        self.id = f"{started:%Y%m%dT%H%M%S%fZ}-{os.getpid()}"
        self.path = Path(store_root) / "invocations" / f"{self.id}.json"
        self.meta = {"id": self.id, "started": started.isoformat(), "status": "running", **meta}
        self._write()

    def finish(self, **extra: Any) -> None:
        """Mark the run finished; a file still saying "running" belongs to a run that was killed."""
        self.meta.update(status="finished", finished=_now().isoformat(), **extra)
        self._write()

    def _write(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        tmp.write_text(json.dumps(self.meta, indent=2, default=str) + "\n")
        os.replace(tmp, self.path)


def history(store_root: str | Path) -> list[dict[str, Any]]:
    """Every invocation recorded in a store, oldest first."""
    paths = sorted((Path(store_root) / "invocations").glob("*.json"))
    return [json.loads(p.read_text()) for p in paths]
