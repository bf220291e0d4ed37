"""Levenberg-Marquardt refinement: its residuals are the objective, and it finds a known optimum."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from mmg import Parameters, bounds, efd_parameters, simulate
from mmg.params import N_THETA, PARAMETER_NAMES
from sweep.data.objective import Objective
from sweep.data.recordings import Recording, read_recordings
from sweep.identification.cmaes import Box
from sweep.identification.polish import (
    PolishSettings,
    _standardised_residuals,
    damped_step,
    polish,
    residual_vectors,
    totals,
)
from tests.conftest import kernels

pytestmark = pytest.mark.kernels(*kernels((), "simulate", "moments"))


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


def test_the_residual_pass_flags_and_zeroes_a_lane_that_went_non_finite():
    """A NaN state mid-run and a heading beyond the sine's range (2^50 rad) each flag their lane
    and leave its row 0; the other lanes' residuals are the standardised observables."""
    rng = np.random.default_rng(3)
    S, K, m = 2, 30, 7
    states = rng.standard_normal((4, K + 1, 6))
    states[1, 12, 1] = np.nan
    states[2, 7, 4] = 2.0**51
    steps = np.array([K, K - 5], dtype=np.int64)
    channels = np.arange(m, dtype=np.int64)
    ref = rng.standard_normal((S, K + 1, m))
    sqrt_w = np.ones((S, K + 1))
    out = np.full((4, (K + 1) * m), 7.0)
    bad = np.zeros(4, dtype=bool)
    _standardised_residuals(states, steps, channels, ref, np.full(m, 1e-3), sqrt_w, out, bad)
    assert bad.tolist() == [False, True, True, False]
    assert not out[1].any() and not out[2].any()
    # lane 3 simulates subsequence 1 (K - 5 steps): its sin psi channel, standardised
    n = K - 5
    z = np.sin(states[3, : n + 1, 4])
    want = ref[1, : n + 1, 4] - (z - z.mean()) / z.std()
    np.testing.assert_allclose(out[3].reshape(K + 1, m)[: n + 1, 4], want, rtol=1e-12, atol=1e-12)
    assert not out[3].reshape(K + 1, m)[n + 1 :].any()


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


def test_damped_step_holds_a_coordinate_pushed_out_of_the_box():
    """On a coupled quadratic whose minimum lies outside the box in coordinate 0, the step
    keeps coordinate 0 on its bound and takes coordinate 1 to the constrained minimum (the
    minimum of the quadratic along z_0 = 0), not to the clipped unconstrained one."""
    H = np.array([[2.0, 1.2], [1.2, 1.0]])
    z_star = np.array([-0.5, 0.9])
    z = np.array([0.0, 0.5])
    g = H @ (z - z_star)
    assert g[0] > 0  # the gradient pushes coordinate 0 below its bound
    new = damped_step(H, g, np.diag(H).copy(), z, 1e-12)
    constrained = z_star[1] - H[1, 0] / H[1, 1] * (0.0 - z_star[0])
    assert new[0] == 0.0
    assert new[1] == pytest.approx(constrained, abs=1e-9)
    assert abs(constrained - z_star[1]) > 0.5  # what solving all and clipping would give
    # inside the box every coordinate is free: the plain Gauss-Newton step
    inside = np.array([0.3, 0.5])
    star_in = np.array([0.2, 0.6])
    step = damped_step(H, H @ (inside - star_in), np.diag(H).copy(), inside, 1e-12)
    np.testing.assert_allclose(step, star_in, atol=1e-9)


def test_prior_picks_the_plausible_point_along_a_flat_direction(windows):
    """epsilon trades off against other rudder terms on these windows: from a start 10 % off,
    J falls to ~0 either way, but with a weak prior toward the true values epsilon comes back
    much closer to them."""
    truth = efd_parameters()
    data = _synthetic(windows, truth)
    obj = Objective(data, "J2")
    lo, hi = bounds()
    start = truth.vector().copy()
    i_eps = PARAMETER_NAMES.index("epsilon")
    start[i_eps] *= 1.1
    f0 = float(obj.evaluate(start[None])[0])
    box = Box(lo, hi)
    plain = polish(obj, box, start, PolishSettings(max_iterations=40))
    prior = polish(
        obj,
        box,
        start,
        PolishSettings(max_iterations=40, prior_weight=1e-2, prior_dims=N_THETA),
        prior_center=truth.vector(),
    )
    err_plain = abs(plain.theta[i_eps] - truth.vector()[i_eps])
    err_prior = abs(prior.theta[i_eps] - truth.vector()[i_eps])
    assert plain.f < 1e-3 * f0 and prior.f < 1e-3 * f0
    assert err_prior < 0.1 * err_plain, (err_prior, err_plain)


def test_a_quadratic_penalty_enters_the_normal_equations(windows):
    """theta' P theta on two parameters: a large weight on (a - b)^2 pulls them together (the
    second-difference penalty of a shape does this to neighbouring coefficients); J alone is
    what Polished.f reports."""
    truth = efd_parameters()
    data = _synthetic(windows, truth)
    obj = Objective(data, "J2")
    lo, hi = bounds()
    i, j = PARAMETER_NAMES.index("t_R"), PARAMETER_NAMES.index("a_H")
    start = truth.vector().copy()
    start[i] *= 1.05
    P = np.zeros((N_THETA, N_THETA))
    P[np.ix_([i, j], [i, j])] = 1e4 * np.array([[1.0, -1.0], [-1.0, 1.0]])
    s = PolishSettings(max_iterations=30)
    plain = polish(obj, Box(lo, hi), start, s)
    pen = polish(obj, Box(lo, hi), start, s, penalty=P)
    gap = truth.vector()[i] - truth.vector()[j]
    assert abs(pen.theta[i] - pen.theta[j]) < 0.2 * abs(gap)  # pulled together
    assert abs(plain.theta[i] - plain.theta[j]) > 0.5 * abs(gap)
    r, bad = residual_vectors(obj, pen.theta[None])
    assert pen.f == pytest.approx(float(totals(obj, r, bad)[0]), rel=1e-12)


def test_refinement_runs_its_linear_algebra_on_one_blas_thread(windows):
    """With two BLAS threads, OpenBLAS's second thread spins on after each J J' and takes a core
    from the simulator's threads; the refinement limits BLAS to one thread and restores it."""
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> set[int]:
        return {int(i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"}

    seen: list[set[int]] = []
    obj = Objective(windows, "J2")
    lo, hi = bounds()
    with threadpool_limits(limits=2, user_api="blas"):
        outside = blas_threads()
        polish(
            obj,
            Box(lo, hi),
            efd_parameters().vector(),
            PolishSettings(max_iterations=1),
            progress=lambda row: seen.append(blas_threads()),
        )
        after = blas_threads()
    assert seen and all(s == {1} for s in seen)
    assert after == outside
