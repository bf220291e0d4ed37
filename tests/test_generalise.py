"""Does the model carry over to recordings it was not fitted to? The generalisation test."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from benchmarks.planted import PlantedSpec, generate, noise_levels, perturbed_ship, pick_windows

from mmg import get_effect
from mmg.discovered import with_bounds
from sweep.data.recordings import Recording, read_recordings
from sweep.diagnose.floor import NoiseModel, simulate_windows
from sweep.diagnose.generalise import generalisation_test
from sweep.diagnose.windows import cut_windows
from sweep.identification.vector import with_effects
from tests.conftest import kernels

pytestmark = [
    pytest.mark.integration,  # a planted case through the diagnosis's fits
    pytest.mark.kernels(*kernels((), "simulate"), *kernels(("discovered:Y_one",), "simulate")),
]


@pytest.fixture(scope="module")
def case(data_dir: Path):
    """A perturbed ship, three training and one test window (100 s each), the noise levels."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        runs = {k: read_recordings(data_dir / "data" / k) for k in ("random", "turning", "zigzag")}
    rng = np.random.default_rng(3)
    ship = perturbed_ship(rng, 0.15)
    wins = pick_windows(runs, {"random": 2, "turning": 1, "zigzag": 1}, rng)
    levels = noise_levels([r for v in runs.values() for r in v])
    clean, _ = generate(wins, ship, PlantedSpec("none"), dict.fromkeys(levels, 0.0), rng)
    windows = cut_windows(clean)
    return ship, windows[:3], windows[3:], NoiseModel(levels, dict.fromkeys(levels, 0.0))


def _noisy(params, windows, noise, seed):
    rng = np.random.default_rng(seed)
    return [
        Recording(w.name, None, w.t, x + noise.draw(rng, x.shape[0]), w.u, w.w)
        for w, x in zip(windows, simulate_windows(params, windows), strict=True)
    ]


def test_the_exact_model_carries_over_and_a_missing_force_does_not(case):
    """Test recordings of the same ship: J within the null (not significant, near its median).
    Test recordings with a sway force the training windows never saw: significant, several
    times the null's median, and the test run is named as beyond its own limit."""
    ship, train, test, noise = case
    data = _noisy(ship, train, noise, 1)
    same = generalisation_test(
        ship, data, _noisy(ship, test, noise, 2), noise, np.random.default_rng(4), draws=60
    )
    assert not same.significant
    assert 0.3 < same.ratio < 2.0
    assert same.p_value > 0.01
    assert same.median <= same.quantile < same.limit
    eff = with_bounds(get_effect("discovered:Y_one"), [2e-3])
    pushed = with_effects(ship, (eff,), [1e-3])
    other = generalisation_test(
        ship, data, _noisy(pushed, test, noise, 2), noise, np.random.default_rng(4), draws=60
    )
    assert other.significant
    assert other.ratio > 3.0
    assert other.p_value == 0.0
    assert other.per_run[0]["significant"]
    # the null does not depend on the test recordings' values, only on their windows
    assert other.median == pytest.approx(same.median)
