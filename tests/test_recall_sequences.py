"""Registration recall at thresholds, error percentiles and the per-sequence breakdown, on hand-built records.

Five frames of one row (protocol thresholds 5° and 2 m): sequence 00 has (RTE 0.3 m, RRE 0.8°), (1.5, 4.0) and a
failure (inf, inf); sequence 01 has (0.6, 12.0) and (3.0, 1.5).
"""

from __future__ import annotations

import math
import re

import pandas as pd
from conftest import nuscenes_sample

from i2pbench.cli import main
from i2pbench.report import sequences
from i2pbench.report.html import write_report
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.scoring.recall import by_sequence, cells, sequence

INF = math.inf
RECORDS = pd.DataFrame({
    "dataset": "kitti", "combination": "a", "weights": "none", "corruption": "",
    "frame_id": ["00/000001", "00/000002", "00/000003", "01/000001", "01/000002"],
    "rte_m": [0.3, 1.5, INF, 0.6, 3.0],
    "rre_deg": [0.8, 4.0, INF, 12.0, 1.5],
})  # fmt: skip


def test_recall_counts_every_frame_and_meets_acc_at_the_protocols_thresholds():
    row = cells(RECORDS, Protocol())
    # RRE steps at RTE < 2 m: 1° and 2° only the first frame; 5° and 10° add (1.5, 4.0); 20° adds (0.6, 12.0)
    assert [row[f"recall RRE<{t}° (%)"] for t in ("1", "2", "5", "10", "20")] == [20.0, 20.0, 40.0, 40.0, 60.0]
    # RTE steps at RRE < 5°: (0.6, 12.0) never counts; 5 m adds (3.0, 1.5)
    assert [row[f"recall RTE<{t} m (%)"] for t in ("0.25", "0.5", "1", "2", "5")] == [0.0, 20.0, 20.0, 40.0, 60.0]


def test_percentiles_take_a_frames_error_and_a_failure_is_infinite():
    row = cells(RECORDS, Protocol())
    # sorted RTE 0.3, 0.6, 1.5, 3.0, inf: the first whose share of frames reaches 25, 50, 75, 90 %
    assert [row[f"RTE p{q} (m)"] for q in (25, 50, 75, 90)] == [0.6, 1.5, 3.0, INF]
    assert [row[f"RRE p{q} (°)"] for q in (25, 50, 75, 90)] == [1.5, 4.0, 12.0, INF]


def test_by_sequence_splits_each_row_by_the_frame_ids_folder():
    table = by_sequence(RECORDS, Protocol()).set_index("sequence")
    assert table.loc["all"].tolist() == ["a", "none", 5, 40.0, 1.5, INF, 4.0, INF]
    assert table.loc["00"].tolist() == ["a", "none", 3, 66.67, 1.5, INF, 4.0, INF]
    assert table.loc["01"].tolist() == ["a", "none", 2, 0.0, 0.6, 3.0, 1.5, 12.0]


def test_each_row_and_sequence_is_one_line_and_all_only_sums_several_sequences():
    """Row a spans 00 and 01; row b (trained weights) only 00, where an "all" line would repeat the 00 line (the
    report's duplicated row, issue 45); row c is a's combination with other weights."""
    b = RECORDS[RECORDS["frame_id"].str.startswith("00/")].assign(weights="w.pt")
    c = RECORDS.iloc[3:].assign(weights="other.pt", rte_m=[0.1, 0.2], rre_deg=[0.3, 0.4])
    table = by_sequence(pd.concat([RECORDS, b, c]), Protocol())
    assert table[["combination", "weights", "sequence"]].values.tolist() == [
        ["a", "none", "all"], ["a", "none", "00"], ["a", "none", "01"], ["a", "w.pt", "00"], ["a", "other.pt", "01"]
    ]  # fmt: skip
    assert table.iloc[3, 3:].tolist() == [3, 66.67, 1.5, INF, 4.0, INF]  # frames 00/1-3 as row a's 00 line
    assert table.iloc[4, 3:].tolist() == [2, 100.0, 0.1, 0.2, 0.3, 0.4]


def test_nuscenes_frames_are_grouped_by_camera():
    assert sequence("nuscenes", "0a1b2c/CAM_FRONT") == "camera CAM_FRONT"
    assert sequence("kitti-drives", "2011_09_26_drive_0005/0000000010") == "2011_09_26_drive_0005"


def test_the_board_and_the_report_carry_them(shared_data, tmp_path):
    runs = tmp_path / "runs"
    argv = ["run", "--extractor", "canny", "--extractor3d", "depth", "--matcher", "oracle", "--solver",
            "epnp-ransac", "--dataset", "kitti", "--split", "all", "--data-root", str(shared_data / "kitti_odometry"),
            "--frames", "3", "--runs-dir", str(runs), "--quiet", "--out", str(tmp_path / "board")]  # fmt: skip
    assert main(argv) == 0
    board = pd.read_parquet(tmp_path / "board.parquet")
    records = ResultsStore(runs / "kitti-all").load()
    assert records["sequence"].tolist() == [f.partition("/")[0] for f in records["frame_id"]]
    assert board["recall RRE<5° (%)"].tolist() == board["Acc. (%) ↑"].tolist()
    assert board["recall RTE<2 m (%)"].tolist() == board["Acc. (%) ↑"].tolist()
    assert "RRE p90 (°)" in board
    write_report(runs / "kitti-all", tmp_path / "report.html", overlays=0)
    page = (tmp_path / "report.html").read_text()
    section = page[page.index("<h2>By sequence</h2>") : page.index("<h2>Latency</h2>")]
    heads = re.findall(r"<th>([^<]*)</th>", section)
    assert heads[:4] == ["combination", "weights", "sequence", "frames"]
    combination = "canny &gt; depth &gt; oracle &gt; epnp-ransac"
    assert section.count(f'<td class="text name" data-sort="{combination}">') == 1  # 3 frames, all of sequence 00
    assert '<td class="text" data-sort="00">00</td>' in section and ">all</td>" not in section


def test_a_recorded_sequence_wins_over_the_frame_ids_folder():
    records = RECORDS.assign(sequence=["scene-1", "scene-1", "scene-2", "", ""])  # the last two written before
    table = by_sequence(records, Protocol()).set_index("sequence")
    assert list(table.index) == ["all", "01", "scene-1", "scene-2"]
    assert table.loc["scene-1", "frames"] == 2 and table.loc["01", "frames"] == 2


def test_a_nuscenes_frame_belongs_to_its_scene(tmp_path):
    from test_data_nuscenes import SAMPLE, build_dataroot

    nuscenes_sample()

    from i2pbench.data.nuscenes import NuScenes

    data = NuScenes("val", {"root": str(build_dataroot(tmp_path, "v1.0-trainval"))})
    assert data.sequence_of(f"{SAMPLE}/CAM_FRONT") == "scene-0916"
    assert data.sequence_of("no-such-sample/CAM_BACK") == "camera CAM_BACK"


def test_the_reports_table_follows_the_leaderboards_order():
    b = RECORDS.assign(weights="w.pt")
    table = sequences.table(pd.concat([RECORDS, b]), Protocol(), [("a", "w.pt"), ("a", "none")])
    assert table["weights"].tolist() == ["w.pt"] * 3 + ["none"] * 3
    assert table["sequence"].tolist() == ["all", "00", "01"] * 2


def test_evaluate_by_sequence_prints_one_named_line_per_row_and_sequence(tmp_path, capsys):
    runs = tmp_path / "runs"
    argv = ["run", "--extractor", "lsd,canny", "--extractor3d", "depth", "--matcher", "oracle", "--solver",
            "epnp-ransac", "--dataset", "synthetic", "--split", "test", "--frames", "2", "--threads", "1",
            "--runs-dir", str(runs), "--out", str(tmp_path / "board"), "--quiet"]  # fmt: skip
    assert main(argv) == 0
    capsys.readouterr()
    assert main(["evaluate", str(runs / "synthetic-test"), "--by-sequence"]) == 0
    table = capsys.readouterr().out.split("\n\n")[1].splitlines()
    assert table[0].startswith("| combination | weights | sequence | frames | Acc. (%) ↑ |")
    cells = [line.strip("| ").split(" | ")[:4] for line in table[2:]]
    assert cells == [[f"{e} > depth > oracle > epnp-ransac", "none", "02", "2"] for e in ("lsd", "canny")]
