"""The RK4 kernel: convergence order, batch vs single trajectory, limiter, divergence flags."""

from __future__ import annotations

import re
from typing import Any

import numba
import numpy as np
import pandas as pd
import pytest
from scipy.linalg import expm

from mmg import bounds, derivatives, efd_parameters, simulate, simulate_batch
from mmg.integrate import chunk_width, parameter_matrix, rk4_reference
from mmg.kernel import LANE_BLOCK, LIMIT_A, load_kernel
from tests.conftest import SHARED_EFFECTS, kernels, shared_effects
from tests.rk4_linear import A, linear_rhs

pytestmark = pytest.mark.kernels(*kernels(()), *kernels(SHARED_EFFECTS, "derivatives"))


def _run_linear(dt: float, T: float) -> np.ndarray:
    kern = load_kernel(rhs_override=linear_rhs)
    K = round(T / dt)
    x0 = np.array([[1.0, 0.0, 0.5, -0.5, 0.2, 0.1]])
    out = np.empty((1, K + 1, 6))
    bad = np.empty(1, np.int64)
    p = efd_parameters()
    kern.simulate_lanes(
        x0, np.zeros(1), np.zeros((1, K, 2)), np.zeros((1, K, 2)), parameter_matrix(p, 1),
        np.array([K]), np.array([0]), p.ship, dt, LIMIT_A, LIMIT_A, 8, 1, out, bad,
    )  # fmt: skip
    return out[0, -1]


def test_rk4_error_slope_is_four_on_a_linear_system():
    T = 10.0
    exact = expm(A * T) @ np.array([1.0, 0.0, 0.5, -0.5, 0.2, 0.1])
    dts = np.array([0.4, 0.2, 0.1, 0.05])
    errors = np.array([np.linalg.norm(_run_linear(dt, T) - exact) for dt in dts])
    slope = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    assert 3.8 < slope < 4.2, (slope, errors)


def _random_inputs(rng, B, K):
    u = np.empty((B, K, 2))
    u[..., 0] = rng.uniform(-0.6, 0.6, (B, 1)) + 0.1 * np.sin(np.arange(K) * 0.05)
    u[..., 1] = rng.choice([-15.0, -5.0, 0.0, 4.0, 10.0], (B, 1))
    w = np.empty((B, K, 2))
    w[..., 0] = rng.uniform(0.0, 3.0, (B, 1))
    w[..., 1] = rng.uniform(-np.pi, np.pi, (B, 1))
    x0 = np.zeros((B, 6))
    x0[:, 1] = rng.uniform(-0.2, 0.35, B)
    x0[:, 3] = rng.uniform(-0.05, 0.05, B)
    x0[:, 4] = rng.uniform(-3, 3, B)
    x0[:, 5] = rng.uniform(-0.03, 0.03, B)
    return x0, u, w


def _perturbed(rng, n, scale=0.2):
    base = efd_parameters().vector()
    lo, hi = bounds()
    theta = base * (1 + scale * rng.standard_normal((n, base.size)))
    return np.clip(theta, lo, hi)


def test_batched_paths_agree_with_single_trajectory_reference():
    rng = np.random.default_rng(1)
    B, K = 13, 150
    x0, u, w = _random_inputs(rng, B, K)
    theta = _perturbed(rng, B)
    steps = rng.integers(40, K + 1, B)
    res = simulate_batch(x0, u, w, theta, n_steps=steps, chunk=8)
    p0 = efd_parameters()
    for b in range(B):
        ref = rk4_reference(
            x0[b], u[b, : steps[b]], w[b, : steps[b]], type(p0).from_vector(theta[b])
        )
        got = res.states[b, : steps[b] + 1]
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)
        assert np.all(np.isnan(res.states[b, steps[b] + 1 :]))


def test_results_do_not_depend_on_chunking_or_batch_companions():
    rng = np.random.default_rng(2)
    x0, u, w = _random_inputs(rng, 37, 200)
    theta = _perturbed(rng, 37)
    a = simulate_batch(x0, u, w, theta, chunk=8).states
    b = simulate_batch(x0, u, w, theta, chunk=120).states
    c = simulate_batch(x0[5:6], u[5:6], w[5:6], theta[5:6]).states
    assert np.array_equal(a, b)
    assert np.array_equal(a[5], c[0])


def test_chunks_come_in_whole_vector_blocks_and_cover_the_batch():
    """No lane of a full chunk goes through the vectorised loop's scalar remainder: widths are
    multiples of LANE_BLOCK, and the chunks still cover B lanes in about ``chunk``-wide pieces."""
    for B in (1, 5, 13, 37, 70, 540, 812, 19440):
        for chunk in (8, 100, 120):
            width = chunk_width(B, chunk)
            assert width % LANE_BLOCK == 0
            n_chunks = -(-B // width)
            assert (n_chunks - 1) * width < B <= n_chunks * width
            assert width <= -(-chunk // LANE_BLOCK) * LANE_BLOCK or n_chunks == 1
    if numba.get_num_threads() == 2:  # 8 chunks (7 of 104, one of 84): 102 left 6 lanes scalar
        assert chunk_width(812, 120) == 104


def test_objective_moments_do_not_depend_on_chunking_and_match_the_trajectories():
    """The objective's kernel (fused multiply-adds) gives every (candidate, segment) lane the same
    moments at any chunk width and alone, and agrees with the simulated trajectories (strict
    arithmetic) to rounding."""
    from mmg.integrate import OBSERVABLES, Segments, segment_moments

    rng = np.random.default_rng(5)
    S, K, C = 7, 120, 5
    x0, u, w = _random_inputs(rng, S, K)
    theta = _perturbed(rng, C)
    steps = rng.integers(60, K + 1, S)
    ref = rng.normal(0.0, 1.0, (S, K + 1, len(OBSERVABLES)))
    seg = Segments(x0, u, w, steps, ref, np.zeros((S, len(OBSERVABLES))))
    m8, b8 = segment_moments(seg, theta, chunk=8)
    m120, _ = segment_moments(seg, theta, chunk=120)
    m3, _ = segment_moments(seg, theta, chunk=3)
    alone, _ = segment_moments(seg, theta[2:3])
    assert not (b8 >= 0).any()
    assert np.array_equal(m8, m120) and np.array_equal(m8, m3)
    assert np.array_equal(m8[2], alone[0])
    # sum z and sum z^2 over the samples of the simulated trajectory of candidate 1, segment 4
    traj = simulate_batch(x0[4:5], u[4:5], w[4:5], theta[1:2], n_steps=steps[4:5]).states[0]
    z = traj[: steps[4] + 1]
    obs = np.stack(
        [z[:, 0], z[:, 1], z[:, 2], z[:, 3], np.sin(z[:, 4]), np.cos(z[:, 4]), z[:, 5]], 1
    )
    np.testing.assert_allclose(m8[1, 4, :, 0], obs.sum(0), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(m8[1, 4, :, 1], (obs * obs).sum(0), rtol=1e-9, atol=1e-12)


def test_derivatives_of_many_parameter_rows_equal_the_per_point_evaluation():
    """derivatives_rows (each point reads its set from R columns) gives bit for bit what
    derivatives gives with the sets broadcast to every point, with an effect and time."""
    from mmg.integrate import derivatives, derivatives_rows

    rng = np.random.default_rng(4)
    x0, u, w = _random_inputs(rng, 1, 30)
    effects = shared_effects()  # the catalog's, neutral, then the terms N_dnn and Y_t (time)
    neutral = np.tile(np.concatenate([e.neutral() for e in effects[:-1]]), (5, 1))
    rows = np.concatenate([_perturbed(rng, 5), neutral, rng.normal(0.0, 1e-3, (5, 2))], axis=1)
    x = np.repeat(x0, 30, axis=0) + rng.normal(0.0, 0.01, (30, 6))
    t = np.linspace(0.0, 90.0, 30)
    got = derivatives_rows(x, u[0], w[0], rows, effects, t=t)
    ref = derivatives(
        np.broadcast_to(x, (5, 30, 6)),
        np.broadcast_to(u[0], (5, 30, 2)),
        np.broadcast_to(w[0], (5, 30, 2)),
        np.broadcast_to(rows[:, None, :], (5, 30, rows.shape[1])),
        effects,
        t=np.broadcast_to(t, (5, 30)),
    )
    assert got.shape == (5, 30, 6)
    assert np.array_equal(got, ref)
    assert not np.array_equal(got[0], got[1])  # the rows differ
    with pytest.raises(ValueError, match="rows must have shape"):
        derivatives_rows(x, u[0], w[0], rows[:, :10], effects)


def test_diverging_candidate_is_flagged_and_does_not_spoil_the_batch():
    rng = np.random.default_rng(3)
    x0, u, w = _random_inputs(rng, 4, 300)
    theta = np.tile(efd_parameters().vector(), (4, 1))
    lo, hi = bounds()
    theta[2] = np.where(rng.random(lo.size) < 0.5, lo, hi)  # a corner of the search box
    theta[2, :3] = 0.7 * efd_parameters().vector()[:3]
    res = simulate_batch(x0, u, w, theta)
    solo = simulate_batch(x0[[0, 1, 3]], u[[0, 1, 3]], w[[0, 1, 3]], theta[[0, 1, 3]])
    assert not res.diverged[[0, 1, 3]].any()
    assert np.array_equal(res.states[[0, 1, 3]], solo.states)
    # a candidate whose derivatives exceed the limiter is flagged, never raised
    theta[1, 0] = -1e12  # m_x' absurdly negative: surge equation is near-singular
    res2 = simulate_batch(x0, u, w, theta)
    assert res2.diverged[1] and res2.bad_step[1] >= 0
    assert not res2.diverged[[0, 3]].any()


def test_limiter_clips_to_the_algorithm_1_bounds():
    """With an absurd mass the limiter must act and position rows follow (2 - t/t_f) a."""
    p = efd_parameters().replace(m_x=-0.27078 + 1e-14)  # m + m_x ~ 0: u_dot explodes
    x0 = np.array([[0.0, 0.3, 0.0, 0.0, 0.0, 0.0]])
    u = np.tile([0.0, 10.0], (1, 10, 1))
    w = np.zeros((1, 10, 2))
    res = simulate_batch(x0, u, w, p)
    ref = rk4_reference(x0[0], u[0], w[0], p)
    assert res.diverged[0] and res.bad_step[0] == 0
    np.testing.assert_allclose(res.states[0], ref, rtol=1e-12)
    raw = derivatives(x0[0], u[0, 0], w[0, 0], p)
    assert abs(raw[1]) > LIMIT_A  # unclipped, u_dot would exceed the limit
    # every stage is clipped, so no step moves a state by more than dt x (its bound)
    step = np.abs(np.diff(res.states[0], axis=0))
    a, L = LIMIT_A, p.ship.L_pp
    bound = 0.1 * np.array([2 * a, a, 2 * a, a, 2 * a / (0.5 * L), a / (0.5 * L)])
    assert np.all(step <= bound * (1 + 1e-12))
    assert step.max() > 1e6  # and the limiter, not the physics, set the scale


def test_recorded_turning_test_is_followed_for_100_seconds(data_dir):
    """EFD model, 100 s of the recorded Test-T run (t = 300-400 s, steady 35 deg turn)."""
    df = pd.read_csv(data_dir / "data/turning/turn_14-Sep-2020_14_50_41.csv")
    cols = ["x_position_mid [m]", "u_velo [m/s]", "y_position_mid [m]", "vm_velo [m/s]"]
    cols += ["psi_hat [rad]", "r_angvelo [rad/s]"]
    x = df[cols].to_numpy()
    x[:, 4] = np.unwrap(x[:, 4])
    u = df[["delta_rudder [rad]", "n_prop [rps]"]].to_numpy()
    w = df[["wind_velo_true [m/s]", "wind_dir_true [rad]"]].to_numpy()
    s0, K = 3000, 1000
    traj = simulate(x[None, s0], u[None, s0 : s0 + K], w[None, s0 : s0 + K], efd_parameters())[0]
    assert np.all(np.isfinite(traj))
    err = np.hypot(traj[:, 0] - x[s0 : s0 + K + 1, 0], traj[:, 2] - x[s0 : s0 + K + 1, 2])
    # measured: 2.1 m after 100 s and 17 m of travel (model length 3 m)
    assert err[-1] < 3.0
    # the ship turns to starboard like the recording: heading grows by more than 2 rad
    assert traj[-1, 4] - traj[0, 4] > 2.0
    assert abs(traj[-1, 4] - x[s0 + K, 4]) < 1.0


def test_states_written_into_a_given_array_equal_a_fresh_one_and_a_wrong_one_is_refused():
    """``simulate_batch(out=...)`` (reused batch after batch by the residuals) writes the same
    states, bit for bit, into the caller's array; an array of another shape or layout is a
    ValueError naming the expected shape, not memory written out of bounds."""
    rng = np.random.default_rng(5)
    B, K = 12, 40
    x0 = np.zeros((B, 6))
    x0[:, 1] = rng.uniform(1.0, 4.0, B)
    u = np.stack([rng.uniform(-0.3, 0.3, (B, K)), rng.uniform(2.0, 8.0, (B, K))], axis=-1)
    w = np.zeros((B, K, 2))
    p = efd_parameters()
    fresh = simulate_batch(x0, u, w, p)
    buf = np.full((B, K + 1, 6), 123.0)
    again = simulate_batch(x0, u, w, p, out=buf)
    assert again.states is buf
    assert np.array_equal(buf, fresh.states) and np.array_equal(again.bad_step, fresh.bad_step)
    with pytest.raises(ValueError, match=r"\(12, 41, 6\)"):
        simulate_batch(x0, u, w, p, out=np.empty((B, K, 6)))
    with pytest.raises(ValueError, match="C-contiguous"):
        simulate_batch(x0, u, w, p, out=np.empty((6, K + 1, B)).transpose(2, 1, 0))


@pytest.mark.skipif(
    bool(getattr(numba.config, "DISABLE_JIT", 0)), reason="inspects the compiled kernel"
)
@pytest.mark.parametrize("step", ["rk4_step", "rk4_step_fused"])
@pytest.mark.integration  # compiles the step on its own, never cached
def test_the_rk4_stage_loop_compiles_to_vector_instructions(step):
    """Lanes are innermost so that LLVM vectorises the right-hand side across trajectories
    (README, "How it is fast"): the square roots and divisions of the stage loop must be vector
    operations in the simulator's step and in the objective's fused one. One construct that LLVM
    cannot vectorise in a sub-model (a float ``min()``, for instance) leaves the whole loop scalar
    and the kernel about half as fast, with every result unchanged: this finds it without
    timing anything. The step's multiplies, its sub-models' included, are all strict in the
    simulator's step and all contracted in the objective's. (Compiles the step on its own, about
    10 s.)"""
    kern = load_kernel()
    W = 16
    cur = np.zeros((4, W))
    P = parameter_matrix(efd_parameters(), W)
    fn = getattr(kern, step)
    fn(
        np.zeros((6, W)), np.zeros((4, 6, W)), np.zeros((4, W)), cur[0], cur[1], cur[2], cur[3],
        P, np.ones((kern.N_INERTIA, W)), efd_parameters().ship, 0, 0.1, np.ones(W), np.zeros(W),
        LIMIT_A, LIMIT_A, np.full(W, -1, np.int64), W,
    )  # fmt: skip
    ir = fn.inspect_llvm(fn.signatures[0])
    assert re.search(r"llvm\.sqrt\.v\d+f64", ir), "no vector square root in the stage loop"
    assert re.search(r"fdiv (?:[a-z]+ )*<\d+ x double>", ir), "no vector division either"
    # the sub-models inlined into the step have its arithmetic: the fused step calls their fused
    # twins (no strict multiply left), the simulator's step the strict ones (no contraction)
    assert re.search(r"= fmul ", ir)
    if step == "rk4_step_fused":
        assert not re.search(r"= fmul (?!contract)", ir), "a strict multiply in the fused step"
    else:
        assert " contract " not in ir, "a contracted multiply in the simulator's step"


@pytest.mark.skipif(
    bool(getattr(numba.config, "DISABLE_JIT", 0)), reason="inspects the compiled code"
)
def test_a_sub_model_used_by_the_fused_kernel_is_contracted_there_and_strict_elsewhere():
    """The objective's kernel calls the sub-models' fused twins, which contract their
    multiply-adds, also in the sub-models they call; the sub-model itself, called from Python
    afterwards (or by the simulator's kernel), keeps strict arithmetic. Numba compiles a callee
    once per process with the arithmetic of whichever caller reached it first, so one compiled
    form for both would make the simulator's last bits depend on which kernel a process compiled
    first."""
    from mmg._jit import FUSED_OPTIONS, fused_source, subfunction

    def scaled_sum(a, b, c):
        return a * b + c

    inner: Any = subfunction(scaled_sum)  # the dispatcher (typed as the function it wraps)

    def twice(a, b, c):
        return inner(a, b, c) * b + c

    sub: Any = subfunction(twice)

    def fused_caller(x):
        s = 0.0
        for i in range(x.shape[0]):
            s = s + sub(x[i], x[i], 1.0)
        return s

    caller = numba.njit(**FUSED_OPTIONS)(fused_source(fused_caller))
    assert caller(np.arange(3.0)) == 1.0 + 3.0 + 11.0  # compiles the fused twins first
    assert sub(2.0, 3.0, 1.0) == 22.0  # then the sub-models on their own, from Python
    for strict in (sub, inner):
        ir = strict.inspect_llvm(strict.signatures[0])
        assert re.search(r"fmul (?:[a-z]+ )*double", ir) and " contract " not in ir
    caller_ir = caller.inspect_llvm(caller.signatures[0])
    # both multiply-adds of the inlined twins contracted: no strict multiplication is left
    assert re.search(r"fmul contract ", caller_ir), "the fused caller's sub is not contracted"
    assert not re.search(r"fmul (?!contract)", caller_ir), "a strict multiply in the fused caller"


def test_thread_shares_cover_every_chunk_once_and_an_error_reaches_the_caller():
    """The trajectory entry points run thread t's share (chunks t, t + n_threads, ...) in a pool
    of threads: every share runs once, with its own t, whatever the number of threads; an error
    in any share reaches the caller."""
    from mmg._threads import run_threads

    for n in (1, 2, 5):
        seen = np.zeros(n, np.int64)

        def share(t: int, out: np.ndarray) -> None:
            out[t] += 1

        run_threads(share, n, (seen,))
        assert seen.tolist() == [1] * n

    def failing(t: int) -> None:
        if t == 2:
            raise RuntimeError("share 2 failed")

    with pytest.raises(RuntimeError, match="share 2 failed"):
        run_threads(failing, 3, ())


def test_the_states_do_not_depend_on_the_number_of_threads():
    """Thread shares only split the chunks among threads (all of the machine's, or one)."""
    rng = np.random.default_rng(3)
    x0, u, w = _random_inputs(rng, 40, 30)
    theta = _perturbed(rng, 40)
    every = simulate_batch(x0, u, w, theta, chunk=8).states
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = simulate_batch(x0, u, w, theta, chunk=8).states
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(every, one)
