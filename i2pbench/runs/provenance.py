"""Which code produced a result: the git commit of the checkout, and whether it had uncommitted changes."""

from __future__ import annotations

import subprocess
from pathlib import Path


def _git(*args: str) -> str | None:
    """A git command's stdout in this package's checkout, or None outside a checkout or when git fails."""
    try:
        out = subprocess.run(["git", *args], capture_output=True, text=True, timeout=10,
                             cwd=Path(__file__).resolve().parent)  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout if out.returncode == 0 else None


def git_commit() -> str:
    return (_git("rev-parse", "--short", "HEAD") or "").strip() or "unknown"


def git_dirty() -> bool | None:
    """Whether the checkout has uncommitted changes (then the commit alone does not name the code)."""
    status = _git("status", "--porcelain", "--untracked-files=no")
    return None if status is None else bool(status.strip())
