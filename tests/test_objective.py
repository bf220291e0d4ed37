"""The objectives J1, J2, J3: definition, streaming algebra, J2 = J1 + J3, penalties, floors."""

from __future__ import annotations

import numpy as np
import pytest

from mmg import bounds, efd_parameters, simulate
from sweep.data.datasets import load_split
from sweep.data.objective import (
    DEFAULT_FLOORS,
    PENALTY_FACTOR,
    Objective,
    objective_per_segment,
    observables,
    split_recording,
)
from sweep.data.recordings import Recording
from tests.conftest import kernels

pytestmark = pytest.mark.kernels(*kernels((), "simulate", "moments"))


@pytest.fixture(scope="module")
def test_set(data_dir):
    return load_split("paper").load(data_dir)


def _synthetic(rec: Recording, theta, n: int | None = None) -> Recording:
    """The recording's controls and wind, states simulated (one run, no noise)."""
    n = n or rec.n_samples
    traj = simulate(rec.x[None, 0], rec.u[None, : n - 1], rec.w[None, : n - 1], theta)[0]
    return Recording(f"synthetic_{rec.name}", None, rec.t[:n], traj, rec.u[:n], rec.w[:n])


def test_subsequences_are_contiguous_100_s_windows(test_set):
    rec = test_set["Test-R"]  # 717.8 s
    segs = split_recording(rec)
    assert [s.n_steps for s in segs] == [1000] * 7 + [178]
    assert [s.start for s in segs] == [0, 1000, 2000, 3000, 4000, 5000, 6000, 7000]


def test_train_r_is_2694_6_seconds_of_subsequences(data_dir):
    train = load_split("R").load(data_dir)
    obj = Objective(list(train.values()))
    assert obj.data.durations.sum() == pytest.approx(2694.6, abs=1e-6)


def test_j2_equals_j1_plus_j3(test_set):
    obj = Objective(list(test_set.values()), labels=list(test_set))
    rng = np.random.default_rng(0)
    lo, hi = bounds()
    theta = np.clip(efd_parameters().vector() * rng.uniform(0.7, 1.3, (3, 57)), lo, hi)
    cost, _ = obj.costs(theta)
    J1 = objective_per_segment(cost, "J1")
    J2 = objective_per_segment(cost, "J2")
    J3 = objective_per_segment(cost, "J3")
    assert np.array_equal(J2, J1 + J3)
    np.testing.assert_allclose(obj.evaluate(theta, "J2"), J1.sum(1) + J3.sum(1), rtol=1e-13)


def _direct_J(recs, theta, floors):
    """J per channel from full trajectories and numpy (the paper's formula, no streaming)."""
    total = np.zeros(7)
    floor = np.array(list(floors.values()))
    for rec in recs:
        for seg in split_recording(rec):
            sl = slice(seg.start, seg.start + seg.n_steps + 1)
            x_in = rec.x[sl]
            traj = simulate(x_in[None, 0], rec.u[None, sl][:, :-1], rec.w[None, sl][:, :-1], theta)[
                0
            ]
            z_in, z_sim = observables(x_in), observables(traj)
            zh_in = (z_in - z_in.mean(0)) / np.maximum(z_in.std(0), floor)
            zh_sim = (z_sim - z_sim.mean(0)) / np.maximum(z_sim.std(0), floor)
            total += np.trapezoid((zh_in - zh_sim) ** 2, dx=0.1, axis=0)
    return total


def test_streamed_objective_equals_direct_computation(test_set):
    recs = [test_set["Test-Z"], test_set["Test-B-P"]]
    obj = Objective(recs)
    theta = efd_parameters().replace(N_r=-0.06, a_H=0.3)
    cost, bad = obj.costs(theta.vector()[None])
    assert not bad.any()
    direct = _direct_J(recs, theta, DEFAULT_FLOORS)
    np.testing.assert_allclose(cost[0].sum(0), direct, rtol=1e-8)


def test_the_true_model_has_zero_objective(test_set):
    truth = efd_parameters().replace(Y_v=-0.5, N_r=-0.06, X_vr=0.2)
    recs = [_synthetic(test_set["Test-Z"], truth), _synthetic(test_set["Test-B-S"], truth)]
    obj = Objective(recs)
    J = obj.evaluate(np.stack([truth.vector(), efd_parameters().vector()]))
    assert J[0] < 1e-6  # the simulator reproduces its own recordings
    assert J[1] > 10.0


def test_diverged_candidate_costs_a_finite_penalty(test_set):
    rec = test_set["Test-B-P"]
    obj = Objective([rec])
    theta = np.tile(efd_parameters().vector(), (2, 1))
    theta[1, 0] = -0.27078 + 1e-14  # m + m_x = 0: surge acceleration explodes
    cost, bad = obj.costs(theta)
    assert bad[1].all() and not bad[0].any()
    np.testing.assert_allclose(cost[1], PENALTY_FACTOR * obj.data.durations[:, None] * np.ones(7))
    J = obj.evaluate(theta)
    assert np.all(np.isfinite(J)) and J[1] > J[0]


def test_floor_keeps_a_still_channel_from_exploding():
    """Heading constant to 1e-6 rad in the recording: sin/cos psi are pure noise without a floor."""
    n = 301
    t = np.arange(n, dtype=np.float64) * 0.1
    x = np.zeros((n, 6))
    x[:, 1] = 0.2
    x[:, 0] = 0.2 * t
    x[:, 4] = 1e-6 * np.random.default_rng(0).standard_normal(n)  # a straight run-in
    rec = Recording("straight", None, t, x, np.tile([0.0, 6.0], (n, 1)), np.zeros((n, 2)))
    no_floor = {k: 1e-12 for k in DEFAULT_FLOORS}
    J_floor = Objective([rec], "J3").evaluate(efd_parameters())[0]
    J_raw = Objective([rec], "J3", floors=no_floor).evaluate(efd_parameters())[0]
    # the unfloored sin psi channel compares two unrelated standardised series: cost ~ 2 x 30 s
    assert J_raw > 40.0
    assert J_floor < 5.0


def test_population_evaluation_equals_one_by_one(test_set):
    obj = Objective([test_set["Test-B-S"]], "J1")
    rng = np.random.default_rng(4)
    theta = efd_parameters().vector() * rng.uniform(0.9, 1.1, (5, 57))
    together = obj.evaluate(theta)
    alone = np.array([obj.evaluate(theta[i : i + 1])[0] for i in range(5)])
    np.testing.assert_array_equal(together, alone)
