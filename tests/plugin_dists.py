"""Entry-point plugins without pip, and watching the processes of an `i2pbench` subprocess that uses them.

A bare `.dist-info` folder on PYTHONPATH is an installed distribution to importlib.metadata, so a subprocess of
`i2pbench` loads the plugins it names as it would any user's installed ones.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

TESTS = Path(__file__).resolve().parent
LOG = "i2pbench.log"


def install(site: Path, entry_points: dict[str, str], name: str = "i2pbench-test-plugins") -> Path:
    """Write a distribution `name` into `site` offering `entry_points` ({entry-point name: module[:attr]})."""
    info = site / f"{name.replace('-', '_')}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    lines = "".join(f"{ep} = {target}\n" for ep, target in entry_points.items())
    (info / "entry_points.txt").write_text(f"[i2pbench]\n{lines}")
    return site


def env(site: Path, **variables: str) -> dict[str, str]:
    """This environment without I2PBENCH_* settings, seeing `site` and the test plugins in tests/."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("I2PBENCH_")}
    path = os.pathsep.join([str(site), str(TESTS), clean.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return {**clean, "PYTHONPATH": path, **variables}


def i2pbench(*args: str, env: dict[str, str], cwd: Path, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "i2pbench.cli", *args], env=env, cwd=cwd, capture_output=True, text=True, **kwargs
    )


def popen(*args: str, env: dict[str, str], cwd: Path) -> subprocess.Popen:
    """`i2pbench ARGS` started in the background, its output going to `cwd`/i2pbench.log: a file, not a pipe, so
    that processes it leaves behind cannot block the test reading it."""
    with open(cwd / LOG, "w") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "i2pbench.cli", *args],
            env=env,
            cwd=cwd,
            stdout=log,
            stderr=subprocess.STDOUT,
            preexec_fn=default_sigint,
        )


def default_sigint() -> None:
    """a child that hears Ctrl-C whatever started the tests: an ignored SIGINT (a background job, nohup, some CI
    runners) is inherited across exec, and the child would never see the test's SIGINT."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def wait_for_markers(markers: Path, run: subprocess.Popen, cwd: Path, count: int = 1, limit_s: float = 240) -> set[int]:
    """The pids of the processes that reached a fault plugin's stage (files `<frame>.<pid>` in `markers`), once
    `count` of them have; `run` is the `popen` started in `cwd`."""
    deadline = time.monotonic() + limit_s
    while len(pids := {int(m.name.rsplit(".", 1)[1]) for m in markers.iterdir()}) < count:
        assert run.poll() is None, f"the run ended early:\n{(cwd / LOG).read_text()}"
        assert time.monotonic() < deadline, f"only {len(pids)} of {count} processes reached the stage"
        time.sleep(0.2)
    return pids


def gone(pid: int, limit_s: float = 30) -> bool:
    """Whether the process exits (or is left a zombie, which holds no memory) within `limit_s`."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        stat = Path(f"/proc/{pid}/stat")
        if stat.exists() and stat.read_text().rsplit(")", 1)[-1].split()[0] == "Z":
            return True
        time.sleep(0.2)
    return False


def descendants(pid: int) -> set[int]:
    """Every live process below `pid` (children, their children...), from /proc (Linux)."""
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[-1].split()
        except OSError:  # exited while listed
            continue
        parents[int(stat.parent.name)] = int(fields[1])
    below, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - below
        below |= frontier
    return below
