"""`run --workers 2` whose driver is SIGKILLed leaves no worker behind (each held ~450 MB of weights for good)."""

import contextlib
import os
import signal
import sys

import plugin_dists
import pytest

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="reads /proc to find the worker processes")


@pytest.mark.parametrize("isolate", ["thread", "process"])
def test_workers_exit_when_the_driver_is_killed(tmp_path, isolate):
    site = plugin_dists.install(tmp_path / "site", {"toy": "toy_plugin", "faults": "fault_plugin"})
    markers = tmp_path / "markers"
    markers.mkdir()
    env = plugin_dists.env(site, I2PBENCH_LOAD_PLUGINS="toy,faults", I2PBENCH_STAGE_TIMEOUT_S="none")
    nap = ["--extractor3d", "nap", "--conf", "extractor3d.frame=any", "--conf", "extractor3d.seconds=600"]
    stages = ["--dataset", "toy", "--extractor", "grid", "--matcher", "truth", "--solver", "truth", *nap]
    args = [*stages, "--conf", f"extractor3d.markers={markers}", "--workers", "2", "--isolate", isolate, "--quiet"]
    driver = plugin_dists.popen("run", *args, env=env, cwd=tmp_path)
    below: set[int] = set()
    try:
        # both workers (or, isolated, their children) inside a 10-minute stage
        napping = plugin_dists.wait_for_markers(markers, driver, tmp_path, count=2)
        below = plugin_dists.descendants(driver.pid)  # the workers, their children, multiprocessing's tracker
        assert napping <= below
        driver.send_signal(signal.SIGKILL)
        driver.wait(timeout=30)
        assert [pid for pid in below if not plugin_dists.gone(pid, limit_s=30)] == []
    finally:  # what a regression would leave behind is this test's to clean up
        for pid in below | plugin_dists.descendants(driver.pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        driver.kill()
        driver.wait()
