"""Small planted cases for the end-to-end tests of the diagnosis: the real recordings' windows
with an effect planted (benchmarks.planted), written as a case directory and diagnosed through
the command's entry point."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from benchmarks.planted import PlantedSpec, generate, noise_levels, pick_windows, write_case

from mmg import efd_parameters
from sweep.data.recordings import read_recordings
from sweep.diagnose.__main__ import main

#: the kinds of recordings the cases draw their windows from
KINDS = ("random", "turning", "zigzag")


def read_runs(data_dir: Path) -> dict[str, list]:
    """The real recordings of :data:`KINDS`, by kind."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {k: read_recordings(data_dir / "data" / k) for k in KINDS}


def plant_case(runs: dict[str, list], spec: PlantedSpec, directory: Path, phi: float = 0.0) -> None:
    """Four training windows and one test window of the EFD ship with ``spec`` planted
    (measurement noise coloured by ``phi``, the AR(1) correlation between samples)."""
    rng = np.random.default_rng(3)
    wins = pick_windows(runs, {"random": 3, "turning": 1, "zigzag": 1}, rng)
    noise = noise_levels([r for v in runs.values() for r in v])
    recs, diverged = generate(wins, efd_parameters(), spec, noise, rng, phi=phi)
    assert not diverged
    write_case(directory, recs[1:], recs[:1], spec, efd_parameters())


def run_diagnosis(case: Path, out: Path, *extra: str) -> int:
    """``python -m sweep.diagnose`` on the case (EFD start, small budget, two catalog
    candidates unless ``extra`` says otherwise); its exit status."""
    return main(
        [
            "--params", "efd",
            "--train", str(case / "train"),
            "--test", str(case / "test"),
            "--out", str(out),
            "--budget", "200",
            "--candidates", "rudder_offset,current",
            *extra,
        ]
    )  # fmt: skip
