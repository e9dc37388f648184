"""`i2pbench report` on a real run over the KITTI frames in ../shared/data: a self-contained page that renders in
headless Chromium without script errors, sorts its leaderboard on click, and tolerates moved data."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import cv2
import pytest
from conftest import SAMPLE_DATA, sample

from i2pbench.cli import main
from i2pbench.runs.store import ResultsStore

KITTI = SAMPLE_DATA / "kitti_odometry"
CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-logging=stderr",
    "--v=0",
]
# Injected into a copy of the page: record any script error into the DOM, then click headers as a reader would.
TRAP = (
    '<script>window.addEventListener("error", function (e) { var d = document.documentElement;'
    ' d.setAttribute("data-js-errors", (d.getAttribute("data-js-errors") || "") + e.message + ";"); });</script>'
)
PROBE = """<script>
function firstRow() { return document.querySelector("table.sortable tbody tr").cells[0].textContent; }
var headers = document.querySelectorAll("table.sortable th"), d = document.documentElement;
headers[0].click(); d.setAttribute("data-by-name", firstRow());
headers[0].click(); d.setAttribute("data-by-name-desc", firstRow());
</script>"""


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """Two classic combinations over two real KITTI frames (the smallest run with a best and a worst frame)."""
    sample("kitti_odometry")
    tmp = tmp_path_factory.mktemp("report")
    argv = [
        "run",
        "--preset",
        "classic-oracle",
        "--extractor",
        "lsd,canny",
        "--dataset",
        "kitti",
        "--split",
        "all",
        "--data-root",
        str(KITTI),
        "--frames",
        "2",
        "--runs-dir",
        str(tmp / "runs"),
        "--out",
        str(tmp / "lb"),
        "--quiet",
    ]
    assert main(argv) == 0
    return tmp / "runs" / "kitti-all"


@pytest.fixture(scope="module")
def page(run_dir) -> Path:
    out = run_dir.parent.parent / "report.html"
    assert main(["report", str(run_dir), "--out", str(out), "--quiet"]) == 0
    return out


def test_page_is_self_contained(page):
    text = page.read_text()
    assert not re.search(r"""(src|href)=["']?(https?:|//|file:)""", text)
    assert "<link" not in text
    images = re.findall(r'<img alt="[^"]*" src="data:image/(png|jpeg);base64,', text)
    assert images.count("png") == 3  # cumulative errors, Acc. curves, latency
    assert images.count("jpeg") == 4  # best and worst frame of each combination


def test_page_lists_both_combinations_with_their_frames(page):
    text = page.read_text()
    for name in ("lsd", "canny"):
        assert f'data-sort="{name} &gt; depth+reflectance &gt; oracle &gt; epnp-ransac">{name} &gt;' in text
    assert text.count("<figcaption>best frame of") == 2 and text.count("<figcaption>worst frame of") == 2


def test_records_of_another_protocol_are_left_out_and_said_so(run_dir, tmp_path):
    copy = tmp_path / "kitti-all"
    shutil.copytree(run_dir, copy)
    store = ResultsStore(copy)
    record = store.load().iloc[0].to_dict()
    store.put("another-protocol", {**record, "protocol": "0123456789abcdef", "combination": "stale"})
    out = tmp_path / "r.html"
    assert main(["report", str(copy), "--out", str(out), "--overlays", "0", "--quiet"]) == 0
    text = out.read_text()
    assert "1 records of other protocols left out" in text and "stale" not in text


def test_moved_data_still_gives_a_report_saying_why_overlays_are_missing(run_dir, tmp_path, capsys):
    out = tmp_path / "r.html"
    assert main(["report", str(run_dir), "--out", str(out), "--data-root", str(tmp_path / "gone"), "--quiet"]) == 0
    text = out.read_text()
    assert "not drawn" in text and "<figure>" not in text
    assert "not drawn" in capsys.readouterr().err


def test_not_a_runs_directory_is_refused(tmp_path, capsys):
    assert main(["report", str(tmp_path), "--quiet"]) == 2
    assert "not a runs directory" in capsys.readouterr().err


def chromium(*args: str, tmp: Path) -> subprocess.CompletedProcess:
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (scripts/install.sh installs it)")
    profile = tmp / "chromium-profile"
    cmd = [CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=180)


def test_page_renders_in_headless_chromium_and_is_not_blank(page, tmp_path):
    shot = tmp_path / "shot.png"
    result = chromium(f"--screenshot={shot}", "--window-size=1400,2000", page.resolve().as_uri(), tmp=tmp_path)
    assert shot.is_file(), result.stderr[-2000:]
    image = cv2.imread(str(shot), cv2.IMREAD_GRAYSCALE)
    assert image.shape == (2000, 1400)
    assert image.std() > 20 and (image < 128).mean() > 0.01  # text, tables and plots, not an empty white page
    assert "CONSOLE" not in result.stderr, result.stderr  # the browser logs every console message, errors included


def test_page_scripts_run_without_errors_and_sort_the_leaderboard(page, tmp_path):
    probed = tmp_path / "probed.html"
    text = page.read_text()
    probed.write_text(text.replace("<head>", "<head>" + TRAP, 1).replace("</body>", PROBE + "</body>", 1))
    dom = chromium("--dump-dom", probed.as_uri(), tmp=tmp_path).stdout
    assert "<html" in dom and 'data-js-errors="' not in dom
    assert 'aria-sort="none"' in dom  # the page's script ran and marked every header sortable
    assert 'data-by-name="canny' in dom and 'data-by-name-desc="lsd' in dom
    assert dom.split("</table>")[0].count("<tr>") == 3  # the leaderboard: header and two combinations
