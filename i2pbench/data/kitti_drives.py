"""Real KITTI frames from several folders, split by scene through a committed split file (`splits/NAME.yaml`).

A split file names scenes (the unit of every split: a raw drive, or several folders' sequences showing one place)
and lists the scenes of train, val and test. `fold: K/N` replaces those lists by k-fold cross-validation over all
the file's scenes: the scenes, in the file's order (largest first), are dealt to N folds snake-wise (0, 1, .., N-1,
N-1, .., 0, ...), so folds differ by at most one scene and their frame counts stay close; fold K is `test`, fold
K + 1 (mod N) is `val` (checkpoint selection never sees the test fold) and the other N - 2 folds are `train`.
Frames are read in place, `<root>/<folder>/sequences/<seq>/...` (the KITTI Odometry layout), with ids `SEQ/STEM`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import yaml

from ..errors import DataError
from ..types import SensorFrame
from . import yaml_input
from .base import Dataset
from .kitti import KittiOdometry, read_frame, sequence_stems

SPLITS_DIR = Path(__file__).resolve().parent / "splits"
DEFAULT_SPLIT_FILE = "kitti-real-drives"
SPLIT_NAMES = ("train", "val", "test")


@dataclass(frozen=True)
class SplitFile:
    """scenes: name -> its sequences (`folder/seq`), in the file's order; splits: train/val/test -> scene names."""

    name: str
    path: Path
    sha256: str
    scenes: dict[str, tuple[str, ...]]
    splits: dict[str, tuple[str, ...]]

    def sequences(self, scenes: tuple[str, ...] | list[str]) -> list[str]:
        return [seq for scene in scenes for seq in self.scenes[scene]]


def split_file_path(name_or_path: str | Path) -> Path:
    """a committed split's name (`kitti-real-drives`) or a path to a split file."""
    text = str(name_or_path)
    committed = SPLITS_DIR / f"{text}.yaml"
    if "/" not in text and not text.endswith((".yaml", ".yml")) and committed.is_file():
        return committed
    path = Path(text).expanduser()
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in SPLITS_DIR.glob("*.yaml")))
        raise DataError(f"split file {text!r} not found (neither a file nor a committed split: {known})")
    return path


def load_split_file(name_or_path: str | Path) -> SplitFile:
    """read and check a split file: every sequence in one scene, every scene in exactly one of train/val/test,
    sequence names unique across folders (they are the frame ids' first part)."""
    path = split_file_path(name_or_path)
    raw = path.read_bytes()
    try:
        data = yaml_input.load(raw)
    except yaml.YAMLError as exc:
        raise DataError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("scenes"), dict):
        raise DataError(f"{path}: expected a mapping with scenes: {{name: [folder/seq, ...]}} and train/val/test lists")
    scenes = {str(k): tuple(str(s) for s in (v or [])) for k, v in data["scenes"].items()}
    splits = {s: tuple(str(x) for x in (data.get(s) or [])) for s in SPLIT_NAMES}
    _check(path, scenes, splits)
    return SplitFile(str(data.get("name") or path.stem), path, hashlib.sha256(raw).hexdigest(), scenes, splits)


def _check(path: Path, scenes: dict[str, tuple[str, ...]], splits: dict[str, tuple[str, ...]]) -> None:
    owner: dict[str, str] = {}
    for scene, sequences in scenes.items():
        if not sequences:
            raise DataError(f"{path}: scene {scene!r} lists no sequence")
        for seq in sequences:
            folder, sep, name = seq.rpartition("/")
            if not sep or not folder or not name:
                raise DataError(f"{path}: scene {scene!r}: {seq!r} is not FOLDER/SEQ")
            if name in owner:
                raise DataError(f"{path}: sequence name {name!r} appears twice ({owner[name]!r} and {scene!r})")
            owner[name] = scene
    placed: dict[str, str] = {}
    for split, names in splits.items():
        for scene in names:
            if scene not in scenes:
                raise DataError(f"{path}: {split} lists {scene!r}, which is no scene of the file")
            if scene in placed:
                raise DataError(f"{path}: scene {scene!r} is in both {placed[scene]} and {split}")
            placed[scene] = split
    left = [s for s in scenes if s not in placed]
    if left:
        raise DataError(f"{path}: scenes in no split: {', '.join(left)}")


def parse_fold(text: str) -> tuple[int, int]:
    """`"2/5"` -> (2, 5): fold K of N, 1 <= K <= N, N >= 3 (a test fold, a val fold and at least one to train)."""
    k, sep, n = str(text).partition("/")
    try:
        fold, folds = int(k), int(n)
    except ValueError:
        fold = folds = 0
    if not sep or folds < 3 or not 1 <= fold <= folds:
        raise DataError(f"fold {text!r}: expected K/N with N >= 3 and 1 <= K <= N (e.g. 2/5)")
    return fold, folds


def deal_folds(scenes: list[str], folds: int) -> list[list[str]]:
    """scenes dealt to `folds` folds snake-wise in their order: fold sizes differ by at most one."""
    out: list[list[str]] = [[] for _ in range(folds)]
    for i, scene in enumerate(scenes):
        lap, pos = divmod(i, folds)
        out[pos if lap % 2 == 0 else folds - 1 - pos].append(scene)
    return out


def fold_splits(split_file: SplitFile, fold: int, folds: int) -> dict[str, tuple[str, ...]]:
    """train/val/test scene lists of fold `fold` (1-based) of `folds` over all the file's scenes."""
    if folds > len(split_file.scenes):
        raise DataError(f"fold {fold}/{folds}: {split_file.name} has only {len(split_file.scenes)} scenes")
    dealt = deal_folds(list(split_file.scenes), folds)
    test, val = fold - 1, fold % folds
    train = [s for i, f in enumerate(dealt) if i not in (test, val) for s in f]
    return {"train": tuple(train), "val": tuple(dealt[val]), "test": tuple(dealt[test])}


def _recorded_split_file(conf: dict[str, Any] | None) -> tuple[dict[str, Any] | None, str | None]:
    """a config whose split_file is a run's record of it (`{name, sha256}`, as `identity()` writes it, so a report
    reopens the run's split) as one naming the file, and the sha256 the file must still have."""
    recorded = (conf or {}).get("split_file")
    if not isinstance(recorded, dict) or set(recorded) != {"name", "sha256"}:
        return conf, None
    return {**conf, "split_file": recorded["name"]}, recorded["sha256"]


class KittiDrives(Dataset):
    """Real KITTI drives from several folders, split by scene by a split file (default: the committed
    kitti-real-drives over ../shared/data's kitti_drives, kitti_real and kitti_odometry); `fold: K/N` for k-fold
    cross-validation by scene; "all" = every scene."""

    name = "kitti-drives"
    splits = ("train", "val", "test", "all")
    default_conf: ClassVar[dict[str, Any]] = {
        "root": None,  # holds the split file's folders (../shared/data); None reads I2PBENCH_KITTI_DRIVES_ROOT
        "split_file": DEFAULT_SPLIT_FILE,  # a committed split's name (i2pbench/data/splits/NAME.yaml) or a file path
        "fold": None,  # "K/N": k-fold by scene over all the file's scenes (test = fold K, val = fold K + 1)
        "camera": 2,  # 2 (left colour) or 3 (right colour)
    }
    match_radius_px = KittiOdometry.match_radius_px

    def __init__(self, split: str, conf: dict[str, Any] | None = None) -> None:
        conf, recorded = _recorded_split_file(conf)
        super().__init__(split, conf)
        if self.conf["camera"] not in (2, 3):
            raise DataError(f"dataset {self.name!r}: camera must be 2 or 3, got {self.conf['camera']!r}")
        self.split_file = load_split_file(self.conf["split_file"])
        if recorded is not None and recorded != self.split_file.sha256:
            raise DataError(
                f"dataset {self.name!r}: split file {self.split_file.path} has sha256 {self.split_file.sha256[:12]}, "
                f"not the run's {str(recorded)[:12]}: its scenes changed since the run"
            )
        self.fold = parse_fold(self.conf["fold"]) if self.conf["fold"] is not None else None
        self._ids: list[str] | None = None
        self._dirs: dict[str, Path] | None = None

    def scenes(self) -> tuple[str, ...]:
        """the scenes of this split (of this fold, with `fold`)."""
        if self.split == "all":
            return tuple(self.split_file.scenes)
        splits = fold_splits(self.split_file, *self.fold) if self.fold else self.split_file.splits
        return splits[self.split]

    def sequence_dirs(self) -> dict[str, Path]:
        """sequence name -> its folder on disk, for this split's scenes; every one must exist."""
        if self._dirs is not None:
            return self._dirs
        out = {}
        for seq in self.split_file.sequences(self.scenes()):
            folder, _, name = seq.rpartition("/")
            path = self.root / folder / "sequences" / name
            if not path.is_dir():
                raise DataError(f"dataset {self.name!r}: {path} not found (sequence {seq} of {self.split_file.path})")
            out[name] = path
        self._dirs = out
        return out

    def frame_ids(self) -> list[str]:
        if self._ids is None:
            camera = self.conf["camera"]
            ids = [f"{n}/{stem}" for n, d in sorted(self.sequence_dirs().items()) for stem in sequence_stems(d, camera)]
            if not ids:
                raise DataError(f"dataset {self.name!r}: no frames for split {self.split!r}")
            self._ids = ids
        return list(self._ids)

    def scene_of(self, frame_id: str) -> str:
        """the scene a frame belongs to (the unit to resample when putting an interval on a score)."""
        seq = frame_id.partition("/")[0]
        for scene, sequences in self.split_file.scenes.items():
            if any(s.rpartition("/")[2] == seq for s in sequences):
                return scene
        raise DataError(f"dataset {self.name!r}: frame {frame_id!r} is in no scene of {self.split_file.name}")

    def _sequence_dir(self, frame_id: str) -> tuple[Path, str]:
        sequence, sep, stem = frame_id.partition("/")
        dirs = self.sequence_dirs()
        if not sep or sequence not in dirs:
            raise DataError(f"dataset {self.name!r}: frame id {frame_id!r} is not SEQ/STEM of split {self.split!r}")
        return dirs[sequence], stem

    def load(self, frame_id: str) -> SensorFrame:
        directory, stem = self._sequence_dir(frame_id)
        return read_frame(directory, stem, self.conf["camera"], self.name, self.match_radius_px)

    def frame_files(self, frame_id: str) -> list[Path]:
        directory, stem = self._sequence_dir(frame_id)
        return KittiOdometry.layout_files(directory, stem, self.conf["camera"])

    @property
    def board_suffix(self) -> str:
        """what tells this split's boards from another fold's or split file's: `-fold2of5`, `-<file>`."""
        own = "" if self.split_file.name == DEFAULT_SPLIT_FILE else f"-{self.split_file.name}"
        return own + (f"-fold{self.fold[0]}of{self.fold[1]}" if self.fold else "")

    def identity(self) -> dict[str, Any]:
        fold = f"{self.fold[0]}/{self.fold[1]}" if self.fold else None
        split_file = {"name": self.split_file.name, "sha256": self.split_file.sha256}
        return {**super().identity(), "camera": self.conf["camera"], "split_file": split_file, "fold": fold}
