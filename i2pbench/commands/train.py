"""`i2pbench train`: train the learned stages of one combination; each ablation gets its own weights."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .run import STAGE_OPTIONS


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train a combination's learned stages on a dataset split")
    for kind, flags in STAGE_OPTIONS.items():
        p.add_argument(*flags, dest=kind, help=f"{kind} name ('none' skips)")
    p.add_argument("--preset", help="start from this preset's first combination (default: 'default')")
    p.add_argument("--conf", action="append", default=[], metavar="KIND.KEY=VALUE", help="component config override")
    p.add_argument("--dataset", default="synthetic")
    p.add_argument("--split", default="train")
    p.add_argument("--val-split", default="val", help="split for the periodic validation ('none' to skip)")
    p.add_argument("--data-root", help="dataset root directory (else I2PBENCH_<NAME>_ROOT)")
    p.add_argument("--out", required=True, help="checkpoint path; training resumes from it when it exists")
    p.add_argument("--steps", type=int, default=20000)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--checkpoint-every", type=int, default=250)
    p.add_argument("--validate-every", type=int, default=1000)
    p.add_argument("--val-frames", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="auto")
    p.add_argument("--threads", type=int, default=None, help="torch, OpenCV and BLAS threads (default min(4, cores))")
    p.add_argument("--quiet", action="store_true")


def _combination(registry, args: argparse.Namespace):
    from ..grid import base_combinations, expand, parse_conf_overrides

    choices = {kind: [getattr(args, kind)] for kind in STAGE_OPTIONS if getattr(args, kind)}
    bases = base_combinations(registry, args.preset, stages_named=bool(choices))[:1]
    return expand(bases, choices, parse_conf_overrides(args.conf), registry)[0]


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..pipeline import Pipeline
    from ..plugins import default_registry
    from ..runs.environment import fix_threads
    from ..training import TrainConfig, Trainer, training_meta

    fix_threads(args.threads)
    registry = default_registry()
    pipeline = Pipeline.build(registry, _combination(registry, args))
    data_conf = {"root": args.data_root} if args.data_root else {}
    train_set = registry.dataset(args.dataset)(args.split, data_conf)
    val_set = None if args.val_split == "none" else registry.dataset(args.dataset)(args.val_split, data_conf)
    config = TrainConfig(
        steps=args.steps,
        lr=args.lr,
        checkpoint_every=args.checkpoint_every,
        validate_every=args.validate_every,
        val_frames=args.val_frames,
        seed=args.seed,
        device=args.device,
    )
    trainer = Trainer(pipeline, train_set, val_set, Path(args.out), config)
    resumed = trainer.resume()
    print(
        f"training {pipeline.combination.label} ({pipeline.model_size_mb():.2f} MB) on {args.dataset}/{args.split}"
        f"{f', resumed at step {trainer.step}' if resumed else ''}",
        file=sys.stderr,
    )
    bar = tqdm(total=config.steps, initial=trainer.step, disable=args.quiet, file=sys.stderr, unit="step")

    def report(step: int, terms: dict) -> None:
        if any(k.startswith("val_") for k in terms):
            tqdm.write(
                " ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in terms.items()),
                file=sys.stderr,
            )
            return
        bar.update(step - bar.n)
        bar.set_postfix({k: f"{v:.3f}" for k, v in terms.items() if isinstance(v, float)}, refresh=False)

    trainer.run(training_meta(train_set, config), report)
    bar.close()
    print(f"checkpoint: {args.out} (step {trainer.step}); validation: {trainer.validation}", file=sys.stderr)
    return 0
