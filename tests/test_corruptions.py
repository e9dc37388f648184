"""Corruptions as part of the protocol: deterministic, identity at severity 0, monotone in severity, blind to the
ground truth, valid stage inputs, open to third-party plugins through `register_corruptions`, and run by the CLI."""

import csv
import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import toy_plugin

from i2pbench.api import Corruption, hookimpl
from i2pbench.boards import leaderboard
from i2pbench.corruptions.base import CorruptionError
from i2pbench.errors import I2PBenchError, PluginError
from i2pbench.registry.build import build_registry, default_registry
from i2pbench.registry.listing import components_of
from i2pbench.report.rundir import resolved
from i2pbench.runs.executors import run_grid
from i2pbench.runs.grid import protocols
from i2pbench.runs.jobs import frame_key, prepare
from i2pbench.runs.store import ResultsStore
from i2pbench.runs.upstream import StoredUpstream
from i2pbench.scoring.metrics import true_matches
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.testing.frames import R_CAM_LIDAR, Scene, _image, _lidar
from i2pbench.types import SensorFrame

BUILTINS = {
    "gaussian-noise": "image",
    "motion-blur": "image",
    "defocus-blur": "image",
    "low-light": "image",
    "jpeg": "image",
    "fog": "image",
    "beam-reduction": "lidar",
    "point-dropout": "lidar",
    "range-noise": "lidar",
    "reflectance-noise": "lidar",
    "missing-sector": "lidar",
    "intrinsic-error": "geometry",
}
GEOMETRY = {"tilt": "geometry", "time-offset": "lidar"}  # tested in test_corruptions_geometry.py: one moves the cloud,
# the other needs the ego motion this file's hand-built frames do not have
NO_RANDOMNESS = {"defocus-blur", "jpeg", "fog", "beam-reduction"}  # the same output under every seed
T_CAM_LIDAR = np.eye(4)
T_CAM_LIDAR[:3, :3] = R_CAM_LIDAR  # camera looks along LiDAR +x
K = np.array([[32.0, 0.0, 32.0], [0.0, 32.0, 24.0], [0.0, 0.0, 1.0]])  # 64 x 48 px, fx = W / 2: a 90 degree view


def scan(image: np.ndarray | None = None) -> SensorFrame:
    """64 rings x 360 azimuths (1 degree apart, -180..179) on a 10 m cylinder, reflectance 0.5: 23040 points."""
    az, el = np.meshgrid(np.radians(np.arange(-180, 180)), np.radians(np.linspace(-24, 2, 64)))
    xyz = 10 * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    points = np.c_[xyz, np.full(len(xyz), 0.5)].astype(np.float32)
    ring = np.repeat(np.arange(64), 360).astype(np.int16)
    if image is None:
        image = np.random.default_rng(0).integers(0, 256, (48, 64, 3)).astype(np.uint8)  # white noise
    return SensorFrame("hand", "f0", image, points, ring, K, T_CAM_LIDAR)


def grey(value: int = 128) -> SensorFrame:
    return scan(np.full((48, 64, 3), value, np.uint8))


def impulse() -> SensorFrame:
    """One white pixel at (32, 24) on black: a blur turns it into the blur's kernel."""
    image = np.zeros((48, 64, 3), np.uint8)
    image[24, 32] = 255
    return scan(image)


def corrupt(name: str, sensor: SensorFrame, severity: int, seed: int = 0) -> SensorFrame:
    corruption = default_registry().corruption(name)()
    return Protocol(seed=seed).corrupted(corruption, severity).corrupt(sensor)


def spread_px(sensor: SensorFrame) -> float:
    """Root-mean-square distance of the image's light from its centroid (a blurred impulse: the blur's extent)."""
    weight = sensor.image[..., 0].astype(np.float64)
    v, u = np.indices(weight.shape)
    cu, cv = (weight * u).sum() / weight.sum(), (weight * v).sum() / weight.sum()
    return math.sqrt((weight * ((u - cu) ** 2 + (v - cv) ** 2)).sum() / weight.sum())


def disk_spread(r: int) -> float:
    """The rms radius of the discrete disk x^2 + y^2 <= r^2 (uniform weights survive rounding: 255 / pixels)."""
    y, x = np.mgrid[-r : r + 1, -r : r + 1]
    inside = x**2 + y**2 <= r**2
    return math.sqrt((x**2 + y**2)[inside].mean())


def test_every_builtin_is_registered_with_its_kind_a_meaning_and_five_levels():
    registry, builtins = default_registry(), {**BUILTINS, **GEOMETRY}
    assert {name: registry.corruption(name).kind for name in builtins} == builtins
    for name in builtins:
        cls = registry.corruption(name)
        assert cls.meaning and cls.parameter and len(cls.levels) == 5
    assert components_of(registry, "datasets")["corruption"] == sorted(builtins)


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_a_corruption_is_deterministic_per_seed(name):
    sensor = scan()
    first, again = corrupt(name, sensor, 3, seed=1), corrupt(name, sensor, 3, seed=1)
    fields = ("image", "points", "ring", "K")
    assert all(np.array_equal(getattr(first, f), getattr(again, f)) for f in fields)
    others = [corrupt(name, sensor, 3, seed=s) for s in (2, 3, 4)]
    differs = [any(not np.array_equal(getattr(first, f), getattr(o, f)) for f in fields) for o in others]
    assert any(differs) == (name not in NO_RANDOMNESS)


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_severity_zero_is_the_identity(name):
    sensor = scan()
    assert default_registry().corruption(name)().apply(sensor, 0, np.random.default_rng(0)) is sensor


def test_the_corruption_has_its_own_generator_so_the_protocols_transform_is_unchanged():
    p = Protocol(seed=4)
    corrupted = p.corrupted(default_registry().corruption("point-dropout")(), 2)
    assert np.array_equal(corrupted.random_transform("hand", "f0"), p.random_transform("hand", "f0"))
    salted = p.rng("hand", "f0", "point-dropout", "2").random(3)
    assert not np.array_equal(salted, p.rng("hand", "f0").random(3))
    assert not np.array_equal(salted, p.rng("hand", "f0", "point-dropout", "3").random(3))


def _series(name: str, sensor: SensorFrame, statistic) -> list[float]:
    return [statistic(sensor if s == 0 else corrupt(name, sensor, s)) for s in range(6)]


def test_beam_reduction_keeps_48_32_16_8_4_of_64_rings_each_inside_the_last():
    kept = [set(np.unique(corrupt("beam-reduction", scan(), s).ring)) if s else set(range(64)) for s in range(6)]
    assert [len(k) for k in kept] == [64, 48, 32, 16, 8, 4]
    assert kept[2] == set(range(1, 64, 2)) and kept[3] == set(range(3, 64, 4))  # evenly spread: every 2nd, every 4th
    assert all(a >= b for a, b in zip(kept, kept[1:], strict=False))
    assert [len(corrupt("beam-reduction", scan(), s).points) for s in (2, 3)] == [32 * 360, 16 * 360]


def test_point_dropout_drops_each_point_with_its_probability():
    counts = _series("point-dropout", scan(), lambda f: len(f.points))
    for count, p in zip(counts[1:], (0.2, 0.4, 0.6, 0.75, 0.9), strict=True):
        assert abs(count - 23040 * (1 - p)) < 4 * math.sqrt(23040 * p * (1 - p))  # binomial, 4 sigma
    assert counts == sorted(counts, reverse=True)


def test_missing_sector_removes_a_wedge_of_its_width_inside_the_cameras_view():
    for severity, width in enumerate((10, 20, 30, 45, 60), start=1):
        out = corrupt("missing-sector", scan(), severity)
        removed_azimuths = (23040 - len(out.points)) / 64  # one point per degree and ring
        assert width - 1 <= removed_azimuths <= width + 1
        gone = set(np.round(np.degrees(np.arctan2(scan().points[:, 1], scan().points[:, 0]))).astype(int))
        gone -= set(np.round(np.degrees(np.arctan2(out.points[:, 1], out.points[:, 0]))).astype(int))
        assert max(abs(a) for a in gone) < 45  # the camera sees azimuths -45..45 degrees
    assert _series("missing-sector", scan(), lambda f: len(f.points)) == [23040, 22400, 21760, 21120, 20160, 19200]


def test_range_noise_moves_returns_along_their_rays_and_the_frames_ranges_follow():
    stds = _series("range-noise", scan(), lambda f: float(np.linalg.norm(f.points[:, :3], axis=1).std()))
    assert stds[0] < 1e-5 and stds == sorted(stds)
    assert np.allclose(stds[1:], (0.02, 0.05, 0.1, 0.2, 0.4), rtol=0.05)
    out, sensor = corrupt("range-noise", scan(), 5), scan()
    unit = out.points[:, :3] / np.linalg.norm(out.points[:, :3], axis=1, keepdims=True)
    assert np.allclose(unit, sensor.points[:, :3] / 10.0, atol=1e-5)  # directions kept
    protocol = Protocol().corrupted(default_registry().corruption("range-noise")(), 5)
    frame = protocol.apply(sensor)
    assert np.allclose(frame.ranges, np.linalg.norm(out.points[:, :3], axis=1))
    assert np.allclose(np.linalg.norm(frame.points[:, :3] - protocol.random_transform("hand", "f0")[:3, 3], axis=1),
                       frame.ranges, atol=1e-4)  # fmt: skip


def test_reflectance_noise_grows_with_severity_and_stays_in_range():
    errors = _series("reflectance-noise", scan(), lambda f: float(np.abs(f.points[:, 3] - 0.5).mean()))
    assert errors[0] == 0 and errors == sorted(errors) and len(set(errors)) == 6
    out = corrupt("reflectance-noise", scan(), 5)
    assert out.points[:, 3].min() >= 0 and out.points[:, 3].max() <= 1


def test_gaussian_noise_has_its_sigma():
    stds = _series("gaussian-noise", grey(), lambda f: float((f.image.astype(float) - 128).std()))
    assert stds[0] == 0 and stds == sorted(stds)
    assert np.allclose(stds[1:], (8, 16, 24, 32, 48), rtol=0.05)  # clipping at 0 and 255 trims the largest


def test_low_light_darkens_grey_128_by_its_gamma():
    means = _series("low-light", grey(), lambda f: float(f.image.mean()))
    expected = [255 * (128 / 255) ** g for g in (1.5, 2.0, 2.5, 3.0, 3.5)]  # 90.7, 64.3, 45.6, 32.3, 22.9
    assert means[0] == 128 and means == sorted(means, reverse=True)
    assert np.allclose(means[1:], expected, atol=0.6)


def test_fog_scales_contrast_by_its_transmission_towards_the_airlight():
    sensor = scan()
    for severity, t in enumerate((0.8, 0.65, 0.5, 0.35, 0.2), start=1):
        out = corrupt("fog", sensor, severity).image.astype(float)
        assert abs(out.std() - t * sensor.image.std()) < 0.5
        assert abs(out.mean() - (t * sensor.image.mean() + (1 - t) * 200)) < 0.5
    variances = _series("fog", sensor, lambda f: float(f.image.var()))
    assert variances == sorted(variances, reverse=True)


def test_defocus_blur_spreads_a_point_into_its_disk():
    spreads = _series("defocus-blur", impulse(), spread_px)
    assert spreads[0] == 0
    assert np.allclose(spreads[1:], [disk_spread(r) for r in (1, 2, 3, 5, 7)], atol=1e-6)  # 0.89 .. 4.9 px


def test_motion_blur_spreads_a_point_along_a_line_of_its_length():
    spreads = _series("motion-blur", impulse(), spread_px)
    assert spreads[0] == 0 and spreads == sorted(spreads)
    for spread, length in zip(spreads[1:], (3, 7, 11, 15, 21), strict=True):
        assert abs(spread - math.sqrt((length**2 - 1) / 12)) < 0.6  # a uniform segment's rms, plus anti-aliasing
    laplacian = _series("motion-blur", scan(), lambda f: float(cv2.Laplacian(f.image, cv2.CV_64F).var()))
    assert laplacian[0] > 2 * max(laplacian[1:])  # white noise loses its fine detail


def test_jpeg_error_grows_as_quality_falls():
    sensor = scan()
    errors = _series("jpeg", sensor, lambda f: float(np.abs(f.image.astype(float) - sensor.image).mean()))
    assert errors[0] == 0 and errors == sorted(errors) and len(set(errors)) == 6


def test_intrinsic_error_moves_the_stages_focal_and_principal_point_by_its_percentage():
    for severity, e in enumerate((1, 2, 4, 7, 10), start=1):
        out = corrupt("intrinsic-error", scan(), severity)
        assert abs(out.K[0, 0] - 32) == pytest.approx(0.32 * e) and out.K[0, 0] / 32 == pytest.approx(out.K[1, 1] / 32)
        assert abs(out.K[0, 2] - 32) == pytest.approx(0.32 * e) and abs(out.K[1, 2] - 24) == pytest.approx(0.24 * e)
        assert np.array_equal(out.image, scan().image) and np.array_equal(out.points, scan().points)


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_the_ground_truth_is_never_touched(name):
    sensor = scan()
    before = {f: getattr(sensor, f).copy() for f in ("image", "points", "ring", "K", "T_cam_lidar")}
    clean = Protocol(seed=2).apply(sensor)
    frame = Protocol(seed=2).corrupted(default_registry().corruption(name)(), 5).apply(sensor)
    assert np.array_equal(frame.T_gt, clean.T_gt) and np.array_equal(frame.T_init, clean.T_init)
    assert np.array_equal(frame.K_true, K) and frame.match_radius_px == clean.match_radius_px
    assert all(np.array_equal(getattr(sensor, f), value) for f, value in before.items())  # the input is not mutated
    hidden = frame.without_ground_truth()
    assert hidden.T_gt is None and hidden.K_gt is None
    if name == "intrinsic-error":  # what the stages see is wrong; the truth rides with T_gt
        assert not np.array_equal(frame.K, K) and np.array_equal(frame.K_gt, K)
        assert not np.array_equal(hidden.K, K)
    else:
        assert frame.K_gt is None


class Recalibrate(Corruption):
    """A broken corruption: it changes the calibration it must not touch."""

    name, kind, meaning, parameter, levels = "recalibrate", "geometry", "wrong", "m", (1, 2, 3)

    def corrupt(self, sensor, level, rng):
        T = sensor.T_cam_lidar.copy()
        T[0, 3] += level
        return dataclasses.replace(sensor, T_cam_lidar=T)


class Darken(Corruption):
    """A broken image corruption: it also drops points."""

    name, kind, meaning, parameter, levels = "darken", "image", "wrong", "-", (1, 2, 3)

    def corrupt(self, sensor, level, rng):
        return dataclasses.replace(sensor, image=sensor.image // 2, points=sensor.points[:10], ring=sensor.ring[:10])


def test_a_corruption_changing_the_ground_truth_or_more_than_its_kind_is_refused():
    with pytest.raises(CorruptionError, match="'recalibrate' .* changed the ground truth"):
        Recalibrate().apply(scan(), 1, np.random.default_rng(0))
    with pytest.raises(CorruptionError, match=r"'darken' .* changed \['image', 'points', 'ring'\]; a image"):
        Darken().apply(scan(), 1, np.random.default_rng(0))


def conformance_sensor() -> SensorFrame:
    """The conformance kit's analytic scene (walls and a road, 16 rings) as a dataset would deliver it."""
    scene, size = Scene.random(3), (160, 96)
    k = np.array([[80.0, 0.0, 80.0], [0.0, 80.0, 48.0], [0.0, 0.0, 1.0]])
    points, ring = _lidar(scene, 16, 720)
    return SensorFrame("conformance", "scene-3", _image(scene, k, size), points, ring, k, T_CAM_LIDAR)


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_a_corrupted_frame_passes_the_stage_contracts(name):
    registry = default_registry()
    combination = {"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle",
                   "solver": "epnp-ransac"}  # fmt: skip
    pipeline = Pipeline.build(registry, Combination(combination))
    frame = Protocol().corrupted(registry.corruption(name)(), 5).apply(conformance_sensor())
    n = len(frame.points)
    assert frame.points.dtype == np.float32 and frame.ring.shape == frame.ranges.shape == (n,)
    assert frame.image.dtype == np.uint8 and frame.image.shape == (96, 160, 3)
    outcome = pipeline.run(frame)
    assert outcome.failed_component in ("", "solver 'epnp-ransac'"), outcome.error  # no contract broken upstream
    assert outcome.n_kp2d > 0 and outcome.n_kp3d > 0


def test_a_stored_upstream_keeps_the_true_intrinsics_so_a_resolve_counts_true_matches_as_the_run_did():
    registry = default_registry()
    combination = {"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle",
                   "solver": "epnp-ransac"}  # fmt: skip
    frame = Protocol().corrupted(registry.corruption("intrinsic-error")(), 5).apply(conformance_sensor())
    outcome = Pipeline.build(registry, Combination(combination)).run(frame)
    solver_frame = StoredUpstream.decode(StoredUpstream.of(frame, outcome).encode()).solver_frame()
    assert np.array_equal(solver_frame.K, frame.K) and np.array_equal(solver_frame.K_gt, frame.K_gt)
    assert true_matches(solver_frame, outcome) == true_matches(frame, outcome) == outcome.n_matches  # the oracle's


class Vignette(Corruption):
    """A third party's corruption: the image darkened towards its corners (lens vignetting)."""

    name, kind = "vignette", "image"
    meaning = "light falling off towards the image corners"
    parameter = "darkening at the corners"
    levels = (0.25, 0.5, 0.75)

    def corrupt(self, sensor, level, rng):
        h, w = sensor.image.shape[:2]
        v, u = np.indices((h, w))
        r2 = ((u - w / 2) / (w / 2)) ** 2 + ((v - h / 2) / (h / 2)) ** 2
        gain = 1 - level * np.clip(r2 / 2, 0, 1)
        return dataclasses.replace(sensor, image=(sensor.image * gain[..., None]).astype(np.uint8))


class VignettePlugin:
    __name__ = "vignette-plugin"

    @hookimpl
    def register_corruptions(self, register):
        register(Vignette)


@pytest.fixture
def third_party(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    return build_registry((toy_plugin, VignettePlugin()), strict=True)


def test_a_third_party_corruption_registered_through_the_hook_runs(third_party, tmp_path):
    assert components_of(third_party, "vignette-plugin") == {"corruption": ["vignette"]}
    assert third_party.corruption("vignette") is Vignette
    combination = Combination({"extractor2d": "grid", "extractor3d": "first", "matcher": "truth", "solver": "truth"})
    dataset = toy_plugin.ToyDataset("test", {})
    chosen = protocols(third_party, Protocol(), ["clean", "vignette:2"])
    store = ResultsStore(tmp_path / "runs")
    run = lambda name: [run_grid(third_party, [combination], dataset, p, store, invocation=name) for p in chosen]  # noqa: E731
    records = pd.concat(run("first"), ignore_index=True)
    assert list(zip(records["corruption"], records["severity"], records["frame_id"], strict=True)) == [
        ("", 0, "a"), ("", 0, "bad"), ("", 0, "c"), ("vignette", 2, "a"), ("vignette", 2, "bad"), ("vignette", 2, "c"),
    ]  # fmt: skip
    assert list(records["status"]) == ["ok", "failed", "ok"] * 2
    job = prepare(third_party, [combination])[0]
    keys = {frame_key(dataset, "a", job, p) for p in [*chosen, *protocols(third_party, Protocol(), ["vignette:3"])]}
    assert len(keys) == 3  # clean, severity 2 and severity 3 are cached apart
    assert len(store.load()) == 6 and set(pd.concat(run("second"))["invocation"]) == {"first"}  # a rerun is cached
    board = leaderboard.build(records)
    assert list(zip(board["corruption"], board["severity"], strict=True)) == [("", ""), ("vignette", "2")]


def test_corruption_specs_expand_to_protocols_and_bad_ones_are_refused(third_party):
    names = lambda ps: [(p.corruption, p.severity) for p in ps]  # noqa: E731
    assert names(protocols(third_party, Protocol(), ["vignette"])) == [("vignette", s) for s in (1, 2, 3)]
    assert names(protocols(third_party, Protocol(), ["clean", "all", "vignette:1"], [1, 3])) == [
        ("", 0), ("vignette", 1), ("vignette", 3),
    ]  # fmt: skip
    with pytest.raises(PluginError, match="unknown corruption 'vignete'; did you mean 'vignette'"):
        protocols(third_party, Protocol(), ["vignete"])
    with pytest.raises(PluginError, match="'vignette' has severities 1..3, not 4"):
        protocols(third_party, Protocol(), ["vignette:4"])


def test_a_corruption_of_an_unknown_kind_or_too_few_levels_is_refused_naming_the_plugin(monkeypatch):
    class Bad:
        __name__ = "bad-corruptions"

        @hookimpl
        def register_corruptions(self, register):
            register(type("TwoLevels", (Corruption,), {"name": "two", "kind": "image", "levels": (1, 2)}))

    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "")
    with pytest.raises(PluginError, match="plugin 'bad-corruptions' registered corruption 'two' with 2 levels"):
        build_registry((Bad(),), strict=True)


def test_the_clean_card_and_identity_are_those_before_corruptions_existed():
    assert "corruption" not in Protocol().card() and Protocol().identity() == "71a877f2ef9c7dc4"
    corrupted = Protocol(seed=3).corrupted(Vignette(), 2)
    assert corrupted.card()["corruption"] == "vignette" and corrupted.card()["severity"] == 2
    assert Protocol.from_card(corrupted.card()) == corrupted and corrupted.identity() != Protocol(seed=3).identity()


def test_a_card_read_back_names_its_corruption_and_its_reader_resolves_the_component(third_party):
    sensor = scan()
    corrupted = Protocol(seed=3).corrupted(Vignette(), 2)
    read_back = Protocol.from_card(corrupted.card())  # as the report reads a run's card
    with pytest.raises(I2PBenchError, match="names corruption 'vignette' but holds no component"):
        read_back.apply(sensor)
    again = resolved(third_party, read_back)
    assert type(again.component()) is Vignette and again == corrupted
    assert np.array_equal(again.apply(sensor).image, corrupted.apply(sensor).image)
    assert resolved(third_party, Protocol(seed=3)) == Protocol(seed=3)  # the clean card has nothing to resolve


def _records(corruption: str, severity: int, successes: list[bool]) -> pd.DataFrame:
    n = len(successes)
    return pd.DataFrame({
        "dataset": "kitti", "split": "test", "combination": "a", "weights": "none", "weights_trained_on": "",
        "extractor2d": "a", "extractor3d": "b", "encoder2d": "none", "encoder3d": "none", "exchanger": "none",
        "matcher": "c", "solver": "d", "frame_id": [str(i) for i in range(n)], "status": "ok", "failed_component": "",
        "rte_m": [0.1 if s else 9.0 for s in successes], "rre_deg": [1.0 if s else 30.0 for s in successes],
        "geodesic_deg": 1.0, "model_size_mb": 0.0, "t_total_s": 0.01, "corruption": corruption, "severity": severity,
    })  # fmt: skip


def test_the_robustness_summary_averages_severities_and_corruptions():
    records = pd.concat([
        _records("", 0, [True, True]),  # clean: 100 %
        _records("fog", 1, [True, False]),  # 50 %
        _records("fog", 3, [False, False]),  # 0 %
        _records("jpeg", 1, [True, True]),  # 100 %; no severity 3 run
    ], ignore_index=True)  # fmt: skip
    board = leaderboard.build(records)
    assert list(zip(board["corruption"], board["severity"], board[leaderboard.ACC], strict=True)) == [
        ("", "", 100.0), ("fog", "1", 50.0), ("fog", "3", 0.0), ("jpeg", "1", 100.0),
    ]  # fmt: skip
    summary = leaderboard.robustness(board, {"fog": "image", "jpeg": "image"}).set_index("corruption")
    s1, s3 = leaderboard.severity_column(1), leaderboard.severity_column(3)
    assert summary.loc["fog", [s1, s3, leaderboard.MEAN_ACC]].tolist() == [50.0, 0.0, 25.0]
    assert summary.loc["jpeg", s1] == 100.0 and math.isnan(summary.loc["jpeg", s3])
    mean = summary.loc[leaderboard.MEAN_ROW]
    assert [mean[s1], mean[s3], mean[leaderboard.MEAN_ACC]] == [75.0, 0.0, 50.0]  # (50 + 0 + 100) / 3 cells
    assert mean[leaderboard.CLEAN_ACC] == 100.0 and mean[leaderboard.RETAINED] == 50.0


def test_the_cli_runs_beam_reduction_on_two_kitti_frames_in_rows_of_its_own(shared_data, tmp_path):
    out = tmp_path / "board"
    cmd = [sys.executable, "-m", "i2pbench.cli", "run", "--matcher", "oracle", "--dataset", "kitti", "--split", "all",
           "--data-root", str(shared_data / "kitti_odometry"), "--frames", "2", "--threads", "1", "--quiet",
           "--corruption", "clean,beam-reduction:2", "--runs-dir", str(tmp_path / "runs"),
           "--out", str(out)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = list(csv.DictReader(out.with_suffix(".csv").open()))
    assert [(r["corruption"], r["severity"], r["frames"]) for r in rows] == [
        ("", "", "2"),
        ("beam-reduction", "2", "2"),
    ]
    assert rows[0]["combination"] == rows[1]["combination"] == "lsd > depth+reflectance > oracle > epnp-ransac"
    summary = list(csv.DictReader((tmp_path / "board-robustness.csv").open()))
    assert [(r["corruption"], r["kind"]) for r in summary] == [
        ("beam-reduction", "lidar"),
        ("mean corruption Acc.", ""),
    ]
    assert summary[0][leaderboard.severity_column(2)] == rows[1][leaderboard.ACC]
    stored = ResultsStore(tmp_path / "runs" / "kitti-all").load()
    assert (
        sorted(zip(stored["corruption"], stored["severity"], strict=True))
        == [("", 0)] * 2 + [("beam-reduction", 2)] * 2
    )


def test_every_builtin_is_documented_with_its_table():
    doc = (Path(__file__).resolve().parents[1] / "docs" / "robustness.md").read_text()
    rows = [line for line in doc.splitlines() if line.startswith("| `")]
    for name in {**BUILTINS, **GEOMETRY}:
        cls = default_registry().corruption(name)
        cells = [", ".join(f"{x:g}" for x in v) if isinstance(v, tuple) else f"{v:g}" for v in cls.levels]
        assert f"| `{name}` | {cls.kind} | {cls.parameter} | {' | '.join(cells)} | {cls.meaning} |" in rows
