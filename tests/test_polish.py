"""Levenberg-Marquardt refinement: its residuals are the objective, and it finds a known optimum."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from mmg import Parameters, bounds, efd_parameters, simulate
from mmg.params import N_THETA, PARAMETER_NAMES
from sweep.cmaes import Box
from sweep.objective import Objective
from sweep.polish import PolishSettings, polish, residual_vectors, totals
from sweep.recordings import Recording, read_recordings


@pytest.fixture(scope="module")
def windows(data_dir: Path) -> list[Recording]:
    """Three 60-s windows of real runs (controls, wind, first states)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recs = read_recordings(data_dir / "data" / "random")[:3]
    out = []
    for r in recs:
        sl = slice(0, 601)
        out.append(Recording(f"{r.name}-w", None, r.t[sl], r.x[sl], r.u[sl], r.w[sl]))
    return out


def _synthetic(windows: list[Recording], p: Parameters) -> list[Recording]:
    """The windows re-simulated with ``p`` from their first states (noise-free)."""
    out = []
    for r in windows:
        x = simulate(r.x[:1], r.u[None, :-1], r.w[None, :-1], p, dt=r.dt)[0]
        out.append(Recording(r.name, None, r.t, x, r.u, r.w))
    return out


@pytest.mark.parametrize("name", ["J1", "J2", "J3"])
def test_sum_of_squared_residuals_is_the_objective(windows, name):
    obj = Objective(windows, name)
    efd = efd_parameters().vector()
    thetas = np.stack([efd, efd * 1.05, efd * 0.9])
    r, bad = residual_vectors(obj, thetas)
    np.testing.assert_allclose(totals(obj, r, bad), obj.evaluate(thetas), rtol=1e-9)


def test_a_diverging_candidate_costs_the_penalty(windows):
    obj = Objective(windows, "J2")
    theta = efd_parameters().vector().copy()
    theta[:3] = [-0.9, -0.9, -0.9]  # negative added masses: the simulation blows up
    r, bad = residual_vectors(obj, theta[None])
    assert bad.all()
    np.testing.assert_allclose(totals(obj, r, bad), obj.evaluate(theta[None]))


def test_polish_recovers_perturbed_parameters(windows):
    """Data from the EFD model; start 10 % off in six influential parameters: J falls to ~0."""
    truth = efd_parameters()
    data = _synthetic(windows, truth)
    obj = Objective(data, "J2")
    lo, hi = bounds()
    start = truth.vector().copy()
    names = ("Y_v", "N_r", "N_v", "t_P", "w_P0", "epsilon")
    idx = [PARAMETER_NAMES.index(n) for n in names]
    start[idx] *= 1.1
    start = np.clip(start, lo, hi)
    f0 = float(obj.evaluate(start[None])[0])
    res = polish(obj, Box(lo, hi), start, PolishSettings(max_iterations=30))
    assert res.f_start == pytest.approx(f0)
    assert res.f < 1e-3 * f0
    assert res.f == pytest.approx(float(obj.evaluate(res.theta[None])[0]), rel=1e-6, abs=1e-9)
    # hull and propeller coefficients come back; epsilon trades off against other rudder terms
    np.testing.assert_allclose(res.theta[idx[:5]], truth.vector()[idx[:5]], rtol=1e-3)
    assert res.theta.shape == (N_THETA,)
    assert np.all(res.theta >= lo) and np.all(res.theta <= hi)
    # the fit is deterministic
    again = polish(obj, Box(lo, hi), start, PolishSettings(max_iterations=3))
    first3 = polish(obj, Box(lo, hi), start, PolishSettings(max_iterations=3))
    np.testing.assert_array_equal(again.theta, first3.theta)
