"""`i2pbench train`: train the learned stages of one combination; each ablation gets its own weights."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .options import (
    add_conf_option,
    add_data_options,
    add_stage_options,
    non_negative_int,
    parse_data_conf,
    positive_float,
    positive_int,
    split_conf,
    stage_choices,
)

if TYPE_CHECKING:  # the CLI starts without importing the training code
    from ..data.base import Dataset
    from ..training.mix import MixedSource, SourceSpec


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a combination's learned stages on a dataset split")
    add_stage_options(p, "{kind} name ('none' skips)", many=False)
    p.add_argument("--preset", help="start from this preset's first combination (default: 'default')")
    add_conf_option(p)
    add_data_options(p, split="train", frames=False)  # the train and val splits of --dataset
    p.add_argument(
        "--mix",
        action="append",
        default=[],
        metavar="DATASET:SPLIT[@ROOT]=SHARE",
        help="also draw this share of the samples from another dataset split (repeatable; e.g. kitti:train@DIR=0.5)",
    )
    p.add_argument("--val-split", help="split of --dataset for the periodic validation (default val; 'none' skips)")
    p.add_argument("--val-dataset", metavar="DATASET:SPLIT[@ROOT]", help="validate on this split instead")
    p.add_argument(
        "--init-2d",
        metavar="FILE",
        help="initialise the learned encoder2d from a state dict of its own keys (e.g. superpoint_v1.pth)",
    )
    p.add_argument(
        "--out",
        required=True,
        help="checkpoint path, outside the installed packages; training resumes from it when it exists with its "
        "resume file (<out>.resume)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="continue training (and overwrite) an existing checkpoint that has no resume file of its own, e.g. to "
        "fine-tune a copy",
    )
    add_config_options(p)
    p.add_argument(
        "--epochs",
        type=positive_float,  # 0 trained one step
        default=None,
        help="train this many passes over the split (sets --steps; each pass a permutation seeded by (seed, epoch))",
    )
    p.add_argument("--cache-dir", default="runs/cache/train", help="per-frame extractor/grouping cache ('none': off)")
    p.add_argument("--log", help="JSON-lines log, one record per step (default: <out>.log.jsonl)")
    p.add_argument("--tensorboard", metavar="DIR", help="also log the step and validation scalars for TensorBoard")
    p.add_argument("--threads", type=positive_int, default=None, help="torch, OpenCV and BLAS threads")
    p.add_argument("--quiet", action="store_true")


def augment_list(text: str) -> str:
    """An argparse type: a comma list of augmentation names, checked and normalised ("a, b" -> "a,b")."""
    from ..training.augment import augmentation_names

    try:
        return ",".join(augmentation_names(text))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


# The options that set a TrainConfig field of the same name: (type, or the choices, or bool for a flag; help;
# metavar). Their defaults are TrainConfig's, so the command line and the library train alike.
CONFIG_OPTIONS: dict[str, tuple[Any, str, str | None]] = {
    "steps": (positive_int, "optimiser steps", None),
    "batch_size": (positive_int, "frames per forward pass (per rank)", None),
    "accumulate": (positive_int, "forward passes per optimiser step", None),
    "workers": (non_negative_int, "DataLoader worker processes for data work", None),
    "lr": (positive_float, "peak learning rate (finite, positive)", None),
    "warmup_steps": (non_negative_int, "linear learning-rate warm-up", None),
    "schedule": (("constant", "cosine"), "after the warm-up", None),
    "grad_clip": (positive_float, "gradient-norm clip (finite, positive)", None),
    "augment": (augment_list, "per-sample augmentation: none, photometric, lidar-dropout, or a comma list", "NAMES"),
    "amp": (("off", "bf16"), "bf16 autocast of the learned stages", None),
    "deterministic": (bool, "deterministic kernels only (GPU reruns bit-exact)", None),
    "compile": (
        str,
        "torch.compile the stages' fixed-shape blocks with this backend (inductor; aot_eager: no C++ compiler)",
        "BACKEND",
    ),  # fmt: skip
    "freeze": (str, "learned stages kept as loaded, a comma list (e.g. encoder3d,exchanger,matcher)", "KINDS"),
    "checkpoint_every": (positive_int, "optimiser steps between checkpoints", None),
    "validate_every": (positive_int, "optimiser steps between validations", None),
    "val_frames": (positive_int, "validation frames, spread over the split", None),
    "seed": (int, "initial weights, frame order and transforms", None),
    "device": (str, "auto, cpu, cuda, cuda:N", None),
}


def add_config_options(p: argparse.ArgumentParser) -> None:
    """One option per CONFIG_OPTIONS entry, defaulting to TrainConfig's value."""
    from ..training.config import TrainConfig

    defaults = TrainConfig()
    for name, (kind, help, metavar) in CONFIG_OPTIONS.items():
        flag, default = "--" + name.replace("_", "-"), getattr(defaults, name)
        if kind is bool:
            p.add_argument(flag, action="store_true", default=default, help=help)
        elif isinstance(kind, tuple):
            p.add_argument(flag, choices=kind, default=default, help=help)
        else:
            p.add_argument(flag, type=kind, default=default, metavar=metavar, help=help)


def train_config(args: argparse.Namespace, device: str):
    """The TrainConfig the options give: each CONFIG_OPTIONS field as parsed, and the ones the command derives."""
    from ..training.config import TrainConfig

    cache_dir = None if args.cache_dir == "none" else args.cache_dir
    config = {name: getattr(args, name) for name in CONFIG_OPTIONS}
    return TrainConfig(**{**config, "device": device, "cache_dir": cache_dir, "epochs": args.epochs is not None})


def _source_specs(args: argparse.Namespace) -> tuple[list[SourceSpec], SourceSpec | None]:
    """--mix and --val-dataset parsed and checked, before any work."""
    from ..errors import I2PBenchError
    from ..training.mix import SourceSpec, check_mix, parse_source

    mix = [parse_source(text, "--mix", with_share=True) for text in args.mix]
    check_mix(SourceSpec(args.dataset, args.split, args.data_root), mix)
    if mix and args.epochs is not None:
        raise I2PBenchError("--epochs counts passes over one split; with --mix give --steps")
    if args.val_dataset and args.val_split:
        raise I2PBenchError("--val-split names a split of --dataset; with --val-dataset give the split there")
    val = parse_source(args.val_dataset, "--val-dataset", with_share=False) if args.val_dataset else None
    return mix, val


def _datasets(
    registry, args: argparse.Namespace, mix_specs: list[SourceSpec], val_spec: SourceSpec | None
) -> tuple[Dataset, Dataset | None, list[MixedSource]]:
    """(train set, val set or None, mixed-in sources); each --mix and --val-dataset split is listed now, so a
    wrong one stops the run before the pipeline is built."""
    from ..errors import DataError
    from ..training.mix import MixedSource, open_source

    data_conf = parse_data_conf(args.data_conf)
    if args.data_root:
        data_conf["root"] = args.data_root
    data_conf = split_conf(registry, args, data_conf)
    others = [spec.dataset for spec in [*mix_specs, val_spec] if spec is not None]
    if (args.fold or args.split_file) and args.dataset in others:
        raise DataError(f"--fold/--split-file apply to --dataset's splits only; validate with --val-split, not "
                        f"--val-dataset/--mix naming {args.dataset!r} again")  # fmt: skip
    train_set = registry.dataset(args.dataset)(args.split, data_conf)
    mix = [MixedSource(open_source(registry, spec, "--mix"), spec.share) for spec in mix_specs]
    if val_spec is not None:
        return train_set, open_source(registry, val_spec, "--val-dataset"), mix
    val_split = args.val_split or "val"
    val_set = None if val_split == "none" else registry.dataset(args.dataset)(val_split, data_conf)
    return train_set, val_set, mix


def _check_val(val_set: Dataset | None) -> None:
    """the validation split read before any step (and its log line): one with no frames is refused now, not at the
    first validation."""
    from ..errors import DataError

    if val_set is not None and not val_set.frame_ids():
        raise DataError(
            f"validation split {val_set.split!r} of dataset {val_set.name!r} has no frames; give another --val-split, "
            "or --val-split none to train without validation"
        )


def _combination(registry, args: argparse.Namespace):
    from ..runs.grid import base_combinations, expand, parse_conf_overrides

    choices = {kind: [name] for kind, name in stage_choices(args).items()}
    bases = base_combinations(registry, args.preset, stages_named=bool(choices))[:1]
    return expand(bases, choices, parse_conf_overrides(args.conf), registry)[0]


def _init_2d(pipeline, path: str) -> dict:
    """--init-2d: the encoder2d loaded from `path`, and the record of it for the checkpoint."""
    from ..errors import I2PBenchError
    from ..weights.checkpoints import load_init

    stage = pipeline.learned_modules().get("encoder2d")
    if stage is None:
        raise I2PBenchError("--init-2d needs a learned encoder2d in the combination")
    return {"init_2d": load_init(stage, path)}


def run(args: argparse.Namespace) -> int:
    from ..weights.checkpoints import check_out

    check_out(Path(args.out), args.force)  # a refused --out or --mix is said before torch loads (seconds)
    mix_specs, val_spec = _source_specs(args)

    import torch

    from ..execution.devices import resolve_device
    from ..execution.isolation import isolated
    from ..registry.build import default_registry
    from ..runs.environment import fix_threads
    from ..stages.pipeline import Pipeline
    from ..training.lineage import training_meta
    from ..training.loop import Trainer, steps_for_epochs

    device = resolve_device(args.device)
    fix_threads(args.threads)
    registry = default_registry()
    train_set, val_set, mix = _datasets(registry, args, mix_specs, val_spec)
    torch.manual_seed(args.seed)  # initial weights: two runs with one seed start (and end) alike
    pipeline = isolated(Pipeline.build(registry, _combination(registry, args)))
    init = _init_2d(pipeline, args.init_2d) if args.init_2d else {}
    _check_val(val_set)  # after the cheap checks, before a step is logged
    config = train_config(args, str(device))
    if args.epochs is not None:
        world = int(os.environ.get("WORLD_SIZE", 1))
        config = replace(config, steps=steps_for_epochs(args.epochs, len(train_set.frame_ids()), config, world))
    out = Path(args.out)
    trainer = Trainer(pipeline, train_set, val_set, out, config, mix)
    _announce(trainer, train_set, mix, trainer.resume())
    bar = _StepBar(config.steps, trainer.step, disable=args.quiet or not trainer.dist.main)
    log = Path(args.log) if args.log else out.with_name(out.name + ".log.jsonl")
    board = Path(args.tensorboard) if args.tensorboard else None
    meta = {**training_meta(train_set, config, trainer.dist.world, mix), **init}
    trainer.run(meta, bar, log=log, tensorboard=board)
    bar.close()
    if trainer.dist.main:
        print(f"checkpoint: {args.out} (step {trainer.step}); validation: {trainer.validation}", file=sys.stderr)
    return 0


def _announce(trainer, train_set, mix, resumed: str) -> None:
    """What trains, on what data, at which effective batch, resumed or compiled (by rank 0 only)."""
    from ..training.lineage import data_identity
    from ..weights.checkpoints import data_label

    if not trainer.dist.main:
        return
    pipeline, config = trainer.pipeline, trainer.config
    compiled = f"; compiled {len(trainer.compiled)} blocks ({config.compile})" if trainer.compiled else ""
    print(
        f"training {pipeline.combination.label} ({pipeline.model_size_mb():.2f} MB) on "
        f"{data_label(data_identity(train_set, mix))}, "
        f"effective batch {trainer.dist.world * config.accumulate * config.batch_size}"
        f"{f'; {resumed}' if resumed else ''}{compiled}",
        file=sys.stderr,
    )


class _StepBar:
    """The training's report callable: steps and loss terms on a progress bar, validation results as lines."""

    def __init__(self, total: int, initial: int, disable: bool) -> None:
        from ..execution.progress import bar

        self.bar = bar(total, unit="step", initial=initial, disable=disable)

    def __call__(self, step: int, terms: dict) -> None:
        if any(k.startswith("val_") for k in terms):
            line = " ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in terms.items())
            self.bar.write(line, file=sys.stderr)
            return
        self.bar.update(step - self.bar.n)
        self.bar.set_postfix({k: f"{v:.3f}" for k, v in terms.items() if isinstance(v, float)}, refresh=False)

    def close(self) -> None:
        self.bar.close()
