"""The command line starts without the heavy libraries it does not need (speed itself: benchmarks/cli_startup.py)."""

import os
import subprocess
import sys

import pytest

from i2pbench.cli import COMMANDS, build_parser, invoked

HEAVY = {"torch", "scipy", "pandas"}
# the console script's code, printing the modules loaded when the process ends
PROBE = """
import atexit, sys
atexit.register(lambda: print("MODULES", *sorted(sys.modules), file=sys.stderr))
from i2pbench.cli import main
sys.argv[0] = "i2pbench"
sys.exit(main())
"""


def _run(*argv: str) -> tuple[str, set[str]]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("I2PBENCH_")}
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, env=env, check=True)
    modules = next(line for line in out.stderr.splitlines() if line.startswith("MODULES ")).split()[1:]
    return out.stdout, set(modules)


def test_help_imports_no_command_module_and_none_of_torch_scipy_pandas():
    stdout, modules = _run("--help")
    assert all(name in stdout for name in COMMANDS)
    assert modules & HEAVY == set()
    assert not any(m.startswith("i2pbench.commands.") for m in modules)


def test_plugins_lists_every_component_without_importing_them_or_torch_scipy_pandas():
    stdout, modules = _run("plugins")
    assert "lsd" in stdout and "attention" in stdout and "kitti" in stdout
    assert modules & HEAVY == set()
    assert not {"i2pbench_classic.extract2d", "i2pbench_edgeregnet.attention", "i2pbench.data.kitti"} & modules


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
