"""Where i2pbench keeps what it can remake (the synthetic dataset, the entry-point cache): the XDG cache folder.

`$XDG_CACHE_HOME/i2pbench` when that variable names an absolute path (the XDG Base Directory rule: a relative one is
ignored), else `~/.cache/i2pbench`. Read at each call, so a test or a CI job can move it with the environment.
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_home() -> Path:
    """The i2pbench cache folder (not created here); `~` is left unexpanded only when there is no home folder."""
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if os.path.isabs(xdg) else Path(os.path.expanduser("~/.cache"))
    return base / "i2pbench"
