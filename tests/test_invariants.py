"""Invariants that catch sign errors and broken branch switches."""

from __future__ import annotations

import numpy as np
import pytest

from mmg import all_forces, derivatives, efd_parameters, simulate
from mmg.hull import cross_flow_integrals
from mmg.propeller import propeller_forces
from tests.conftest import kernels

pytestmark = pytest.mark.kernels(*kernels((), "simulate", "derivatives"))


def test_zero_force_at_rest_in_still_air():
    p = efd_parameters()
    f = all_forces(0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, p.theta, p.ship)
    assert np.allclose(f, 0.0, atol=1e-12)
    xd = derivatives(np.zeros(6), np.zeros(2), np.zeros(2), p)
    assert np.allclose(xd, 0.0, atol=1e-12)


@pytest.mark.parametrize("delta", [0.2, 0.6])
def test_positive_rudder_turns_to_starboard(delta):
    p = efd_parameters()
    K = 300
    x0 = np.array([[0.0, 0.3, 0.0, 0.0, 0.0, 0.0]])
    u = np.tile([delta, 8.0], (1, K, 1))
    traj = simulate(x0, u, np.zeros((1, K, 2)), p)[0]
    assert traj[-1, 5] > 0.01  # r > 0
    assert traj[-1, 4] > 0.3  # psi grows clockwise
    assert traj[-1, 2] > 0.3  # the track bends to +y0
    mirrored = simulate(x0, u * [[-1.0, 1.0]], np.zeros((1, K, 2)), p)[0]
    # without wind and with u, n fixed, the ship is nearly symmetric: mirror turn
    assert mirrored[-1, 4] < -0.3


def test_ahead_propeller_pushes_ahead_and_astern_propeller_pulls_back():
    p = efd_parameters()
    ahead = derivatives(np.array([0, 0.1, 0, 0, 0, 0.0]), np.array([0.0, 10.0]), np.zeros(2), p)
    astern = derivatives(np.array([0, 0.1, 0, 0, 0, 0.0]), np.array([0.0, -10.0]), np.zeros(2), p)
    assert ahead[1] > 0 > astern[1]


def test_head_wind_decelerates_and_beam_wind_pushes_to_leeward():
    p = efd_parameters()
    x = np.zeros(6)
    x[4] = 0.7  # heading
    head = derivatives(x, np.zeros(2), np.array([5.0, 0.7]), p)  # from ahead
    assert head[1] < 0
    starboard = derivatives(x, np.zeros(2), np.array([5.0, 0.7 + np.pi / 2]), p)
    assert starboard[3] < 0  # pushed to port


@pytest.mark.parametrize("J_break", [-0.35, -0.06])
def test_reversal_side_force_polynomials_are_continuous_at_breakpoints(J_break):
    """Continuous up to the rounding of the published EFD coefficients (7e-4 at -0.06)."""
    p = efd_parameters()
    th, sh = p.theta, p.ship
    n = -10.0
    for eps in (1e-9,):
        lo = propeller_forces(0.05, n, J_break - eps, 1.0, th, sh)
        hi = propeller_forces(0.05, n, J_break + eps, 1.0, th, sh)
        assert lo[1] == pytest.approx(hi[1], rel=1e-3)
        assert lo[2] == pytest.approx(hi[2], rel=1e-3)


def test_ahead_propeller_forces_are_continuous_across_zero_speed():
    """For n_p > 0 every branch meets at u = 0. (For n_p < 0 the rudder inflow jumps there, from
    Kitagawa's form to u_R = u, as in the authors' code: reference "Branch choices".)"""
    p = efd_parameters()
    for n in (3.0, 10.0):
        a = derivatives(np.array([0, -1e-9, 0, 0.01, 0, 0.0]), np.array([0.1, n]), np.zeros(2), p)
        b = derivatives(np.array([0, 1e-9, 0, 0.01, 0, 0.0]), np.array([0.1, n]), np.zeros(2), p)
        assert a[1] == pytest.approx(b[1], rel=1e-4, abs=1e-7)


def _quadrature(v, b, L, weight):
    x = np.linspace(-L / 2, L / 2, 200001)
    s = v + b * x
    f = np.abs(s) * s * (x if weight else 1.0)
    return np.trapezoid(f, x)


@pytest.mark.parametrize(
    "v,b",
    [
        (0.1, 0.01),
        (0.01, 0.1),
        (-0.02, 0.05),
        (0.0, 0.03),
        (0.05, 0.0),
        (0.045, 0.03),
        (-0.3, -0.7),
    ],
)
def test_cross_flow_closed_forms_match_quadrature(v, b):
    L = 3.0
    I0, I1 = cross_flow_integrals(v, b, L)
    assert pytest.approx(_quadrature(v, b, L, False), rel=1e-8, abs=1e-12) == I0
    assert pytest.approx(_quadrature(v, b, L, True), rel=1e-8, abs=1e-12) == I1


def test_cross_flow_continuous_where_the_closed_form_switches():
    L, b = 3.0, 0.04
    v = b * L / 2  # |v| = |b| L / 2: switch between polynomial and antiderivative form
    lo = cross_flow_integrals(v * (1 - 1e-12), b, L)
    hi = cross_flow_integrals(v * (1 + 1e-12), b, L)
    assert lo[0] == pytest.approx(hi[0], rel=1e-9)
    assert lo[1] == pytest.approx(hi[1], rel=1e-9)


def test_wind_is_continuous_across_the_back_of_the_ship():
    p = efd_parameters()
    x = np.zeros(6)
    a = derivatives(x, np.zeros(2), np.array([4.0, np.pi - 1e-9]), p)
    b = derivatives(x, np.zeros(2), np.array([4.0, -np.pi + 1e-9]), p)
    np.testing.assert_allclose(a, b, atol=1e-8)
