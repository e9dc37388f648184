"""The report's robustness section: Acc. against severity per corruption, and what each corruption does to a frame.

A robustness run (`i2pbench run --robustness` or `--corruption`) stores every corrupted protocol's records beside the
clean ones. The report's other sections show one protocol (the run's first, the clean one); this section shows the
corruptions of that same protocol (same seed and thresholds), severity 0 being its clean records. The curves are
drawn from the robustness summary (`leaderboard.robustness`, the table a run writes as `<out>-robustness`), so every
point on a curve is a cell of that table. The overlays re-run no pipeline, only the corruption: one frame is reloaded
and corrupted at each severity the run used, exactly as the run corrupted it (the corruption's generator depends only
on seed, dataset, frame, corruption and severity).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ..boards import leaderboard as lb
from ..corruptions.base import MAX_LEVELS, Corruption
from ..errors import DataError, I2PBenchError
from ..registry.build import default_registry
from ..runs.store import ResultsStore
from ..scoring.protocol import Protocol
from ..types import Frame, SensorFrame
from . import draw, overlay
from .curves import png, row_label
from .examples import Example, jpeg
from .labels import chars_in, line_count, wrapped
from .rundir import RunDir, open_dataset, pose

PANEL_PX = 620  # widest overlay panel: four severities of a 1241 px KITTI frame side by side stay ~2500 px wide
POINT_RADIUS = 1  # a 3 x 3 dot at full resolution, still about 2 px after the panel is halved
PANELS_PER_ROW = 4
MARKERS = "osD^v<>p"  # rows at the same Acc. overlap; distinct hollow markers keep each visible


@dataclass(frozen=True)
class Robustness:
    """The clean and corrupted records of one protocol, with their robustness summary."""

    records: pd.DataFrame
    summary: pd.DataFrame  # leaderboard.robustness of these records' board
    kinds: dict[str, str]  # corruption -> kind ("" when the corruption is no longer installed)


@dataclass(frozen=True)
class Curve:
    """Acc. of one leaderboard row against one corruption's severity; severity 0 is the clean Acc."""

    label: str
    corruption: str
    severities: list[int]
    acc: list[float]


@dataclass(frozen=True)
class Section:
    """What the page shows: the summary table, the curves figure, one overlay per corruption, and notes."""

    summary: pd.DataFrame
    curves_png: bytes
    overlays: list[Example]
    notes: list[str]
    corrupted_records: int


def clean(protocol: Protocol) -> Protocol:
    """The protocol without its corruption: the base every corruption of a run modifies."""
    return dataclasses.replace(protocol, corruption="", severity=0, corrupter=None)


def under(base: Protocol, corruption: str, severity: int) -> Protocol:
    """`base` corrupted by name (identity only: no component is resolved)."""
    return base if not corruption else dataclasses.replace(base, corruption=corruption, severity=int(severity))


def of_protocol(records: pd.DataFrame, base: Protocol) -> pd.DataFrame:
    """The records scored under `base` or a corruption of it (another seed or threshold is another protocol)."""
    if "corruption" not in records:
        records = records.assign(corruption="", severity=0)
    records = records.assign(corruption=records["corruption"].fillna(""), severity=records["severity"].fillna(0))
    records = records.assign(severity=records["severity"].astype(int))
    if "protocol" not in records:
        return records.reset_index(drop=True)
    conditions = list(zip(records["corruption"], records["severity"], strict=True))
    identity = {c: under(base, *c).identity() for c in set(conditions)}
    keep = records["protocol"].to_numpy() == np.asarray([identity[c] for c in conditions])
    return records[keep].reset_index(drop=True)


def kind_of(name: str) -> str:
    try:
        return default_registry().corruption(name).kind
    except I2PBenchError:
        return ""


def same_frames(records: pd.DataFrame) -> pd.DataFrame:
    """Clean records only of the frames their row was also corrupted on: a store may hold clean results of more
    frames (an earlier, longer run), and a clean Acc. over other frames would not compare."""
    corrupted = records["corruption"] != ""
    keys = list(zip(records["combination"], records["weights"], records["frame_id"], strict=True))
    wanted = {k for k, c in zip(keys, corrupted, strict=True) if c}
    return records[corrupted | np.array([k in wanted for k in keys], dtype=bool)].reset_index(drop=True)


def run_order(run: RunDir) -> list[str]:
    """Corruptions in the order the run's invocations ran them, oldest first (as its `<out>-robustness` lists them)."""
    cards = [card for m in run.meta for card in m.get("protocols", [m.get("protocol")])]
    return list(dict.fromkeys(card.get("corruption", "") for card in cards if isinstance(card, dict)))


def in_order(records: pd.DataFrame, order: list[str]) -> pd.DataFrame:
    """Records sorted by corruption (in `order`, then by name) and severity: a store lists them by cache key."""
    rank = {name: i for i, name in enumerate(order)}
    ranked = records.assign(_rank=records["corruption"].map(lambda c: rank.get(c, len(rank))))
    ranked = ranked.sort_values(["_rank", "corruption", "severity", "frame_id"], kind="stable")
    return ranked.drop(columns="_rank").reset_index(drop=True)


def collect(records: pd.DataFrame, base: Protocol, order: list[str] | None = None) -> Robustness | None:
    """The robustness data of `records` under `base`, corruptions in `order`; None when none of them is corrupted."""
    records = of_protocol(records, base)
    if (records["corruption"] == "").all():
        return None
    records = in_order(same_frames(records), order or [])
    board = lb.build(records, base)
    kinds = {name: kind_of(name) for name in pd.unique(records["corruption"]) if name}
    return Robustness(records, lb.robustness(board, kinds), kinds)


def load(run: RunDir) -> Robustness | None:
    """The run directory's robustness data (its store holds every protocol's records; `run.records` only one)."""
    return collect(ResultsStore(run.root).load(), clean(run.protocol), run_order(run))


def severities(summary: pd.DataFrame) -> list[int]:
    """The severities the summary has columns for, in order."""
    return [s for s in range(1, MAX_LEVELS + 1) if lb.severity_column(s) in summary]


def curves(summary: pd.DataFrame) -> list[Curve]:
    """One curve per (row, corruption) of the summary, the mean row included; severity 0 is the clean Acc. and
    severities that were not run are left out, so each point is a number of the summary table."""
    out = []
    for _, row in summary.iterrows():
        points = [(0, row[lb.CLEAN_ACC])] + [(s, row[lb.severity_column(s)]) for s in severities(summary)]
        kept = [(s, float(a)) for s, a in points if not pd.isna(a)]
        label = row_label(row["combination"], row["weights"])
        out.append(Curve(label, row["corruption"], [s for s, _ in kept], [a for _, a in kept]))
    return out


def severity_figure(found: list[Curve], kinds: dict[str, str]) -> Figure:
    """A panel per corruption (the mean over corruptions last), Acc. against severity, a line per leaderboard row."""
    names = list(dict.fromkeys(c.corruption for c in found))
    labels = list(dict.fromkeys(c.label for c in found))
    n_cols = min(PANELS_PER_ROW, len(names))
    n_rows = math.ceil(len(names) / n_cols)
    width = 3.2 * n_cols
    shown = [wrapped(label, chars_in(width - 0.3)) for label in labels]  # narrow with one corruption: wrap
    lines = sum(line_count(label) for label in shown)
    fig = Figure(figsize=(width, 2.6 * n_rows + 0.17 * lines + 0.08 * len(labels) + 0.3), layout="constrained")
    axes = np.atleast_1d(fig.subplots(n_rows, n_cols, sharey=True, squeeze=False)).ravel()
    top = max((max(c.severities) for c in found if c.severities), default=1)
    for i, (ax, name) in enumerate(zip(axes, names, strict=False)):
        title = name if not kinds.get(name) else f"{name} ({kinds[name]})"
        ax.set(title=title, xlabel="severity (0 = clean)", xlim=(-0.3, top + 0.3), xticks=range(top + 1))
        ax.set(ylabel="Acc. (%)" if i % n_cols == 0 else "", ylim=(-4, 104))
        ax.title.set_fontsize(10)
        ax.grid(True, alpha=0.3)
        for curve in (c for c in found if c.corruption == name):
            _plot(ax, curve, labels.index(curve.label))
    for ax in axes[len(names) :]:
        ax.set_visible(False)
    handles = [_style(Line2D([], []), i, label) for i, label in enumerate(shown)]
    fig.legend(handles=handles, loc="outside lower center", ncol=1, fontsize=8, frameon=False)
    return fig


def _plot(ax, curve: Curve, index: int) -> None:
    (line,) = ax.plot(curve.severities, curve.acc)
    _style(line, index, curve.label)


def _style(line: Line2D, index: int, label: str) -> Line2D:
    line.set(color=f"C{index % 10}", marker=MARKERS[index % len(MARKERS)], markerfacecolor="none", label=label)
    line.set(markersize=9 - 1.5 * (index % 4))  # nested hollow markers where rows coincide
    return line


def corruption_panel(frame: Frame, kind: str) -> np.ndarray:
    """What a corruption of `kind` changed, as a picture: the image itself for an image corruption; otherwise the
    scan projected over the grey image by the K the stages are told, under the ground truth (so a sparser scan, a
    missing wedge or a wrong calibration shows as points missing or off their objects)."""
    if kind == "image":
        return frame.image.copy()
    return overlay.points_panel(frame, frame.T_gt, POINT_RADIUS)


def corrupted_frames(
    sensor: SensorFrame, base: Protocol, corruption: Corruption, chosen: list[int]
) -> list[tuple[int, Frame]]:
    """[(severity, frame)]: the registration problem under `corruption` at each severity, 0 being `base`'s."""
    return [(s, (base.corrupted(corruption, s) if s else base).apply(sensor)) for s in [0, *chosen]]


def strip(frames: list[tuple[int, Frame]], corruption: Corruption) -> np.ndarray:
    """The frame at each severity side by side, each captioned with its severity and level (one RGB image)."""
    columns = []
    for severity, frame in frames:
        panel = _fit(corruption_panel(frame, corruption.kind))
        lines = [_level_text(corruption, severity)]
        if corruption.kind == "lidar":
            lines.append(f"{len(frame.points)} points in the scan")
        columns.append(draw.stack([draw.caption(lines, panel.shape[1]), panel]))
    gap = np.zeros((columns[0].shape[0], 4, 3), np.uint8)
    image = np.concatenate([part for column in columns for part in (column, gap)][:-1], axis=1)
    return image if corruption.kind == "image" else draw.stack([image, draw.legend(image.shape[1])])


def _fit(panel: np.ndarray) -> np.ndarray:
    h, w = panel.shape[:2]
    if w <= PANEL_PX:
        return panel
    return cv2.resize(panel, (PANEL_PX, round(h * PANEL_PX / w)), interpolation=cv2.INTER_AREA)


def _level_text(corruption: Corruption, severity: int) -> str:
    if severity == 0:
        return "severity 0: clean"
    level = corruption.level(severity)
    shown = ", ".join(f"{v:g}" for v in level) if isinstance(level, tuple | list) else f"{level:g}"
    return f"severity {severity}: {corruption.parameter} = {shown}"


def overlays(data: Robustness, run: RunDir, data_root: str | None = None) -> tuple[list[Example], list[str]]:
    """(one overlay per corruption, notes): the run's first frame at every severity the run used for it; every
    failure to reload or corrupt becomes a note, never an exception, as for the best and worst frames."""
    try:
        dataset = open_dataset(default_registry(), run.dataset, data_root)
    except I2PBenchError as exc:
        return [], [f"corruption overlays left out: cannot open the run's dataset ({exc}); pass --data-root"]
    frame_id = sorted(data.records["frame_id"])[0]
    try:
        sensor = dataset.load(frame_id)
    except I2PBenchError as exc:
        return [], [f"corruption overlays left out: frame {frame_id} does not load ({exc})"]
    examples, notes = [], []
    for name in data.kinds:
        try:
            examples.append(_overlay(data, run, sensor, name))
        except I2PBenchError as exc:
            notes.append(f"overlay of corruption {name!r} on frame {frame_id} not drawn: {exc}")
    return examples, notes


def _overlay(data: Robustness, run: RunDir, sensor: SensorFrame, name: str) -> Example:
    corruption = default_registry().corruption(name)()
    ran = data.records[(data.records["corruption"] == name) & (data.records["frame_id"] == sensor.frame_id)]
    frames = corrupted_frames(sensor, clean(run.protocol), corruption, sorted({int(s) for s in ran["severity"]}))
    _check_truth(frames[0][1], data.records[data.records["frame_id"] == sensor.frame_id])
    what = "image" if corruption.kind == "image" else "LiDAR points under the ground truth, by the K the stages see"
    title = f"{name} ({corruption.kind}, {corruption.parameter}) on frame {sensor.frame_id}"
    return Example(title, f"{what}; {corruption.meaning}", jpeg(strip(frames, corruption)))


def _check_truth(frame: Frame, records: pd.DataFrame) -> None:
    """The reloaded frame is the one the run scored: its ground truth equals the stored one."""
    stored = pose(records.iloc[0], "T_gt") if len(records) else None
    if stored is not None and not np.allclose(stored, frame.T_gt, atol=1e-6):
        raise DataError("the reloaded ground truth differs from the stored one")


def section(run: RunDir, data_root: str | None = None) -> Section | None:
    """The robustness section of a run directory's page; None when it holds no corrupted records."""
    data = load(run)
    if data is None:
        return None
    figure = severity_figure(curves(data.summary), data.kinds)
    examples, notes = overlays(data, run, data_root)
    n_corrupted = int((data.records["corruption"] != "").sum())
    return Section(data.summary, png(figure), examples, notes, n_corrupted)


EXPLAIN_CURVES = (
    "One panel per corruption, the mean over corruptions last; one line per leaderboard row. Severity 0 is the "
    "clean Acc.; each point is a cell of the table above. Severities that were not run are left out."
)
EXPLAIN_OVERLAYS = (
    "The run's first frame at severity 0 (clean) and at each severity the run used. Image corruptions: the image "
    "the stages were given. LiDAR and calibration corruptions: the scan they were given, projected under the ground "
    "truth with the intrinsics they were told (for intrinsic-error, the wrong ones), coloured by distance."
)


def explain(robust: Section) -> str:
    return (
        f"{robust.corrupted_records} frame results under corruptions of this page's protocol (left out of the "
        "sections above, which show the clean protocol). Acc. per corruption and severity, as the run's "
        "<out>-robustness table: mean Acc. over the severities run, retained = mean / clean Acc.; the last row per "
        "combination averages every corruption and severity (mean corruption Acc.). Click a header to sort."
    )
