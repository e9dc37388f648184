"""The dataset contract shared by KITTI, nuScenes, the synthetic set and third-party datasets."""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from ..errors import DataError, I2PBenchError
from ..stages.config import merge_conf

if TYPE_CHECKING:
    from ..types import SensorFrame


class Dataset:
    """A split of a dataset on disk. Subclasses set `name`, `splits`, `default_conf` and implement two methods.

    `conf["root"]` is the dataset's directory; when None it is read from the environment variable
    `I2PBENCH_<NAME>_ROOT` (e.g. `I2PBENCH_KITTI_ROOT`), so users keep their paths out of commands.
    """

    name: ClassVar[str] = ""
    splits: ClassVar[tuple[str, ...]] = ("train", "val", "test")
    default_conf: ClassVar[dict[str, Any]] = {"root": None}
    match_radius_px: ClassVar[float] = 3.0  # eps_c for this sensor set-up

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "load" in cls.__dict__:
            cls.load = _failing_as_data_error(cls.__dict__["load"])  # type: ignore[method-assign]
        if "frame_ids" in cls.__dict__:
            cls.frame_ids = _utf8_frame_ids(cls.__dict__["frame_ids"])  # type: ignore[method-assign]

    def __init__(self, split: str, conf: Mapping[str, Any] | None = None) -> None:
        if split not in self.splits:
            raise DataError(f"dataset {self.name!r} has no split {split!r}; choose one of {list(self.splits)}")
        self.split = split
        self.conf = merge_conf(self.default_conf, conf, f"dataset {self.name!r}")

    @property
    def root(self) -> Path:
        root = self.conf.get("root") or os.environ.get(f"I2PBENCH_{self.name.upper().replace('-', '_')}_ROOT")
        if not root:
            raise DataError(
                f"dataset {self.name!r}: no root directory; pass --data-root or set "
                f"I2PBENCH_{self.name.upper().replace('-', '_')}_ROOT"
            )
        return Path(root).expanduser()

    def frame_ids(self) -> list[str]:
        """Sorted ids of the frames in this split."""
        raise NotImplementedError

    def load(self, frame_id: str) -> SensorFrame:
        """Read one frame; raise DataError naming the file when it is malformed."""
        raise NotImplementedError

    def identity(self) -> dict[str, Any]:
        """What identifies this data for caching and leaderboards."""
        return {"dataset": self.name, "split": self.split, "root": str(self.conf.get("root") or "")}

    def sequence_of(self, frame_id: str) -> str:
        """The sequence, drive or scene a frame belongs to (a leaderboard's per-sequence breakdown); the default,
        the frame id's folder, is a KITTI sequence or drive."""
        return frame_id.partition("/")[0]

    def frame_files(self, frame_id: str) -> list[Path]:
        """The files `load(frame_id)` reads, so a cached result is dropped once one of them changes.

        The default, none, keys a frame's results by its id alone, as for a dataset that cannot list its files.
        """
        return []

    def fingerprint(self, frame_id: str) -> list[list[int] | None]:
        """The state of the frame's files, part of its cache key; override for data that lives outside files."""
        return [file_stamp(path) for path in self.frame_files(frame_id)]


def file_stamp(path: Path) -> list[int] | None:
    """[size, mtime_ns, ctime_ns] of a file, None when it is absent.

    Stats, not a content hash: hashing reads every frame (~3 MB a KITTI frame, ~4 ms at 725 MB/s from the page
    cache), which would turn a fully cached rerun of a large split into minutes of I/O. ctime catches what size and
    mtime miss: a same-size repair written back with its old mtime (cp -p, rsync -a) still moves ctime, which no
    user call can set.
    """
    try:
        st = path.stat()
    except OSError:  # absent or unreadable: load() reports it, and the frame is recomputed once that changes
        return None
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns]


def _failing_as_data_error(load: Callable[[Any, str], SensorFrame]) -> Callable[[Any, str], SensorFrame]:
    """Wrap a subclass's `load` so that any exception becomes a DataError naming the dataset and frame.

    Why here, once: the runner and its workers turn an I2PBenchError from `load` into a failed frame and the CLI
    into a one-line error, so a reader's own bug (a LinAlgError, a KeyError in a third-party dataset) fails that
    frame, named, in every caller instead of ending the run with a traceback.
    """

    @functools.wraps(load)
    def wrapped(self: Dataset, frame_id: str) -> SensorFrame:
        raw = self.__dict__.get(NOT_UTF8, {}).get(frame_id)
        if raw is not None:
            raise DataError(_not_utf8(self, frame_id, raw))
        try:
            return load(self, frame_id)
        except I2PBenchError:
            raise
        except Exception as exc:
            raise DataError(f"dataset {self.name!r} frame {frame_id!r}: {type(exc).__name__}: {exc}") from exc

    return wrapped


NOT_UTF8 = "_frame_ids_not_utf8"  # instance attribute: a listed id as shown -> the id as the file system gave it


def printable(text: str) -> str:
    """`text` as UTF-8 can hold it: a byte of a file name that is no UTF-8 (a surrogate in the str os.listdir made
    of it) becomes `\\xNN`, as `ls -b` shows it."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a lone surrogate that is no escaped byte (e.g. from JSON's \\ud800)
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def _utf8_frame_ids(frame_ids: Callable[[Any], list[str]]) -> Callable[[Any], list[str]]:
    """Wrap a subclass's `frame_ids` so that every id is UTF-8: an id made of a file name that is not (fault 9 of
    issue 31) is listed as `printable` shows it and remembered, so that `load` fails that one frame naming the file,
    while cache keys, Parquet records and invocation records, all UTF-8, never meet the raw name (it ended the whole
    run with a UnicodeEncodeError)."""

    @functools.wraps(frame_ids)
    def wrapped(self: Dataset) -> list[str]:
        ids = frame_ids(self)
        shown = [printable(i) for i in ids]
        for i, s in zip(ids, shown, strict=True):
            if s != i:
                self.__dict__.setdefault(NOT_UTF8, {})[s] = i
        return shown

    return wrapped


def _not_utf8(dataset: Dataset, frame_id: str, raw: str) -> str:
    files = [printable(str(p)) for p in dataset.frame_files(raw) if printable(str(p)) != str(p)]
    named = ", ".join(files) if files else f"frame {frame_id}"
    return (
        f"dataset {dataset.name!r} frame '{frame_id}': the file name is not UTF-8 ({named}), which results cannot "
        "store; rename it"
    )
