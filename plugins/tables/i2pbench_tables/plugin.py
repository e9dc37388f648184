"""Presets that lay out the seed paper's comparison (EdgeRegNet, Table I): one row per method, in the paper's order.

The rows are the methods' own presets, named rather than copied (`register_presets` takes a preset's name as an
entry), so a row runs exactly what `--preset deepi2p` or `--preset corri2p` runs, with the weights `--weights auto`
picks for it (or untrained, which the row then says). VP2P-Match, the paper's fourth peer, runs as its authors'
network only (no weights are trained or shipped here: untrained unless given imported ones, which its weights column
says), and so does CoFiI2P, which Table I lacks (a later peer, RA-L 2024). The oracle row, which the paper lacks, is
the ceiling of the protocol.
`i2pbench table` joins one such leaderboard per dataset into the paper's layout (KITTI and nuScenes columns).
"""

from __future__ import annotations

from i2pbench.api import hookimpl

# Table I's rows: DeepI2P's grid classification + PnP, its frustum classification + inverse projection in 3D and 2D,
# CorrI2P, VP2P-Match, CoFiI2P (not in the paper), then EdgeRegNet ("Ours"); every method at the size whose weights
# are trained here, and beside DeepI2P's and CorrI2P's CPU look-alikes their authors' own networks, with VP2P-Match's
# and CoFiI2P's authors' networks (`official`: untrained here unless given imported weights, as their rows' weights
# column says)
TABLE_1 = (
    "deepi2p",
    "deepi2p-frustum-3d",
    "deepi2p-frustum-2d",
    "deepi2p-official",
    "corri2p",
    "corri2p-official",
    "vp2p-match-official",
    "cofii2p-official",
    "default",
    "classic-oracle",
)
# the same rows at the sizes the papers report (their encoders and keypoint counts; no weights shipped for them)
TABLE_1_PAPER_SIZE = ("deepi2p-paper", "corri2p-paper", "edgeregnet-full", "classic-oracle")


@hookimpl
def register_presets(register) -> None:
    register(
        "paper-table-1",
        list(TABLE_1),
        "the seed paper's Table I: DeepI2P (grid + PnP, frustum 3D, frustum 2D), CorrI2P, VP2P-Match, CoFiI2P, "
        "EdgeRegNet, the oracle ceiling; each method's trainable size, and DeepI2P's, CorrI2P's, VP2P-Match's and "
        "CoFiI2P's authors' networks (untrained here unless imported)",
    )
    register(
        "paper-table-1-paper-size",
        list(TABLE_1_PAPER_SIZE),
        "Table I's methods at the sizes their papers report (DeepI2P grid + PnP, CorrI2P, EdgeRegNet), the oracle",
    )
