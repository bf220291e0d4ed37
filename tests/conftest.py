"""Shared fixtures: where the reference files and the real recordings are."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def recordings_root() -> Path:
    """The FRT-DS-ESSO recordings: $MMG_DATA_DIR, else ../shared/data/frt-ds-esso."""
    env = os.environ.get("MMG_DATA_DIR")
    return Path(env) if env else SHARED / "data" / "frt-ds-esso"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"the shared reference directory {SHARED} is missing")
    return SHARED


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The recordings' root directory (fails, never skips, when they are missing)."""
    d = recordings_root()
    if not (d / "data").is_dir():
        pytest.fail(
            f"FRT-DS-ESSO recordings not found in {d}: set MMG_DATA_DIR or run "
            "`python -m sweep.download --root <dir>`"
        )
    return d
