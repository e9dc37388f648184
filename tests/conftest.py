from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.exists():
        pytest.skip("../shared/data is not present")
    return SHARED_DATA


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
