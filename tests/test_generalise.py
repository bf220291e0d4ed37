"""Does the model carry over to recordings it was not fitted to? The generalisation test."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mmg import get_effect
from mmg.discovered import with_bounds
from sweep.diagnose.floor import FirstSample
from sweep.diagnose.generalise import generalisation_test
from sweep.identification.vector import with_effects
from tests.conftest import kernels, noisy_windows

pytestmark = [
    pytest.mark.integration,  # a planted case through the diagnosis's fits
    pytest.mark.kernels(*kernels((), "simulate"), *kernels(("discovered:Y_one",), "simulate")),
]


@pytest.fixture(scope="module")
def case(small_case):
    """A perturbed ship, three training and one test window (100 s each), the noise levels."""
    ship, windows, noise = small_case
    return ship, windows[:3], windows[3:], noise


def test_the_exact_model_carries_over_and_a_missing_force_does_not(case):
    """Test recordings of the same ship: J within the null (not significant, near its median).
    Test recordings with a sway force the training windows never saw: significant, several
    times the null's median, and the test run is named as beyond its own limit."""
    ship, train, test, noise = case
    data = noisy_windows(ship, train, noise, 1)
    same = generalisation_test(
        ship, data, noisy_windows(ship, test, noise, 2), noise, np.random.default_rng(4), draws=60
    )
    assert not same.significant
    assert 0.3 < same.ratio < 2.0
    assert same.p_value > 0.01
    assert same.median <= same.quantile < same.limit
    eff = with_bounds(get_effect("discovered:Y_one"), [2e-3])
    pushed = with_effects(ship, (eff,), [1e-3])
    other = generalisation_test(
        ship, data, noisy_windows(pushed, test, noise, 2), noise, np.random.default_rng(4), draws=60
    )
    assert other.significant
    assert other.ratio > 3.0
    assert other.p_value == 0.0
    assert other.per_run[0]["significant"]
    # the null does not depend on the test recordings' values, only on their windows
    assert other.median == pytest.approx(same.median)


def test_copies_begin_as_the_windows_do(case):
    """Windows that begin at the exact simulated state (planted data) get copies that begin
    exactly too, and a narrower null: the exact model's test J near its median (on this case the
    99 % quantile 4.5 x lower). The same
    windows begun at a noisy state (recorded data) keep copies that begin noisy, whose null
    is wider."""
    ship, train, test, noise = case
    exact = replace(noise, first=FirstSample(noisy=False, copies_exact=True))
    data = noisy_windows(ship, train, exact, 1)
    held = noisy_windows(ship, test, exact, 2)
    g = generalisation_test(ship, data, held, noise, np.random.default_rng(4), draws=60)
    assert g.copies_exact
    assert not g.starts["noisy"]
    assert not g.significant
    assert 0.5 < g.ratio < 2.0
    recorded = generalisation_test(
        ship,
        noisy_windows(ship, train, noise, 1),
        noisy_windows(ship, test, noise, 2),
        noise,
        np.random.default_rng(4),
        draws=60,
    )
    assert not recorded.copies_exact
    assert recorded.starts["noisy"]
    assert recorded.median > 1.2 * g.median
    assert recorded.quantile > 2.0 * g.quantile
