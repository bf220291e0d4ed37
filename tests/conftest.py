"""Shared fixtures: where the reference files and the real recordings are."""

from __future__ import annotations

import os
import subprocess
import sys
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


#: the CI smoke sweep: two jobs at budget=smoke through Hydra, Ray and MLflow
SMOKE_COMMAND = [
    sys.executable, "-m", "sweep", "-m", "objective=J1,J2", "train=R", "seed=0",
    "budget=smoke", "sweep.name=ci-smoke", "ray.num_cpus=2",
]  # fmt: skip


def run_smoke(cwd: Path, data_dir: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, MMG_DATA_DIR=str(data_dir), RAY_AUTH_MODE="disabled")
    return subprocess.run(
        SMOKE_COMMAND, cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )


@pytest.fixture(scope="session")
def smoke(tmp_path_factory: pytest.TempPathFactory, data_dir: Path):
    """(directory, completed process) of one smoke sweep, shared by the CLI and UI tests."""
    cwd = tmp_path_factory.mktemp("sweep")
    first = run_smoke(cwd, data_dir)
    assert first.returncode == 0, first.stderr[-3000:]
    return cwd, first


@pytest.fixture
def checkpoint_writes(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The evaluations of every checkpoint the test writes, in order (the writes still happen)."""
    from sweep.identification import cmaes

    writes: list[int] = []
    real_save = cmaes.save_checkpoint

    def counting_save(state: cmaes.State, path: str | Path) -> None:
        writes.append(state.evaluations)
        real_save(state, path)

    monkeypatch.setattr(cmaes, "save_checkpoint", counting_save)
    return writes
