"""Issue 31's weak list, Ctrl-C during `run`: no traceback, the workers stopped, every finished frame kept, the board
of what finished printed, the invocation marked. Deterministic: a 2D extractor registered here stalls on every frame
but the first, so the run can never finish on its own; the test signals once that frame's file is in the store."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import require
from i2pbench_classic.extract2d import CannyExtractor
from plugin_dists import default_sigint
from test_report_html import KITTI

from i2pbench.api import hookimpl

FIRST = "00/000000"
TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent


class StallAfterFirst(CannyExtractor):
    """Canny on the first frame; on any other it sleeps until the run is stopped."""

    name = "stall-after-first"

    def __call__(self, frame):
        if frame.frame_id != FIRST:
            time.sleep(3600)
        return super().__call__(frame)


class StallPlugin:
    @hookimpl
    def register_extractors_2d(self, register):
        register(StallAfterFirst)


# The CLI with the stalling extractor registered; spawned pool workers import this module to unpickle it.
LAUNCHER = f"""
import sys
sys.path.insert(0, {str(TESTS)!r})
if __name__ == "__main__":
    import test_issue31_interrupt
    from i2pbench.registry import build
    from i2pbench.cli import main

    registry = build.build_registry((test_issue31_interrupt.StallPlugin(),))
    build.default_registry = lambda: registry
    sys.exit(main())
"""


def _interrupted_run(tmp_path: Path, *extra: str) -> tuple[subprocess.CompletedProcess, Path]:
    require(KITTI)
    launcher, runs = tmp_path / "launch.py", tmp_path / "runs"
    launcher.write_text(LAUNCHER)
    args = ["run", "--dataset", "kitti", "--split", "all", "--data-root", str(KITTI), "--extractor",
            "stall-after-first", "--extractor3d", "depth", "--matcher", "oracle", "--solver", "epnp-ransac",
            "--runs-dir", str(runs), "--quiet", *extra]  # fmt: skip
    process = subprocess.Popen(
        [sys.executable, str(launcher), *args],
        cwd=tmp_path,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=default_sigint,  # else a suite started under nohup hands the run an ignored SIGINT
    )
    frames = runs / "kitti-all" / "frames"
    deadline = time.monotonic() + 300  # a guard against a hang, not a timing assertion
    while not list(frames.glob("*.parquet")):
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"the run ended or hung before its first frame: {process.communicate()[1][-2000:]}")
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=300)
    return subprocess.CompletedProcess(process.args, process.returncode, out, err), runs / "kitti-all"


@pytest.mark.parametrize("workers", [[], ["--workers", "2"]], ids=["serial", "pool"])
def test_ctrl_c_stops_the_workers_keeps_the_finished_frame_and_prints_its_board(tmp_path, workers):
    done, store = _interrupted_run(tmp_path, *workers)
    # the workers stalled for an hour: that the run came back at all says they were stopped, not waited for
    assert done.returncode == 130, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        f"i2pbench: interrupted (Ctrl-C): workers stopped; 1 of 6 frames finished (1 computed by this run), all kept "
        f"in {store / 'frames'}; the board above is of those; the same command resumes"
    )
    row = next(line for line in done.stdout.splitlines() if "stall-after-first > depth" in line)
    cells = [c.strip() for c in row.strip("|").split("|")]
    header = next(line for line in done.stdout.splitlines() if line.startswith("| dataset"))
    assert dict(zip([c.strip() for c in header.strip("|").split("|")], cells, strict=True))["frames"] == "1"

    import pandas as pd

    kept = [pd.read_parquet(p) for p in (store / "frames").glob("*.parquet")]
    assert [k["frame_id"].item() for k in kept] == [FIRST] and kept[0]["status"].item() == "ok"
    assert not list((store / "frames").glob(".*.tmp"))  # no half-written frame left
    (record,) = [json.loads(p.read_text()) for p in (store / "invocations").glob("*.json")]
    assert record["status"] == "failed" and record["error"] == "interrupted by Ctrl-C after 1 of 6 frames"
