import importlib.util
import os
from pathlib import Path

import pytest

# The real KITTI and nuScenes sample frames (README, "Sample data"): ../shared/data beside the checkout, or elsewhere
SAMPLE_DATA = Path(os.environ.get("I2PBENCH_SAMPLE_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data")


def missing_sample(*parts: str) -> str | None:
    """Why a test needing SAMPLE_DATA/parts cannot run (one line naming the folder and the variable), or None."""
    path = SAMPLE_DATA.joinpath(*parts)
    if path.exists():
        return None
    return f"sample data not found: {path} (set I2PBENCH_SAMPLE_DATA to the folder holding it)"


def require(path: Path) -> Path:
    """`path`, a file or folder of the sample data, or skip the calling test with the one line naming it and the
    variable."""
    if not path.exists():
        pytest.skip(f"sample data not found: {path} (set I2PBENCH_SAMPLE_DATA to the folder holding it)")
    return path


def sample(*parts: str) -> Path:
    """SAMPLE_DATA/parts, or skip the calling test (or fixture) with missing_sample's reason."""
    reason = missing_sample(*parts)
    if reason:
        pytest.skip(reason)
    return SAMPLE_DATA.joinpath(*parts)


def needs_sample(*parts: str) -> pytest.MarkDecorator:
    """A skip mark for a whole module or test that reads SAMPLE_DATA/parts."""
    reason = missing_sample(*parts)
    return pytest.mark.skipif(reason is not None, reason=reason or "")


# the authors' checkouts the peer tests run (outside the repo; docs/methods.md, "Against the authors' code")
CHECKOUTS = {
    "corri2p": ("I2PBENCH_CORRI2P_CHECKOUT", "rsy6318/CorrI2P"),
    "cofii2p": ("I2PBENCH_COFII2P_CHECKOUT", "WHU-USI3DV/CoFiI2P"),
    "deepi2p": ("I2PBENCH_DEEPI2P_CHECKOUT", "lijx10/DeepI2P"),
    "vp2p-match": ("I2PBENCH_VP2P_CHECKOUT", "junshengzhou/VP2P-Match"),
}


def peer_checkout(peer: str) -> Path:
    """the authors' checkout of `peer` its variable names, or skip the calling test naming the variable."""
    variable, repository = CHECKOUTS[peer]
    checkout = os.environ.get(variable, "")
    if not checkout:
        pytest.skip(f"{variable} is not set: the path of a {repository} checkout")
    return Path(checkout)


def missing_nuscenes(*parts: str) -> str | None:
    """Why a test of the nuScenes sample (nuscenes_records/parts) cannot run: the records, or the devkit that reads
    them (installed by scripts/install.sh, not by the dev extra), are missing; or None."""
    if importlib.util.find_spec("nuscenes") is None:
        return "nuscenes-devkit is not installed (scripts/install.sh installs it; docs/datasets.md)"
    return missing_sample("nuscenes_records", *parts)


def nuscenes_sample(*parts: str) -> Path:
    """SAMPLE_DATA/nuscenes_records/parts, or skip with missing_nuscenes' reason."""
    reason = missing_nuscenes(*parts)
    if reason:
        pytest.skip(reason)
    return SAMPLE_DATA.joinpath("nuscenes_records", *parts)


def needs_nuscenes(*parts: str) -> pytest.MarkDecorator:
    reason = missing_nuscenes(*parts)
    return pytest.mark.skipif(reason is not None, reason=reason or "")


@pytest.fixture
def shared_data() -> Path:
    return sample()


@pytest.fixture
def counted(monkeypatch):
    """Frames actually computed (not read from the store), in order."""
    from i2pbench.runs import worker

    calls = []
    real = worker.compute  # every computed frame passes here, run whole or re-solved, whichever executor runs it

    def compute(ctx, frame_id, *args, **kwargs):
        calls.append(frame_id)
        return real(ctx, frame_id, *args, **kwargs)

    monkeypatch.setattr(worker, "compute", compute)
    return calls
