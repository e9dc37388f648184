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
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import WeightsError, os_problem
from ..runs.provenance import git_commit
from ..stages.pipeline import Pipeline, pretrained_sources

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

    @staticmethod
    def read(path: str | Path) -> dict[str, torch.Tensor]:
        """the state dict in another code base's torch file, for an importer: `read_state_dict`."""
        return read_state_dict(path)

    @staticmethod
    def require_fit(state: Mapping[str, torch.Tensor], expected: Mapping[str, torch.Tensor], what: str) -> None:
        """refuse, naming the keys (the first 12 and a count), a state whose keys or shapes are not exactly
        `expected`'s: every importer's last check before its state becomes a checkpoint. `what` says what the state
        failed to be, as `FILE is not <what>: ...`."""
        problems = [f"missing key {k}" for k in expected if k not in state]
        problems += [f"unexpected key {k}" for k in state if k not in expected]
        problems += [
            f"key {k}: shape {tuple(state[k].shape)}, expected {tuple(v.shape)}"
            for k, v in expected.items()
            if k in state and state[k].shape != v.shape
        ]
        if problems:
            shown = "; ".join(problems[:12]) + (f"; and {len(problems) - 12} more" if len(problems) > 12 else "")
            raise WeightsError(f"{what}: {shown}")


def read_state_dict(path: str | Path) -> dict[str, torch.Tensor]:
    """A plain state dict (parameter name -> tensor) from a torch file, unwrapped from a `{'state_dict': ...}`, read
    with `weights_only` (no code in the file runs). A folder, an empty or text file, a pickle of other objects, a key
    that is no string and a value that is no tensor are refused, naming the file and what is wrong."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise WeightsError(f"{path} is a folder, not a file" if path.is_dir() else f"{path} does not exist")
    if path.stat().st_size == 0:
        raise WeightsError(f"{path} is empty (0 bytes), not a torch file")
    if _is_text(path):
        raise WeightsError(f"{path} is a text file, not a torch file of tensors")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise WeightsError(f"{path} is not a readable torch file: {_unreadable(exc)}") from None
    if isinstance(state, dict) and isinstance(state.get("state_dict"), dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise WeightsError(f"{path} holds a {type(state).__name__}, not a state dict of tensors")
    for key, value in state.items():
        if not isinstance(key, str):
            raise WeightsError(f"{path}: key {key!r} ({type(key).__name__}) is not a parameter name (a string)")
        if not isinstance(value, torch.Tensor):
            raise WeightsError(f"{path}: {key} is a {type(value).__name__}, not a tensor")
    return dict(state)


def _is_text(path: Path) -> bool:
    """whether the file starts as text (torch files start with zip or pickle bytes, which are not UTF-8)."""
    with path.open("rb") as f:
        head = f.read(1024)
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        return exc.start >= len(head) - 3  # a character cut at the 1024th byte is still text
    return b"\0" not in head


def value_problems(state: dict[str, torch.Tensor], own: dict[str, torch.Tensor]) -> list[str]:
    """keys whose tensor cannot stand for the stage's own floating one: a bool, integer or complex tensor (loading
    casts it silently: True becomes 1.0), or one holding NaN or inf (which surfaces only frame by frame)."""
    import torch

    problems = []
    for key, value in state.items():
        if key not in own or not own[key].is_floating_point():
            continue  # integer buffers (a batch norm's counter) stay integers
        if not value.is_floating_point():
            problems.append(f"{key} is {str(value.dtype).removeprefix('torch.')}, not floating point")
        elif not bool(torch.isfinite(value).all()):
            bad = int((~torch.isfinite(value)).sum())
            problems.append(f"{key} holds {bad} NaN or infinite value(s) of {value.numel()}")
    return problems


def _refuse_values(state: dict[str, torch.Tensor], module: torch.nn.Module, source: Path) -> None:
    problems = value_problems(state, module.state_dict())
    if problems:
        shown = "; ".join(problems[:6]) + (f"; and {len(problems) - 6} more" if len(problems) > 6 else "")
        label = getattr(module, "label", type(module).__name__)
        raise WeightsError(f"{source}: not finite floating-point weights for {label}: {shown}")


def import_weights(registry: Any, importer: str, source: str | Path, out: str | Path, force: bool = False) -> Path:
    """Run a method's importer on `source` and save its weights at `out` as a checkpoint of the importer's size,
    recording the source file's name and sha256; a state that does not load exactly is refused, and so is an `out`
    that must not be overwritten (`check_out`: a shipped checkpoint, the source, another kind of file; an existing
    checkpoint without `force`)."""
    import importlib

    from ..runs.grid import expand

    owners = {name: m for m in registry.methods.values() for name in m.importers}
    if importer not in owners:
        known = ", ".join(sorted(owners)) or "none"
        raise WeightsError(f"unknown weights importer {importer!r} (known: {known})")
    source = Path(source)
    if not source.is_file():
        raise WeightsError(f"{source} is a folder, not a file" if source.is_dir() else f"{source} does not exist")
    check_out(Path(out), force, writer="the import", source=source)
    method = owners[importer]
    module, _, function = method.importers[importer].partition(":")
    imported = getattr(importlib.import_module(module), function)(source)
    pipeline = Pipeline.build(registry, expand([method.row(imported.size)], {}, None, registry)[0])
    for kind, module_ in pipeline.learned_modules().items():
        _refuse_values(imported.state.get(kind, {}), module_, source)
        try:
            module_.load_state_dict(imported.state[kind])
        except (KeyError, RuntimeError) as exc:
            raise WeightsError(f"{source}: the {importer} import does not load into {module_.label}: {exc}") from exc
    origin = {"file": source.name, "sha256": file_digest(source), "importer": importer, **imported.meta}
    return save_checkpoint(out, pipeline, trained_on=imported.trained_on, imported_from=origin)


# Where a checkpoint may be written (`train --out`, `weights import --out`): never inside an installed package (shipped
# weights, code), never over the file it is made from, never over a file that is not a checkpoint, and over an
# existing checkpoint only when asked (`--force`) or when it is a training of ours in progress.


def package_folders() -> list[Path]:
    """the folders of i2pbench and of every installed i2pbench plugin's top-level package: shipped code and
    weights, which nothing writes into."""
    import importlib.util

    from ..registry.entry_points import installed
    from ..registry.loading import ENTRY_POINT_GROUP

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
    try:
        load_checkpoint(out)
    except WeightsError as exc:
        raise WeightsError(
            f"--out {out} exists and is no i2pbench checkpoint ({exc}); {writer} never overwrites it. Give another "
            "--out, or move that file aside"
        ) from None


def load_init(module: torch.nn.Module, path: str | Path) -> dict[str, str]:
    """Initialise a learned stage from a plain state dict of its own keys (e.g. Magic Leap's `superpoint_v1.pth` for
    a SuperPoint encoder), strictly: a missing, unexpected or misshaped key is refused by name. -> what to record."""
    path = Path(path)
    state = read_state_dict(path)
    _refuse_values(state, module, path)
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
    try:
        _write_atomically(payload, path)
    except OSError as exc:  # errors name the path asked for, not the temp file beside it
        raise WeightsError(f"checkpoint {path} could not be written: {os_problem(exc)}") from None
    return path


def _write_atomically(payload: dict[str, Any], path: Path) -> None:
    import torch

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        torch.save(payload, tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a checkpoint is data to share
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


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
    if stat.st_size == 0 or _is_text(path):
        what = "empty (0 bytes)" if stat.st_size == 0 else "a text file"
        raise WeightsError(f"checkpoint {path} is {what}, not an i2pbench checkpoint")
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
