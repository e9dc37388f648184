"""i2pbench: a plugin-based benchmark for image-to-LiDAR registration.

From Python: `i2pbench.run(...)`, `i2pbench.evaluate(run_dir)`, `i2pbench.compare(new, baseline)` and
`i2pbench.score(predictions)` are the commands as calls (docs/python.md); each is imported on first use, so
`import i2pbench` stays as light as the command line needs.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"
CALLS = ("run", "evaluate", "compare", "score")
__all__ = ["__version__", *CALLS]


def __getattr__(name: str) -> Any:
    if name not in CALLS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from .commands import calls

    return getattr(calls, name)
