"""Readers for what the peers' own test scripts leave on disk, each into the predictions table (`predictions.py`).

- EdgeRegNet `test.py`: `KITTI.xlsx`, a pandas sheet (index, RRE, RTE) of the peers' errors, a failed PnP as inf.
- CorrI2P `cal_error_all.py`: a `result_error_*` folder of per-batch arrays `T_pred_<n>.npy`, `T_gt_<n>.npy`
  (N x 4 x 4) and `is_success_<n>.npy` (N), one set per test batch file n.
- CoFiI2P `evaluation/eval_all.py`: a folder of `<step:06d>.npy` files, each a pickled dict holding `pred_P` and
  `GT_P` (4 x 4); no success flag is saved, and a step whose PnP failed keeps the previous step's `pred_P`.
  Reading a pickle runs code from the file: read only folders you made.
- VP2P-Match `run_kitti.py`: `test_acc_trans` returns per-frame RTE and RRE arrays and saves nothing; saved with
  `np.save("<name>_t_error.npy", t)` and `np.save("<name>_r_error.npy", r)` (CoFiI2P's own error arrays' names),
  either file of the pair is read with its sibling.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import DataError
from . import predictions

FORMATS = ("auto", "table", "edgeregnet-xlsx", "corri2p", "cofii2p", "error-arrays")


def read(path: str | Path, fmt: str = "auto") -> pd.DataFrame:
    """The predictions table of `path` in `fmt` (auto: from the file's name or the folder's contents), checked."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file or folder")
    fmt = detect(path) if fmt == "auto" else fmt
    readers = {"table": predictions.read, "edgeregnet-xlsx": edgeregnet_xlsx, "corri2p": corri2p_folder,
               "cofii2p": cofii2p_folder, "error-arrays": error_arrays}  # fmt: skip
    if fmt not in readers:
        raise DataError(f"{path}: unknown predictions format {fmt!r}; known: {', '.join(FORMATS)}")
    table = readers[fmt](path)
    return table if fmt == "table" else predictions.check(table, str(path))


def detect(path: Path) -> str:
    name = path.name.lower()
    if path.is_file():
        if name.endswith(".xlsx"):
            return "edgeregnet-xlsx"
        if re.search(r"_[tr]_error\.npy$", name):
            return "error-arrays"
        return "table"
    if any(path.glob("T_pred_*.npy")):
        return "corri2p"
    if any(_cofii2p_files(path)):
        return "cofii2p"
    raise DataError(f"{path}: a folder of neither CorrI2P's T_pred_<n>.npy nor CoFiI2P's <step>.npy files")


def edgeregnet_xlsx(path: Path) -> pd.DataFrame:
    try:
        sheet = pd.read_excel(path, index_col=0)
    except ImportError:
        raise DataError(f"{path}: reading .xlsx needs openpyxl (pip install openpyxl; in the dev extra)") from None
    except ValueError as exc:
        raise DataError(f"{path}: not a readable .xlsx sheet ({exc})") from None
    missing = [c for c in ("RRE", "RTE") if c not in sheet]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)} (EdgeRegNet's test.py writes RRE, RTE)")
    return pd.DataFrame({"frame_id": sheet.index.astype(str), "rte": _numbers(sheet["RTE"]),
                         "rre": _numbers(sheet["RRE"]), "method": "EdgeRegNet test.py"})  # fmt: skip


def corri2p_folder(path: Path) -> pd.DataFrame:
    parts = []
    for number in sorted(int(p.stem.rsplit("_", 1)[1]) for p in path.glob("T_pred_*.npy")):
        arrays = {name: _load(path / f"{name}_{number}.npy") for name in ("T_pred", "T_gt", "is_success")}
        n = len(arrays["T_pred"])
        if arrays["T_gt"].shape != (n, 4, 4) or arrays["T_pred"].shape != (n, 4, 4) or len(arrays["is_success"]) != n:
            raise DataError(f"{path}: batch {number}: T_pred, T_gt must be N x 4 x 4 and is_success N, got "
                            f"{arrays['T_pred'].shape}, {arrays['T_gt'].shape}, {arrays['is_success'].shape}")
        part = _pose_table(arrays["T_pred"], arrays["T_gt"], arrays["is_success"].astype(bool))
        parts.append(part.assign(frame_id=[f"{number}/{i}" for i in range(n)]))
    return pd.concat(parts, ignore_index=True).assign(method="CorrI2P cal_error_all.py")


def cofii2p_folder(path: Path) -> pd.DataFrame:
    files = sorted(_cofii2p_files(path))
    pred, gt = [], []
    for file in files:
        saved = _load(file, pickled=True)
        entry = saved.item() if isinstance(saved, np.ndarray) and saved.dtype == object else saved
        if not isinstance(entry, dict) or not {"pred_P", "GT_P"} <= set(entry):
            raise DataError(f"{file}: not CoFiI2P's saved dict (expected keys pred_P and GT_P)")
        pred.append(_matrix(entry["pred_P"], file, "pred_P"))
        gt.append(_matrix(entry["GT_P"], file, "GT_P"))
    table = _pose_table(np.stack(pred), np.stack(gt), np.ones(len(files), bool))
    return table.assign(frame_id=[f.stem for f in files], method="CoFiI2P eval_all.py")


def error_arrays(path: Path) -> pd.DataFrame:
    stem = re.sub(r"_[tr]_error\.npy$", "", path.name)
    rte, rre = (_load(path.with_name(f"{stem}_{k}_error.npy")).astype(np.float64).ravel() for k in ("t", "r"))
    if len(rte) != len(rre):
        raise DataError(f"{path.parent / stem}_[tr]_error.npy: {len(rte)} RTE but {len(rre)} RRE values")
    return pd.DataFrame({"frame_id": [str(i) for i in range(len(rte))], "rte": rte, "rre": rre, "method": stem})


def _cofii2p_files(path: Path) -> list[Path]:
    return [p for p in path.glob("*.npy") if re.fullmatch(r"\d{6}", p.stem)]


def _load(path: Path, pickled: bool = False):
    if not path.is_file():
        raise DataError(f"{path}: missing (expected beside the other arrays)")
    try:
        return np.load(path, allow_pickle=pickled)
    except (OSError, ValueError, EOFError) as exc:
        raise DataError(f"{path}: not a readable .npy file ({exc})") from None


def _matrix(value, file: Path, key: str) -> np.ndarray:
    array = np.asarray(value.detach().cpu().numpy() if hasattr(value, "detach") else value, np.float64)
    if array.size != 16:
        raise DataError(f"{file}: {key} has shape {array.shape}, expected 4 x 4")
    return array.reshape(4, 4)


def _pose_table(pred: np.ndarray, gt: np.ndarray, success: np.ndarray) -> pd.DataFrame:
    table = pd.DataFrame(np.concatenate([pred.reshape(-1, 16), gt.reshape(-1, 16)], axis=1),
                         columns=predictions.PRED + predictions.GT)  # fmt: skip
    return table.assign(pnp_success=success)


def _numbers(column: pd.Series) -> np.ndarray:
    """pandas writes inf to a sheet as the text 'inf' (to_excel's inf_rep): back to a float."""
    return pd.to_numeric(column.replace({"inf": np.inf, "-inf": -np.inf}), errors="coerce").to_numpy(np.float64)
