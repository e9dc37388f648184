"""The long runs' bookkeeping (scripts/long_run.py): where chunks stop, and which points its table joins."""

import json

import long_run  # scripts/ is on pytest's path, as on a script's
import pandas as pd


def test_chunks_stop_at_the_next_multiple_and_never_past_the_end():
    assert long_run.next_stop(8500, 100, 9500) == 8600
    assert long_run.next_stop(8650, 100, 9500) == 8700  # a run stopped between chunks rejoins the grid
    assert long_run.next_stop(8600, 100, 8650) == 8650


def test_the_table_joins_the_curves_13_drive_points_to_the_plain_run_and_drops_the_shipped_record(tmp_path):
    records = [
        {"name": "augment", "lever": "augment", "step": 100, "val_P": 36.9},  # the shipped weights, before a step
        {"name": "augment", "lever": "augment", "step": 8600, "val_P": 13.91},
        {"name": "plain", "lever": "", "step": 8800, "val_P": 15.07},
    ]
    (tmp_path / "progress.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    curve = pd.DataFrame(
        [
            {"arm": "synthetic", "lever": None, "drives": 13, "steps": 100, "val_P": 13.59},
            {"arm": "synthetic", "lever": None, "drives": 13, "steps": 200, "val_P": 14.56},
            {"arm": "synthetic", "lever": None, "drives": 1, "steps": 100, "val_P": 18.83},  # another drive count
            {"arm": "scratch", "lever": None, "drives": 13, "steps": 100, "val_P": 17.45},  # another arm
            {"arm": "synthetic", "lever": "mix", "drives": 13, "steps": 50, "val_P": 23.71},  # a lever
            {"arm": "shipped (synthetic only)", "lever": None, "drives": 0, "steps": 0, "val_P": 36.9},
        ]
    )
    curve.to_csv(tmp_path / "curve.csv", index=False)
    table = long_run.table([tmp_path], tmp_path / "curve.csv")
    got = list(zip(table["name"], table["step"], table["val_P"], strict=True))
    assert got == [("augment", 8600, 13.91), ("plain", 8600, 13.59), ("plain", 8700, 14.56), ("plain", 8800, 15.07)]
