"""Build a devkit dataroot from record folders (`calib_records.json` + the sample's files), as shipped in shared/data.

A record folder holds one keyframe: its LIDAR_TOP sweep, six camera JPEGs, and the raw devkit records of its
sample, scene and each sensor's sample_data, calibrated_sensor and ego_pose. The devkit wants whole tables, so
this writes the thirteen tables for the keyframes given (samples of one scene chained in time order, sweeps left
out) and links or copies the files under `samples/`, so `NuScenes` reads them like the real dataset.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from ..errors import DataError
from .nuscenes import CAMERAS

RECORDS_FILE = "calib_records.json"
CHANNELS = ("LIDAR_TOP", *CAMERAS)
EMPTY_TABLES = ("category", "attribute", "visibility", "instance", "sample_annotation")
PLACEHOLDER_MAP = "maps/placeholder.png"  # the devkit only checks that a map file exists


def record_folders(paths: Iterable[Path]) -> list[Path]:
    """Each path is a record folder, or a folder of record folders (as `nuscenes_records/` is)."""
    found: list[Path] = []
    for path in map(Path, paths):
        if (path / RECORDS_FILE).is_file():
            found.append(path)
            continue
        inner = sorted(p.parent for p in path.glob(f"*/{RECORDS_FILE}"))
        if not inner:
            raise DataError(f"{path}: no {RECORDS_FILE}, here or in its subfolders")
        found += inner
    return found


def read_records(folder: Path) -> dict[str, Any]:
    path = folder / RECORDS_FILE
    try:
        records = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: unreadable ({exc})") from exc
    missing = [k for k in ("sample", "scene", *CHANNELS) if k not in records]
    if missing:
        raise DataError(f"{path}: no {', '.join(missing)} record(s)")
    return records


def _log(scene: dict[str, Any], filename: str) -> dict[str, Any]:
    """A log record from the file names (`<logfile>__<CHANNEL>__<time>`): the records do not carry the log table."""
    logfile = Path(filename).name.split("__")[0]  # e.g. n015-2018-10-08-15-36-50+0800
    return {"token": scene["log_token"], "logfile": logfile, "vehicle": logfile.split("-")[0],
            "date_captured": logfile[5:15], "location": "unknown"}  # fmt: skip


def _chained(samples: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One scene's samples in time order, prev/next linking only the samples present."""
    ordered = sorted(samples, key=lambda s: s["timestamp"])
    tokens = ["", *(s["token"] for s in ordered), ""]
    return [{**s, "prev": tokens[i], "next": tokens[i + 2]} for i, s in enumerate(ordered)]


def _unique(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    return list({row["token"]: row for row in rows}.values())


def _scenes(records: Sequence[dict[str, Any]]) -> tuple[list[dict], list[dict], list[dict]]:
    """(samples, scenes, logs): each scene's samples chained, its sample count and first/last tokens rewritten."""
    by_scene: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        by_scene.setdefault(r["scene"]["token"], []).append(r)
    samples, scenes, logs = [], [], []
    for group in by_scene.values():
        chain, scene = _chained([r["sample"] for r in group]), group[0]["scene"]
        samples += chain
        scenes.append({**scene, "nbr_samples": len(chain), "first_sample_token": chain[0]["token"],
                       "last_sample_token": chain[-1]["token"]})  # fmt: skip
        logs.append(_log(scene, group[0]["LIDAR_TOP"]["sample_data"]["filename"]))
    return samples, scenes, _unique(logs)


def tables(records: Sequence[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """The devkit tables for these keyframes (one record set each; a sample given twice counts once)."""
    records = list({r["sample"]["token"]: r for r in records}.values())
    samples, scenes, logs = _scenes(records)
    per_channel = [(c, r[c]) for r in records for c in CHANNELS]
    sensors = ({"token": d["calibrated_sensor"]["sensor_token"], "channel": c, "modality": c.split("_")[0].lower()}
               for c, d in per_channel)  # fmt: skip
    return {
        **{name: [] for name in EMPTY_TABLES},
        "sensor": _unique(sensors),
        "calibrated_sensor": _unique(d["calibrated_sensor"] for _, d in per_channel),
        "ego_pose": _unique(d["ego_pose"] for _, d in per_channel),
        "log": logs,
        "scene": scenes,
        "sample": samples,
        "sample_data": [{**d["sample_data"], "prev": "", "next": ""} for _, d in per_channel],  # no sweeps here
        "map": [{"token": "placeholder", "log_tokens": [log["token"] for log in logs], "category": "semantic_prior",
                 "filename": PLACEHOLDER_MAP}],
    }  # fmt: skip


def build_dataroot(
    folders: Sequence[Path], root: Path, version: str = "v1.0-trainval", copy: bool = False
) -> dict[str, int]:
    """Write `root/<version>/*.json` and `root/samples/...` (symlinks, or copies with `copy`); returns table sizes.

    Refuses a root that already holds this version, so a dataroot is never half-overwritten.
    """
    root = Path(root)
    if (root / version).exists():
        raise DataError(f"{root / version} already exists; choose another --out or remove it")
    folders = record_folders(folders)
    records = [read_records(f) for f in folders]
    built = tables(records)
    for folder, rec in zip(folders, records, strict=True):
        for channel in CHANNELS:
            _place(folder, root / rec[channel]["sample_data"]["filename"], copy)
    (root / PLACEHOLDER_MAP).parent.mkdir(parents=True, exist_ok=True)
    (root / PLACEHOLDER_MAP).touch()
    (root / version).mkdir(parents=True)
    for name, rows in built.items():
        (root / version / f"{name}.json").write_text(json.dumps(rows, indent=0))
    return {name: len(rows) for name, rows in built.items()}


def _place(folder: Path, target: Path, copy: bool) -> None:
    """Put one sensor file of a record folder at its dataroot path."""
    source = folder / target.name
    if not source.is_file():
        raise DataError(f"{source}: named by {folder / RECORDS_FILE} but not found")
    if target.exists() or target.is_symlink():
        return  # the same keyframe given twice
    target.parent.mkdir(parents=True, exist_ok=True)
    if copy:
        shutil.copyfile(source, target)
    else:
        target.symlink_to(source.resolve())
