"""Per-frame predictions from any code base, in one documented table (docs/python.md, "Scoring predictions"):
read, checked, and turned into records `scoring.score` takes, like the store's.

A row is one frame: `frame_id`, `sequence`, the estimate `T_pred_RC` and ground truth `T_gt_RC` (R, C = 0..3: the
4 x 4 matrices row by row, LiDAR -> camera as the protocol cards define them), `pnp_success`, and optionally
`n_matches`, `n_inliers` and `method` (one board row per method). A table from a script that kept only the peers'
errors has `rte` and `rre` (P_diff's translation norm and sum of absolute 'xzy' Euler angles, inf for a failure)
instead of the matrices; the cards whose rules need the poses are then left unscored.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import DataError

PRED = [f"T_pred_{r}{c}" for r in range(4) for c in range(4)]
GT = [f"T_gt_{r}{c}" for r in range(4) for c in range(4)]
ERRORS = ["rte", "rre"]
OPTIONAL = ["n_matches", "n_inliers", "method"]
ROTATION_TOL = 1e-4  # |R^T R - I| and |det R - 1|: float32 poses written as text keep ~1e-6


def read(path: str | Path) -> pd.DataFrame:
    """A predictions file (.csv or .parquet), checked; errors name the file, the row and the column."""
    path = Path(path)
    if path.suffix.lower() not in (".csv", ".parquet"):
        raise DataError(f"{path}: predictions are a .csv or .parquet file (docs/python.md, 'Scoring predictions')")
    try:
        table = pd.read_parquet(path) if path.suffix.lower() == ".parquet" else pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: could not read it as a table ({exc})") from None
    return check(table, str(path))


def check(table: pd.DataFrame, source: str = "predictions") -> pd.DataFrame:
    """The table with defaults filled in (sequence '', method 'predictions'), or a DataError naming `source`, the
    row (0-based, as pandas and a CSV's data lines after the header count) and the column at fault."""
    has_poses = all(c in table for c in GT)
    needed = ["frame_id", *(PRED + GT + ["pnp_success"] if has_poses else ERRORS)]
    missing = [c for c in needed if c not in table]
    if missing:
        raise DataError(f"{source}: missing column(s) {', '.join(missing)} (needs frame_id, sequence, T_pred_00.."
                        "T_pred_33, T_gt_00..T_gt_33, pnp_success; or frame_id, rte, rre)")  # fmt: skip
    table = table.reset_index(drop=True).assign(
        frame_id=table["frame_id"].astype(str).to_numpy(),
        sequence=table["sequence"].fillna("").astype(str).to_numpy() if "sequence" in table else "",
        method=table["method"].fillna("").astype(str).to_numpy() if "method" in table else "predictions",
    )
    _check_unique(table, source)
    if has_poses:
        table["pnp_success"] = _flags(table["pnp_success"], source)
        _check_poses(table, source)
    else:
        _check_errors(table, source)
    return table


def records(table: pd.DataFrame) -> pd.DataFrame:
    """Store-like records (T_pred, T_gt as 16 floats, None for no pose) of a checked table with poses."""
    gt = table[GT].to_numpy(np.float64)
    pred = table[PRED].to_numpy(np.float64)
    out = table[["method", "sequence", "frame_id"]].copy()
    out["T_gt"] = list(gt)
    out["T_pred"] = [row if ok else None for row, ok in zip(pred, table["pnp_success"], strict=True)]
    for column in ("n_matches", "n_inliers"):
        out[column] = table[column].to_numpy(np.float64) if column in table else np.nan
    return out


def has_poses(table: pd.DataFrame) -> bool:
    return all(c in table for c in GT)


def _check_unique(table: pd.DataFrame, source: str) -> None:
    twice = table.duplicated(["method", "sequence", "frame_id"], keep=False)
    if twice.any():
        rows = list(table.index[twice])
        first = table.loc[rows[0]]
        raise DataError(f"{source}: rows {', '.join(map(str, rows))}, column frame_id: frame {first['frame_id']!r} "
                        f"(sequence {first['sequence']!r}) appears more than once")  # fmt: skip


def _flags(column: pd.Series, source: str) -> pd.Series:
    text = column.astype(str).str.strip().str.lower()
    known = text.isin(["true", "false", "1", "0", "1.0", "0.0"])
    if not known.all():
        row = int(np.flatnonzero(~known.to_numpy())[0])
        raise DataError(f"{source}: row {row}, column pnp_success: {column.iloc[row]!r} is not true/false or 1/0")
    return text.isin(["true", "1", "1.0"])


def _check_poses(table: pd.DataFrame, source: str) -> None:
    for columns, name in ((GT, "T_gt"), (PRED, "T_pred")):
        values = table[columns].apply(pd.to_numeric, errors="coerce").to_numpy(np.float64)
        for row in range(len(table)):
            if name == "T_pred" and not table["pnp_success"].iloc[row]:
                continue  # no pose: its cells may hold anything (NaN, the identity, a previous frame's estimate)
            _check_matrix(values[row].reshape(4, 4), columns, row, source)


def _check_matrix(matrix: np.ndarray, columns: list[str], row: int, source: str) -> None:
    bad = np.flatnonzero(~np.isfinite(matrix))
    if len(bad):
        raise DataError(f"{source}: row {row}, column {columns[bad[0]]}: not a finite number (a pose needs all 16)")
    if not np.allclose(matrix[3], [0, 0, 0, 1]):
        raise DataError(f"{source}: row {row}, columns {columns[12]}..{columns[15]}: the last row must be 0 0 0 1")
    R = matrix[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOL or abs(np.linalg.det(R) - 1.0) > ROTATION_TOL:
        raise DataError(f"{source}: row {row}, columns {columns[0]}..{columns[10]}: the 3 x 3 block is not a rotation "
                        f"(|R^T R - I| = {np.abs(R.T @ R - np.eye(3)).max():.2g}, det = {np.linalg.det(R):.6g})")


def _check_errors(table: pd.DataFrame, source: str) -> None:
    for column in ERRORS:
        values = pd.to_numeric(table[column], errors="coerce").to_numpy(np.float64)
        bad = np.flatnonzero(np.isnan(values) | (values < 0))
        if len(bad):
            raise DataError(f"{source}: row {bad[0]}, column {column}: {table[column].iloc[bad[0]]!r} is not an "
                            "error (a number >= 0, or inf for a failure)")  # fmt: skip
        table[column] = values


def from_records(store_records: pd.DataFrame) -> pd.DataFrame:
    """An i2pbench run's records (`RunResult.records`) in this schema, one method per combination and condition
    (`<combination> [<corruption>:<severity>]` under a corruption): how a run's poses are handed to another tool,
    and scored back the way foreign ones are."""
    rows = []
    for record in store_records.itertuples(index=False):
        pred = np.asarray(record.T_pred if record.T_pred is not None else np.full(16, np.nan), np.float64).ravel()
        gt = np.asarray(record.T_gt, np.float64).ravel()
        solved = bool(np.isfinite(pred).all())
        ids = [method_label(record.combination, getattr(record, "corruption", ""), getattr(record, "severity", 0)),
               record.sequence, record.frame_id]  # fmt: skip
        rows.append([*ids, *pred, *gt, solved, record.n_matches, record.n_inliers])
    names = ["method", "sequence", "frame_id", *PRED, *GT, "pnp_success", "n_matches", "n_inliers"]
    return pd.DataFrame(rows, columns=names)


def method_label(combination: str, corruption: str | None, severity) -> str:
    return f"{combination} [{corruption}:{int(severity)}]" if corruption else combination
