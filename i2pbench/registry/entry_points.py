"""The entry points of a group, found with importlib.metadata once per change of the installed distributions.

Finding them costs ~30 ms a start, a third of `i2pbench plugins`: importing importlib.metadata loads the email
package, then it reads every installed distribution. So what it finds is kept in the cache folder (`i2pbench.paths`:
$XDG_CACHE_HOME/i2pbench, else ~/.cache/i2pbench; a file per interpreter) with a fingerprint of what it read: the
`.dist-info` and `.egg-info` folders in the folders on sys.path (installing or removing a distribution adds or
removes one), the time and size of their entry points and metadata (a reinstall in place rewrites them), and the
time and size of each sys.path entry that is no folder (a zip). A start with the stored fingerprint reads the file
(~3 ms); any other finds the entry points anew and stores them. A cache that cannot be written costs only that;
deleting it is always safe.
"""

from __future__ import annotations

import functools
import importlib
import json
import os
import re
import sys
import zlib
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

from ..paths import cache_home

if TYPE_CHECKING:
    from importlib.metadata import Distribution

METADATA_FILE = {".dist-info": "METADATA", ".egg-info": "PKG-INFO"}  # a distribution folder's name and version
# an object reference, `module` or `module:attr.attr`, and the extras old distributions add (as importlib.metadata)
REFERENCE = re.compile(r"(?P<module>[\w.]+)\s*(:\s*(?P<attr>[\w.]+)\s*)?((?P<extras>\[.*\])\s*)?$")


@dataclass(frozen=True)
class EntryPoint:
    """What importlib.metadata.EntryPoint gives of an entry point, with its distribution's version and name."""

    name: str
    value: str  # the object reference, e.g. "i2pbench_classic.plugin"
    version: str  # of the distribution that offers it ("?" when there is none)
    distribution: str

    def load(self) -> Any:
        """The object the entry point names, imported (as importlib.metadata.EntryPoint.load)."""
        match = REFERENCE.match(self.value)
        if match is None:
            raise ValueError(f"{self.value!r} is no object reference, 'module' or 'module:attr'")
        attrs = match["attr"].split(".") if match["attr"] else []
        return functools.reduce(getattr, attrs, importlib.import_module(match["module"]))


def installed(group: str) -> list[EntryPoint]:
    """The entry points of `group` in the installed distributions, as importlib.metadata finds them."""
    folder = str(cache_home())
    if folder.startswith("~"):  # no home folder to keep them in (and no absolute XDG_CACHE_HOME)
        return _find(group)
    path = os.path.join(folder, f"entry-points-{zlib.crc32(sys.executable.encode()):08x}.json")
    fingerprint = [sys.version, group, *_fingerprint()]
    try:
        with open(path) as file:
            stored = json.load(file)
        if stored["fingerprint"] == fingerprint:
            return [EntryPoint(**ep) for ep in stored["entry_points"]]
    except (OSError, ValueError, KeyError, TypeError):  # none yet, or not ours: found anew
        pass
    found = _find(group)
    try:
        os.makedirs(folder, exist_ok=True)
        with open(f"{path}.{os.getpid()}", "w") as file:
            json.dump({"fingerprint": fingerprint, "entry_points": [asdict(ep) for ep in found]}, file)
        os.replace(f"{path}.{os.getpid()}", path)  # whole, whatever other processes write
    except OSError:
        pass
    return found


def _find(group: str) -> list[EntryPoint]:
    import importlib.metadata

    about = functools.cache(_version_and_name)  # the entry points of one distribution share its object
    return [EntryPoint(ep.name, ep.value, *about(ep.dist)) for ep in importlib.metadata.entry_points(group=group)]


def _version_and_name(dist: Distribution | None) -> tuple[str, str]:
    """A distribution's version and name from one parse of its metadata (`dist.version` parses it again)."""
    if dist is None:
        return "?", "?"
    metadata = dist.metadata
    return metadata["Version"], metadata["Name"]


def _fingerprint() -> list[list[Any]]:
    """What importlib.metadata reads to find the distributions, as it stands now: the distributions in the folders
    on sys.path, in order, and each entry that is no folder (a zip, or missing). Folders without any (the script's,
    the current one) leave no mark, so `i2pbench` and `python -m i2pbench.cli` share the cache."""
    marks: list[list[Any]] = []
    for entry in sys.path:
        try:
            children = os.scandir(os.path.abspath(entry))
        except OSError:
            marks.append([entry, *_stamp(entry)])
            continue
        with children:
            for child in children:
                name = child.name.lower()
                kind = ".egg-info" if name == "egg-info" else os.path.splitext(name)[1]  # an egg's EGG-INFO too
                if kind in METADATA_FILE and child.is_dir():
                    files = [os.path.join(child.path, file) for file in ("entry_points.txt", METADATA_FILE[kind])]
                    marks.append([child.path, *_stamp(files[0]), *_stamp(files[1])])
                elif kind == ".egg-info":  # a file: the metadata alone
                    marks.append([child.path, *_stamp(child.path)])
    return marks


def _stamp(path: str) -> tuple[int, int]:
    """(modification time, size) of `path`; (0, -1) when there is none."""
    try:
        stat = os.stat(path)
    except OSError:
        return 0, -1
    return stat.st_mtime_ns, stat.st_size
