"""`run --out STEM`: a leaderboard is several files (STEM.csv, STEM.md, STEM.parquet, STEM.env.json), so --out is
a stem, and what a user may type instead is caught before any frame runs (issue 31: `--out /dev/null` wrote
`/dev/null.csv`): a device, pipe or folder is refused, and a file name ending in one of the written suffixes loses
it (`--out board.csv` writes board.csv, not board.csv.csv), said in a note that lists what will be written.
`table --out` is a stem of fewer files (STEM.csv, STEM.md) and is read the same way.
"""

from __future__ import annotations

import stat
import sys
from pathlib import Path

from ..errors import I2PBenchError

WRITTEN = (".csv", ".md", ".parquet", ".env.json")


def board_stem(out: str | None, written: tuple[str, ...] = WRITTEN) -> str | None:
    """The stem `--out` stands for, or an error when it names something the `written` files cannot sit beside."""
    if out is None:
        return None
    path = Path(out)
    if path.is_dir():
        raise I2PBenchError(f"--out {out} is a folder; --out is a file stem: pass e.g. --out {path / 'board'}")
    if path.exists() and not stat.S_ISREG(path.stat().st_mode):
        raise I2PBenchError(
            f"--out {out} is not a regular file but a device, pipe or socket; --out is a file stem (it writes "
            f"STEM{', STEM'.join(written)}); the {'board' if written == WRITTEN else 'table'} is printed either way"
            + (", and without --out written under RUNS_DIR/leaderboards/" if written == WRITTEN else "")
        )
    suffix = next((s for s in written if path.name.endswith(s) and path.name != s), None)
    if suffix is None:
        return out
    stem = str(path.with_name(path.name[: -len(suffix)]))
    print(f"i2pbench: note: --out {out} is taken as the stem {stem}: writing {stem}{f', {stem}'.join(written)}",
          file=sys.stderr)  # fmt: skip
    return stem
