"""Checkpoints with identity: the learned stages' state dicts plus what they were trained with and on.

A checkpoint belongs to the combination of learned stages (and extractors) it was trained with; loading it into a
pipeline whose learned stages differ in name or config is refused. Files are read with `weights_only=True`.
"""

from __future__ import annotations

import datetime
import functools
import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import WeightsError
from .pipeline import Pipeline, pretrained_sources
from .provenance import git_commit

if TYPE_CHECKING:  # checkpoints are read and written where a learned stage runs, not by every run
    import torch

FORMAT = "i2pbench-checkpoint/1"
EXTRACTOR_KINDS = ("extractor2d", "extractor3d")


@dataclass(frozen=True)
class Checkpoint:
    path: Path
    meta: dict[str, Any]
    state: dict[str, dict[str, torch.Tensor]]  # stage kind -> state dict

    @functools.cached_property
    def identity(self) -> str:
        """`<file stem>@<first 8 hex of the file's sha256>`: names the exact bytes that produced a result (read
        once: a file rewritten later is another checkpoint, loaded anew)."""
        return f"{self.path.stem}@{file_digest(self.path)[:8]}"

    @property
    def trained_on(self) -> str:
        """`dataset/split, N steps`, after the stages it was fine-tuned from: `synthetic/train 6500 + kitti/train,
        7000 steps` (steps are cumulative: the last figure is the checkpoint's total); a mixed-in source follows its
        phase's main dataset with its share: `synthetic/train + kitti/train (0.5), 7000 steps`. Steps of more than
        one frame say so (`4250 steps of 2 frames`), so rows trained on batches compare by frames seen."""
        batch = (self.meta.get("train_config") or {}).get("effective_batch") or 1
        steps = f"{self.meta.get('steps', '?')} steps" + (f" of {batch} frames" if batch > 1 else "")
        here = data_label(self.meta.get("trained_on", {}))
        if "steps" in self.meta or "release" not in self.meta.get("trained_on", {}):  # an import counts no steps
            here += f", {steps}"
        earlier = [f"{data_label(d)} {d.get('steps', '?')}" for d in self.lineage]
        return " + ".join([*earlier, here])

    @property
    def lineage(self) -> list[dict[str, Any]]:
        """the data of earlier training phases this checkpoint continued from, oldest first."""
        return list(self.meta.get("lineage", []))


def data_label(data: dict[str, Any]) -> str:
    """`dataset/split` of a training phase's data, then `+ dataset/split (share)` per mixed-in source; a dataset
    made in a non-default style says which: `synthetic[kitti]/train`."""
    mixed = [f" + {_source(m)} ({m.get('share', '?')})" for m in data.get("mix", [])]
    return _source(data) + "".join(mixed)


def _source(data: dict[str, Any]) -> str:
    if "release" in data:  # weights imported from another code base: who trained them, on what
        return str(data["release"])
    style = f"[{data['style']}]" if data.get("style") else f"[fold {data['fold']}]" if data.get("fold") else ""
    return f"{data.get('dataset', '?')}{style}/{data.get('split', '?')}"


@dataclass(frozen=True)
class ImportedWeights:
    """What a method's importer (`Method.importers`) makes of another code base's checkpoint."""

    size: str  # the method's size whose learned stages the state fills
    state: dict[str, dict[str, torch.Tensor]]  # stage kind -> state dict, in the stages' own layout
    trained_on: dict[str, Any]  # {"release": "who trained it on what"}, recorded as the checkpoint's training data
    meta: dict[str, Any]  # anything else worth recording (the source's format)


def import_weights(registry: Any, importer: str, source: str | Path, out: str | Path) -> Path:
    """Run a method's importer on `source` and save its weights at `out` as a checkpoint of the importer's size,
    recording the source file's name and sha256; a state that does not load exactly is refused."""
    import importlib

    from .grid import expand

    owners = {name: m for m in registry.methods.values() for name in m.importers}
    if importer not in owners:
        known = ", ".join(sorted(owners)) or "none"
        raise WeightsError(f"unknown weights importer {importer!r} (known: {known})")
    source = Path(source)
    if not source.is_file():
        raise WeightsError(f"{source} does not exist")
    method = owners[importer]
    module, _, function = method.importers[importer].partition(":")
    imported = getattr(importlib.import_module(module), function)(source)
    pipeline = Pipeline.build(registry, expand([method.row(imported.size)], {}, None, registry)[0])
    for kind, module_ in pipeline.learned_modules().items():
        try:
            module_.load_state_dict(imported.state[kind])
        except (KeyError, RuntimeError) as exc:
            raise WeightsError(f"{source}: the {importer} import does not load into {module_.label}: {exc}") from exc
    origin = {"file": source.name, "sha256": file_digest(source), "importer": importer, **imported.meta}
    return save_checkpoint(out, pipeline, trained_on=imported.trained_on, imported_from=origin)


def load_init(module: torch.nn.Module, path: str | Path) -> dict[str, str]:
    """Initialise a learned stage from a plain state dict of its own keys (e.g. Magic Leap's `superpoint_v1.pth` for
    a SuperPoint encoder), strictly: a missing, unexpected or misshaped key is refused by name. -> what to record."""
    import torch

    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise WeightsError(f"{path} is not a readable torch file: {exc}") from exc
    state = state.get("state_dict", state) if isinstance(state, dict) else state
    try:
        module.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise WeightsError(f"{path} does not initialise {getattr(module, 'label', module)}: {exc}") from exc
    return {"file": path.name, "sha256": file_digest(path)}


def file_digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def content_digest(meta_text: str, state: dict[str, dict[str, torch.Tensor]]) -> str:
    """sha256 of the metadata and every tensor's bytes, in a fixed order: torch's loader skips the zip CRCs, so a
    flipped bit in a weight would otherwise load silently."""
    import torch

    h = hashlib.sha256(meta_text.encode())
    for kind in sorted(state):
        for name in sorted(state[kind]):
            tensor = state[kind][name]
            h.update(f"{kind}.{name}:{tensor.dtype}:{tuple(tensor.shape)}".encode())
            h.update(tensor.detach().cpu().contiguous().view(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def stage_signature(pipeline: Pipeline) -> dict[str, dict[str, Any]]:
    """Name and config of every learned stage and extractor: what a checkpoint must agree with."""
    kinds = list(pipeline.learned_modules()) + [k for k in EXTRACTOR_KINDS if k in pipeline.stages]
    return {k: {"name": pipeline.stages[k].name, "conf": _jsonable(pipeline.stages[k].conf)} for k in sorted(kinds)}


def _jsonable(value: Any) -> Any:
    return json.loads(json.dumps(value, default=str))


def save_checkpoint(path: str | Path, pipeline: Pipeline, **meta: Any) -> Path:
    """Write atomically (temp file + rename), so an interrupted save never leaves a truncated checkpoint."""
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    full_meta = {
        "format": FORMAT,
        "stages": stage_signature(pipeline),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "git_commit": git_commit(),
        "size_mb": round(pipeline.model_size_mb(), 3),
        "torch": torch.__version__,
        **_jsonable(meta),
    }
    state = {k: m.state_dict() for k, m in pipeline.learned_modules().items()}
    meta_text = json.dumps(full_meta)
    payload = {"meta": meta_text, "state": state, "sha256": content_digest(meta_text, state)}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        torch.save(payload, tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a checkpoint is data to share
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def load_checkpoint(path: str | Path) -> Checkpoint:
    """The checkpoint at path, verified; a file read before and unchanged since (size, mtime, ctime) is not read
    again, so `--weights auto` over a grid of combinations reads each shipped file once."""
    path = Path(path)
    if not path.is_file():
        if path.is_dir():
            raise WeightsError(f"checkpoint {path} is a folder, not a checkpoint file")
        if not path.parent.is_dir():
            raise WeightsError(f"checkpoint {path}: its folder {path.parent} does not exist")
        raise WeightsError(f"checkpoint {path} does not exist")
    stat = path.stat()
    return _read_checkpoint(path, (stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns))


@functools.lru_cache(maxsize=8)  # a few shipped checkpoints of ~10 MB each
def _read_checkpoint(path: Path, stamp: tuple[int, int, int]) -> Checkpoint:
    import torch

    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        meta = json.loads(payload["meta"])
        state = payload["state"]
    except Exception as exc:
        raise WeightsError(f"checkpoint {path} is not a readable i2pbench checkpoint: {_unreadable(exc)}") from exc
    recorded = payload.get("sha256")  # absent in checkpoints written before it was recorded: nothing to check
    if recorded is not None and recorded != content_digest(payload["meta"], state):
        raise WeightsError(
            f"checkpoint {path} is corrupt: its content no longer matches the sha256 recorded when it was saved "
            "(flipped bytes on disk or in transfer); restore it from a good copy"
        )
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        found = meta.get("format") if isinstance(meta, dict) else meta
        raise WeightsError(f"checkpoint {path} has format {found!r}, expected {FORMAT!r}")
    problem = _meta_problem(meta, state)
    if problem:
        raise WeightsError(f"checkpoint {path} is malformed: {problem}; refusing it")
    return Checkpoint(path, meta, state)


def _unreadable(exc: Exception) -> str:
    """Why torch could not read a file, in one line. torch's own message for a pickle of other objects advises
    `weights_only=False`, which would run whatever code the file holds: i2pbench never does, nor advises it."""
    text = str(exc).strip()
    if "weights_only" in text or "Unpickl" in type(exc).__name__:
        return "it holds Python objects, not only tensors (not a file i2pbench wrote), and is not unpickled"
    if isinstance(exc, KeyError):
        return f"no {text} entry (a torch file, but not an i2pbench checkpoint)"
    return text.splitlines()[0] if text else f"{type(exc).__name__} (an empty or cut-short file)"


def _meta_problem(meta: dict[str, Any], state: Any) -> str | None:
    """what in a checkpoint's metadata or state is not of the shape the loaders read (None: all is), so a
    hand-edited or foreign file is refused naming the field instead of failing later on an attribute."""
    stages = meta.get("stages")
    if not isinstance(stages, dict):
        return f"meta field 'stages' is {type(stages).__name__}, not an object of stage kind -> name and conf"
    for kind, sig in stages.items():
        if not (isinstance(sig, dict) and isinstance(sig.get("name"), str) and isinstance(sig.get("conf"), dict)):
            return f"meta field 'stages.{kind}' is not an object with a 'name' string and a 'conf' object"
    for field, kind in (("trained_on", dict), ("lineage", list), ("train_config", dict), ("validation", dict)):
        if field in meta and meta[field] is not None and not isinstance(meta[field], kind):
            return (
                f"meta field {field!r} is {type(meta[field]).__name__}, not {'an object' if kind is dict else 'a list'}"
            )
    if any(not isinstance(d, dict) for d in meta.get("lineage") or []):
        return "meta field 'lineage' holds an entry that is not an object"
    if not isinstance(state, dict) or any(not isinstance(v, dict) for v in state.values()):
        return "its state is not an object of stage kind -> state dict"
    return None


def mismatch(checkpoint: Checkpoint, pipeline: Pipeline, *, strict_extractors: bool) -> str | None:
    """Why this checkpoint does not fit the pipeline, or None if it does."""
    want, have = stage_signature(pipeline), checkpoint.meta["stages"]
    kinds = set(want) | set(have)
    if not strict_extractors:
        kinds -= set(EXTRACTOR_KINDS)
    learned = pipeline.learned_modules()
    for kind in sorted(kinds):
        runtime = learned[kind].runtime_keys if kind in learned else frozenset()  # a LearnedComponent declares them
        w, h = _without(want.get(kind), runtime), _without(have.get(kind), runtime)
        if w != h:
            return (
                f"{kind}: the pipeline has {_short(w)} but checkpoint {checkpoint.path.name} was trained with "
                f"{_short(h)}"
            )
    return None


def _without(sig: dict[str, Any] | None, keys: frozenset[str]) -> dict[str, Any] | None:
    """A stage signature less its runtime-only config keys (checkpoints store them all, for the record)."""
    if sig is None or not keys:
        return sig
    return {**sig, "conf": {k: v for k, v in sig["conf"].items() if k not in keys}}


def _short(sig: dict[str, Any] | None) -> str:
    return "nothing" if sig is None else f"{sig['name']!r} {sig['conf']}"


def apply_checkpoint(pipeline: Pipeline, checkpoint: Checkpoint) -> None:
    """Load the state dicts and stamp the pipeline with the checkpoint's identity."""
    reason = mismatch(checkpoint, pipeline, strict_extractors=False)
    if reason:
        raise WeightsError(f"refusing checkpoint: {reason}")
    for kind, module in pipeline.learned_modules().items():
        try:
            module.load_state_dict(checkpoint.state[kind])
        except (KeyError, RuntimeError) as exc:
            raise WeightsError(f"checkpoint {checkpoint.path}: cannot load {module.label}: {exc}") from exc
    pipeline.weights_identity = checkpoint.identity
    # the summary string wins; a stage trained over pretrained weights names them, as an untrained row does
    pretrained = pretrained_sources(pipeline.learned_modules())
    trained_on = checkpoint.trained_on + (f" (from {', '.join(pretrained)})" if pretrained else "")
    pipeline.weights_meta = {**checkpoint.meta, "trained_on": trained_on}


def select_checkpoint(
    pipeline: Pipeline, choice: str, shipped: list[str], dataset: str | None = None
) -> Checkpoint | None:
    """Resolve `--weights`: "untrained", "auto" (a shipped checkpoint trained with exactly these stages), or a path.

    Among shipped checkpoints that fit, "auto" prefers one whose last training phase was on `dataset` (e.g. weights
    fine-tuned on KITTI for a KITTI run), then the one with the fewest phases (trained on one dataset from scratch).
    """
    if not pipeline.learned_modules() or choice == "untrained":
        return None
    if choice != "auto":
        return load_checkpoint(choice)
    fitting = [c for c in map(load_checkpoint, shipped) if mismatch(c, pipeline, strict_extractors=True) is None]
    if not fitting:
        return None

    def preference(checkpoint: Checkpoint) -> tuple[bool, int]:
        last = checkpoint.meta.get("trained_on", {}).get("dataset")
        return (dataset is None or last != dataset, len(checkpoint.lineage))

    return min(fitting, key=preference)  # min is stable: ties keep the registration order
