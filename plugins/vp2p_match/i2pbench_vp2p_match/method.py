"""VP2P-Match as one declared method: the authors' network (official/: junshengzhou/VP2P-Match be76104, proven on
tensors their code computed, tests/test_vp2p_reference.py) with their pixels, points and inference (official/), the
`official` size. It runs untrained unless given weights from `i2pbench weights import vp2p-match-official FILE` (the
authors' released KITTI checkpoint, user-supplied: it carries no licence, so it is never shipped) or trained with
`i2pbench train --preset vp2p-match-official` (official/loss.py: the authors' adapt_loss and det_loss and EPro-PnP's
pose loss).
"""

from __future__ import annotations

from i2pbench.api import Method, MethodPreset, Row, Size

# the authors' crop's stride-4 cells and 40,960 voxel points, one learned stage (the matcher), EPnP in RANSAC with
# run_kitti.py's 500 iterations and 1 px at K/4 of the half-size crop (8 px in full-size pixels)
OFFICIAL_STAGES = {
    "extractor2d": "vp2p-match-official-grid",
    "extractor3d": "vp2p-match-official-points",
    "encoder2d": "none",
    "encoder3d": "none",
    "exchanger": "none",
    "matcher": "vp2p-match-official",
    "solver": "epnp-ransac",
}
OFFICIAL_SOLVER = {"iterations": 500, "reprojection_error_px": 8.0}  # run_kitti.py:89-94, in full-size pixels
OFFICIAL = Size(
    "official",
    pins={"solver": OFFICIAL_SOLVER},
    stages=OFFICIAL_STAGES,
    description="the authors' code exactly (junshengzhou/VP2P-Match): ResNet-34, Point Transformer and SPVCNN "
    "branches, 36,677,448 values; weights: i2pbench weights import vp2p-match-official FILE (their KITTI release)",
)

PRESETS = (
    MethodPreset(
        "vp2p-match-official",
        (Row("official"),),
        "VP2P-Match's authors' own network (junshengzhou/VP2P-Match); untrained unless given --weights from "
        "`i2pbench weights import vp2p-match-official`",
    ),
)


def vp2p_match() -> Method:
    """The declaration, built when the plugin registers (nothing is loaded then)."""
    return Method(
        "vp2p-match",
        dict(OFFICIAL_STAGES),
        (OFFICIAL,),
        PRESETS,
        (),
        "the authors' crop's stride-4 cells and voxel points, image + point + voxel branches fused, overlap scores, "
        "nearest-descriptor matching, EPnP",
        importers={"vp2p-match-official": "i2pbench_vp2p_match.official.importer:import_official"},
        title="VP2P-Match",
    )
