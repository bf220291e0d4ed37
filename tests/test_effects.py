"""Extra physics plugs in without editing the sub-models."""

from __future__ import annotations

import numpy as np
import pytest

from mmg import ESSO_OSAKA, Parameters, catalog, derivatives, efd_parameters, get_effect, simulate


def test_catalog_lists_effects_with_parameters():
    cat = catalog()
    assert {"current", "propeller_walk"} <= set(cat)
    assert get_effect("current").param_names == ("V_c", "beta_c")
    with pytest.raises(KeyError, match="known effects"):
        get_effect("warp_drive")


def test_neutral_effect_changes_nothing():
    p = efd_parameters()
    effects = (get_effect("current"), get_effect("propeller_walk"))
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
    traj = simulate(
        x, np.zeros((1, 500, 2)), np.zeros((1, 500, 2)), p, effects=(get_effect("current"),)
    )[0]
    np.testing.assert_allclose(traj[-1, 0], 50.0 * V_c * np.cos(beta_c), rtol=1e-9)
    np.testing.assert_allclose(traj[-1, 2], 50.0 * V_c * np.sin(beta_c), rtol=1e-9)
    np.testing.assert_allclose(traj[-1, [1, 3, 4, 5]], [u0, v0, psi, 0.0], atol=1e-12)


def test_propeller_walk_adds_its_side_force():
    eff = get_effect("propeller_walk")
    p0 = efd_parameters()
    p1 = Parameters(
        p0.theta, p0.ship, effects=(("propeller_walk", (("C_Yw", 1e-3), ("C_Nw", 0.0))),)
    )
    x = np.array([0.0, 0.2, 0.0, 0.0, 0.0, 0.0])
    u = np.array([0.0, 10.0])
    a = derivatives(x, u, np.zeros(2), p0, effects=(eff,))
    b = derivatives(x, u, np.zeros(2), p1, effects=(eff,))
    sh = p0.ship
    Y = 0.5 * sh.rho * sh.L_pp * sh.d * (10.0 * sh.D_p) ** 2 * 1e-3
    m = sh.m_nd * 0.5 * sh.rho * sh.L_pp**2 * sh.d
    # the extra force raises v_m_dot, and through x_G couples into r_dot
    assert b[3] - a[3] > 0.5 * Y / (m + p0.theta.m_y * 0.5 * sh.rho * sh.L_pp**2 * sh.d)
    assert b[3] - a[3] < 1.5 * Y / m
