"""The probe of forces periodic in time (:mod:`sweep.diagnose.waves`): its periods, and a
wave's amplitude and phase read off its columns in the time shapes' basis."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from benchmarks.planted import PlantedSpec, generate, noise_levels, pick_windows, unforeseen_spec

from mmg import efd_parameters
from mmg.shapes import Group, basis, curve, parse_form
from sweep.data.recordings import read_recordings
from sweep.diagnose.naming import WAVE_KNOTS
from sweep.diagnose.waves import (
    LONGEST,
    PERIOD_RATIO,
    period_peaks,
    periods,
    phase_form,
    refined_frequency,
    wave_basis,
)
from sweep.diagnose.windows import cut_windows
from tests.conftest import kernels, probe_kernels


def test_the_period_moves_from_the_peak_while_the_fit_improves_then_is_refined() -> None:
    """A minimum 2.3 grid steps from the periodogram's peak is reached (the J still falling
    where a fixed search of a half and a quarter step stopped), to an eighth of a step; a peak
    at the minimum stays there; at most 13 distinct frequencies are tried (the caller caches
    each fit)."""
    grid = 1.0 / (8 * 3700.0)
    calls: list[float] = []

    def J(f: float) -> float:
        calls.append(f)
        return 1.0 + ((f - f_min) / grid) ** 2

    for f_min, f_peak in ((1.0 / 300.0, 1.0 / 300.0 + 2.3 * grid), (1.0 / 40.0, 1.0 / 40.0)):
        calls.clear()
        f = refined_frequency(J, f_peak, grid)
        assert abs(f - f_min) <= grid / 8 + 1e-15
        assert len(set(calls)) <= 3 + 6 + 4
    # a J that falls without end stops after the walk's steps
    f = refined_frequency(lambda f: -f, 0.01, grid, walk=3, halvings=0)
    assert f == pytest.approx(0.01 + 3 * grid / 2, rel=0, abs=1e-12)


def test_the_periods_run_from_a_few_knot_intervals_to_twice_the_range() -> None:
    grid = periods(5.0, 405.0, 40)
    assert math.isclose(grid[0], WAVE_KNOTS * 400.0 / 37)
    assert grid[-1] <= LONGEST * 400.0 < grid[-1] * PERIOD_RATIO
    assert np.allclose(np.diff(np.log(grid)), math.log(PERIOD_RATIO))
    assert periods(5.0, 5.0, 40) == []


def test_a_wave_in_the_basis_gives_back_its_level_amplitude_and_phase() -> None:
    group = Group("x", "t", 5.0, 405.0, 40)
    z = np.linspace(5.0, 405.0, 801)
    for period, a, b, phi in ((300.0, 0.2, 1.5, 0.7), (47.0, -0.1, 0.3, -2.5)):
        W = wave_basis(group, period)
        assert W is not None and W.shape == (40, 3)
        g_s = np.max(np.abs(np.sin(2 * np.pi * z / period)))
        g_c = np.max(np.abs(np.cos(2 * np.pi * z / period)))
        # b sin(w t + phi) = b cos(phi) sin(w t) + b sin(phi) cos(w t), each column over its
        # largest value on the range
        coefficients = np.array([a, b * math.cos(phi) * g_s, b * math.sin(phi) * g_c])
        truth = a + b * np.sin(2 * np.pi * z / period + phi)
        spline = basis(group, z) @ (W @ coefficients)
        assert np.max(np.abs(spline - truth)) < 0.01 * b
        named, values = phase_form(group, period, coefficients)
        form = parse_form(named.form)
        assert named.components == "x" and named.n == 2 and form.key == "wave"
        assert math.isclose(form.args[0], period, rel_tol=1e-5)
        assert np.max(np.abs(curve(named, values, z) - truth)) < 1e-3 * b


@pytest.mark.kernels(*kernels((), "derivatives"), *probe_kernels())
def test_the_periodogram_finds_the_period_of_a_push_turning_over_the_basin(data_dir) -> None:
    """A push of constant size whose direction over the basin turns once in 300 s (of the
    fresh planted set), on windows recorded at clock times from 5 s to an hour: the
    periodogram of the equation residual of the model without it has a peak within 2 % of
    300 s among its first (which the fit by output error chooses from); on the same windows
    without the push nothing stands out as much."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        runs = {k: read_recordings(data_dir / "data" / k) for k in ("random", "zigzag")}
    rng = np.random.default_rng(5)
    wins = pick_windows(runs, {"random": 4, "zigzag": 3}, rng)
    noise = noise_levels([r for v in runs.values() for r in v])
    shares = {}
    for scale in (1.0, 0.0):
        spec = unforeseen_spec("turning_current", scale) if scale else PlantedSpec("none")
        recs, diverged = generate(wins, efd_parameters(), spec, noise, np.random.default_rng(7))
        assert not diverged
        windows = cut_windows(recs)
        span = max(float(w.t[-1]) for w in windows) - min(float(w.t[0]) for w in windows)
        assert span > 1000.0  # (clock times beyond the shapes' guard of 1e3)
        peaks = period_peaks(efd_parameters(), windows)
        shares[scale] = peaks[0][1]
        if scale:
            assert any(abs(p - 300.0) < 6.0 for p, _ in peaks), peaks
    assert shares[1.0] > 3.0 * shares[0.0], shares
