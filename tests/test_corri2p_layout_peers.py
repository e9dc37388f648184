"""The authors' own loaders, run on i2pbench's export of the real KITTI frames, return what i2pbench hands the
stages (scripts/corri2p_layout_check.py; its last run is docs/results/corri2p-layout-check.json). Each peer needs its
checkout, named by an environment variable; without one the test skips naming it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from conftest import SHARED_DATA
from corri2p_layout_check import TOLERANCES, check

from i2pbench.data.corri2p_export import export_kitti

KITTI = SHARED_DATA / "kitti_odometry"
CHECKOUTS = {"corri2p": "I2PBENCH_CORRI2P_CHECKOUT", "cofii2p": "I2PBENCH_COFII2P_CHECKOUT"}
REPOS = {"corri2p": "rsy6318/CorrI2P", "cofii2p": "WHU-USI3DV/CoFiI2P"}


@pytest.fixture(scope="module")
def export(tmp_path_factory) -> Path:
    if not KITTI.is_dir():
        pytest.skip(f"{KITTI} is not present")
    out = tmp_path_factory.mktemp("peers") / "export"
    export_kitti(KITTI, out)
    return out


@pytest.fixture(params=["corri2p", "cofii2p"])
def peer(request) -> tuple[str, Path]:
    """(peer, its checkout), before any export is made."""
    checkout = os.environ.get(CHECKOUTS[request.param], "")
    if not checkout:
        pytest.skip(f"{CHECKOUTS[request.param]} is not set: the path of a {REPOS[request.param]} checkout")
    return request.param, Path(checkout)


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
