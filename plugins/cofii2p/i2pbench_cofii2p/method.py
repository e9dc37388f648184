"""CoFiI2P as one declared method: the authors' network (official/: WHU-USI3DV/CoFiI2P ed90edf, proven on tensors
their code computed, tests/test_cofii2p_reference.py) with their loader's pixels and points and eval_all.py's
inference (official/stages.py, official/solver.py), the `official` size. It runs untrained unless given weights from
`i2pbench weights import cofii2p-official FILE` (the authors' released KITTI or nuScenes checkpoint, user-supplied:
their repository carries no licence, so none is shipped).
"""

from __future__ import annotations

from i2pbench.api import Method, MethodPreset, Row, Size

# the loader's fine-map cells and 20,480 points, one learned stage (the matcher: network + fine matching), and
# eval_all.py's solvePnPRansac (SOLVEPNP_ITERATIVE, 10,000 iterations, 8 px on the fine map)
OFFICIAL_STAGES = {
    "extractor2d": "cofii2p-official-grid",
    "extractor3d": "cofii2p-official-points",
    "encoder2d": "none",
    "encoder3d": "none",
    "exchanger": "none",
    "matcher": "cofii2p-official",
    "solver": "cofii2p-official-pnp",
}
OFFICIAL = Size(
    "official",
    stages=OFFICIAL_STAGES,
    description="the authors' code exactly (WHU-USI3DV/CoFiI2P): ResNet-34, KPConv-FPN, coarse transformer, fine "
    "matching in 4 x 4 patches, solvePnPRansac; weights: i2pbench weights import cofii2p-official FILE (their release)",
)

# Options_Nuscenes (data/options.py:68-74) and data/nuscenes.py: a 160 x 320 crop of the stored image halved, feats
# of intensity (0-255 in their files; i2pbench's frames hold it / 255) and the point itself instead of normals
NUSCENES_CROP = {"top_rows": 0, "scale": 0.5, "crop": (320, 160)}
OFFICIAL_NUSCENES = Size(
    "official-nuscenes",
    confs={
        "extractor2d": NUSCENES_CROP,
        "matcher": {**NUSCENES_CROP, "features": "xyz", "intensity_scale": 255.0},
        "solver": NUSCENES_CROP,
    },
    stages=OFFICIAL_STAGES,
    description="the authors' code as their nuScenes options and loader set it (160 x 320, intensity and xyz "
    "features), for the cofii2p-nuscenes layout; weights: their nuScenes release through the same importer",
)

PRESETS = (
    MethodPreset(
        "cofii2p-official",
        (Row("official"),),
        "CoFiI2P's authors' own network (WHU-USI3DV/CoFiI2P); untrained unless given --weights from "
        "`i2pbench weights import cofii2p-official`",
    ),
    MethodPreset(
        "cofii2p-official-nuscenes",
        (Row("official-nuscenes"),),
        "CoFiI2P's authors' own network at their nuScenes settings (--dataset cofii2p-nuscenes --protocol cofii2p); "
        "untrained unless given --weights from `i2pbench weights import cofii2p-official`",
    ),
)


def cofii2p() -> Method:
    """The declaration, built when the plugin registers (nothing is loaded then)."""
    return Method(
        "cofii2p",
        dict(OFFICIAL_STAGES),
        (OFFICIAL, OFFICIAL_NUSCENES),
        PRESETS,
        (),
        "the loader's fine-map cells and 20,480 points, ResNet-34 + KPConv-FPN, coarse transformer matching "
        "super-points to super-pixels, fine matching in patches, PnP-RANSAC",
        importers={"cofii2p-official": "i2pbench_cofii2p.official.importer:import_official"},
        title="CoFiI2P",
    )
