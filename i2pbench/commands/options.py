"""Options several commands share (the stages, --conf, the dataset and its split), the argparse types they parse
with, and what the commands build from them: the dataset, the combinations to run."""

from __future__ import annotations

import argparse
import math
from typing import Any

from ..stages.components import STAGES

CONF_HELP = "component config override (VALUE is YAML)"
DEVICE_HELP = "where learned stages run: auto (cuda if available), cpu, cuda, cuda:N, mps"


def add_stage_options(p: argparse.ArgumentParser, help: str, many: bool = True) -> None:
    """One option per stage kind (`--matcher`, ...); `many`: comma-separated names, a list each."""
    for kind, spec in STAGES.items():
        p.add_argument(*spec.options, dest=kind, type=split_list if many else None, help=help.format(kind=kind))


def stage_choices(args: argparse.Namespace) -> dict[str, Any]:
    """The stage options given, by kind."""
    return {kind: getattr(args, kind) for kind in STAGES if getattr(args, kind)}


def add_conf_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--conf", action="append", default=[], type=yaml_setting, metavar="KIND.KEY=VALUE", help=CONF_HELP)


def split_list(value: str) -> list[str]:
    return [v.strip() for v in value.split(",") if v.strip()]


def positive_int(value: str) -> int:
    """An argparse type: a count that must be at least 1 (`--frames -2` slicing off the last 2 frames is no count)."""
    refusal = argparse.ArgumentTypeError(f"{value!r} is not a positive integer")
    try:
        number = int(value)
    except ValueError:
        raise refusal from None
    if number < 1:
        raise refusal
    return number


def severity_list(value: str) -> list[int]:
    """An argparse type: `1,3,5`, the severities a corruption given without one runs at."""
    return [positive_int(v) for v in split_list(value)]


def yaml_setting(value: str) -> str:
    """An argparse type for KEY=VALUE options whose value is YAML: refuse malformed YAML while parsing options."""
    import yaml

    from ..data import yaml_input

    try:
        yaml_input.load(value.partition("=")[2])  # aliases refused too
    except yaml.YAMLError as exc:
        raise argparse.ArgumentTypeError(f"{value!r}: the value is not valid YAML ({yaml_problem(exc)})") from None
    return value


def yaml_problem(exc: Exception) -> str:
    """PyYAML's one-line reason and position, without its multi-line excerpt."""
    problem, mark = getattr(exc, "problem", None), getattr(exc, "problem_mark", None)
    if problem is None:
        return str(exc).splitlines()[0]
    return f"{problem} at line {mark.line + 1}, column {mark.column + 1}" if mark else problem


def non_negative_int(text: str) -> int:
    """An argparse type: a count that may be 0 (`--workers 0`: data work in the main process)."""
    if text.strip() == "0":
        return 0
    try:
        return positive_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"{text!r} is not 0 or a positive integer") from None


def positive_float(text: str) -> float:
    """An argparse type: a finite number above 0 (an inf or NaN learning rate trains NaN weights)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite positive number")
    return value


def add_data_options(p: argparse.ArgumentParser, split: str = "test", frames: bool = True) -> None:
    """--dataset and its --split (default `split`), root, config and split file; `frames`: --frames N too."""
    p.add_argument("--dataset", default="synthetic", help="dataset name (kitti, nuscenes, synthetic, ...)")
    p.add_argument("--split", default=split)
    p.add_argument("--data-root", help="dataset root directory (else I2PBENCH_<NAME>_ROOT)")
    p.add_argument(
        "--data-conf",
        action="append",
        default=[],
        type=yaml_setting,
        metavar="KEY=VALUE",
        help=f"dataset config (YAML values; dotted keys nest, e.g. frames.{split}=3)",
    )
    if frames:
        p.add_argument("--frames", type=positive_int, default=None, help="use only the first N frames of the split")
    add_split_options(p)


def add_split_options(p: argparse.ArgumentParser) -> None:
    """Splits by scene from a split file (kitti-drives; docs/datasets.md#kitti-drives)."""
    p.add_argument("--split-file", metavar="NAME|PATH", help="the dataset's split file: a committed name "
                   "(kitti-real-drives) or a path; datasets with a split_file config only")  # fmt: skip
    p.add_argument("--fold", metavar="K/N", help="k-fold cross-validation by scene: test = fold K, val = fold K+1, "
                   "train = the rest (datasets with a fold config only)")  # fmt: skip


def split_conf(registry, args: argparse.Namespace, conf: dict[str, Any]) -> dict[str, Any]:
    """`conf` with --split-file and --fold as the dataset's config, refused for a dataset without those keys."""
    from ..errors import DataError

    given = {"split_file": getattr(args, "split_file", None), "fold": getattr(args, "fold", None)}
    for key, value in given.items():
        if value is None:
            continue
        if key not in registry.dataset(args.dataset).default_conf:
            option = "--" + key.replace("_", "-")
            raise DataError(f"{option}: dataset {args.dataset!r} has no {key} config (kitti-drives has)")
        conf[key] = value
    return conf


def parse_data_conf(items: list[str]) -> dict[str, Any]:
    """`["frames.test=3"]` -> {"frames": {"test": 3}}."""
    from ..data import yaml_input
    from ..errors import DataError

    conf: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise DataError(f"--data-conf {item!r}: expected KEY=VALUE")
        *parents, leaf = key.split(".")
        node = conf
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = yaml_input.load(value)
    return conf


def open_dataset(registry, args: argparse.Namespace):
    conf = parse_data_conf(getattr(args, "data_conf", []))
    if args.data_root:
        conf["root"] = args.data_root
    return registry.dataset(args.dataset)(args.split, split_conf(registry, args, conf))


def chosen_combinations(registry, args: argparse.Namespace):
    """The combinations the stage options, --preset, --grid and --conf name (CLI options winning over the grid file)."""
    from ..runs.grid import base_combinations, expand, parse_conf_overrides
    from ..stages.config import overlay

    choices = stage_choices(args)
    bases = base_combinations(registry, args.preset, stages_named=bool(choices or args.grid))
    confs = parse_conf_overrides(args.conf)
    if args.grid:
        grid = grid_file(args.grid)
        choices = {**{k: [v] for k, v in grid.base.items()}, **grid.grid, **choices}
        confs = {k: overlay(grid.confs.get(k, {}), confs.get(k, {})) for k in {*grid.confs, *confs}}
    return expand(bases, choices, confs, registry)


def check_confs(registry, combinations) -> None:
    """Each stage's config merged over its defaults before any folder is made: an unknown key or a value of another
    kind is refused while nothing is written (Pipeline.build checks the same, but after the run's store exists)."""
    from ..stages.config import merge_conf

    for combination in combinations:
        for kind, conf in combination.confs.items():
            component = registry.component(kind, combination.names[kind])
            merge_conf(component.default_conf, conf, f"{kind} {component.name!r}")


def grid_file(path: str):
    """The grid file, or a PluginError naming it when it cannot be read or is not a grid."""
    import yaml

    from ..errors import PluginError
    from ..runs.grid import load_grid_file

    shape = "base: {kind: name}, grid: {kind: [names]}, confs: {kind: {key: value}}"
    try:
        grid = load_grid_file(path)
    except OSError as exc:
        raise PluginError(f"--grid {path}: cannot read it ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        raise PluginError(f"--grid {path}: not valid YAML ({yaml_problem(exc)})") from None
    except (AttributeError, TypeError, ValueError) as exc:
        raise PluginError(f"--grid {path}: expected {shape} ({exc})") from None
    if not (grid.base or grid.grid or grid.confs):  # else the default pipeline would run as the grid
        raise PluginError(f"--grid {path}: the file names no stage; expected {shape}")
    return grid
