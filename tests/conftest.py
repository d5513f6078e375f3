import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("VTS_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data beside the checkout (real Axis frames, real checkerboard pairs)."""
    assert SHARED_DATA.is_dir(), f"real test data missing: {SHARED_DATA} (set VTS_SHARED_DATA)"
    return SHARED_DATA


@pytest.fixture(scope="session")
def axis_frames(shared_data) -> Path:
    return shared_data / "axis-frames"
