"""`i2pbench run`: run combinations of stages over a dataset split and write the leaderboard."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..runs.context import RunContext
from .options import (
    DEVICE_HELP,
    add_conf_option,
    add_data_options,
    add_stage_options,
    check_confs,
    chosen_combinations,
    open_dataset,
    positive_int,
    severity_list,
    split_list,
    stage_choices,
)

if TYPE_CHECKING:
    from .results import RunResult


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run combinations of stages over a dataset split and print the leaderboard")
    add_stage_options(p, "{kind} name(s), comma-separated; 'none' skips")
    p.add_argument("--preset", help="a registered list of combinations (e.g. edge-ablation); a,b: their union")
    p.add_argument("--grid", help="YAML grid file: base: {kind: name}, grid: {kind: [names]}, confs: {kind: {k: v}}")
    add_conf_option(p)
    add_data_options(p)
    p.add_argument(
        "--weights", default="auto", help="'auto' (shipped checkpoint fitting the stages), 'untrained', or a path"
    )
    p.add_argument("--device", default="auto", help=DEVICE_HELP)
    p.add_argument("--seed", type=int, default=0, help="protocol seed for the random transforms")
    p.add_argument("--protocol", default="edgeregnet", metavar="NAME", help="the protocol card to run under "
                   "(docs/protocol.md): refused when its inputs are ones i2pbench cannot give")  # fmt: skip
    p.add_argument("--corruption", type=split_list, metavar="NAME[:SEVERITY],...", help="run under corruptions "
                   "(docs/robustness.md), each a set of rows: NAME at every severity, NAME:S, all, clean")  # fmt: skip
    p.add_argument("--severities", type=severity_list, metavar="S,...", help="severities for a corruption named "
                   "without one (e.g. 1,3,5)")  # fmt: skip
    p.add_argument("--robustness", action="store_true", help="the robustness grid: clean rows, then every corruption "
                   "at every severity (or --severities); writes OUT-robustness.md/.csv too")  # fmt: skip
    p.add_argument("--runs-dir", default="runs", help="where per-frame results are cached")
    p.add_argument("--out", help="leaderboard file stem (default RUNS_DIR/leaderboards/<dataset>-<split>)")
    p.add_argument("--overwrite", action="store_true", help="recompute frames already in the cache")
    p.add_argument("--threads", type=positive_int, help="torch and OpenCV threads (default min(4, cores))")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no `written:` line (errors still show)")
    p.add_argument("--isolate", choices=("thread", "process"), help="run stages in a killable child process (process) "
                   "for untrusted plugins; default I2PBENCH_ISOLATE, else thread")  # fmt: skip
    add_scale_options(p)


def add_scale_options(p: argparse.ArgumentParser) -> None:
    """Parallel runs (docs/scale-out.md): worker processes here, or actors on a Ray cluster."""
    p.add_argument("--workers", type=positive_int, help="worker processes (local; default 1, serial) or Ray actors "
                   "(default: as many as the cluster's CPUs hold)")  # fmt: skip
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="where workers run")
    p.add_argument("--address", help="Ray cluster address (auto: the one `ray start` began; default: a local Ray)")
    p.add_argument(
        "--threads-per-worker", type=positive_int, default=1, help="torch/OpenCV/BLAS threads in each worker"
    )
    p.add_argument(
        "--chunk-size", type=positive_int, default=8, help="most frames of one combination in one worker task"
    )


def run(args: argparse.Namespace) -> int:
    outcome = execute(args)
    return outcome if isinstance(outcome, int) else 0


def execute(args: argparse.Namespace) -> RunResult | int:
    """The run `args` describe (the CLI's and `i2pbench.run`'s one path): its result, or after Ctrl-C the exit
    status, once the finished frames' board is printed."""
    from ..errors import I2PBenchError
    from ..runs.invocation import Invocation

    ctx = _prepare(args)
    store = _open_store(Path(args.runs_dir) / ctx.board_name)
    ctx = ctx.with_store(store)
    invocation = Invocation(store.root, _meta(ctx))
    start = time.perf_counter()
    try:
        records = _run_grid(ctx, invocation.id)
    except OSError as exc:  # the store's disk full or gone read-only: frames written so far stay
        raise _store_failed(exc, store, invocation) from None
    except I2PBenchError as exc:  # a worker lost, a cluster that does not answer: the record says so, not "running"
        invocation.fail(str(exc))
        raise
    except KeyboardInterrupt as exc:  # Ctrl-C: workers stopped, finished frames kept, the board of those printed
        from .run_notes import stopped

        return stopped(exc, store, invocation, ctx.protocol)
    stem = Path(args.out or Path(args.runs_dir) / "leaderboards" / board_name(ctx.board_name, args))
    try:
        return _publish(ctx, records, invocation, time.perf_counter() - start, stem)
    except KeyboardInterrupt as exc:  # while the board is built or written: every frame is stored, the record says so
        from .run_notes import stopped

        return stopped(exc, store, invocation, ctx.protocol)


def _prepare(args: argparse.Namespace) -> RunContext:
    """Everything checked before the run's store is made: options, combinations and their configs, the dataset and
    its frames, the protocols."""
    from ..boards.out_stem import board_stem
    from ..errors import DataError
    from ..execution.devices import resolve_device_name
    from ..registry.build import default_registry
    from ..runs.environment import fix_threads
    from ..scoring.installed import for_run

    args.out = board_stem(args.out)  # a device, pipe or folder refused before any work; board.csv read as board
    if args.isolate:  # Pipeline.build reads it; worker processes receive pipelines built here
        os.environ["I2PBENCH_ISOLATE"] = args.isolate
    threads = fix_threads(args.threads)
    args.device = resolve_device_name(args.device)  # resolved once: "auto" would read differently in the record
    registry = default_registry()
    combinations = chosen_combinations(registry, args)
    check_confs(registry, combinations)
    dataset = open_dataset(registry, args)
    frame_ids = _frame_ids(dataset, args)
    if not frame_ids:
        raise DataError(f"dataset {dataset.name!r} split {dataset.split!r} has no frames to run")
    base = for_run(args.protocol, args.seed, dataset.name, registry)
    protocols = _protocols(registry, base, args, dataset, frame_ids)
    return RunContext(registry, tuple(combinations), dataset, tuple(frame_ids), tuple(protocols), threads, args)


def _publish(ctx: RunContext, records, invocation, wall_s: float, stem: Path) -> RunResult:
    """The finished run's board: recorded with the invocation, printed with its notes (the board on stdout for the
    CLI, not for a Python caller: `echo`), then written to `stem`."""
    from ..boards import leaderboard
    from ..execution import progress
    from ..scoring.installed import active
    from .results import RunResult
    from .run_notes import failure_reasons, latency_reused

    args, store_root, metrics = ctx.options, ctx.store.root, active(ctx.registry)
    board = leaderboard.build(records, ctx.protocol, metrics, ctx.registry)
    counts = _summary(records, board, invocation.id, wall_s)
    invocation.finish(**counts)
    progress.note(f"{counts['reused']} of {len(records)} frames reused from the cache in {store_root}")
    if getattr(args, "echo", True):
        # first: a leaderboard that cannot be written is still seen
        print(leaderboard.to_markdown(board, metrics=metrics))
    for line in [*failure_reasons(records), *latency_reused(records, invocation.id, ctx.threads, args)]:
        progress.note(line)
    summary = _robustness(ctx.registry, board, getattr(args, "echo", True))
    paths = _write_board(board, records, stem, store_root, summary, metrics)
    progress.note(f"\nwritten: {', '.join(str(p) for p in paths)}; per-frame results in {store_root}")
    return RunResult(board, records, store_root, paths, invocation.id)


def board_name(store_name: str, args: argparse.Namespace) -> str:
    """The default board's name: the store's (<dataset>-<split>) and what was run, so a run's board never replaces
    another's. The default pipeline keeps the bare name; a preset, a grid file, stage choices, --conf, --weights,
    corruptions, a seed other than 0 and a --protocol other than the default each add a part, e.g.
    synthetic-test-paper-table-1, kitti-all-classic, kitti-all-canny-depth-oracle-epnp-ransac."""
    import hashlib
    import re

    parts = [p.replace(",", "+") for p in [args.preset or ""] if p and p != "default"]
    parts += [Path(args.grid).stem] if args.grid else []
    parts += ["+".join(names) for names in stage_choices(args).values()]
    if args.conf:
        parts.append("conf-" + hashlib.sha256("\n".join(sorted(args.conf)).encode()).hexdigest()[:6])
    parts += [f"weights-{Path(args.weights).stem}"] if args.weights != "auto" else []
    parts += ["robustness"] if args.robustness else ["+".join(args.corruption)] if args.corruption else []
    parts += ["s" + "+".join(map(str, args.severities))] if args.severities else []
    parts += [f"seed{args.seed}"] if args.seed else []
    parts += [args.protocol] if getattr(args, "protocol", "edgeregnet") != "edgeregnet" else []
    name = re.sub(r"[^A-Za-z0-9._+=-]", "_", "-".join([store_name, *parts]))
    if len(name) > 120:  # a file name has room for 255 bytes; keep it readable and still unique
        name = f"{name[:110]}-{hashlib.sha256(name.encode()).hexdigest()[:8]}"
    return name


def _frame_ids(dataset, args: argparse.Namespace) -> list[str]:
    """The split's first --frames frames; a root that cannot be read or written (the synthetic dataset generates its
    frames there on first use) is one error naming it."""
    from ..errors import DataError, os_problem

    try:
        return dataset.frame_ids()[: args.frames]
    except OSError as exc:
        where = f"--data-root {args.data_root}" if args.data_root else "(its default root)"
        raise DataError(
            f"dataset {dataset.name!r} {where}: could not list or make its frames: {os_problem(exc)}"
        ) from None


def _store_failed(exc: OSError, store, invocation) -> Exception:
    """the one error line of a run whose results could not be stored; the invocation is marked failed (when its
    record can still be written) and every finished frame is kept, so the same command resumes."""
    from ..errors import I2PBenchError

    marked = invocation.fail(f"{type(exc).__name__}: {exc}")
    kept = len(store.keys())
    return I2PBenchError(
        f"{exc.filename or store.root}: {exc.strerror or exc} while storing results; invocation {invocation.id} "
        f"{'marked failed' if marked else 'could not be marked failed'}; {kept} finished frame record(s) kept in "
        f"{store.frames_dir}, so the same command resumes once the problem is fixed"
    )


def _protocols(registry, base, args: argparse.Namespace, dataset, frame_ids: list[str]) -> list:
    """The protocols to run, each a set of rows: the clean one, or those `--corruption` / `--robustness` name; a
    corruption the run's frames cannot take (time-offset without ego motion) is left out of `all` with a note, and
    refused before any frame runs when named."""
    from ..errors import PluginError
    from ..runs.grid import ALL, CLEAN, protocols

    specs = [*([CLEAN, ALL] if args.robustness else []), *(args.corruption or [])]
    if not specs:
        if args.severities:
            raise PluginError("--severities chooses the severities of --corruption NAME or --robustness; give one")
        return [base]
    return protocols(registry, base, specs, args.severities, dataset=dataset, frame_ids=frame_ids)


def _robustness(registry, board, echo: bool = True):
    """The summary per corruption when the board has corrupted rows (printed when `echo`, written beside the board),
    else None."""
    from ..boards import leaderboard

    if (board["corruption"] == "").all():
        return None
    kinds = {name: registry.corruption(name).kind for name in set(board["corruption"]) if name}
    summary = leaderboard.robustness(board, kinds)
    if echo:
        print("\n" + leaderboard.to_markdown(summary, list(summary.columns)))
    return summary


def _open_store(root: Path):
    """The per-frame results store, or an error naming the folder when it cannot be created."""
    from ..errors import I2PBenchError
    from ..runs.store import ResultsStore

    try:
        return ResultsStore(root)
    except OSError as exc:
        raise I2PBenchError(
            f"--runs-dir: could not write per-frame results into {root} ({exc.strerror or exc})"
        ) from None


def _write_board(board, records, stem: Path, store_root: Path, summary=None, metrics=None) -> list[Path]:
    """The leaderboard's files with the environment record of the invocations whose frames it holds (and the
    robustness summary's, `<stem>-robustness`); an unwritable folder is an error that says nothing computed is lost."""
    from ..boards import leaderboard
    from ..errors import I2PBenchError
    from ..runs import board_env

    try:
        paths = [*leaderboard.write(board, stem, metrics), board_env.write(stem, store_root, records)]
        if summary is not None:
            paths += leaderboard.write_robustness(summary, stem.with_name(f"{stem.name}-robustness"))
        return paths
    except OSError as exc:
        raise I2PBenchError(
            f"could not write the leaderboard into {stem.parent} ({exc.strerror or exc}); it is printed above, and "
            f"the per-frame results are kept in {store_root}: rerun with --out STEM in a writable folder to write it "
            "without recomputing"
        ) from None


def _meta(ctx: RunContext) -> dict[str, Any]:
    """What this invocation depends on, recorded before any frame runs (a killed run keeps it too); `protocol` is
    the first protocol's card, `protocols` every one's when corruptions add more."""
    from ..runs.environment import environment

    args = ctx.options
    more = {"protocols": [p.card() for p in ctx.protocols]} if len(ctx.protocols) > 1 else {}
    return {
        "argv": sys.argv,
        "threads": ctx.threads,
        "device": args.device,
        "executor": {k: getattr(args, k) for k in ("executor", "workers", "threads_per_worker", "address")},
        "protocol": ctx.protocol.card(),
        "dataset": ctx.dataset.identity(),
        "frames": list(ctx.frame_ids),
        "environment": environment(),
        "combinations": [c.describe() for c in ctx.combinations],
        **more,
    }


def _summary(records, board, invocation: str, wall_s: float) -> dict[str, Any]:
    from ..boards import leaderboard

    computed = int((records["invocation"] == invocation).sum())
    return {
        "wall_s": wall_s,
        "computed": computed,
        "reused": len(records) - computed,
        "rows": board[leaderboard.GROUP + leaderboard.CONDITION].to_dict("records"),
    }


def _run_grid(ctx: RunContext, invocation: str):
    """run_grid under each protocol in turn, with one progress bar (ETA) over every frame of every combination and
    protocol, cached ones included."""
    import pandas as pd

    from ..execution.progress import bar as progress_bar
    from ..runs import executors

    args = ctx.options
    executor = executors.make_executor(args.executor, args.workers, args.threads_per_worker, args.address, args.device)
    what = f"{len(ctx.combinations)} combination(s) x {len(ctx.frame_ids)} frames"
    what += f" x {len(ctx.protocols)} conditions" if len(ctx.protocols) > 1 else ""
    with progress_bar(ctx.frames_in_all(), what, disable=args.quiet) as bar:
        grids = [_run_protocol(ctx, p, invocation, executor, _Bar(bar)) for p in ctx.protocols]
    return pd.concat(grids, ignore_index=True)


class _Bar:
    """The run's progress callable: counts frames on the bar and names the combination running after it."""

    def __init__(self, bar) -> None:
        self.bar, self.label = bar, ""

    def __call__(self, frames: int) -> None:
        self.bar.update(frames)

    def describe(self, label: str) -> None:
        if label != self.label:  # shown at once: the first frame of a combination may take long (its warm-up)
            self.bar.set_postfix_str(label)
            self.label = label


def _run_protocol(ctx: RunContext, protocol, invocation: str, executor, progress):
    """One protocol's grid, serially in this process (no executor: its learned stages on --device) or on the
    executor's workers (each choosing its own device)."""
    from ..runs.executors import run_grid

    args = ctx.options
    return run_grid(
        ctx.registry, list(ctx.combinations), ctx.dataset, protocol, ctx.store, executor, weights=args.weights,
        device=args.device, frame_ids=list(ctx.frame_ids), overwrite=args.overwrite, progress=progress,
        invocation=invocation, chunk_size=args.chunk_size,
    )  # fmt: skip
