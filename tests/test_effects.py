"""Extra physics plugs in without editing the sub-models."""

from __future__ import annotations

import numpy as np
import pytest

from mmg import ESSO_OSAKA, Parameters, catalog, derivatives, efd_parameters, get_effect, simulate
from mmg.integrate import effect_vector
from tests.conftest import SHARED_EFFECTS, kernels, shared_effects

#: one effect kernel for every test here (the effects not studied at their neutral values)
pytestmark = pytest.mark.kernels(*kernels((), "simulate", "moments"), *kernels(SHARED_EFFECTS))


def test_catalog_lists_effects_with_parameters():
    cat = catalog()
    assert {
        "current",
        "propeller_walk",
        "a_h_drift",
        "rudder_stall",
        "actuator_lag",
        "heading_bias",
        "rudder_offset",
    } <= set(cat)
    for eff in cat.values():
        lo, hi = eff.bounds
        assert all(a <= n <= b for a, n, b in zip(lo, eff.neutral(), hi, strict=True)), eff.name
    assert get_effect("current").param_names == ("V_c", "beta_c")
    with pytest.raises(KeyError, match="known effects"):
        get_effect("warp_drive")


def test_loading_the_catalog_keeps_the_public_catalog_function():
    """The subpackage mmg.catalog and the function mmg.catalog share a name: loading the
    catalog (on the first get_effect) must not replace the function with the subpackage."""
    import mmg

    get_effect("current")
    catalog()
    assert callable(mmg.catalog) and "current" in mmg.catalog()
    from mmg import catalog as again

    assert callable(again)


def test_neutral_effect_changes_nothing():
    """Every catalog effect (and the shared generated terms) at neutral values: bit for bit the
    ship without effects."""
    p = efd_parameters()
    effects = shared_effects()
    assert set(catalog()) <= {e.name for e in effects}
    x = np.array([[1.0, 0.25, -2.0, 0.03, 0.4, 0.01]])
    u = np.tile([0.2, 9.0], (1, 200, 1))
    w = np.tile([2.0, 1.0], (1, 200, 1))
    a = simulate(x, u, w, p)
    b = simulate(x, u, w, p, effects=effects)
    np.testing.assert_array_equal(a, b)


def test_ship_drifting_with_the_current_feels_no_water_force():
    """Moving exactly with a uniform current, hull, propeller and rudder see no flow."""
    ship = ESSO_OSAKA._replace(rho_A=0.0)  # no air
    V_c, beta_c, psi = 0.05, 0.8, 0.3
    p = Parameters(
        efd_parameters().theta, ship, effects=(("current", (("V_c", V_c), ("beta_c", beta_c))),)
    )
    u0 = V_c * np.cos(beta_c - psi)
    v0 = V_c * np.sin(beta_c - psi)
    x = np.array([[0.0, u0, 0.0, v0, psi, 0.0]])
    traj = simulate(x, np.zeros((1, 500, 2)), np.zeros((1, 500, 2)), p, effects=shared_effects())[0]
    np.testing.assert_allclose(traj[-1, 0], 50.0 * V_c * np.cos(beta_c), rtol=1e-9)
    np.testing.assert_allclose(traj[-1, 2], 50.0 * V_c * np.sin(beta_c), rtol=1e-9)
    np.testing.assert_allclose(traj[-1, [1, 3, 4, 5]], [u0, v0, psi, 0.0], atol=1e-12)


def test_propeller_walk_adds_its_side_force():
    effects = shared_effects()
    p0 = efd_parameters()
    p1 = Parameters(
        p0.theta, p0.ship, effects=(("propeller_walk", (("C_Yw", 1e-3), ("C_Nw", 0.0))),)
    )
    x = np.array([0.0, 0.2, 0.0, 0.0, 0.0, 0.0])
    u = np.array([0.0, 10.0])
    a = derivatives(x, u, np.zeros(2), p0, effects=effects)
    b = derivatives(x, u, np.zeros(2), p1, effects=effects)
    sh = p0.ship
    Y = 0.5 * sh.rho * sh.L_pp * sh.d * (10.0 * sh.D_p) ** 2 * 1e-3
    m = sh.m_nd * 0.5 * sh.rho * sh.L_pp**2 * sh.d
    # the extra force raises v_m_dot, and through x_G couples into r_dot
    assert b[3] - a[3] > 0.5 * Y / (m + p0.theta.m_y * 0.5 * sh.rho * sh.L_pp**2 * sh.d)
    assert b[3] - a[3] < 1.5 * Y / m


def _with(name: str, **values: float) -> Parameters:
    p = efd_parameters()
    return Parameters(p.theta, p.ship, effects=((name, tuple(values.items())),))


def _forces_with_a_H(x: np.ndarray, delta: float, n_p: float, a_H: float) -> np.ndarray:
    from mmg.model import hydrodynamic_forces

    p = efd_parameters()
    th = p.theta._replace(a_H=a_H)
    F = hydrodynamic_forces(x[1], x[3], x[5], np.sin(delta), np.cos(delta), n_p, th, p.ship)
    return np.array(F[6:9])


def test_a_h_drift_is_a_drift_dependent_a_H():
    """The hook's extra force equals the rudder force with a_H + k sin^2(beta) minus the paper's."""
    from mmg.catalog.a_h_drift import AHDriftParams, a_h_drift_force

    p = efd_parameters()
    x = np.array([0.0, 0.2, 0.0, -0.12, 0.0, 0.01])  # drift angle 31 deg
    delta, n_p, k = 0.4, 8.0, -0.8
    sin2 = 0.12**2 / (0.2**2 + 0.12**2)
    want = _forces_with_a_H(x, delta, n_p, p.theta.a_H + k * sin2) - _forces_with_a_H(
        x, delta, n_p, p.theta.a_H
    )
    got = a_h_drift_force(
        x[1], x[3], x[5], 0.0, delta, n_p, 0.0, 0.0, AHDriftParams(k), p.theta, p.ship
    )
    np.testing.assert_allclose(got[1:], want[1:], rtol=1e-9)
    assert got[0] == 0.0 and abs(want[0]) < 1e-12


def test_rudder_stall_caps_the_normal_force_beyond_the_stall_angle():
    from mmg.catalog.rudder_stall import RudderStallParams, rudder_stall_force

    p = efd_parameters()
    x = np.array([0.0, 0.3, 0.0, 0.0, 0.0, 0.0])
    e = RudderStallParams(alpha_s=np.radians(20.0), k_s=1.0)
    small = rudder_stall_force(
        x[1], x[3], x[5], 0.0, np.radians(10.0), 8.0, 0, 0, e, p.theta, p.ship
    )
    assert small == (0.0, 0.0, 0.0)
    # with k_s = 1 the normal force at 35 deg equals the paper's at the stall angle of attack
    a35 = _forces_with_a_H(x, np.radians(35.0), 8.0, p.theta.a_H)
    extra = rudder_stall_force(
        x[1], x[3], x[5], 0.0, np.radians(35.0), 8.0, 0, 0, e, p.theta, p.ship
    )
    from mmg.model import hydrodynamic_forces

    # alpha_R = delta here (v_R = 0 with v_m = r = 0): F_N scales with sin(alpha_R)
    ratio = np.sin(np.radians(20.0)) / np.sin(np.radians(35.0))
    np.testing.assert_allclose(a35[1] + extra[1], ratio * a35[1], rtol=1e-9)
    np.testing.assert_allclose(a35[2] + extra[2], ratio * a35[2], rtol=1e-9)
    assert hydrodynamic_forces is not None


def test_actuator_lag_is_a_first_order_lag_of_the_logged_rudder():
    """With the ship held still in an empty world, the lagged rudder shows in X_R over time:
    compare simulations with the logged step and with the analytic lagged input."""
    ship = ESSO_OSAKA._replace(rho_A=0.0)
    p0 = Parameters(efd_parameters().theta, ship)
    T = 1.5
    p1 = Parameters(p0.theta, ship, effects=(("actuator_lag", (("T_delta", T), ("T_n", 0.0))),))
    K = 100
    x = np.array([[0.0, 0.3, 0.0, 0.0, 0.0, 0.0]])
    log = np.zeros((1, K, 2))
    log[0, :, 0] = 0.5
    log[0, :, 1] = 8.0
    log[0, 0, 0] = 0.0  # the logged rudder steps from 0 to 0.5 rad after the first step
    lagged = log.copy()
    a = 1.0 - np.exp(-0.1 / T)
    d = 0.0
    for k in range(K):
        d = d + a * (log[0, k, 0] - d) if k else log[0, 0, 0]
        lagged[0, k, 0] = d
    w = np.zeros((1, K, 2))
    with_effect = simulate(x, log, w, p1, effects=shared_effects())
    by_hand = simulate(x, lagged, w, p0)
    np.testing.assert_allclose(with_effect, by_hand, rtol=1e-12, atol=1e-12)
    assert np.abs(simulate(x, log, w, p0) - by_hand).max() > 1e-3


def _dead_time_case(tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A zigzag-like logged rudder and propeller, and the same controls a dead time tau earlier
    (linear interpolation between the 0.1-s samples, the first sample held before the start)."""
    K = 300
    t = 0.1 * np.arange(K)
    log = np.zeros((1, K, 2))
    log[0, :, 0] = 0.35 * np.sign(np.sin(2 * np.pi * t / 12.0))
    log[0, :, 1] = 8.0 + 2.0 * np.sin(2 * np.pi * t / 7.0)
    acting = log.copy()
    for c in range(2):
        acting[0, :, c] = np.interp(t - tau, t, log[0, :, c])  # holds log[0] before t = 0
    x = np.array([[0.0, 0.4, 0.0, 0.0, 0.0, 0.0]])
    w = np.tile([1.5, 0.7], (1, K, 1))
    return x, log, acting, w


@pytest.mark.parametrize("tau", [1.0, 0.35])
def test_actuator_dead_time_shifts_the_logged_controls(tau: float) -> None:
    vals = (("T_delta", 0.0), ("T_n", 0.0), ("tau_delta", tau), ("tau_n", tau))
    p0 = efd_parameters()
    p1 = Parameters(p0.theta, p0.ship, effects=(("actuator_lag", vals),))
    x, log, acting, w = _dead_time_case(tau)
    with_effect = simulate(x, log, w, p1, effects=shared_effects())
    by_hand = simulate(x, acting, w, p0)
    np.testing.assert_allclose(with_effect, by_hand, rtol=1e-12, atol=1e-12)
    assert np.abs(simulate(x, log, w, p0) - by_hand).max() > 1e-2


def test_dead_time_acts_in_the_objective_kernel_too():
    """The objective's own kernel (moments of the observables) delays the controls the same way."""
    from sweep.data.objective import Objective
    from sweep.data.recordings import Recording

    effects = shared_effects()
    p0 = efd_parameters()
    tau = 1.0
    x, log, acting, w = _dead_time_case(tau)
    truth = simulate(x, acting, w, p0)[0]
    t = 0.1 * np.arange(truth.shape[0])
    u_rec = np.vstack([log[0], log[0, -1:]])
    w_rec = np.vstack([w[0], w[0, -1:]])
    rec = Recording(name="dead_time", path=None, t=t, x=truth, u=u_rec, w=w_rec)
    obj = Objective([rec], "J2", effects=effects)
    theta = np.concatenate([p0.vector(), effect_vector(p0, effects)])  # neutral: no dead time
    dead = Parameters(p0.theta, p0.ship, (("actuator_lag", (("tau_delta", tau), ("tau_n", tau))),))
    right = np.concatenate([p0.vector(), effect_vector(dead, effects)])
    f = obj.evaluate(np.stack([theta, right]))
    assert f[1] < 1e-12 < 1e-4 < f[0]


def test_rudder_offset_shifts_the_logged_rudder():
    p0 = efd_parameters()
    p1 = _with("rudder_offset", delta_0=0.03)
    x = np.array([[0.0, 0.3, 0.0, 0.0, 0.2, 0.0]])
    u = np.tile([0.1, 8.0], (1, 300, 1))
    w = np.tile([1.0, 0.5], (1, 300, 1))
    shifted = u.copy()
    shifted[..., 0] += 0.03
    np.testing.assert_allclose(
        simulate(x, u, w, p1, effects=shared_effects()),
        simulate(x, shifted, w, p0),
        rtol=1e-12,
        atol=1e-12,
    )


def test_heading_bias_reports_the_logged_heading_and_velocities():
    """The simulation starts from the true state behind the log and returns logged quantities."""
    b_psi, b_v = 0.05, 0.03
    p1 = _with("heading_bias", b_psi=b_psi, b_v=b_v)
    p0 = efd_parameters()
    logged0 = np.array([1.0, 0.3, 2.0, 0.01, 0.7, 0.004])
    true0 = logged0.copy()
    true0[4] -= b_psi
    true0[1] = logged0[1] * np.cos(b_v) - logged0[3] * np.sin(b_v)
    true0[3] = logged0[1] * np.sin(b_v) + logged0[3] * np.cos(b_v)
    u = np.tile([0.2, 8.0], (1, 200, 1))
    w = np.tile([2.0, 0.5], (1, 200, 1))
    got = simulate(logged0[None], u, w, p1, effects=shared_effects())[0]
    truth = simulate(true0[None], u, w, p0)[0]
    np.testing.assert_allclose(got[0], logged0, rtol=1e-12)
    np.testing.assert_allclose(got[1:, 4], truth[1:, 4] + b_psi, rtol=1e-12)
    np.testing.assert_allclose(got[1:, [0, 2, 5]], truth[1:, [0, 2, 5]], rtol=1e-12)
    u_log = truth[1:, 1] * np.cos(b_v) + truth[1:, 3] * np.sin(b_v)
    v_log = -truth[1:, 1] * np.sin(b_v) + truth[1:, 3] * np.cos(b_v)
    np.testing.assert_allclose(got[1:, 1], u_log, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got[1:, 3], v_log, rtol=1e-12, atol=1e-15)


def test_time_terms_see_the_recordings_clock():
    """A force that depends on time gets the time on the recording's clock: the simulation of a
    segment starting at t0 = 900 s feels the force of t = 900 s onwards, in the kernel, in the
    NumPy reference and in the objective (segments start at the recording's own times)."""
    from mmg.integrate import rk4_reference
    from sweep.data.objective import Objective
    from sweep.data.recordings import Recording

    effects = shared_effects()  # with the generated terms N_dnn and the time term Y_t
    p0 = efd_parameters()
    p1 = Parameters(p0.theta, p0.ship, (("discovered:N_dnn+Y_t", (("C_Y_t", 0.02),)),))
    K = 200
    x = np.array([[0.0, 0.6, 0.0, 0.0, 0.0, 0.0]])
    u = np.tile([0.0, 10.0], (1, K, 1))
    w = np.zeros((1, K, 2))
    at_0 = simulate(x, u, w, p1, effects=effects, t0=0.0)[0]
    at_900 = simulate(x, u, w, p1, effects=effects, t0=900.0)[0]
    # Y = 0.5 rho L d C t / T_ref: at 900 s the side force is ~0.9 * 0.02 * q, at 0 s nearly none
    without = simulate(x, u, w, p0)[0]
    assert abs(at_900[-1, 3] - at_0[-1, 3]) > 20 * abs(at_0[-1, 3] - without[-1, 3])
    ref = rk4_reference(x[0], u[0], w[0], p1, effects=effects, t0=900.0)
    np.testing.assert_allclose(at_900, ref, rtol=1e-9, atol=1e-9)
    # the objective: the same recording on two clocks gives different J with the time term only
    traj = simulate(x, u, w, p0)[0]
    t = np.arange(K + 1, dtype=np.float64) * 0.1
    log = np.vstack([u[0], u[0, -1:]])
    wind = np.zeros((K + 1, 2))
    early = Recording("early", None, t, traj, log, wind)
    late = Recording("late", None, t + 900.0, traj, log, wind)
    for p, with_effects, same in ((p0, (), True), (p1, effects, False)):
        J_early = Objective([early], "J2", effects=with_effects).evaluate(p)[0]
        J_late = Objective([late], "J2", effects=with_effects).evaluate(p)[0]
        assert (abs(J_early - J_late) < 1e-9 * max(J_early, 1e-12)) == same, (J_early, J_late)


def test_a_discovered_effect_pickles_into_a_fresh_process():
    """Ray workers receive effects pickled: a generated effect's module is not on the import
    path, so it travels by name and parameter table and is rebuilt from the library there."""
    import pickle
    import subprocess
    import sys

    from mmg.discovered import with_bounds

    eff = with_bounds(
        get_effect("discovered:N_s3b+Y_t+N_bt"), [0.3, 0.2, 0.1], {"N_bt": {"tau": 600.0}}
    )
    code = (
        "import pickle, sys; e = pickle.loads(sys.stdin.buffer.read()); "
        "print(e.name, [q.upper for q in e.params], e.neutral()[-1], e.force_at is not None)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], input=pickle.dumps(eff), capture_output=True, check=True
    )
    # the shape parameter (tau of N_bt) travels with its start and box (150-2400 s)
    assert out.stdout.decode().split() == [
        "discovered:N_s3b+Y_t+N_bt",
        "[0.3,",
        "0.2,",
        "0.1,",
        "2400.0]",
        "600.0",
        "True",
    ]
    catalog_effect = get_effect("current")  # field by field, as before
    assert pickle.loads(pickle.dumps(catalog_effect)) == catalog_effect
