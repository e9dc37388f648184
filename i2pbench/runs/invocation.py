"""One JSON file per run invocation under `<store>/invocations/`, so a store keeps its whole history.

Each rerun into the same store (a resume, an `--overwrite`, a wider grid) adds a file rather than replacing the
last one; every per-frame record names the invocation that computed it, so a leaderboard can be traced to the
code, machine and thread count behind each of its frames.
"""

from __future__ import annotations

import datetime
import json
import os
import sys
from pathlib import Path
from typing import Any

from ..errors import I2PBenchError


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

    def fail(self, error: str) -> bool:
        """Mark the run failed (a full disk, say); False when even that cannot be written."""
        self.meta.update(status="failed", finished=_now().isoformat(), error=error)
        try:
            self._write()
        except I2PBenchError:
            return False
        return True

    def _write(self) -> None:
        folder = self.path.parent
        if folder.exists() and not folder.is_dir():
            raise I2PBenchError(f"{folder} is a file, not the folder where the store keeps its invocation records; "
                                "move it aside")  # fmt: skip
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        try:
            folder.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(self.meta, indent=2, default=str) + "\n")
            os.replace(tmp, self.path)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise I2PBenchError(f"{self.path}: could not write the invocation record ({exc.strerror or exc})") from None


def history(store_root: str | Path) -> list[dict[str, Any]]:
    """Every readable invocation recorded in a store, oldest first; one that cannot be read (truncated, not JSON)
    is named on stderr and left out, so the others still count."""
    paths = sorted((Path(store_root) / "invocations").glob("*.json")) if _folder(store_root) else []
    runs = []
    for path in paths:
        try:
            meta = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(meta, dict):
                raise ValueError(f"a JSON {type(meta).__name__}, not an object")
        except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
            print(f"i2pbench: warning: {path}: not a readable invocation record ({exc}); left out", file=sys.stderr)
            continue
        runs.append(meta)
    return runs


def _folder(store_root: str | Path) -> bool:
    folder = Path(store_root) / "invocations"
    if folder.exists() and not folder.is_dir():
        print(f"i2pbench: warning: {folder} is a file, not a folder of invocation records; left out", file=sys.stderr)
        return False
    return True


def record_file(store_root: str | Path, meta: dict[str, Any]) -> Path:
    """the file an invocation's record was read from (named by its id)."""
    return Path(store_root) / "invocations" / f"{meta.get('id', '?')}.json"


def written_by(meta: dict[str, Any]) -> str:
    """which i2pbench wrote an invocation record: its version and commit, as the record says."""
    environment = meta.get("environment") if isinstance(meta.get("environment"), dict) else {}
    version = (environment.get("packages") or {}).get("i2pbench", "an unrecorded version")
    return f"i2pbench {version} (commit {environment.get('git_commit', 'unrecorded')})"
