"""`i2pbench evaluate RUN_DIR --rules NAMES`: the run's rows scored under several protocol cards' rules, one table."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .results import EvaluateResult


def run_rules(args: argparse.Namespace, thresholds: dict[str, float | None], echo: bool = True) -> EvaluateResult:
    """The table (printed when `echo`) and where it was written."""
    from ..errors import I2PBenchError
    from ..runs.evaluate import evaluate
    from ..scoring.table import chosen, notes, rules_table, to_markdown
    from .results import EvaluateResult

    if not args.rules:
        raise I2PBenchError("--rules-only goes with --rules NAMES (or --rules all)")
    given = [option for option, value in zip(("--acc-rre", "--acc-rte", "--filter-rre", "--filter-rte"),
                                             thresholds.values(), strict=True) if value is not None]  # fmt: skip
    if given:
        raise I2PBenchError(f"{', '.join(given)} and --rules do not go together: each card's rules set its thresholds")
    wanted = chosen(args.rules)
    result = evaluate(args.run_dir, args.invocation)
    table = rules_table(result.records, result.protocol, wanted, args.rules_only)
    markdown = to_markdown(table.table)
    lines = notes(table, result.protocol)
    if echo:
        print(markdown)
        print("\n" + "\n".join(lines), file=sys.stderr)
    paths = []
    if args.out:
        stem = Path(args.out)
        try:
            stem.parent.mkdir(parents=True, exist_ok=True)
            for ext, write in (("csv", lambda p: table.table.to_csv(p, index=False)),
                               ("md", lambda p: p.write_text(markdown + "\n"))):  # fmt: skip
                path = stem.with_name(f"{stem.name}.{ext}")
                tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
                write(tmp)
                os.replace(tmp, path)
                paths.append(path)
        except OSError as exc:
            raise I2PBenchError(f"--out {args.out}: could not write the table ({exc.strerror or exc})") from None
        if echo:
            print(f"written: {stem}.csv, {stem}.md", file=sys.stderr)
    return EvaluateResult(table.table, result.records, Path(args.run_dir), paths, lines)
