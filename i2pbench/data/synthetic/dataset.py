"""The embedded synthetic dataset: procedural street scenes in the KITTI Odometry layout, made on first use.

Splits are sequences: train = "00", val = "01", test = "02". Each split is generated the first time it is asked
for (into a temporary folder renamed into place, so an interrupted or concurrent generation never leaves a partial
sequence) and read back through the KITTI reader, so the synthetic frames exercise the same code as real ones.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from ...errors import DataError
from ...paths import cache_home
from ...types import SensorFrame
from ..base import Dataset
from ..kitti import KittiOdometry, read_frame, sequence_stems
from .style import get_style
from .version import GENERATOR_VERSION

SPLIT_SEQUENCES = {"train": "00", "val": "01", "test": "02"}
MARKER = "synthetic.json"
MAX_FRAMES = 50_000  # per split: more than all of KITTI Odometry (43,552 frames), about 125 GB of images and scans
STALE_AFTER_S = 600  # a temp folder with no owner's pid this old is a killed generation's, not one starting up


def default_root(seed: int, style: str = "default") -> Path:
    """<cache>/synthetic-v{version}-seed{seed}, or ...-v{version}-{style}-seed{seed} for another style, where <cache>
    is $XDG_CACHE_HOME/i2pbench or ~/.cache/i2pbench."""
    tag = "" if style == "default" else f"-{style}"
    return cache_home() / f"synthetic-v{GENERATOR_VERSION}{tag}-seed{seed}"


def marker(seed: int, sequence: str, n_frames: int, style: str = "default") -> dict[str, Any]:
    """What a sequence was made with. The style (and its knob values, so a refitted style regenerates) only when it
    is not the default, so the caches made before styles existed stay valid."""
    made = {"generator_version": GENERATOR_VERSION, "seed": int(seed), "sequence": sequence, "frames": int(n_frames)}
    return made if style == "default" else {**made, "style": style, "style_knobs": get_style(style).knobs()}


def ensure_sequence(
    root: Path, sequence: str, n_frames: int, seed: int, workers: int | None = None, style: str = "default"
) -> Path:
    """The sequence folder, generated unless a complete one with the same marker is already there.

    An outdated sequence of the same style is replaced; one of another style is refused, not overwritten (each style
    has its own default root, so this only happens when one root is given for two styles).
    """
    if not 0 <= n_frames <= MAX_FRAMES:
        raise DataError(f"synthetic sequence {sequence}: {n_frames} frames asked; a split holds 0 to {MAX_FRAMES:,}")
    target = Path(root) / "sequences" / sequence
    sweep_stale(target.parent)
    wanted = marker(seed, sequence, n_frames, style)
    look = get_style(style)
    found = json.loads((target / MARKER).read_text()) if (target / MARKER).is_file() else None
    if found == wanted:
        return target
    refuse_foreign_root(Path(root))
    if found is not None:
        if found.get("style", "default") != style:
            raise DataError(
                f"{target} holds synthetic style {found.get('style', 'default')!r}, not {style!r}; not replacing it "
                "(use another root for this style)"
            )
        _retire(target)
    elif target.exists():
        raise DataError(f"{target} exists but was not made by the synthetic generator (no {MARKER}); not touching it")
    from .kitti_writer import write_sequence  # the ray caster (open3d) loads only when frames are made

    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = _owned_temp(target.parent, f".{sequence}-") / sequence
    try:
        write_sequence(tmp, n_frames, seed, workers, look)
        (tmp / MARKER).write_text(json.dumps(wanted, indent=1) + "\n")
        try:
            os.rename(tmp, target)
        except OSError:  # another process finished first; keep its copy if it matches
            if not (target / MARKER).is_file() or json.loads((target / MARKER).read_text()) != wanted:
                raise
    finally:
        shutil.rmtree(tmp.parent, ignore_errors=True)
    return target


def refuse_foreign_root(root: Path) -> None:
    """Generating writes only into a folder that is empty or holds only what the generator made, so a root given
    for real data (a KITTI copy, a nuScenes dataroot) under the synthetic dataset is refused, never written into."""
    if not root.is_dir():
        return
    foreign = [p for p in sorted(root.iterdir()) if not p.name.startswith(".") and p.name != "sequences"]
    sequences = root / "sequences"
    if sequences.is_dir():
        foreign += [p for p in sorted(sequences.iterdir()) if not p.name.startswith(".") and not (p / MARKER).is_file()]
    if foreign:
        names = ", ".join(str(p.relative_to(root)) for p in foreign[:4]) + (", ..." if len(foreign) > 4 else "")
        raise DataError(
            f"synthetic dataset root {root} holds data not made by the synthetic generator ({_looks_like(root)}: "
            f"{names}); not writing into it. To read it, name its dataset (--dataset kitti / nuscenes); to "
            "generate, give an empty or new folder"
        )


def _looks_like(root: Path) -> str:
    if any(p.name.startswith("v1.0-") for p in root.iterdir()) or (root / "samples").is_dir():
        return "it looks like a nuScenes dataroot"
    if any((p / "velodyne").is_dir() or (p / "calib.txt").is_file() for p in root.glob("sequences/*")):
        return "it looks like KITTI Odometry"
    return "files without the generator's marker"


def _retire(target: Path) -> None:
    """Move an outdated sequence aside before deleting it, so readers never see it half-deleted."""
    trash = _owned_temp(target.parent, ".old-")
    os.rename(target, trash / target.name)
    shutil.rmtree(trash, ignore_errors=True)


def _owned_temp(parent: Path, prefix: str) -> Path:
    """a hidden temp folder naming this process as its owner, so a later generation can tell a killed one's."""
    folder = Path(tempfile.mkdtemp(prefix=prefix, dir=parent))
    (folder / OWNER).write_text(str(os.getpid()))
    return folder


OWNER = "owner.pid"


def sweep_stale(sequences: Path) -> None:
    """delete the hidden temp folders of generations that were killed (their owner process is gone); a live
    concurrent generation's are left alone."""
    if not sequences.is_dir():
        return
    for folder in sequences.glob(".*-*"):
        if folder.is_dir() and not _owner_alive(folder):
            shutil.rmtree(folder, ignore_errors=True)


def _owner_alive(folder: Path) -> bool:
    try:
        pid = int((folder / OWNER).read_text())
    except (OSError, ValueError):  # no pid yet (just made) or none ever (made before owners were recorded)
        return time.time() - folder.stat().st_mtime < STALE_AFTER_S
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def generate(
    root: Path | str | None = None,
    n_train: int = 400,
    n_val: int = 20,
    n_test: int = 40,
    seed: int = 0,
    workers: int | None = None,
    style: str = "default",
) -> Path:
    """Generate (or reuse) all three splits under root (default <cache>/synthetic-v{version}-seed{seed},
    with `-{style}` before `-seed` for a style other than the default)."""
    get_style(style)
    root = Path(root).expanduser() if root else default_root(seed, style)
    for split, n in (("train", n_train), ("val", n_val), ("test", n_test)):
        ensure_sequence(root, SPLIT_SEQUENCES[split], n, seed, workers, style)
    return root


class SyntheticStreets(Dataset):
    """Procedural streets seen by a KITTI-like rig; the default dataset, and the one EdgeRegNet trains on."""

    name = "synthetic"
    splits = ("train", "val", "test")
    default_conf: ClassVar[dict[str, Any]] = {
        "root": None,  # None: <cache>/synthetic-v{version}[-{style}]-seed{seed} (or I2PBENCH_SYNTHETIC_ROOT)
        "seed": 0,  # scene seed; every frame is a function of (seed, sequence, index)
        "frames": {"train": 400, "val": 20, "test": 40},  # frames per split (missing keys keep the defaults)
        "workers": None,  # processes for generation; None = all cores
        "style": "default",  # generator style (style.py): "kitti" moves the statistics towards real KITTI's
    }
    match_radius_px = 3.0

    def __init__(self, split: str, conf: Mapping[str, Any] | None = None) -> None:
        super().__init__(split, conf)
        get_style(self.conf["style"])  # an unknown style fails here, before any folder is named or made

    @property
    def root(self) -> Path:
        root = self.conf.get("root") or os.environ.get("I2PBENCH_SYNTHETIC_ROOT")
        return Path(root).expanduser() if root else default_root(int(self.conf["seed"]), self.conf["style"])

    @property
    def n_frames(self) -> int:
        frames = self.conf["frames"] or self.default_conf["frames"]  # merged over the defaults key by key
        return int(frames[self.split])

    def sequence_dir(self) -> Path:
        seed, workers, style = int(self.conf["seed"]), self.conf["workers"], self.conf["style"]
        return ensure_sequence(self.root, SPLIT_SEQUENCES[self.split], self.n_frames, seed, workers, style)

    def frame_ids(self) -> list[str]:
        seq = self.sequence_dir()
        return [f"{seq.name}/{stem}" for stem in sequence_stems(seq)]

    def load(self, frame_id: str) -> SensorFrame:
        sequence, _, stem = frame_id.partition("/")
        if sequence != SPLIT_SEQUENCES[self.split] or not stem:
            raise DataError(
                f"dataset 'synthetic' {self.split}: frame id {frame_id!r} is not of the form "
                f"'{SPLIT_SEQUENCES[self.split]}/NNNNNN'"
            )
        return read_frame(self.sequence_dir(), stem, 2, self.name, self.match_radius_px)

    def frame_files(self, frame_id: str) -> list[Path]:
        """The KITTI-layout files of the frame, without generating the split (the run that loads it will)."""
        sequence, _, stem = frame_id.partition("/")
        return KittiOdometry.layout_files(self.root / "sequences" / sequence, stem)

    def identity(self) -> dict[str, Any]:
        """Generator version, seed, frame count and style fix the data; the folder it sits in does not. The style
        is named only when it is not the default, so results of the default data keep their identity."""
        identity = {
            "dataset": self.name,
            "split": self.split,
            "seed": int(self.conf["seed"]),
            "frames": self.n_frames,
            "generator_version": GENERATOR_VERSION,
        }
        if self.conf["style"] != "default":
            identity["style"] = self.conf["style"]
        return identity
