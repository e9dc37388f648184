"""How the report writes numbers and row names: numbers as its tables show them, and a leaderboard row's name (a
combination of up to seven stages plus its weights, often 140 characters) wrapped onto lines that fit beside a plot.
"""

from __future__ import annotations

import math
import textwrap

STAGE_JOIN = " > "  # how a combination's name joins its stages
KEEP = "\u00a0"  # textwrap never breaks at a no-break space: it ties each ">" to the stage before it
CHAR_PX = 6.5  # a generous width of one 8 pt character at the report's 100 dpi (measured: ~5.9 px on average)


def number(value: float, unit: str = "") -> str:
    """`value` with two decimals and thousands grouped ("1,001.85"), "-" when it is missing (NaN), "inf" for a
    failure's error."""
    if value is None or math.isnan(value):
        return "-"
    return f"{value:,.2f}" + (f" {unit}" if unit else "")


def tick(value: float) -> str:
    """An axis tick: a whole number grouped by thousands ("10,000"), a fraction as short as it reads ("0.01")."""
    return f"{value:,.0f}" if value >= 1 else f"{value:g}"


def wrapped(label: str, width: int) -> str:
    """`label` on lines of at most `width` characters, broken after a stage's ">" or at a space; a word longer than
    a line (a checkpoint path) is cut."""
    tied = label.replace(STAGE_JOIN, KEEP + ">" + " ")
    lines = textwrap.wrap(tied, width, break_on_hyphens=False) or [""]
    return "\n".join(line.replace(KEEP, " ") for line in lines)


def chars_in(inches: float) -> int:
    """How many 8 pt characters a line `inches` wide holds at 100 dpi."""
    return max(8, int(inches * 100 / CHAR_PX))


def line_count(text: str) -> int:
    return text.count("\n") + 1
