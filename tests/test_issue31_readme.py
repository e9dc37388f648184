"""Issue 31 first contact 8: every README table with latencies says where they come from (the machine, its thread
count, when), since a reader's own run prints other numbers."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _tables_with_latency() -> list[tuple[str, str]]:
    """(the paragraph just before the table, the table's header) for each Markdown table with a latency column."""
    blocks = re.split(r"\n\s*\n", README.read_text())
    return [
        (blocks[i - 1], block.splitlines()[0])
        for i, block in enumerate(blocks)
        if block.startswith("| ") and "latency" in block.splitlines()[0]
    ]


def test_every_readme_table_with_latencies_says_where_they_come_from():
    tables = _tables_with_latency()
    assert len(tables) >= 3  # the KITTI classic table, the synthetic board, KITTI sequence 26
    for before, header in tables:
        said = " ".join(before.split())
        assert re.search(r"[Ll]atenc(y|ies)", said), header
        assert "machine" in said and "thread" in said, said  # which machine, at how many threads
        assert re.search(r"2026-\d\d-\d\d|load average|idle", said), said  # and when or under what load
