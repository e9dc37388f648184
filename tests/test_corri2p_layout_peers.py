"""The authors' own loaders, run on i2pbench's export of the real KITTI frames, return what i2pbench hands the
stages (scripts/corri2p_layout_check.py; its last run is docs/results/corri2p-layout-check.json). Each peer needs its
checkout, named by an environment variable; without one the test skips naming it."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SAMPLE_DATA, peer_checkout, sample
from corri2p_layout_check import TOLERANCES, check

from i2pbench.data.corri2p_export import export_kitti

KITTI = SAMPLE_DATA / "kitti_odometry"


@pytest.fixture(scope="module")
def export(tmp_path_factory) -> Path:
    sample("kitti_odometry")
    out = tmp_path_factory.mktemp("peers") / "export"
    export_kitti(KITTI, out)
    return out


@pytest.fixture(params=["corri2p", "cofii2p"])
def peer(request) -> tuple[str, Path]:
    """(peer, its checkout), before any export is made."""
    return request.param, peer_checkout(request.param)


def test_the_authors_loader_returns_what_i2pbench_hands_the_stages(peer, export, tmp_path):
    peer, checkout = peer
    result = check(peer, checkout, export, tmp_path)
    assert [r["frame"] for r in result["frames"]] == ["00/000000", "00/000001", "00/000002", "00/000003",
                                                      "00/000004", "01/000000"]  # fmt: skip
    assert [r["index"] for r in result["frames"]] == [0, 2, 4, 6, 8, 10]
    for row in result["frames"]:
        assert row["points"] == (40960 if peer == "corri2p" else 20480)
        for array, tolerance in TOLERANCES.items():
            assert row[array] <= tolerance, (row["frame"], array, row[array])
