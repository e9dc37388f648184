"""The authors' own code on i2pbench's nuScenes layouts (scripts/nuscenes_layout_check.py; its last run is
docs/results/nuscenes-layout-check.json): each peer's loader returns what i2pbench hands the stages under its card,
and CoFiI2P's build scripts write the files i2pbench's export writes. Each peer needs its checkout, named by an
environment variable; without one the test skips naming it."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SAMPLE_DATA, peer_checkout, sample
from nuscenes_layout_check import TOLERANCES, check, check_build, export_both

RECORDS = SAMPLE_DATA / "nuscenes_real"


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    sample("nuscenes_real")
    return tmp_path_factory.mktemp("nuscenes-peers")


@pytest.mark.parametrize("peer", ["corri2p", "cofii2p"])
def test_the_authors_loader_returns_what_i2pbench_hands_the_stages(peer, scratch):
    checkout = peer_checkout(peer)
    if not (scratch / peer).is_dir():
        export_both(RECORDS, scratch)
    result = check(peer, checkout, scratch / peer, scratch)
    assert [r["index"] for r in result["frames"]] == list(range(10))
    for row in result["frames"]:
        assert row["points"] == (40960 if peer == "corri2p" else 20480)
        for array, tolerance in TOLERANCES.items():
            assert row[array] <= tolerance, (row["frame"], array, row[array])


def test_cofii2ps_build_scripts_write_the_exports_files(scratch):
    result = check_build(peer_checkout("cofii2p"), RECORDS, scratch)
    assert result["frames"] == 5 and len(result["files"]) == 20
    assert all(row["diff"] == 0.0 for row in result["files"]), [r for r in result["files"] if r["diff"]]
