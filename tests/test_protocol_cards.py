"""Protocol cards and their scoring rules, on hand-built per-frame rows whose numbers are worked out by hand.

Eight frames, each with a chosen error E = P_diff = inv(T_pred) @ T_gt (so T_pred = T_gt @ inv(E)); R_gt = I except
frame D, so ICL's yaw angle and its ||t_gt - t_pred|| are readable from E too:

| frame | E (rotation, translation m)  | RTE | xzy sum ° | geodesic ° | ICL RRE ° | note                          |
|-------|------------------------------|-----|-----------|------------|-----------|-------------------------------|
| A     | Rx(2), (1, 0, 0)             | 1   | 2         | 2          | 0         | pitch: ICL reads 0            |
| B     | Rz(3), (0, 1.5, 0)           | 1.5 | 3         | 3          | 3         |                               |
| C     | Rz(3) Rx(3), (0.5, 0, 0)     | 0.5 | 6         | 4.24       | 3         | xzy sum misses, geodesic hits |
| D     | failed PnP; T_gt = Ry(40), t (3, 0, 4) | identity: 5 | 40 | 40   | 40        |                               |
| E     | Rx(20), (6, 0, 0)            | 6   | 20        | 20         | 0         | beyond every filter           |
| F     | Rz(8), (0, 0, 3)             | 3   | 8         | 8          | 8         | a miss the (10°, 5 m) filter keeps |
| G     | I, (0, 0, -4); t_gt (0, 0, 11) | 4 | 0         | 0          | 0         | ||t_pred|| = 15 >= 14.14      |
| H     | Rx(1), (0.2, 0, 0), every match an inlier | 0.2 | 1 | 1     | 0         | DeepI2P leaves it out         |
"""

from __future__ import annotations

import math
import statistics

import numpy as np
import pandas as pd
import pytest

from i2pbench.geometry.transforms import invert
from i2pbench.registry.build import build_registry
from i2pbench.registry.hookspecs import hookimpl
from i2pbench.scoring import cards, installed
from i2pbench.scoring.cards import NATIVE, ProtocolCard
from i2pbench.scoring.protocol import Protocol
from i2pbench.scoring.rules import ScoringRules
from i2pbench.scoring.score import frame_errors, score


def rot(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


def pose(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def row(E: np.ndarray | None, T_gt: np.ndarray, inliers: int = 20) -> dict:
    T_pred = None if E is None else T_gt @ invert(E)
    return {
        "T_pred": None if T_pred is None else T_pred.ravel().tolist(),
        "T_gt": T_gt.ravel().tolist(),
        "status": "ok" if E is not None else "failed",
        "n_inliers": inliers if E is not None else np.nan,
        "n_matches": 50,
    }


I4 = np.eye(4)
FRAMES = pd.DataFrame([
    row(pose(rot("x", 2), [1, 0, 0]), I4),  # A
    row(pose(rot("z", 3), [0, 1.5, 0]), I4),  # B
    row(pose(rot("z", 3) @ rot("x", 3), [0.5, 0, 0]), I4),  # C
    row(None, pose(rot("y", 40), [3, 0, 4])),  # D
    row(pose(rot("x", 20), [6, 0, 0]), I4),  # E
    row(pose(rot("z", 8), [0, 0, 3]), I4),  # F
    row(pose(np.eye(3), [0, 0, -4]), pose(np.eye(3), [0, 0, 11])),  # G
    row(pose(rot("x", 1), [0.2, 0, 0]), I4, inliers=50),  # H
], index=list("ABCDEFGH"))  # fmt: skip
C_GEODESIC = math.degrees(math.acos((2 * math.cos(math.radians(3)) + math.cos(math.radians(3)) ** 2 - 1) / 2))


def check(result: dict, acc: float, rte: list[float], rre: list[float], scored: int) -> None:
    """`result` against Acc. and the mean and population std of the hand-listed kept errors."""
    assert result["scored"] == scored and result["kept"] == len(rte)
    assert result["acc_pct"] == pytest.approx(acc, abs=1e-9)
    assert result["rte_mean"] == pytest.approx(statistics.fmean(rte), abs=1e-9)
    assert result["rte_std"] == pytest.approx(statistics.pstdev(rte), abs=1e-9)
    assert result["rre_mean"] == pytest.approx(statistics.fmean(rre), abs=1e-9)
    assert result["rre_std"] == pytest.approx(statistics.pstdev(rre), abs=1e-9)


def test_the_frames_errors_are_the_chosen_ones():
    xzy = frame_errors(FRAMES, ScoringRules())
    assert xzy["rte"].round(9).tolist() == [1, 1.5, 0.5, math.inf, 6, 3, 4, 0.2]
    assert xzy["rre"].round(9).tolist() == [2, 3, 6, math.inf, 20, 8, 0, 1]
    geodesic = frame_errors(FRAMES, ScoringRules(rre="geodesic"))
    assert geodesic.loc["C", "rre"] == pytest.approx(C_GEODESIC, abs=1e-9)
    assert 4.24 < C_GEODESIC < 4.25  # the xzy sum says 6°, a miss at 5°; the rotation's angle is a hit


def test_edgeregnet_a_failure_is_an_infinite_miss_and_the_filter_keeps_rre_below_10_rte_below_5():
    # successes A, B, H of 8; kept A, B, C, F, G, H (D infinite, E beyond both thresholds)
    result = score(FRAMES, installed.find("edgeregnet").rules)
    check(result, 300 / 8, [1, 1.5, 0.5, 3, 4, 0.2], [2, 3, 6, 8, 0, 1], scored=8)
    assert result["rte_mean"] == pytest.approx(1.7) and result["rte_std"] == pytest.approx(math.sqrt(11.2 / 6))


@pytest.mark.parametrize("name", ["corri2p", "vp2p-match"])
def test_corri2p_and_vp2p_score_a_failure_as_identity_and_average_every_frame(name):
    # D as the identity pose: RTE = ||t_gt|| = 5, RRE = 40 (a yaw); no filter, so E's 6 m and 20° count too
    check(score(FRAMES, installed.find(name).rules), 300 / 8, [1, 1.5, 0.5, 5, 6, 3, 4, 0.2],
          [2, 3, 6, 40, 20, 8, 0, 1], scored=8)  # fmt: skip


def test_deepi2p_caps_the_translation_and_leaves_out_an_all_inlier_frame():
    # H (50 of 50 matches inliers: cost 0) is left out; G's ||t_pred|| = 15 >= 14.14 becomes the identity: RTE 11
    check(score(FRAMES, installed.find("deepi2p").rules), 200 / 7, [1, 1.5, 0.5, 5, 6, 3, 11],
          [2, 3, 6, 40, 20, 8, 0], scored=7)  # fmt: skip


def test_cofii2p_skips_a_failure_and_counts_successes_at_10_deg_5_m_over_the_solved_frames():
    # D never recorded; of 7, all but E pass (10°, 5 m); mean and std over those 6
    check(score(FRAMES, installed.find("cofii2p").rules), 600 / 7, [1, 1.5, 0.5, 3, 4, 0.2], [2, 3, 6, 8, 0, 1],
          scored=7)  # fmt: skip


def test_icl_reads_only_yaw_and_the_difference_of_translations():
    # A, E and H are pitch errors (0°); C's yaw part is 3°, so C succeeds here where the xzy sum fails it
    check(score(FRAMES, installed.find("icl").rules), 400 / 8, [1, 1.5, 0.5, 5, 6, 3, 4, 0.2],
          [0, 3, 3, 40, 0, 8, 0, 0], scored=8)  # fmt: skip


def test_a_geodesic_rule_turns_the_xzy_miss_into_a_success():
    result = score(FRAMES, ScoringRules(rre="geodesic"))
    check(result, 400 / 8, [1, 1.5, 0.5, 3, 4, 0.2], [2, 3, C_GEODESIC, 8, 0, 1], scored=8)


def test_ddof_1_divides_by_n_minus_1():
    result = score(FRAMES, ScoringRules(ddof=1))
    assert result["rte_std"] == pytest.approx(statistics.stdev([1, 1.5, 0.5, 3, 4, 0.2]), abs=1e-9)


def test_a_frame_without_ground_truth_is_infinite_under_identity_rules_and_skipped_when_failures_are():
    broken = pd.concat([FRAMES.loc[["A"]], pd.DataFrame([{**FRAMES.loc["B"].to_dict(), "T_gt": None}])])
    assert score(broken, installed.find("corri2p").rules)["rte_mean"] == math.inf
    assert score(broken, installed.find("cofii2p").rules)["scored"] == 1


def test_the_default_card_is_the_protocol_every_stored_result_was_made_under():
    # the identity of every clean record in the committed stores; a new field must never move it
    assert Protocol().identity() == "71a877f2ef9c7dc4"
    assert installed.find("edgeregnet").protocol().identity() == "71a877f2ef9c7dc4"
    assert installed.find("edgeregnet").protocol(seed=3) == Protocol(seed=3)
    corri2p = installed.find("corri2p").protocol()
    assert corri2p.card()["name"] == "corri2p" and corri2p.card()["version"] == 2
    assert corri2p.identity() != Protocol().identity()
    assert installed.read_back(corri2p.card()) == corri2p  # read back from an invocation record, its rules the card's


def test_a_run_can_give_every_card_its_kitti_inputs_but_deepi2ps_and_no_accumulated_sweeps():
    assert [c.name for c in cards.BUILTIN if not c.unmet("kitti")] == ["edgeregnet", "corri2p", "vp2p-match",
                                                                         "cofii2p", "icl"]  # fmt: skip
    assert installed.find("deepi2p").unmet("kitti") == [
        "sweeps: 3 sweeps accumulated (i2pbench: the frame's sweep)",
        "frame: another frame's image, up to 10 m away (i2pbench: the scan's own frame)",
    ]
    assert installed.find("cofii2p").unmet("nuscenes") == ["sweeps: 3 sweeps accumulated (i2pbench: the frame's sweep)"]
    assert installed.find("icl").unmet("nuscenes") == ["ICL (ICL-I2PReg)'s code has no nuscenes pipeline to follow"]
    corri2p = installed.find("corri2p").protocol(0, "kitti").card()
    assert {k: corri2p[k] for k in ("image_scale", "image_crop_h", "image_crop_w", "points", "voxel_m", "pose_frame")} \
        == {"image_scale": 0.5, "image_crop_h": 160, "image_crop_w": 512, "points": 40960, "voxel_m": 0.1,
            "pose_frame": "camera"}  # fmt: skip


def test_every_builtin_card_cites_its_code_at_a_pinned_commit():
    for card in cards.BUILTIN:
        assert card.cites, card.name
        for cite in card.cites:
            repo, _, rest = cite.partition("@")
            assert rest.startswith(cards.SOURCES[repo][:8] + " "), cite
            assert ":" in rest.split(" — ")[0], cite  # path:lines


class Geodesic:
    """A third party's card: today's inputs, scored by the geodesic angle."""

    card = ProtocolCard("geodesic-demo", 2, "a demo", NATIVE, NATIVE, ScoringRules(rre="geodesic"), ("demo",))

    @hookimpl
    def register_protocols(self, register):
        register(self.card)


def test_a_plugin_registers_its_own_card_and_cannot_take_a_builtin_name():
    registry = build_registry(extra_plugins=(Geodesic(),), strict=True)
    assert installed.find("geodesic-demo", registry).rules.rre == "geodesic"
    assert list(installed.installed(registry))[:6] == ["edgeregnet", "corri2p", "deepi2p", "vp2p-match", "cofii2p",
                                                     "icl"]  # fmt: skip

    class Clash:
        @hookimpl
        def register_protocols(self, register):
            register(ProtocolCard("corri2p", 1, "x", NATIVE, None, ScoringRules(), ()))

    with pytest.raises(Exception, match="'corri2p' is registered by both"):
        build_registry(extra_plugins=(Clash(),), strict=True)


def test_an_unknown_protocol_suggests_the_closest():
    with pytest.raises(Exception, match="did you mean 'corri2p'"):
        installed.find("corri2")


def test_the_cards_default_name_version_and_rules_are_the_protocols():
    from i2pbench.scoring import protocol

    assert (cards.DEFAULT_NAME, cards.DEFAULT_VERSION) == (protocol.DEFAULT_NAME, protocol.DEFAULT_VERSION)
    assert protocol.DEFAULT_RULES == cards.EDGEREGNET.rules


def test_a_protocol_holds_its_card_s_rules_and_the_default_card_is_a_registered_card(monkeypatch):
    """the rules travel with the Protocol (no look-up by name when a run is scored); the default card is in every
    registry, owned by i2pbench when the plugins are blocked, and no plugin takes its name."""
    deepi2p = cards.DEEPI2P.protocol(0, "kitti")
    assert deepi2p.rules is cards.DEEPI2P.rules and deepi2p.rules.drop_all_inliers  # DeepI2P's cost-0 frames
    assert Protocol().rules == cards.EDGEREGNET.rules and Protocol().acc_rre_deg == 5.0
    assert Protocol().with_thresholds(acc_rre_deg=1.0, acc_rte_m=None).rules == ScoringRules(acc_rre_deg=1.0)
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    blocked = build_registry()
    assert list(installed.installed(blocked)) == ["edgeregnet"] and blocked.protocols.plugin("edgeregnet") == "i2pbench"

    class Usurper:
        @hookimpl
        def register_protocols(self, register):
            register(ProtocolCard("edgeregnet", 1, "x", NATIVE, None, ScoringRules(ddof=1), ()))

    with pytest.raises(Exception, match="protocol name 'edgeregnet' is registered by both plugin 'i2pbench' and"):
        build_registry(extra_plugins=(Usurper(),), strict=True)


def test_docs_protocol_cites_every_line_each_card_follows():
    from pathlib import Path

    page = (Path(__file__).parent.parent / "docs" / "protocol.md").read_text()
    for card in cards.BUILTIN:
        assert f"#### `{card.name}` v{card.version}" in page
        for cite in card.cites:
            assert f"`{cite.split(' — ')[0]}` — {cite.split(' — ')[1]}" in page, cite
