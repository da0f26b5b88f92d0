from pathlib import Path

import pytest

# Real recordings live in ../shared/data beside the checkout (CI has them; a user's clone may not).
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real recordings not found at {SHARED_DATA} (they sit beside the checkout in CI)")
    return SHARED_DATA
