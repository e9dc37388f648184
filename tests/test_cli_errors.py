"""What a new user types wrong gets one `i2pbench: error:` line naming the option, file or variable, never a
traceback; an unwritable --out still shows the leaderboard and keeps every computed frame."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import torch

from i2pbench.commands.diagnose import COLUMNS
from i2pbench.diagnostics.edges import summarize_edge_diagnostics
from i2pbench.errors import I2PBenchError
from i2pbench.execution.devices import DeviceError, resolve_device
from i2pbench.report.overlay import rre_text
from i2pbench.runs.invocation import history
from i2pbench.runs.store import ResultsStore

ROOT = Path(__file__).resolve().parents[1]


def i2pbench(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    env = {**{k: v for k, v in os.environ.items() if not k.startswith("I2PBENCH_")}, **(env or {})}
    cmd = [sys.executable, "-m", "i2pbench.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=cwd, env=env)


def assert_refused(done: subprocess.CompletedProcess, *named: str) -> None:
    assert done.returncode != 0, done.stdout
    assert "Traceback" not in done.stderr, done.stderr
    error = [line for line in done.stderr.splitlines() if line.startswith("i2pbench: error:")]
    assert len(error) == 1, done.stderr
    for name in named:
        assert name in error[0], error[0]


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--conf", "matcher.filter_threshold=[0.2"], ["--conf", "matcher.filter_threshold=[0.2", "YAML"]),
        (["--data-conf", "frames.test={3"], ["--data-conf", "frames.test={3", "YAML"]),
        (["--threads", "-3"], ["--threads", "positive integer"]),
        (["--frames", "-2"], ["--frames", "positive integer"]),
        (["--frames", "0"], ["--frames", "positive integer"]),
    ],
    ids=["conf-yaml", "data-conf-yaml", "threads-negative", "frames-negative", "frames-zero"],
)
def test_a_malformed_option_is_a_usage_error(args, named, tmp_path):
    done = i2pbench("run", *args, "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert done.returncode == 2  # argparse's usage error
    assert done.stderr.startswith("usage: i2pbench run")
    assert_refused(done, *named)


def test_a_grid_file_that_is_not_yaml_is_named_with_the_line_at_fault(tmp_path):
    grid = tmp_path / "grid.yaml"
    grid.write_text("base: {matcher: oracle}\ngrid: {solver: [epnp-ransac\n")
    done = i2pbench("run", "--grid", str(grid), "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert done.returncode == 2
    assert_refused(done, f"--grid {grid}", "not valid YAML", "line 3")  # the list is still open at the end, line 3


def test_a_missing_grid_file_is_named(tmp_path):
    done = i2pbench("run", "--grid", "nowhere.yaml", "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert_refused(done, "--grid nowhere.yaml", "No such file")


def test_an_unknown_device_lists_the_choices(tmp_path):
    done = i2pbench("run", "--device", "tpu", "--matcher", "oracle", "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path)
    assert_refused(done, "--device 'tpu'", "auto, cpu, cuda, cuda:N, mps")
    assert not (tmp_path / "runs").exists()  # refused before any work


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
@pytest.mark.parametrize("command", [["run"], ["viz", "0"]])
def test_cuda_on_a_machine_without_it_is_refused(command, tmp_path):
    done = i2pbench(*command, "--device", "cuda", "--matcher", "oracle", cwd=tmp_path)
    assert_refused(done, "--device 'cuda'", "CUDA is not available", "use cpu")


@pytest.mark.parametrize("value", ["soon", "-5", "nan"])
def test_a_bad_stage_timeout_variable_is_named(value, tmp_path):
    env = {"I2PBENCH_STAGE_TIMEOUT_S": value}
    done = i2pbench("run", "--matcher", "oracle", "--runs-dir", str(tmp_path / "runs"), cwd=tmp_path, env=env)
    assert_refused(done, "I2PBENCH_STAGE_TIMEOUT_S=", "'none'")


def test_device_choices_resolve_and_the_rest_are_refused():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device(" CPU ") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    for wrong in ("tpu", "cuda:x", "gpu", ""):
        with pytest.raises(DeviceError, match="unknown device"):
            resolve_device(wrong)
    with pytest.raises(DeviceError, match="cuda:99"):  # no CUDA here, or fewer than 100 devices
        resolve_device("cuda:99")
    assert issubclass(DeviceError, I2PBenchError)  # so the CLI prints it as one error line


def test_on_a_one_gpu_machine_cuda_0_resolves_and_cuda_1_is_refused(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    assert resolve_device("auto") == torch.device("cuda")
    assert resolve_device("cuda:0") == torch.device("cuda", 0)
    with pytest.raises(DeviceError, match=r"has 1 CUDA device\(s\); the index must be below 1"):
        resolve_device("cuda:1")
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    with pytest.raises(DeviceError, match="MPS"):
        resolve_device("mps")


@pytest.fixture
def unwritable(tmp_path):
    """A folder nothing can be written into: a read-only one, or, where permission bits do not bind (root), a path
    under a regular file, which no one can create."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        (folder / "probe").touch()
    except PermissionError:
        yield folder
    else:
        blocker = tmp_path / "a-file"
        blocker.touch()
        yield blocker / "boards"
    folder.chmod(0o755)


def kitti_run(shared_data: Path, runs: Path, *extra: str) -> list[str]:
    return ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(shared_data / "kitti_odometry"),
            "--matcher", "oracle", "--frames", "2", "--runs-dir", str(runs), "--threads", "1", "--quiet",
            *extra]  # fmt: skip


def test_an_unwritable_out_still_prints_the_leaderboard_and_keeps_the_frames(shared_data, unwritable, tmp_path):
    runs = tmp_path / "runs"
    done = i2pbench(*kitti_run(shared_data, runs, "--out", str(unwritable / "kitti")), cwd=tmp_path)
    assert "| lsd > depth+reflectance > oracle > epnp-ransac |" in done.stdout  # printed before the write failed
    assert_refused(done, "could not write the leaderboard", str(unwritable), "--out")
    assert len(ResultsStore(runs / "kitti-all").load()) == 2  # nothing computed is lost
    rerun = i2pbench(*kitti_run(shared_data, runs, "--out", str(tmp_path / "kitti")), cwd=tmp_path)
    assert rerun.returncode == 0, rerun.stderr
    assert pd.read_csv(tmp_path / "kitti.csv").iloc[0]["frames"] == 2
    last = history(runs / "kitti-all")[-1]
    assert (last["computed"], last["reused"]) == (0, 2)  # the rerun only wrote the leaderboard


def test_diagnose_help_explains_every_summary_column(tmp_path):
    rows = pd.DataFrame(
        {"extractor2d": ["lsd"], "extractor3d": ["depth"], "frame_id": ["0"], "n2d": [10], "n3d": [20],
         "n3d_in_fov": [8], "n3d_matched": [2], "ratio_in_fov": [0.25], "ratio_all": [0.1], "coverage2d": [0.05],
         "lift": [5.0], "time2d_ms": [1.0], "time3d_ms": [2.0]}
    )  # fmt: skip
    columns = set(summarize_edge_diagnostics(rows).columns) - {"extractor2d", "extractor3d"}
    documented = {name for entry in COLUMNS for name in entry.split(", ")}
    assert columns == documented
    done = i2pbench("diagnose", "--help", cwd=tmp_path)
    assert done.returncode == 0
    glossary = done.stdout.partition("columns (")[2]
    for column in columns:
        assert f" {column}" in glossary, column
    assert "the paper's 10%" in glossary and "ratio_in_fov / coverage2d" in glossary
    page = (ROOT / "docs" / "diagnose.md").read_text()
    assert all(f"`{column}`" in page for column in columns)


def test_a_per_frame_rre_past_180_degrees_says_it_is_an_euler_sum():
    assert rre_text(1.3, 1.2) == "RRE 1.30 deg"
    assert rre_text(412.345, 170.0, "°") == "RRE 412.35° (sum of 3 Euler angles; geodesic 170.00°)"
