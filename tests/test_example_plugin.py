"""docs/writing-a-plugin.md, followed as a newcomer would: the example package is installed, listed, run into a
leaderboard next to the reference stages, checked by the conformance kit, blocked and removed.

The tutorial's ```bash blocks run verbatim except for three paths: `.venv/` becomes a throwaway virtual environment
layered over this one (a .pth file adds this environment's site-packages), so installing the example never touches
the environment other tests run in; the example package and the KITTI frames get absolute paths, because the
commands run in a temporary directory that receives the runs/ (leaderboards included) they write.
"""

import importlib.util
import os
import re
import subprocess
import sys
import sysconfig
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "writing-a-plugin.md"
EXAMPLE = "plugins/example-external"
KITTI = "../shared/data/kitti_odometry"


def fenced_blocks(markdown: str, language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", markdown, flags=re.M | re.S)


def layered_venv(path: Path) -> Path:
    """A virtual environment that sees this one's packages (i2pbench included) but installs into its own."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(path)], check=True)
    python = path / "bin" / "python"
    purelib = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    parent = sysconfig.get_paths()["purelib"]
    Path(purelib, "_i2pbench_parent.pth").write_text(f"import site; site.addsitedir({parent!r})\n")
    script = path / "bin" / "i2pbench"
    script.write_text(f'#!/bin/sh\nexec "{python}" -m i2pbench.cli "$@"\n')
    script.chmod(0o755)
    return path


def pip_env(env: dict[str, str]) -> dict[str, str]:
    """Install offline when this environment can build the package itself (setuptools present); else pip fetches
    the build backend as usual."""
    if importlib.util.find_spec("setuptools") is not None:
        env.update(PIP_NO_BUILD_ISOLATION="0", PIP_NO_INDEX="1")
    return env


def run_block(block: str, venv: Path, kitti: Path, cwd: Path, env: dict[str, str]) -> str:
    command = block.replace(".venv/", f"{venv}/").replace(EXAMPLE, str(ROOT / EXAMPLE)).replace(KITTI, str(kitti))
    done = subprocess.run(
        ["bash", "-euo", "pipefail", "-c", command], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, f"{command}\nexit {done.returncode}\n{done.stdout}\n{done.stderr}"
    return done.stdout + done.stderr


def test_the_tutorial_shows_the_example_package_files_verbatim():
    blocks = [b for b in fenced_blocks(TUTORIAL.read_text(), r"\w+") if b.startswith("# file: ")]
    shown = {}
    for block in blocks:
        header, _, body = block.partition("\n")
        shown[header.removeprefix("# file: ")] = body
    assert set(shown) >= {f"{EXAMPLE}/pyproject.toml", f"{EXAMPLE}/i2pbench_example/plugin.py"}
    for path, body in shown.items():
        assert body == (ROOT / path).read_text(), f"docs/writing-a-plugin.md shows an outdated {path}"


@pytest.mark.slow
def test_following_the_tutorial_installs_lists_runs_checks_and_removes_the_plugin(shared_data, tmp_path):
    blocks = fenced_blocks(TUTORIAL.read_text(), "bash")
    venv = layered_venv(tmp_path / "venv")
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("I2PBENCH_", "PIP_", "VIRTUAL_ENV"))}
    # the example's pytest leaves out dash's plugin as the repo's own does (pyproject.toml): open3d pulls dash in, and
    # loading its plugin costs a second and a PytestRemovedIn10Warning
    env = pip_env({**env, "OMP_NUM_THREADS": "1", "PYTEST_ADDOPTS": "-p no:cacheprovider -p no:dash"})
    outputs = {block: run_block(block, venv, shared_data / "kitti_odometry", work, env) for block in blocks}

    def output_of(fragment: str) -> str:
        (match,) = [out for block, out in outputs.items() if fragment in block]
        return match

    listing = output_of("pip install -e")
    assert "example 0.1.0 (i2pbench-example)" in listing
    assert re.search(r"extractor2d\s+harris", listing) and re.search(r"extractor3d\s+curvature", listing)
    assert "harris > curvature > oracle > epnp-ransac" in output_of("i2pbench run")
    board = pd.read_csv(
        work / "runs" / "leaderboards" / "kitti-all-harris-curvature-oracle-epnp-ransac.csv"
    )  # a user's runs, not the repo's boards
    row = board.set_index("combination").loc["harris > curvature > oracle > epnp-ransac"]
    assert (row["extractor2d"], row["extractor3d"], row["frames"]) == ("harris", "curvature", 2)
    assert "extractor2d 'harris' conforms" in output_of("check_component")
    trace = output_of("outcome.records").splitlines()
    assert [line.split(" ")[0] for line in trace[:-1]] == ["extractor2d", "extractor3d", "matcher", "solver"]
    assert trace[0].startswith("extractor2d extractor2d 'harris' ") and trace[-1].endswith(" None")
    assert re.search(r"\b5 passed\b", output_of("pytest"))
    assert "example" not in output_of("I2PBENCH_BLOCK_PLUGINS=example") and "classic" in listing
    assert "Successfully uninstalled i2pbench-example" in output_of("uninstall")
