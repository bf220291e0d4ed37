"""Restart CMA-ES: schedule, cap, determinism, resume, post-filter, penalties, workers."""

from __future__ import annotations

import cma
import numpy as np
import pytest

from mmg import bounds, efd_parameters
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.identification.cmaes import (
    BoundPenalty,
    Box,
    Settings,
    load_checkpoint,
    optimise,
    population_schedule,
)
from sweep.identification.workers import InProcess, ProcessPool
from tests.conftest import kernels

pytestmark = pytest.mark.kernels(*kernels((), "moments"))

N = 8
BOX = Box(-5.0 * np.ones(N), 5.0 * np.ones(N))


def rastrigin(X):
    X = np.asarray(X)
    return 10 * N + np.sum(X * X - 10 * np.cos(2 * np.pi * X), axis=1)


def test_population_doubles_from_20_and_is_capped_at_720():
    assert [population_schedule(r) for r in range(8)] == [20, 40, 80, 160, 320, 640, 720, 720]


def test_vectorised_bound_penalty_runs_exactly_like_pycmas():
    """The numpy repair is pycma's projection: same repaired points (copied or in place), and a
    strategy whose optimum lies outside the box takes the same path with either handler."""
    ours, theirs = BoundPenalty([0.0, 1.0]), cma.BoundPenalty([0.0, 1.0])
    rng = np.random.default_rng(3)
    for _ in range(200):
        x = rng.normal(0.5, 0.8, 9)
        a, b = ours.repair(x), theirs.repair(x)
        assert np.array_equal(a, b) and a is not x and not np.array_equal(a, x)
        y, z = x.copy(), x.copy()
        ours.repair(y, copy_if_changed=False)
        theirs.repair(z, copy_if_changed=False)
        assert np.array_equal(y, z) and np.array_equal(y, a)
    means = []
    for handler in (BoundPenalty, cma.BoundPenalty):
        es = cma.CMAEvolutionStrategy(
            9 * [0.5],
            0.3,
            {"BoundaryHandler": handler, "bounds": [0.0, 1.0], "seed": 5, "verbose": -9},
        )
        for _ in range(40):
            X = es.ask()
            es.tell(X, [float(np.sum((np.asarray(x) - 1.3) ** 2)) for x in X])
        means.append(np.array(es.mean))
    assert np.array_equal(means[0], means[1])
    assert np.all(means[0] > 0.9)  # pushed against the upper bound, as pycma's would be


def test_restarts_follow_the_schedule_and_record_stop_reasons():
    s = Settings(seed=1, max_evaluations=20_000, sigma0=0.3, popsize_max=80, tolfun=1e-3)
    res = optimise(rastrigin, BOX, np.zeros(N), s)
    pops = [r.popsize for r in res.restarts]
    assert pops[:3] == [20, 40, 80] and all(p == 80 for p in pops[3:])  # capped
    assert all(r.stop for r in res.restarts)  # every restart says why it ended
    assert "budget" in res.restarts[-1].stop and res.stop_reason == "budget"
    assert res.evaluations <= 20_000
    assert res.evaluations == sum(r.evaluations for r in res.restarts)
    hist = res.history
    assert [h["evaluations"] for h in hist] == sorted(h["evaluations"] for h in hist)
    assert hist[-1]["best_so_far"] == res.f


def test_a_flat_objective_ends_each_restart_instead_of_raising():
    """Every candidate of the first generations at the same value (a whole population
    diverged to the penalty): pycma's boundary handling cannot scale and raises; the restart
    ends ("flat"), the evaluations count and the start's value is the result."""
    s = Settings(seed=1, max_evaluations=300, sigma0=0.3, popsize_max=40)
    res = optimise(lambda X: np.full(len(X), 42.0), BOX, np.zeros(N), s)
    assert res.f == 42.0 and res.evaluations <= 300
    assert res.restarts and all(r.stop == {"flat": 1} for r in res.restarts[:-1])

    # three quarters of every population at the penalty, the rest spread: no spread either
    def mostly_diverged(X: np.ndarray) -> np.ndarray:
        f = np.full(len(X), 4.2e4)
        f[: len(X) // 4] = np.arange(len(X) // 4)
        return f

    res = optimise(mostly_diverged, BOX, np.zeros(N), s)
    assert res.f == 0.0 and res.restarts[0].stop == {"flat": 1}
    with pytest.raises(ValueError, match="evaluate returned shape"):
        optimise(lambda X: np.zeros(1), BOX, np.zeros(N), s)


def test_same_seed_same_result_other_seed_other_result():
    s = Settings(seed=7, max_evaluations=3000, sigma0=0.3)
    a = optimise(rastrigin, BOX, np.ones(N), s)
    b = optimise(rastrigin, BOX, np.ones(N), s)
    c = optimise(rastrigin, BOX, np.ones(N), Settings(seed=8, max_evaluations=3000, sigma0=0.3))
    assert a.f == b.f and np.array_equal(a.theta, b.theta)
    assert not np.array_equal(a.theta, c.theta)


def test_resumed_run_ends_exactly_like_an_uninterrupted_one(tmp_path):
    s = Settings(seed=11, max_evaluations=8000, sigma0=0.3, tolfun=1e-4)
    full = optimise(rastrigin, BOX, np.zeros(N), s)
    ck = tmp_path / "ck.pkl"
    part = optimise(rastrigin, BOX, np.zeros(N), s, checkpoint=ck, stop_after_generations=45)
    assert part.evaluations < full.evaluations
    state = load_checkpoint(ck)
    assert state.evaluations == part.evaluations and not state.finished
    optimise(rastrigin, BOX, np.zeros(N), s, checkpoint=ck, stop_after_generations=60)
    resumed = optimise(rastrigin, BOX, np.zeros(N), s, checkpoint=ck)
    assert resumed.f == full.f
    assert np.array_equal(resumed.theta, full.theta)
    assert [r.stop for r in resumed.restarts] == [r.stop for r in full.restarts]


class _CrashError(RuntimeError):
    """The process dies (raised out of optimise by the evaluation)."""


def test_checkpoints_are_spaced_in_time_and_a_crash_resumes_from_an_older_one(
    tmp_path, checkpoint_writes
):
    """With checkpoint_seconds the checkpoint is written after the first generation and at
    every restart's end only (here: never in between); every generation with 0. A run that
    crashes many generations after its last checkpoint resumes from it and ends exactly where
    an uninterrupted run ends."""

    s = Settings(seed=11, max_evaluations=8000, sigma0=0.3, tolfun=1e-4)
    full = optimise(rastrigin, BOX, np.zeros(N), s)
    generations = len(full.history)
    restarts = len(full.restarts)
    assert restarts >= 2

    optimise(rastrigin, BOX, np.zeros(N), s, checkpoint=tmp_path / "every.pkl",
             checkpoint_seconds=0.0)  # fmt: skip
    # every generation but the last of a restart that stopped itself (not on the budget,
    # which stops before asking), plus one per restart's end
    stopped_itself = sum("budget" not in r.stop for r in full.restarts)
    assert stopped_itself >= 1
    assert len(checkpoint_writes) == generations - stopped_itself + restarts
    checkpoint_writes.clear()
    optimise(rastrigin, BOX, np.zeros(N), s, checkpoint=tmp_path / "spaced.pkl",
             checkpoint_seconds=1e9)  # fmt: skip
    assert len(checkpoint_writes) == 1 + restarts  # the first generation, each restart's end
    assert checkpoint_writes[0] == 20

    ck = tmp_path / "crash.pkl"
    calls = 0

    def crashing(X):
        nonlocal calls
        calls += 1
        if calls > 30:
            raise _CrashError
        return rastrigin(X)

    checkpoint_writes.clear()
    with pytest.raises(_CrashError):
        optimise(crashing, BOX, np.zeros(N), s, checkpoint=ck, checkpoint_seconds=1e9)
    assert checkpoint_writes == [20]  # 29 generations done since the last checkpoint, lost
    assert load_checkpoint(ck).evaluations == 20
    resumed = optimise(rastrigin, BOX, np.zeros(N), s, checkpoint=ck, checkpoint_seconds=1e9)
    assert resumed.f == full.f and np.array_equal(resumed.theta, full.theta)
    assert resumed.evaluations == full.evaluations
    with pytest.raises(ValueError, match="checkpoint_seconds"):
        optimise(rastrigin, BOX, np.zeros(N), s, checkpoint_seconds=-1.0)


def test_a_bare_pickle_checkpoint_of_before_the_envelope_is_set_aside_unread(tmp_path, capsys):
    """Checkpoints written before they were signed (a bare pickle; here also of the old module
    layout, sweep.cmaes) are of another format: set aside, not read, and the run starts afresh."""
    import pickle

    s = Settings(seed=3, max_evaluations=600, sigma0=0.3)
    ck = tmp_path / "ck.pkl"
    optimise(rastrigin, BOX, np.zeros(N), s, checkpoint=ck, stop_after_generations=5)
    state = load_checkpoint(ck)
    old = pickle.dumps(state, protocol=2).replace(
        b"csweep.identification.cmaes\n", b"csweep.cmaes\n"
    )
    ck.write_bytes(old)
    (tmp_path / "ck.pkl.prev").unlink(missing_ok=True)
    with pytest.raises(ValueError, match="other format"):
        load_checkpoint(ck)
    full = optimise(rastrigin, BOX, np.zeros(N), s)
    again = optimise(rastrigin, BOX, np.zeros(N), s, checkpoint=ck)
    assert again.f == full.f and again.evaluations == full.evaluations
    assert again.recovery is not None and again.recovery.resumed == "fresh"
    assert (tmp_path / "ck.pkl.bad-1").read_bytes() == old
    assert capsys.readouterr().err.count("\n") == 1


def test_checkpoint_with_other_settings_is_refused(tmp_path):
    ck = tmp_path / "ck.pkl"
    optimise(rastrigin, BOX, np.zeros(N), Settings(seed=1, max_evaluations=200), checkpoint=ck)
    with pytest.raises(ValueError, match="other settings"):
        optimise(rastrigin, BOX, np.zeros(N), Settings(seed=2, max_evaluations=200), checkpoint=ck)


def test_post_filter_rejects_results_ten_times_beyond_the_box():
    lo, hi = bounds()
    box = Box(lo, hi)
    efd = efd_parameters().vector()
    assert not box.rejected(efd)
    far = efd.copy()
    far[9] = 10.5 * hi[9]  # C_D beyond 10 x its upper bound
    assert box.rejected(far)
    near = efd.copy()
    near[9] = 5.0 * hi[9]  # outside the box, used "without correction"
    assert not box.rejected(near)
    # unbounded search of a function whose optimum is far outside the box
    res = optimise(
        lambda X: np.sum((X - 60.0) ** 2, axis=1),
        BOX,
        np.zeros(N),
        Settings(seed=0, max_evaluations=4000, sigma0=0.5, bound_handling="none"),
    )
    assert res.rejected
    boxed = optimise(
        lambda X: np.sum((X - 60.0) ** 2, axis=1),
        BOX,
        np.zeros(N),
        Settings(seed=0, max_evaluations=4000, sigma0=0.5, bound_handling="penalty"),
    )
    assert not boxed.rejected and np.all(boxed.theta <= 5.0 + 1e-12)


def test_non_finite_values_do_not_break_a_generation():
    def nasty(X):
        f = rastrigin(X)
        f[::3] = np.nan
        f[1::5] = np.inf
        return f

    res = optimise(nasty, BOX, np.zeros(N), Settings(seed=0, max_evaluations=1000, sigma0=0.3))
    assert np.isfinite(res.f) and res.evaluations == 1000


@pytest.fixture(scope="module")
def small_objective(data_dir):
    from sweep.data.recordings import read_recording

    rec = read_recording(data_dir / "data/berthing/berthing_12-Nov-2020_13_21_03.csv")
    short = Recording(rec.name, None, rec.t[:301], rec.x[:301], rec.u[:301], rec.w[:301])
    return Objective([short], "J2")


def test_diverging_candidates_get_the_penalty_not_an_exception(small_objective):
    theta = np.tile(efd_parameters().vector(), (4, 1))
    theta[2, 0] = -0.27078 + 1e-14  # m + m_x = 0
    f = InProcess(small_objective)(theta)
    assert np.all(np.isfinite(f))
    assert f[2] == pytest.approx(small_objective.max_penalty)
    assert f[2] > 10 * f[0]


def test_worker_processes_give_the_same_values_as_in_process(small_objective):
    rng = np.random.default_rng(0)
    lo, hi = bounds()
    theta = np.clip(efd_parameters().vector() * rng.uniform(0.8, 1.2, (9, 57)), lo, hi)
    here = InProcess(small_objective)(theta)
    with ProcessPool(small_objective, workers=2) as pool:
        there = pool(theta)
    np.testing.assert_array_equal(here, there)


class _Exploding(Objective):
    """An objective that raises for one particular candidate (a bug, a crash)."""

    def evaluate(self, thetas, name=None):
        thetas = np.atleast_2d(thetas)
        if np.any(thetas[:, 4] == 0.123):
            raise RuntimeError("boom")
        return super().evaluate(thetas, name)


def test_a_candidate_that_raises_gets_the_maximum_penalty(data_dir):
    from sweep.data.recordings import read_recording

    rec = read_recording(data_dir / "data/berthing/berthing_12-Nov-2020_13_21_03.csv")
    obj = _Exploding([rec], "J1")
    theta = np.tile(efd_parameters().vector(), (3, 1))
    theta[1, 4] = 0.123
    f = InProcess(obj)(theta)
    assert f[1] == obj.max_penalty
    assert f[0] == f[2] < obj.max_penalty
