import os
from pathlib import Path

import pytest

# Real recordings live in ../shared/data beside the checkout (CI has them; a user's clone may not).
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real recordings not found at {SHARED_DATA} (they sit beside the checkout in CI)")
    return SHARED_DATA


def assert_refused_for_what_it_is(read, path: Path, what: str, match: str) -> None:
    """``read(path)`` with ``path`` missing, a folder or a FIFO (``what``) is refused by a
    PedcalInputError matching ``match`` that names the path: a reader's check that it was given
    a regular file."""
    from pedcal.errors import PedcalInputError

    if what == "folder":
        path.mkdir()
    elif what == "fifo":
        os.mkfifo(path)
    elif what != "missing":
        raise ValueError(f"unknown case {what!r}")
    with pytest.raises(PedcalInputError, match=match) as ei:
        read(path)
    assert ei.value.path == str(path)
