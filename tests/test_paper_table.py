"""A preset may name other presets (a table across plugins' methods), and `i2pbench table` lays one preset's rows
out across several datasets' leaderboards, finding each row by its label in the clean protocol, never inventing
a number for a row a board lacks."""

import math
import os
import types
from pathlib import Path

import pandas as pd
import pytest
import toy_plugin

from i2pbench.boards import paper_table
from i2pbench.boards.leaderboard import ACC, ACC_SKILL, CHANCE, MODEL_SIZE, RTE, TRUE_MATCHES, write
from i2pbench.cli import main
from i2pbench.errors import I2PBenchError, PluginError
from i2pbench.registry.build import build_registry, default_registry
from i2pbench.runs.grid import base_combinations

TRUTH = {"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"}
CONSTANT = {**TRUTH, "solver": "constant"}


@pytest.fixture
def only_toys(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")


def _tables_plugin(*presets):
    """A plugin registering (name, entries) presets, as a third party's tables package would."""

    def register_presets(register):
        for name, entries in presets:
            register(name, list(entries), f"{name} rows")

    return types.SimpleNamespace(register_presets=toy_plugin.hookimpl(register_presets))


def _registry(*presets):
    return build_registry((toy_plugin, _tables_plugin(*presets)), strict=True)


def test_an_included_preset_gives_its_rows_in_place_and_in_order(only_toys):
    registry = _registry(("consts", [CONSTANT]), ("table", ["consts", TRUTH, "default"]))
    assert registry.preset_rows("table") == [CONSTANT, TRUTH, TRUTH]
    assert base_combinations(registry, "table") == [CONSTANT, TRUTH]  # as a run's rows: each combination once


def test_an_included_preset_no_plugin_registers_and_a_cycle_are_errors_naming_them(only_toys):
    registry = _registry(("table", ["default", "corri2p"]), ("a", ["b"]), ("b", ["a"]))
    with pytest.raises(PluginError, match="preset 'table' .*includes preset 'corri2p', which no loaded plugin"):
        registry.preset_rows("table")
    with pytest.raises(PluginError, match="includes itself via 'a'"):
        registry.preset_rows("a")


def test_the_paper_table_lists_the_seed_papers_methods_in_table_1_order():
    registry = default_registry()
    names = [row.name for row in paper_table.preset_rows(registry, "paper-table-1")]
    assert names == [
        "deepi2p",
        "deepi2p (deepi2p-frustum-3d)",
        "deepi2p (deepi2p-frustum-2d)",
        "deepi2p (deepi2p-official)",
        "corri2p",
        "corri2p (corri2p-official)",
        "vp2p-match (vp2p-match-official)",
        "cofii2p (cofii2p-official)",
        "edgeregnet (default)",
        "classic-oracle",
    ]


def _board(rows: list[dict]) -> pd.DataFrame:
    base = {"weights": "none", "weights_trained_on": "", "corruption": "", "frames": 4, MODEL_SIZE: 0.0}
    return pd.DataFrame([{**base, **row} for row in rows])


ROWS = [paper_table.TableRow("ours", "a > b"), paper_table.TableRow("peer", "c > d")]


def test_each_row_takes_its_own_board_row_of_the_clean_protocol_and_a_missing_one_stays_empty():
    kitti = _board(
        [
            {
                "combination": "a > b",
                ACC: 75.0,
                CHANCE: 1,
                ACC_SKILL: 50.0,
                RTE: "0.50 ± 0.10",
                TRUE_MATCHES: 12.0,
                MODEL_SIZE: 9.4,
            },
            {"combination": "a > b", ACC: 25.0, CHANCE: 0, "corruption": "fog", RTE: "1.00 ± 0.20"},
            {"combination": "c > d", ACC: 50.0, CHANCE: 2, ACC_SKILL: 0.0, RTE: "0.90 ± 0.30", TRUE_MATCHES: 3.0},
        ]
    )
    nuscenes = _board([{"combination": "a > b", ACC: 10.0, CHANCE: 0, RTE: "1.50 ± 0.40", TRUE_MATCHES: 5.0}])
    table = paper_table.build(ROWS, {"KITTI": kitti, "nuScenes": nuscenes})
    ours, peer = table.iloc[0], table.iloc[1]
    assert (ours["KITTI Acc. (%) ↑"], ours["KITTI RTE (m) ↓"], ours["KITTI chance successes"]) == (
        75.0,
        "0.50 ± 0.10",
        1,
    )
    assert (ours["nuScenes Acc. (%) ↑"], ours[MODEL_SIZE]) == (10.0, 9.4)
    assert peer["KITTI true matches median ↑"] == 3.0
    assert (ours["KITTI Acc. with true matches (%) ↑"], peer["KITTI Acc. with true matches (%) ↑"]) == (50.0, 0.0)
    assert math.isnan(peer["nuScenes Acc. (%) ↑"]) and math.isnan(peer["nuScenes frames"])
    assert paper_table.missing(table, ["KITTI", "nuScenes"]) == {"KITTI": [], "nuScenes": ["peer"]}
    text = paper_table.to_text(table, ROWS, {"KITTI": "k.csv", "nuScenes": "n.csv"})
    assert "- nuScenes: `n.csv`; not run there: peer" in text
    assert "| peer | 4 | 0.90 ± 0.30 | - | 50.00 | 2 | 0.00 | 3.00 |" in text  # counts whole, numbers to 2 decimals


def test_the_table_command_reads_leaderboards_and_refuses_a_name_given_twice(tmp_path, capsys):
    label = "lsd > depth+reflectance > oracle > epnp-ransac"
    write(
        _board(
            [{"combination": label, ACC: 100.0, CHANCE: 0, ACC_SKILL: 100.0, RTE: "0.03 ± 0.02", TRUE_MATCHES: 110.0}]
        ),
        tmp_path / "k",
    )
    assert (
        main(["table", "--preset", "classic-oracle", f"KITTI={tmp_path / 'k.csv'}", "--out", str(tmp_path / "t")]) == 0
    )
    out = capsys.readouterr().out
    assert (
        f"| {label} | 4 | 0.03 ± 0.02 | - | 100.00 | 0 | 100.00 | 110.00 |" in out
    )  # a plain row is named by its label
    assert (tmp_path / "t.md").read_text().startswith("| method | KITTI frames |")
    assert pd.read_csv(tmp_path / "t.csv")["KITTI Acc. (%) ↑"].tolist() == [100.0]
    assert main(["table", "--preset", "classic-oracle", f"A={tmp_path / 'k.csv'}", f"A={tmp_path / 'k.csv'}"]) == 2
    assert "a column group's name is given twice" in capsys.readouterr().err


def test_a_label_with_rows_of_two_weights_in_one_board_is_refused_not_guessed():
    board = _board([{"combination": "a > b", "weights": w, ACC: 10.0} for w in ("one@1", "two@2")])
    with pytest.raises(I2PBenchError, match=r"leaderboard of KITTI has 2 rows 'a > b' \(one@1, two@2\)"):
        paper_table.build(ROWS[:1], {"KITTI": board})


@pytest.mark.parametrize("kind", ["device", "folder"])
def test_table_out_naming_a_device_or_folder_is_refused_before_reading_a_board(tmp_path, capsys, kind):
    out = os.devnull if kind == "device" else str(tmp_path)
    assert main(["table", "--preset", "classic-oracle", f"KITTI={tmp_path / 'absent.csv'}", "--out", out]) == 2
    err = capsys.readouterr().err
    said = "is not a regular file" if kind == "device" else "is a folder; --out is a file stem"
    assert f"--out {out} {said}" in err and "absent.csv" not in err  # refused before the missing board is read
    assert not Path(f"{os.devnull}.csv").exists()


def test_table_out_ending_in_csv_is_taken_as_the_stem(tmp_path, capsys):
    label = "lsd > depth+reflectance > oracle > epnp-ransac"
    write(
        _board([{"combination": label, ACC: 100.0, CHANCE: 0, ACC_SKILL: 100.0, TRUE_MATCHES: 110.0}]), tmp_path / "k"
    )
    assert (
        main(["table", "--preset", "classic-oracle", f"KITTI={tmp_path / 'k.csv'}", "--out", str(tmp_path / "t.csv")])
        == 0
    )
    stem = tmp_path / "t"
    assert f"--out {stem}.csv is taken as the stem {stem}: writing {stem}.csv, {stem}.md\n" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.glob("t*")) == ["t.csv", "t.md"]
