"""Start-up of the command line: wall time of `i2pbench --help`, `i2pbench plugins` and two classic runs (LSD,
depth+reflectance, oracle matches, EPnP-RANSAC; on the 6 real KITTI frames, and on 3 synthetic frames, which read no
files), each the median of `--repeat` runs and a ratio to `python -c pass` timed in the same run, so the numbers
survive a busy machine. Also shown per command: the seconds
from `main` returning to the process ending (threads joined, atexit, teardown) and which heavy modules it imported.

`--baseline REV` also times a git revision's code (extracted with `git archive` into a temporary folder and put first
on PYTHONPATH, same interpreter and installed packages), interleaved run by run with the working tree's.
`--startup-only` times only `--help` and `plugins`, the two commands that should start at once.

Every process reads and writes its bytecode in a scratch folder (PYTHONPYCACHEPREFIX), and one untimed round runs
first: a start is then timed as an installed tool's, which has its `.pyc` files, even where PYTHONDONTWRITEBYTECODE
is set (as here), which would otherwise charge every start the compiling of each i2pbench module it imports.

    .venv/bin/python benchmarks/cli_startup.py [--repeat 5] [--baseline HEAD~1] [--data-root DIR] [--startup-only]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "scipy", "pandas", "pyarrow", "cv2", "poselib", "ray", "numpy")
STARTUP = ("i2pbench --help", "i2pbench plugins")  # what --startup-only times
# the console script's own code, plus a probe: the time `main` returned, and (last atexit handler) the modules loaded
LAUNCH = """
import atexit, sys, time
from i2pbench.cli import main
atexit.register(lambda: sys.stderr.write(f"\\nPROBE {done} {' '.join(sorted(sys.modules))}\\n"))
sys.argv[0] = "i2pbench"
try:
    code = main()
finally:
    done = time.time()
sys.exit(code)
"""


@dataclass
class Timing:
    walls: list[float] = field(default_factory=list)
    exits: list[float] = field(default_factory=list)
    modules: set[str] = field(default_factory=set)


def commands(data_root: str, runs_dir: str) -> dict[str, list[str]]:
    fresh = ["--runs-dir", runs_dir, "--overwrite", "--quiet"]  # every frame recomputed
    kitti = ["run", "--matcher", "oracle", "--dataset", "kitti", "--split", "all", "--data-root", data_root]
    stages = ["--extractor", "lsd", "--extractor3d", "depth+reflectance", "--matcher", "oracle"]
    stages += ["--solver", "epnp-ransac"]
    synthetic = ["run", *stages, "--dataset", "synthetic", "--split", "test", "--frames", "3"]
    return {
        "i2pbench --help": ["--help"],
        "i2pbench plugins": ["plugins"],
        "classic oracle run": [*kitti, *fresh],
        "classic synthetic run": [*synthetic, *fresh],
    }


def time_once(argv: list[str], env: dict[str, str], cwd: Path, timing: Timing) -> None:
    """One run from `cwd` (not the repository: `python -c` imports from the current folder first)."""
    start = time.time()
    out = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=cwd)
    end = time.time()
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(argv[3:])} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    timing.walls.append(end - start)
    probe = [line for line in out.stderr.splitlines() if line.startswith("PROBE ")]
    if probe:
        done, *modules = probe[-1].split()[1:]
        timing.exits.append(end - float(done))
        timing.modules = set(modules) & set(HEAVY)


def tree_env(tree: Path | None, scratch: Path) -> dict[str, str]:
    """The environment that runs `tree`'s code (None: the installed working tree), its bytecode cached in `scratch`."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("I2PBENCH_") and k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(scratch / "pycache")
    if tree is not None:
        paths = [tree, tree / "plugins" / "classic", tree / "plugins" / "edgeregnet"]
        env["PYTHONPATH"] = os.pathsep.join(map(str, paths))
    return env


def extract(rev: str, into: Path) -> Path:
    into.mkdir()
    archive = subprocess.run(["git", "archive", rev], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def measure(
    trees: dict[str, Path | None], repeat: int, data_root: str, scratch: Path, labels: Collection[str] | None = None
) -> dict[tuple, Timing]:
    """The commands of `labels` (None: all) on each tree, interleaved: an untimed round (bytecode compiled and
    cached), then `repeat` timed ones."""
    results: dict[tuple, Timing] = {}
    for i in range(repeat + 1):
        timed = i > 0
        python = results.setdefault(("python -c pass", "-"), Timing()) if timed else Timing()
        time_once([sys.executable, "-c", "pass"], tree_env(None, scratch), scratch, python)
        for tree, path in trees.items():
            for label, args in commands(data_root, str(scratch / f"runs-{tree}")).items():
                if labels is None or label in labels:
                    timing = results.setdefault((label, tree), Timing()) if timed else Timing()
                    time_once([sys.executable, "-c", LAUNCH, *args], tree_env(path, scratch), scratch, timing)
    return results


def report(results: dict[tuple, Timing]) -> None:
    python = statistics.median(results["python -c pass", "-"].walls)
    print(f"{'command':22s} {'code':9s} {'median s':>9s} {'x python':>9s} {'exit s':>7s}  heavy modules imported")
    for (label, tree), t in results.items():
        wall = statistics.median(t.walls)
        exit_s = f"{statistics.median(t.exits):7.2f}" if t.exits else f"{'-':>7s}"
        heavy = ", ".join(m for m in HEAVY if m in t.modules) or "-"
        print(f"{label:22s} {tree:9s} {wall:9.3f} {wall / python:9.1f} {exit_s}  {heavy if t.exits else ''}")
    runs = len(results["python -c pass", "-"].walls)
    print(f"\nmedian of {runs} runs each, interleaved; python -c pass = {python:.3f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--baseline", help="a git revision to time too (e.g. the commit before a change)")
    parser.add_argument("--data-root", default=str(ROOT.parent / "shared" / "data" / "kitti_odometry"))
    parser.add_argument("--startup-only", action="store_true", help="time only --help and plugins, not the runs")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        trees: dict[str, Path | None] = {}
        if args.baseline:
            trees[args.baseline] = extract(args.baseline, Path(tmp) / "baseline")
        trees["current"] = None
        labels = STARTUP if args.startup_only else None
        report(measure(trees, args.repeat, args.data_root, Path(tmp), labels))


if __name__ == "__main__":
    main()
