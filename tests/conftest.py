"""Shared fixtures: the real light-field data in ../shared/lf_data."""

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _lf_data_dir():
    env = os.environ.get("LFALIAS_LF_DATA")
    return Path(env) if env else REPO.parent / "shared" / "lf_data"


@pytest.fixture(scope="session")
def lf_data():
    """Folder of the real captures (``../shared/lf_data`` beside the checkout).

    Missing data fail the run on CI (``CI`` set) and skip elsewhere.
    """
    path = _lf_data_dir()
    if not path.is_dir():
        message = f"real light-field data not found at {path} (set LFALIAS_LF_DATA)"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    return path
