"""The command line starts without the heavy libraries it does not need (speed itself: benchmarks/cli_startup.py)."""

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from i2pbench.cli import COMMANDS, build_parser, invoked

HEAVY = {"numpy", "torch", "scipy", "pandas"}
# the console script's code, printing what still runs when `main` returns (threads the exit would wait for, child
# processes) and the modules loaded when the process ends
PROBE = """
import atexit, multiprocessing, sys, threading
atexit.register(lambda: print("MODULES", *sorted(sys.modules), file=sys.stderr))
from i2pbench.cli import main
sys.argv[0] = "i2pbench"
code = main()
waited = [t.name for t in threading.enumerate() if not t.daemon and t is not threading.main_thread()]
print("LINGERING", *waited, *(p.name for p in multiprocessing.active_children()), file=sys.stderr)
sys.exit(code)
"""
CLASSIC = ["--matcher", "oracle", "--extractor", "lsd", "--extractor3d", "depth+reflectance", "--solver", "epnp-ransac"]


def _run(*argv: str, env: dict[str, str] | None = None) -> tuple[str, set[str]]:
    env = env or {k: v for k, v in os.environ.items() if not k.startswith("I2PBENCH_")}
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, env=env, check=True)
    modules = _line(out.stderr, "MODULES")
    return out.stdout, set(modules)


def _line(stderr: str, tag: str) -> list[str]:
    return next(line for line in stderr.splitlines() if line.split()[:1] == [tag]).split()[1:]


def test_help_imports_no_command_module_and_none_of_numpy_torch_scipy_pandas():
    stdout, modules = _run("--help")
    assert all(name in stdout for name in COMMANDS)
    assert modules & HEAVY == set()
    assert not any(m.startswith("i2pbench.commands.") for m in modules)


def test_plugins_lists_every_component_without_importing_them_or_numpy_torch_scipy_pandas():
    stdout, modules = _run("plugins")
    assert "lsd" in stdout and "attention" in stdout and "kitti" in stdout
    assert modules & HEAVY == set()
    assert not {"i2pbench_classic.extract2d", "i2pbench_edgeregnet.attention", "i2pbench.data.kitti"} & modules
    assert "i2pbench.types" not in modules  # the plugins import `hookimpl` and methods from i2pbench.api, nothing more


def test_a_second_start_finds_the_plugins_without_importlib_metadata(tmp_path):
    """The entry points found by the first start are kept (i2pbench.registry.entry_points): the next skips the ~30 ms of
    importing importlib.metadata and reading every distribution, and lists the same."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("I2PBENCH_")} | {"XDG_CACHE_HOME": str(tmp_path)}
    first, cold = _run("plugins", env=env)
    second, warm = _run("plugins", env=env)
    assert "importlib.metadata" in cold and "importlib.metadata" not in warm
    assert second == first


def test_every_name_of_the_api_imports():
    """i2pbench.api imports each name on first use from the module its table gives: none is left out or wrong."""
    import i2pbench.api as api

    assert set(api.__all__) == set(api._HOME)
    assert all(hasattr(api, name) for name in api.__all__)


def test_the_top_level_help_is_the_same_whether_or_not_the_commands_are_built():
    assert build_parser(full=()).format_help() == build_parser().format_help()


@pytest.mark.parametrize(
    ("argv", "command"),
    [
        (["run", "--matcher", "oracle"], ("run",)),
        (["--help"], ()),
        (["rnu"], ()),
        (["domain-gap", "-h"], ("domain-gap",)),
    ],
)
def test_only_the_invoked_command_is_built(argv, command):
    assert invoked(argv) == command


def test_a_command_built_alone_parses_as_in_the_whole_command_line():
    argv = ["compare", "new.csv", "base.csv", "--tolerance", "acc=-1"]
    assert vars(build_parser(full=invoked(argv)).parse_args(argv)) == vars(build_parser().parse_args(argv))


def _records(runs: Path) -> pd.DataFrame:
    return pd.concat(pd.read_parquet(path) for path in sorted((runs / "synthetic-test" / "frames").glob("*.parquet")))


@pytest.mark.parametrize(("stages", "learned"), [(CLASSIC, False), (["--preset", "default"], True)], ids=str)
def test_a_classic_run_imports_no_torch_a_learned_one_does_and_both_fix_its_threads(tmp_path, stages, learned):
    """torch is loaded by the learned stages that need it; the thread count set before it loads still reaches it."""
    argv = ["run", *stages, "--dataset", "synthetic", "--split", "test", "--frames", "1", "--threads", "1", "--quiet"]
    env = {k: v for k, v in os.environ.items() if not k.startswith("I2PBENCH_")}
    out = subprocess.run(
        [sys.executable, "-c", PROBE, *argv, "--runs-dir", str(tmp_path)], capture_output=True, text=True, env=env
    )
    assert out.returncode == 0, out.stderr[-2000:]
    modules = set(_line(out.stderr, "MODULES"))
    assert ("torch" in modules) is learned
    assert ("i2pbench_edgeregnet.superpoint" in modules) is learned  # the encoders `--matcher oracle` drops
    assert _line(out.stderr, "LINGERING") == []  # nothing for the exit to wait for
    records = _records(tmp_path)
    assert (records["threads"] == 1).all() and (records["status"] == "ok").all()


@pytest.mark.parametrize(("cuda", "expected"), [("None", "False cpu"), ("'12.4'", "True -")])
def test_whether_torch_has_gpu_support_is_read_without_importing_it(tmp_path, cuda, expected):
    """A torch built without CUDA or ROCm resolves `--device auto` to cpu without being imported (here it cannot be)."""
    fake = tmp_path / "torch"
    fake.mkdir()
    (fake / "__init__.py").write_text("raise ImportError('torch was imported')\n")
    (fake / "version.py").write_text(f"from typing import Optional\ncuda: Optional[str] = {cuda}\nhip = None\n")
    check = "from i2pbench.execution.devices import resolve_device_name, torch_gpu_build as gpu\n"
    check += "print(gpu(), '-' if gpu() else resolve_device_name('auto'))"
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.split() == expected.split()
