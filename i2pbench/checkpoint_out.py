"""Where a checkpoint may be written (`train --out`, `weights import --out`): never inside an installed package
(shipped weights, code), never over the file it is made from, never over a file that is not a checkpoint, and over
an existing checkpoint only when asked (`--force`) or when it is a training of ours in progress."""

from __future__ import annotations

import os
from pathlib import Path

from .errors import WeightsError


def package_folders() -> list[Path]:
    """the folders of i2pbench and of every installed i2pbench plugin's top-level package: shipped code and
    weights, which nothing writes into."""
    import importlib.util

    from .entry_points import installed
    from .plugins import ENTRY_POINT_GROUP

    folders = [Path(__file__).resolve().parent]
    for ep in installed(ENTRY_POINT_GROUP):
        top = ep.value.split(":")[0].split(".")[0]
        try:
            spec = importlib.util.find_spec(top)
        except (ImportError, ValueError):  # a broken plugin is reported by the registry, not here
            spec = None
        folders += [Path(p).resolve() for p in getattr(spec, "submodule_search_locations", None) or []]
    return folders


def check_out(out: Path, force: bool, *, writer: str = "training", source: Path | None = None) -> None:
    """refuse an --out that `writer` must never overwrite: inside an installed package, the `source` file it reads,
    a folder, a file that is no i2pbench checkpoint; and an existing checkpoint unless --force (or, for training, a
    training of ours in progress: `<out>.resume` beside it)."""
    out = Path(out)
    where = out.resolve()
    for folder in package_folders():
        if where.is_relative_to(folder):
            raise WeightsError(
                f"--out {out} is inside the installed package {folder}; {writer} never writes there (shipped "
                "weights and code). Write to another path and copy the result if you mean to ship it"
            )
    if source is not None and out.exists() and os.path.samefile(out, source):
        raise WeightsError(f"--out {out} is the file being imported; {writer} never overwrites its source")
    if out.is_dir():
        raise WeightsError(f"--out {out} is a folder; give a checkpoint file path (e.g. {out / 'mine.pt'})")
    if not out.exists():
        return
    _refuse_another_kind(out, writer)
    if writer == "training" and out.with_name(out.name + ".resume").is_file():
        return
    if not force:
        would = "training would overwrite it" if writer == "training" else f"{writer} would replace it"
        resume = f" with no resume file ({out.name}.resume) of a training in progress" if writer == "training" else ""
        raise WeightsError(
            f"--out {out} is an existing checkpoint{resume}; {would}. Give a new --out, or --force to "
            + ("continue training it in place" if writer == "training" else "replace it")
        )


def _refuse_another_kind(out: Path, writer: str) -> None:
    """an existing --out that is not an i2pbench checkpoint (a text file, someone's data) is never overwritten,
    --force or not."""
    from .weights import load_checkpoint

    try:
        load_checkpoint(out)
    except WeightsError as exc:
        raise WeightsError(
            f"--out {out} exists and is no i2pbench checkpoint ({exc}); {writer} never overwrites it. Give another "
            "--out, or move that file aside"
        ) from None
