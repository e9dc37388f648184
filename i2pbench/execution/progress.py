"""Progress bars for long operations (data synthesis, runs, training), silenced by `--quiet` or I2PBENCH_QUIET=1.

Library code that may run deep inside a command (e.g. a dataset generating itself on first use) cannot see the
command's flags, so `--quiet` is passed down through the environment, which worker processes inherit too.
"""

from __future__ import annotations

import os
import sys

from tqdm import tqdm

ENV_VAR = "I2PBENCH_QUIET"


def quiet() -> bool:
    return os.environ.get(ENV_VAR, "") not in ("", "0")


def set_quiet(value: bool) -> None:
    if value:
        os.environ[ENV_VAR] = "1"


def note(text: str) -> None:
    """a line about what was done (`written: ...`) on stderr, left out under --quiet."""
    if not quiet():
        print(text, file=sys.stderr)


def bar(total: int, desc: str, unit: str = "frame", initial: int = 0) -> tqdm:
    return tqdm(total=total, desc=desc, unit=unit, initial=initial, disable=quiet(), file=sys.stderr)
