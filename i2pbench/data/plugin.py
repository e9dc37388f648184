"""Entry point registering the built-in datasets and corruptions, by import path: each dataset's module (and what it
imports, e.g. SciPy for nuScenes, the devkit only when that dataset is used) loads when the dataset is opened, and the
corruptions' (OpenCV) when a run corrupts its frames; and the built-in protocol cards (i2pbench.scoring.cards)."""

from ..registry.hookspecs import hookimpl

CORRUPTIONS = {
    "gaussian-noise": "GaussianNoise",
    "motion-blur": "MotionBlur",
    "defocus-blur": "DefocusBlur",
    "low-light": "LowLight",
    "jpeg": "JPEG",
    "fog": "Fog",
    "beam-reduction": "BeamReduction",
    "point-dropout": "PointDropout",
    "range-noise": "RangeNoise",
    "reflectance-noise": "ReflectanceNoise",
    "missing-sector": "MissingSector",
    "intrinsic-error": "IntrinsicError",
    "tilt": "Tilt",
    "time-offset": "TimeOffset",
}


@hookimpl
def register_datasets(register) -> None:
    register("i2pbench.data.kitti:KittiOdometry", name="kitti")
    register("i2pbench.data.kitti_drives:KittiDrives", name="kitti-drives")
    register("i2pbench.data.nuscenes:NuScenes", name="nuscenes")
    register("i2pbench.data.corri2p_kitti:Corri2PKitti", name="corri2p-kitti")
    register("i2pbench.data.peer_nuscenes:CoFiI2PNuScenes", name="cofii2p-nuscenes")
    register("i2pbench.data.peer_nuscenes:CorrI2PNuScenes", name="corri2p-nuscenes")
    register("i2pbench.data.synthetic:SyntheticStreets", name="synthetic")


@hookimpl
def register_protocols(register) -> None:
    from ..scoring.cards import BUILTIN

    for card in BUILTIN:
        register(card)


@hookimpl
def register_corruptions(register) -> None:
    for name, cls in CORRUPTIONS.items():
        register(f"i2pbench.corruptions.builtin:{cls}", name=name)
