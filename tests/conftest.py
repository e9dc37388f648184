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


@pytest.fixture
def shared_data() -> Path:
    return sample()


@pytest.fixture
def counted(monkeypatch):
    """Frames actually computed (not read from the store), in order."""
    from i2pbench.runs import worker

    calls = []
    real = worker.compute  # every computed frame passes here, run whole or re-solved, whichever executor runs it

    def compute(job, dataset, frame_id, *args, **kwargs):
        calls.append(frame_id)
        return real(job, dataset, frame_id, *args, **kwargs)

    monkeypatch.setattr(worker, "compute", compute)
    return calls
