"""Shapes of a missing force: the spline basis and penalty, the shape effect by name, in the
kernel, and the selection of shape groups on the linearised trajectory columns."""

from __future__ import annotations

import math
import pickle
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mmg import Effect, efd_parameters, get_effect
from mmg.fixed import kernel_effects
from mmg.hull import hull_forces
from mmg.integrate import derivatives_rows
from mmg.model import rudder_inflow_at
from mmg.params import N_THETA
from mmg.shapes import (
    Form,
    Group,
    basis,
    cardinal_bspline,
    curve,
    difference_penalty,
    form_scale,
    groups_of,
    is_closed_form,
    on_circle,
    parse,
    parse_form,
    penalty,
    penalty_matrix,
    probe_effect,
    probe_rows,
    serves,
    shape_effect,
    shape_name,
    variable_values,
)
from sweep.data.recordings import Recording, read_recordings
from tests.conftest import kernels, noisy_windows, probe_kernels

#: the effect of the hook tests: a shape in beta (Y and N), a share of the hull's sway force
#: in N, a surge force astern, a shape in U times v_m'
HOOK_SPEC = "shape:YN~beta[-0.5:0.5]/6+N~beta[-0.5:0.5]/5*Y_H+X~1*ast+X~U[0:1.2]/4*v"


@pytest.mark.parametrize("n", [4, 5, 8, 13])
def test_the_basis_sums_to_one_and_is_held_constant_outside_its_range(n: int) -> None:
    """Partition of unity on [lo, hi] (cubic B-splines on a uniform grid), non-negative, and
    the clamped variable: below lo the basis is its value at lo, above hi its value at hi."""
    g = Group("Y", "beta", -0.4, 0.7, n)
    z = np.linspace(-0.4, 0.7, 301)
    B = basis(g, z)
    assert B.shape == (301, n)
    np.testing.assert_allclose(B.sum(axis=1), 1.0, atol=1e-14)
    assert B.min() >= -1e-15
    np.testing.assert_array_equal(basis(g, [-3.0, -0.5]), basis(g, [-0.4, -0.4]))
    np.testing.assert_array_equal(basis(g, [0.71, 9.0]), basis(g, [0.7, 0.7]))
    # a cubic polynomial is in the span: the basis reproduces z^3 by least squares to rounding
    coef, *_ = np.linalg.lstsq(B, z**3, rcond=None)
    np.testing.assert_allclose(curve(g, coef, z), z**3, atol=1e-12)
    assert cardinal_bspline(0.0) == pytest.approx(2.0 / 3.0)
    assert cardinal_bspline([1.0, -1.0, 2.0, 2.5]).tolist() == pytest.approx([1 / 6, 1 / 6, 0, 0])
    assert basis(Group("X", "1", multiplier="ast"), [1.0, 2.0]).tolist() == [[1.0], [1.0]]


def test_the_penalty_leaves_straight_lines_free() -> None:
    """Second differences: constants and straight lines in the coefficients cost nothing, a
    bend does; a group's penalty is one block per component; an effect's is block-diagonal."""
    P = difference_penalty(8)
    j = np.arange(8.0)
    assert np.abs(P @ np.ones(8)).max() < 1e-12
    assert np.abs(P @ j).max() < 1e-12
    assert (j**2) @ P @ (j**2) == pytest.approx(4.0 * 6)  # six second differences of 2
    assert np.linalg.matrix_rank(P) == 6
    g = Group("YN", "rp", -0.5, 0.5, 8)
    np.testing.assert_array_equal(penalty(g), np.kron(np.eye(2), P))
    assert not penalty(Group("X", "1", multiplier="rev")).any()
    eff = get_effect("shape:Y~rp[-0.5:0.5]/5+X~1*rev")
    Pm = penalty_matrix(eff)
    assert Pm.shape == (6, 6) and not Pm[5].any()
    np.testing.assert_array_equal(Pm[:5, :5], difference_penalty(5))


def test_a_spec_round_trips_through_its_name() -> None:
    """spec -> groups -> name is the identity for a canonical name; get_effect rebuilds the
    effect from its name with one coefficient per basis function and component (neutral 0),
    pickles by name, and a malformed or non-canonical name is a clear error."""
    groups = parse(HOOK_SPEC)
    assert [g.text for g in groups] == HOOK_SPEC.removeprefix("shape:").split("+")
    assert shape_name(groups) == HOOK_SPEC
    assert groups[1] == Group("N", "beta", -0.5, 0.5, 5, "Y_H")
    eff = get_effect(HOOK_SPEC)
    assert eff.name == HOOK_SPEC
    assert len(eff.params) == 12 + 5 + 1 + 4
    assert eff.param_names[:7] == (*(f"s0_Y{j}" for j in range(6)), "s0_N0")
    assert eff.neutral() == (0.0,) * 22
    assert "Y_H L_pp" in eff.params[12].description
    assert pickle.loads(pickle.dumps(eff)) is eff
    narrow = shape_effect(groups, bound=0.2)
    back = pickle.loads(pickle.dumps(narrow))
    assert back.name == HOOK_SPEC and back.params == narrow.params and back.bounds[1][0] == 0.2
    big = Group("X", "t", 0.0, 1.5e6, 4)
    assert parse(shape_name([big]))[0] == big and "+" not in big.text
    # a range of measured quantiles (full precision) is the range its name writes: the group
    # is the one the name rebuilds in any process, so one kernel serves both
    measured = Group("N", "beta", -2.670770131614281, 2.1866810394510714, 8, "Y_H")
    assert (measured.lo, measured.hi) == (-2.67077, 2.18668)
    assert parse(shape_name([measured]))[0] == measured
    with pytest.raises(KeyError, match="write the shape effect"):
        get_effect("shape:Y~beta[-0.50:0.5]/6")
    for bad, why in (
        ("shape:Q~beta[0:1]/6", "expected e.g."),
        ("shape:Y~warp[0:1]/6", "unknown shape variable"),
        ("shape:Y~beta[1:0]/6", "empty"),
        ("shape:Y~beta[0:1]/3", "basis functions"),
        ("shape:NY~beta[0:1]/6", "in this order"),
        ("shape:Y~beta[0:1]/6*JP", "unknown multiplier"),
        ("shape:Y~beta[0:1]/6*Y_H@U2", "takes no scale"),
        ("shape:Y~1+Y~1", "repeated"),
    ):
        with pytest.raises(KeyError, match=why):
            get_effect(bad)


def test_a_shape_effect_pickles_into_a_fresh_process() -> None:
    """A Ray worker rebuilds the effect from its name (its module is not on the import path)."""
    eff = shape_effect("shape:N~t[0:600]/4", bound=0.3)
    code = (
        "import pickle, sys; e = pickle.loads(sys.stdin.buffer.read()); "
        "print(e.name, e.bounds[1][0], len(e.params), e.force_at is not None)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], input=pickle.dumps(eff), capture_output=True, check=True
    )
    assert out.stdout.decode().split() == ["shape:N~t[0:600]/4", "0.3", "4", "True"]


def test_the_hook_adds_the_scaled_shapes() -> None:
    """The generated hook (called from Python): all coefficients of a component equal to c
    give c times the scaling (partition of unity); the hull-force share gives c Y_H L_pp; the
    astern group acts only astern; the product group carries v_m / U_e."""
    p = efd_parameters()
    th, sh = p.theta, p.ship
    eff = get_effect(HOOK_SPEC)
    q = 0.5 * sh.rho * sh.L_pp * sh.d

    def force(values: dict[str, float], u: float, v_m: float, r: float) -> np.ndarray:
        e = eff.param_type(**{n: values.get(n, 0.0) for n in eff.param_names})
        args = (12.0, 1.0, 2.0, u, v_m, r, 0.3, 0.1, 10.0, 1.0, 0.5, e, th, sh)
        assert eff.force_at is not None
        return np.array(eff.force_at(*args))

    u, v_m, r = 0.5, -0.08, 0.02
    U2 = u * u + v_m * v_m
    for j in range(6):
        assert force({f"s0_Y{j}": 1.0}, u, v_m, r)[1] >= 0.0
    ones_Y = {f"s0_Y{j}": 0.3 for j in range(6)}
    np.testing.assert_allclose(force(ones_Y, u, v_m, r), [0.0, 0.3 * q * U2, 0.0], rtol=1e-12)
    # far outside [-0.5, 0.5] the beta shape keeps its value at the end of the range
    one = {"s0_N5": 1.0}
    beyond = force(one, 0.2, -2.0, r)[2] / (q * sh.L_pp * (0.04 + 4.0))
    at_end = force(one, 0.5, -0.5 * np.tan(0.5), r)[2] / (q * sh.L_pp * 0.25 / np.cos(0.5) ** 2)
    assert beyond == pytest.approx(at_end, rel=1e-12) and beyond == pytest.approx(1 / 6)
    Y_H = hull_forces(u, v_m, r, th, sh)[1]
    share = {f"s1_N{j}": 0.2 for j in range(5)}
    assert force(share, u, v_m, r)[2] == pytest.approx(0.2 * Y_H * sh.L_pp, rel=1e-12)
    assert force({"s2_X0": 0.5}, u, v_m, r)[0] == 0.0
    assert force({"s2_X0": 0.5}, -u, v_m, r)[0] == pytest.approx(0.5 * q * U2, rel=1e-12)
    prod = {f"s3_X{j}": 1.0 for j in range(4)}
    Ue = np.sqrt(U2 + 0.05**2)
    assert force(prod, u, v_m, r)[0] == pytest.approx(q * U2 * v_m / Ue, rel=1e-12)


def test_the_hook_multiplies_the_thrust_the_normal_force_and_the_propeller_loading() -> None:
    """The products of the default candidates beyond the hull's: a share of the thrust X_P in
    beta, of the rudder's normal force F_N in alpha_R, and a shape in n_p times v_m / U_e with
    the propeller's scaling (n_p D_p)^2 (all coefficients of a group equal to c: c times it)."""
    from mmg.model import hydrodynamic_forces

    p = efd_parameters()
    th, sh = p.theta, p.ship
    eff = get_effect("shape:X~beta[-0.5:0.5]/4*X_P+Y~alphaR[-0.8:0.8]/4*F_N+N~n[-12:12]/4*v")
    assert eff.force_at is not None
    force_at = eff.force_at
    u, v_m, r, delta, n_p = 0.4, -0.06, 0.01, 0.1, 10.0

    def force(values: dict[str, float]) -> np.ndarray:
        e = eff.param_type(**{n: values.get(n, 0.0) for n in eff.param_names})
        args = (12.0, 1.0, 2.0, u, v_m, r, 0.3, delta, n_p, 1.0, 0.5)
        return np.array(force_at(*args, e, th, sh))

    forces = hydrodynamic_forces(u, v_m, r, math.sin(delta), math.cos(delta), n_p, th, sh)
    X_P, X_R = forces[3], forces[6]
    F_N = -X_R / ((1.0 - th.t_R) * math.sin(delta))  # Eq. (14)
    got = force({f"s0_X{j}": 0.3 for j in range(4)})
    np.testing.assert_allclose(got, [0.3 * X_P, 0.0, 0.0], rtol=1e-12, atol=1e-9)
    got = force({f"s1_Y{j}": 0.2 for j in range(4)})
    np.testing.assert_allclose(got, [0.0, 0.2 * F_N, 0.0], rtol=1e-12, atol=1e-9)
    q = 0.5 * sh.rho * sh.L_pp * sh.d
    Ue = math.sqrt(u * u + v_m * v_m + 0.05**2)
    got = force({f"s2_N{j}": 1.0 for j in range(4)})
    want = q * sh.L_pp * (n_p * sh.D_p) ** 2 * v_m / Ue
    np.testing.assert_allclose(got, [0.0, 0.0, want], rtol=1e-12, atol=1e-9)


def test_a_shape_in_the_surge_velocity_times_the_wind_s_side_force() -> None:
    """The heel product of the default candidates, ``N~u[..]*Y_A``: a yaw moment f(u) Y_A L_pp,
    Y_A the model's wind side force (Eq. (27)) from the apparent wind (all coefficients c: c
    times it); it is among the default candidates' products."""
    from mmg.wind import apparent_wind, wind_forces
    from sweep.diagnose.shapes import PRODUCTS

    assert ("u", "Y_A") in PRODUCTS
    p = efd_parameters()
    th, sh = p.theta, p.ship
    eff = get_effect("shape:N~u[-0.2:0.6]/4*Y_A")
    assert eff.force_at is not None
    force_at = eff.force_at
    u, v_m, r, psi, delta, n_p = 0.3, -0.04, 0.01, 0.3, 0.1, 10.0

    def force(U_T: float) -> np.ndarray:
        e = eff.param_type(**{n: 0.25 for n in eff.param_names})
        return np.array(force_at(12.0, 1.0, 2.0, u, v_m, r, psi, delta, n_p, U_T, 0.5, e, th, sh))

    sp, cp = math.sin(psi), math.cos(psi)
    u_A, v_A = apparent_wind(u, v_m, sp, cp, 1.5, math.sin(0.5), math.cos(0.5))[:2]
    Y_A = wind_forces(u_A, v_A, th, sh)[1]
    assert abs(Y_A) > 0.0
    np.testing.assert_allclose(force(1.5), [0.0, 0.0, 0.25 * Y_A * sh.L_pp], rtol=1e-12)
    # without true wind the apparent wind is the ship's own motion: the same rule
    u_A, v_A = apparent_wind(u, v_m, sp, cp, 0.0, math.sin(0.5), math.cos(0.5))[:2]
    Y_A0 = wind_forces(u_A, v_A, th, sh)[1]
    np.testing.assert_allclose(force(0.0), [0.0, 0.0, 0.25 * Y_A0 * sh.L_pp], rtol=1e-12)


def test_a_share_of_the_thrust_in_one_quadrant_acts_in_that_branch_alone() -> None:
    """``X_P*pos``: a shape times the thrust of Eq. (5), where n_p >= 0; with the propeller
    reversed (Eq. (11)) it adds nothing. Named as such, and a force times anything but a
    quadrant indicator is a clear error."""
    from mmg.model import hydrodynamic_forces

    spec = "shape:X~beta[-0.5:0.5]/4*X_P*pos"
    group = parse(spec)[0]
    assert shape_name([group]) == spec
    assert (group.force, group.quadrant, group.scale_name) == ("X_P", "pos", "")
    assert group.formula("X") == "X += f_X0(beta) X_P [n_p >= 0]  [N]"
    eff = get_effect(spec)
    assert eff.force_at is not None
    p = efd_parameters()
    th, sh = p.theta, p.ship
    e = eff.param_type(*([0.3] * 4))
    u, v_m, r, delta = 0.4, -0.06, 0.01, 0.1
    for n_p in (10.0, -10.0):
        X, Y, N = eff.force_at(12.0, 1.0, 2.0, u, v_m, r, 0.3, delta, n_p, 1.0, 0.5, e, th, sh)
        s, c = math.sin(delta), math.cos(delta)
        X_P = hydrodynamic_forces(u, v_m, r, s, c, n_p, th, sh)[3]
        assert X_P != 0.0
        assert (Y, N) == (0.0, 0.0)
        assert pytest.approx(0.3 * X_P if n_p > 0 else 0.0, rel=1e-12, abs=1e-12) == X
    for bad, why in (
        ("shape:X~beta[0:1]/6*X_P*v", "times a quadrant indicator"),
        ("shape:X~beta[0:1]/6*ast*pos", "times a quadrant indicator"),
        ("shape:X~beta[0:1]/6*X_P*pos@U2", "takes no scale"),
    ):
        with pytest.raises(KeyError, match=why):
            get_effect(bad)


def test_a_harmonic_of_an_angle_acts_on_the_whole_circle() -> None:
    """A harmonic closed form of an angle (and its odd square) is not held at the ends of its
    range: a function on the circle, in numpy and in the hook, its g_max still over the range;
    a harmonic of no angle, and any other form of an angle, are held there."""
    spec = "shape:X~beta[-0.5:0.5]:cos(2)+Y~beta[-0.5:0.5]:sq"
    circle, held = parse(spec)
    assert on_circle("beta", Form("cos", (2.0,))) and on_circle("gammaA", Form("sinodd", (1.0,)))
    assert not on_circle("beta", Form("sq")) and not on_circle("u", Form("sin", (1.0,)))
    g_max = form_scale(circle)
    assert g_max == pytest.approx(1.0)
    z = np.array([-3.0, -1.0, 0.0, 0.4, 2.5])
    np.testing.assert_allclose(curve(circle, [0.1, 0.5], z), 0.1 + 0.5 * np.cos(2 * z))
    np.testing.assert_allclose(
        curve(held, [0.0, 1.0], z), np.clip(z, -0.5, 0.5) ** 2 / form_scale(held)
    )
    eff = get_effect(spec)
    assert eff.force_at is not None
    p = efd_parameters()
    th, sh = p.theta, p.ship
    q = 0.5 * sh.rho * sh.L_pp * sh.d
    e = eff.param_type(0.1, 0.5, 0.0, 1.0)
    u, v_m, r = -0.3, 0.1, 0.0  # going astern: beta = atan2(-0.1, -0.3), beyond the range
    X, Y, _ = eff.force_at(12.0, 1.0, 2.0, u, v_m, r, 0.3, 0.0, 10.0, 1.0, 0.5, e, th, sh)
    beta = math.atan2(-v_m, u)
    U2 = u * u + v_m * v_m
    assert pytest.approx(q * U2 * (0.1 + 0.5 * math.cos(2 * beta)), rel=1e-12) == X
    assert pytest.approx(q * U2 * 0.25 / form_scale(held), rel=1e-12) == Y
    # a wave (a period of its own) comes and goes beyond its range as within it
    wave = parse("x~t[0:100]:wave(40,0.5)")[0]
    assert on_circle("t", Form("wave", (40.0, 0.5)))
    t = np.array([-30.0, 50.0, 230.0])
    g_max = form_scale(wave)
    np.testing.assert_allclose(
        curve(wave, [0.1, 0.5], t), 0.1 + 0.5 * np.sin(2 * np.pi * t / 40 + 0.5) / g_max
    )
    eff = get_effect("shape:x~t[0:100]:wave(40,0.5)")
    assert eff.force_at is not None
    e = eff.param_type(0.1, 0.5)
    for ti in t:
        X, Y, _ = eff.force_at(ti, 1.0, 2.0, u, v_m, r, 0.0, 0.0, 10.0, 1.0, 0.5, e, th, sh)
        assert pytest.approx(q * (0.1 + 0.5 * np.sin(2 * np.pi * ti / 40 + 0.5) / g_max)) == X


def test_a_force_fixed_to_the_basin_turns_with_the_heading() -> None:
    """Components x and y are a force along the basin's x0 and y0 axes (U_ref^2 scaling for
    time): on the ship's axes X = F_x0 cos psi + F_y0 sin psi, Y = -F_x0 sin psi + F_y0 cos
    psi, no moment; the probe gives each coefficient's force alike; a basin force is not a share
    of a force, nor mixed with the ship's axes."""
    spec = "shape:xy~t[0:400]/6+Y~beta[-0.5:0.5]/4"
    eff, probe = get_effect(spec), get_effect(spec + "#probe")
    group = groups_of(eff)[0]
    assert group.components == "xy" and group.scale_name == "ref"
    assert group.formula("x").startswith("F_x0 += 0.5 rho L_pp d U_ref^2 f_x0(t)")
    assert "Y -= F_x0 sin psi" in group.formula("x") and "F_y0 cos psi" in group.formula("y")
    p = efd_parameters()
    th, sh = p.theta, p.ship
    q = 0.5 * sh.rho * sh.L_pp * sh.d
    assert eff.force_at is not None and probe.force_at is not None
    rng = np.random.default_rng(3)
    cx, cy = rng.uniform(-1, 1, 6), rng.uniform(-1, 1, 6)
    e = eff.param_type(*cx, *cy, *np.zeros(4))
    for t, psi in ((12.0, 0.3), (250.0, -2.6), (500.0, 1.9)):
        args = (t, 1.0, 2.0, 0.4, 0.05, 0.01, psi, 0.1, 10.0, 1.0, 0.5)
        Fx, Fy = (q * curve(group, c, t)[0] for c in (cx, cy))
        X, Y, N = eff.force_at(*args, e, th, sh)
        assert pytest.approx(Fx * math.cos(psi) + Fy * math.sin(psi), rel=1e-12) == X
        assert pytest.approx(-Fx * math.sin(psi) + Fy * math.cos(psi), rel=1e-12) == Y
        assert N == 0.0
        for i, row in enumerate(probe_rows(eff, 0.7)):
            values = np.zeros(len(eff.params))
            values[i] = 0.7
            want = eff.force_at(*args, eff.param_type(*values), th, sh)
            got = probe.force_at(*args, probe.param_type(*row), th, sh)
            assert got == pytest.approx(want, rel=1e-12, abs=1e-300), (i, t)
    for bad, why in (
        ("x~t[0:400]/6*X_P", "not a share of the force X_P"),
        ("Xy~t[0:400]/6", "one or more of X, Y, N"),
        ("yx~t[0:400]/6", "x, y or xy"),
    ):
        with pytest.raises(ValueError, match=why):
            parse(bad)


def test_a_share_scales_a_sub_models_three_components_alike() -> None:
    """A share group (component S) adds f_S(z) (X_R, Y_R, N_R): all coefficients equal to c give
    c times the rudder's surge force, sway force and yaw moment (Eqs. (14)-(16)); its probe
    gives each coefficient's force as the effect does; a share of anything but a sub-model's
    force, or a sub-model's force in X, Y or N, is a clear error."""
    from mmg.model import hydrodynamic_forces

    p = efd_parameters()
    th, sh = p.theta, p.ship
    spec = "shape:S~alphaR[-0.8:0.8]/5*F_R+S~beta[-0.5:0.5]/4*F_H"
    eff = get_effect(spec)
    assert eff.param_names[:2] == ("s0_S0", "s0_S1") and len(eff.params) == 9
    assert "(X_R, Y_R, N_R)" in eff.params[0].description
    probe = probe_effect(spec)
    assert eff.force_at is not None and probe.force_at is not None
    u, v_m, r, delta, n_p = 0.4, -0.06, 0.01, 0.1, 10.0
    args = (12.0, 1.0, 2.0, u, v_m, r, 0.3, delta, n_p, 1.0, 0.5)
    forces = hydrodynamic_forces(u, v_m, r, math.sin(delta), math.cos(delta), n_p, th, sh)
    hull, rudder = np.array(forces[:3]), np.array(forces[6:9])
    values = np.zeros(9)
    values[:5] = 0.3
    got = eff.force_at(*args, eff.param_type(*values), th, sh)
    np.testing.assert_allclose(got, 0.3 * rudder, rtol=1e-12)
    values[:5], values[5:] = 0.0, -0.2
    got = eff.force_at(*args, eff.param_type(*values), th, sh)
    np.testing.assert_allclose(got, -0.2 * hull, rtol=1e-12)
    rows = probe_rows(eff, 0.7)
    assert rows.shape == (9, 7) and set(rows[:, 1]) == {5.0}
    for i, row in enumerate(rows):
        values = np.zeros(9)
        values[i] = 0.7
        want = eff.force_at(*args, eff.param_type(*values), th, sh)
        assert probe.force_at(*args, probe.param_type(*row), th, sh) == pytest.approx(
            want, rel=1e-12, abs=1e-300
        ), i
    for bad in ("shape:S~alphaR[0:1]/5*F_N", "shape:Y~alphaR[0:1]/5*F_R", "shape:S~alphaR[0:1]/5"):
        with pytest.raises(KeyError, match="a share group is"):
            get_effect(bad)


def test_the_probe_gives_the_force_of_each_coefficient() -> None:
    """The probe (parameters G, C, J, A and the knot range L, U) gives exactly the force of the
    shape effect with its coefficient (G, C, J) at A and every other at 0, ahead and astern;
    A = 0 gives nothing."""
    p = efd_parameters()
    eff = get_effect(HOOK_SPEC)
    probe = get_effect(HOOK_SPEC + "#probe")
    assert probe.param_names == ("G", "C", "J", "A", "L", "U", "H")
    assert probe.neutral() == (0.0,) * 5 + (1.0, 1.0)
    rows = probe_rows(eff, 0.7)
    g1 = groups_of(eff)[1]
    assert rows.shape == (22, 7) and rows[12].tolist()[:6] == [1.0, 2.0, 0.0, 0.7, g1.lo, g1.hi]
    assert rows[12, 6] == pytest.approx((g1.n - 3) / (g1.hi - g1.lo), rel=1e-15)
    assert eff.force_at is not None and probe.force_at is not None
    shape_force, probe_force = eff.force_at, probe.force_at
    for u, v_m in ((0.5, -0.08), (-0.3, 0.05)):
        args = (12.0, 1.0, 2.0, u, v_m, 0.02, 0.3, 0.1, 10.0, 1.0, 0.5)
        for i, row in enumerate(rows):
            values = np.zeros(22)
            values[i] = 0.7
            want = shape_force(*args, eff.param_type(*values), p.theta, p.ship)
            got = probe_force(*args, probe.param_type(*row), p.theta, p.ship)
            assert got == pytest.approx(want, rel=1e-12, abs=1e-300), (i, u)
        off = probe.param_type(1.0, 2.0, 3.0, 0.0, 0.0, 1.0, 1.0)
        nothing = probe_force(*args, off, p.theta, p.ship)
        assert nothing == (0.0, 0.0, 0.0)


@pytest.mark.kernels(
    *kernels((HOOK_SPEC,), "derivatives"),
    *kernels(
        (shape_name((Group("XYN", "U", 0.0, 1.0, 6), *parse(HOOK_SPEC))) + "#probe",), "derivatives"
    ),
)
def test_probes_of_one_structure_share_their_code_whatever_the_ranges() -> None:
    """A probe's ranges come with its lanes: the probes of the same groups over other ranges
    are one module (one kernel), and a probe made for more groups gives each of the effect's
    coefficients at the row :func:`probe_rows` maps it to."""
    p = efd_parameters()
    eff = get_effect(HOOK_SPEC)
    gs = groups_of(eff)
    other = tuple(replace(g, lo=g.lo - 0.1, hi=g.hi + 0.3) if g.variable != "1" else g for g in gs)
    assert shape_name(other) != shape_name(gs)
    assert probe_effect(other).param_type is probe_effect(gs).param_type
    # the shape effects too: their knot ranges are parameter rows of one kernel
    assert kernel_effects((shape_effect(other),)) == kernel_effects((eff,)) != (eff,)
    assert shape_effect(other).force_at is not eff.force_at  # its hook: the numbers written in
    wider = (Group("XYN", "U", 0.0, 1.0, 6), *gs)
    probe = probe_effect(wider)
    rows = probe_rows(eff, 0.7, wider)
    assert rows[:, 0].min() == 1.0  # the effect's groups are the probe's groups 1, 2, ...
    args = (12.0, 1.0, 2.0, 0.5, -0.08, 0.02, 0.3, 0.1, 10.0, 1.0, 0.5)

    def probe_is_effect(probe: Effect, eff: Effect, rows: np.ndarray) -> None:
        """Each row of the probe gives the effect's force with that coefficient alone."""
        assert probe.force_at is not None and eff.force_at is not None
        for i, row in enumerate(rows):
            values = np.zeros(len(rows))
            values[i] = 0.7
            want = eff.force_at(*args, eff.param_type(*values), p.theta, p.ship)
            got = probe.force_at(*args, probe.param_type(*row), p.theta, p.ship)
            assert got == pytest.approx(want, rel=1e-12, abs=1e-300), i

    probe_is_effect(probe, eff, rows)
    # in the kernel too: a coefficient's row of the shape effect (the knot ranges put in after
    # the coefficients) moves the ship as its row of the probe (the ranges in the lane's rows)
    x = np.array([1.0, 0.5, 2.0, -0.08, 0.3, 0.02])
    u, w = np.array([0.1, 10.0]), np.array([1.0, 0.5])
    theta = p.vector()
    for i in (0, 5, len(rows) - 1):
        values = np.zeros(len(rows))
        values[i] = 0.7
        want = derivatives_rows(x, u, w, np.concatenate([theta, values])[None], (eff,), t=12.0)
        got = derivatives_rows(x, u, w, np.concatenate([theta, rows[i]])[None], (probe,), t=12.0)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)
    with pytest.raises(ValueError, match="no group of the structure"):
        probe_rows(eff, 0.7, wider[:1])
    # a group of one component is served by a probe's group of the same structure with more
    # components (the lane's C picks the component): no probe of its own, the same force
    one = Group("N", "beta", -0.6, 0.4, 7)
    assert serves(Group("XYN", "beta", 0.0, 1.0, 8), one)
    assert not serves(Group("XY", "beta", 0.0, 1.0, 8), one)
    assert not serves(Group("XYN", "beta", 0.0, 1.0, 8, "Y_H"), one)
    from sweep.diagnose.shapes import probe_groups

    default = probe_groups([])
    assert probe_groups([one]) == default
    single = shape_effect([one])
    rows = probe_rows(single, 0.7, default)
    assert rows[:, 1].tolist() == [2.0] * 7  # component N
    probe_is_effect(probe_effect(default), single, rows)


def test_variables_from_recorded_samples() -> None:
    """The variables as the hook sees them, from recorded samples (for the knot ranges)."""
    p = efd_parameters()
    x = np.array([[1.0, 0.5, 2.0, -0.05, 7.0, 0.01], [3.0, -0.2, 4.0, 0.01, -0.5, 0.0]])
    c = np.array([[0.2, 10.0], [0.0, 5.0]])
    w = np.array([[2.0, 0.0], [0.0, 0.0]])
    t = np.array([5.0, 6.0])

    def values(name: str) -> np.ndarray:
        return variable_values(name, t, x, c, w, p.theta, p.ship)

    assert values("beta") == pytest.approx(np.arctan2([0.05, -0.01], [0.5, -0.2]))
    assert values("psi") == pytest.approx([7.0 - 2 * np.pi, -0.5])
    assert values("UA")[1] == pytest.approx(np.hypot(0.2, 0.01))
    assert values("gammaA")[0] == pytest.approx(
        np.arctan2(2 * np.sin(-7.0) - 0.05, 2 * np.cos(7.0) + 0.5)
    )
    assert values("JP")[0] > 0 > values("JP")[1]
    assert abs(values("alphaR")[0] - 0.2) < 0.2
    assert values("t").tolist() == [5.0, 6.0]
    assert values("vp") == pytest.approx([-0.05 / np.hypot(0.5, 0.05), 0.01 / np.hypot(0.2, 0.01)])
    rest = x.copy()
    rest[:, [1, 3]] = 0.0
    assert variable_values("vp", t, rest, c, w, p.theta, p.ship).tolist() == [0.0, 0.0]
    with pytest.raises(ValueError, match="unknown shape variable"):
        values("warp")


def test_candidate_groups_span_the_recorded_ranges() -> None:
    """Knots over the 0.5-99.5 % range of each variable in the windows; a variable that does
    not vary there (the propeller speed here) is left out; products and quadrant constants."""
    from sweep.diagnose.shapes import candidate_groups

    p = efd_parameters()
    k = np.arange(401)
    x = np.zeros((401, 6))
    x[:, 1] = 0.5 + 0.1 * np.sin(k / 30.0)
    x[:, 3] = 0.05 * np.sin(k / 20.0)
    x[:, 5] = 0.01 * np.cos(k / 25.0)
    c = np.column_stack([0.3 * np.sin(k / 40.0), np.full(401, 10.0)])
    w = np.zeros((401, 2))
    t = np.asarray(0.1 * k, dtype=np.float64)
    wins = [Recording(f"w{i}", None, 100.0 * i + t, x, c, w) for i in range(2)]
    groups = candidate_groups(
        wins, p, products=(("U", "v"),), shares=(("delta", "F_R"),), quadrants=("ast",), n=6
    )
    by = {(g.variable, g.multiplier): g for g in groups}
    assert ("n", "") not in by and ("beta", "") in by and ("t", "") in by
    beta = np.arctan2(-x[:, 3], x[:, 1])
    assert (by["beta", ""].lo, by["beta", ""].hi) == pytest.approx(
        tuple(np.quantile(beta, [0.005, 0.995])), rel=1e-5
    )
    assert by["U", "v"].n == 6 and by["1", "ast"].components == "XYN"
    assert by["delta", "F_R"].components == "S"
    forces = [g for g in groups if not g.control and g.multiplier != "F_R"]
    assert all(g.components == "XYN" for g in forces if g.components != "xy")
    # a force fixed to the basin of position and time, a knot every 10 s of time at most
    basin = [g.variable for g in forces if g.components == "xy"]
    assert basin == ["x0", "y0", "t"] or basin == ["t"]
    times = [g for g in groups if g.variable == "t"]
    assert [g.n for g in times] == [17, 17]  # 14 knot intervals over [0.4, 139.6] s
    assert by["ed", ""].components == "D" and by["ed", ""].lo == -by["ed", ""].hi
    assert by["eda", ""].components == "D" and by["eda", ""].lo == -by["eda", ""].hi


def test_a_time_shape_spans_a_session_s_clock_beyond_the_guard_the_advance_ratio_gets() -> None:
    """A session's split logs go on counting (the real random runs' last logs start at
    1176-3224 s): time's knots span every window, while an advance ratio of 1e4 (the
    propeller at rest) is still a guard, not a state."""
    from sweep.diagnose.shapes import GUARD, sampled, variable_ranges

    p = efd_parameters()
    k = np.arange(201)
    x = np.zeros((201, 6))
    x[:, 1] = 0.5
    c = np.column_stack([np.zeros(201), np.where(k < 100, 10.0, 0.0)])
    w = np.zeros((201, 2))
    clocks = [np.asarray(t0 + 0.1 * k, dtype=np.float64) for t0 in (5.0, 3000.0)]
    wins = [Recording(f"w{i}", None, t, x, c, w) for i, t in enumerate(clocks)]
    lo, hi = variable_ranges(wins, p, ["t"])["t"]
    assert lo < 10.0 and hi > 3000.0
    z = sampled(wins, p, ["JP", "t"])
    assert z["t"].size == 402 and z["JP"].size < 402 and np.all(np.abs(z["JP"]) < GUARD)
    # the waves' gate keeps its knots where they resolve a 40-s wave: the session's first runs
    from sweep.diagnose.waves import gate_groups

    gate = gate_groups(wins, p)
    assert [g.components for g in gate] == ["XYN", "xy"]
    assert all(g.lo < 10.0 and 20.0 < g.hi < 30.0 for g in gate)
    assert gate_groups(wins[1:], p) == []


def test_position_is_a_candidate_fixed_to_the_basin_and_with_the_speed_s_scaling() -> None:
    """Of x0 and y0: a force on the ship's axes at rest (U_ref^2), one along the basin's axes,
    and one on the ship's axes scaled by U^2 (a hull force that changes with where the ship
    is, e.g. the water's depth), and the surface of both in U^2; time keeps the first two
    alone, and one of x0 and y0 no surface."""
    from sweep.diagnose.shapes import PAIR_BASIS, candidate_groups

    p = efd_parameters()
    k = np.arange(401)
    x = np.zeros((401, 6))
    x[:, 0] = 0.05 * k  # x0 [m]
    x[:, 1] = 0.4
    x[:, 2] = 1.0 + np.sin(k / 50.0)  # y0 [m]
    c = np.column_stack([np.zeros(401), np.full(401, 10.0)])
    t = np.asarray(0.1 * k, dtype=np.float64)
    wins = [Recording("w", None, t, x, c, np.zeros((401, 2)))]
    groups = candidate_groups(wins, p, variables=("x0", "y0", "t"), products=(), shares=())
    kinds = [(g.variable, g.variable2, g.components, g.scale) for g in groups if g.variable != "1"]
    assert sorted(kinds) == sorted(
        [
            *((v, "", "XYN", "") for v in ("x0", "y0", "t")),
            *((v, "", "xy", "") for v in ("x0", "y0", "t")),
            ("x0", "", "XYN", "U2"),
            ("y0", "", "XYN", "U2"),
            ("x0", "y0", "XYN", "U2"),
        ]
    )
    (g,) = [g for g in groups if g.variable == "x0" and g.scale == "U2" and not g.variable2]
    assert g.text.endswith("@U2") and g.scale_name == "U2"
    (surface,) = [g for g in groups if g.variable2 == "y0"]
    (g_y0,) = [g for g in groups if g.variable == "y0" and g.scale == "U2"]
    assert surface.size == PAIR_BASIS**2 and surface.text.endswith(f"/{PAIR_BASIS}x{PAIR_BASIS}@U2")
    assert (surface.lo, surface.hi, surface.lo2, surface.hi2) == (g.lo, g.hi, g_y0.lo, g_y0.hi)
    alone = candidate_groups(wins, p, variables=("x0", "t"), products=(), shares=())
    assert not any(g.variable2 for g in alone)


def test_an_angle_recorded_over_most_of_a_turn_gets_knots_a_quarter_radian_apart() -> None:
    """Eight basis functions at least; an angle's knots at most 0.25 rad apart up to 24 basis
    functions (alpha_R ahead and astern), time's 10 s apart up to 40; other variables keep the
    eight."""
    from sweep.diagnose.shapes import basis_count

    assert basis_count("delta", -0.6, 0.6) == 8
    assert basis_count("beta", -1.0, 1.0) == 11
    assert basis_count("alphaR", -3.3, 2.6) == 24
    assert basis_count("U", 0.0, 10.0) == 8 and basis_count("t", 0.0, 50.0, 6) == 8
    assert basis_count("t", 5.9, 403.1) == 40 and basis_count("t", 0.0, 600.0) == 40


def test_a_force_in_the_non_dimensional_sway_velocity_is_the_papers_v_prime() -> None:
    """``vp`` is the paper's v'_m = v_m / U (not v_m / U_e): a side force linear in it, times
    U^2, is 0.5 rho L d U v_m at any speed, however slow, and nothing at rest."""
    p = efd_parameters()
    eff = get_effect("shape:Y~vp[-1:1]:lin")
    assert eff.force_at is not None
    values = {q.name: 0.0 for q in eff.params} | {"s0_Y1": 1.0}
    e = eff.param_type(*(values[q.name] for q in eff.params))
    sh = p.ship
    rest = (0.3, 0.1, 10.0, 0.0, 0.0, e, p.theta, sh)  # psi, delta, n_p, wind, parameters
    for u, v_m in ((0.5, -0.08), (0.02, 0.03), (-0.01, 0.004)):
        surge, sway, yaw = eff.force_at(12.0, 1.0, 2.0, u, v_m, 0.0, *rest)
        assert sway == pytest.approx(0.5 * sh.rho * sh.L_pp * sh.d * np.hypot(u, v_m) * v_m)
        assert surge == 0.0 and yaw == 0.0
    assert eff.force_at(12.0, 1.0, 2.0, 0.0, 0.0, 0.0, *rest) == (0.0, 0.0, 0.0)


#: the candidates of the selection test: shapes in beta, r' and t, six basis functions each
SELECT_SPEC = "shape:XYN~beta[-2.4:0.35]/6+XYN~rp[-0.7:0.8]/6+XYN~t[0:2600]/6"


@pytest.mark.integration  # compiles the kernel of a shape effect
@pytest.mark.kernels(*kernels((), "simulate", "moments"), *kernels((SELECT_SPEC,), "simulate"))
def test_a_shape_in_the_kernel_pushes_the_ship_its_way(data_dir: Path) -> None:
    """A constant sway force to starboard (every Y coefficient of the t shape at c > 0, its
    scaling U_ref^2: Y = 0.5 rho L d c) makes the simulated ship drift to starboard: v_m and
    the cross-track position grow against the neutral effect, which changes nothing."""
    from mmg import simulate_batch

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = read_recordings(data_dir / "data" / "random")[0]
    eff = get_effect(SELECT_SPEC)
    p = efd_parameters()
    K = 300
    x0, u, w = rec.x[:1], rec.u[None, :K], rec.w[None, :K]
    theta = np.zeros((3, N_THETA + len(eff.params)))
    theta[:, :N_THETA] = p.vector()
    theta[2, [eff.param_names.index(f"s2_Y{j}") for j in range(6)]] = 2e-3
    base = simulate_batch(x0, u, w, p.vector()[None]).states[0]
    runs = [simulate_batch(x0, u, w, th[None], effects=(eff,)).states[0] for th in theta[1:]]
    np.testing.assert_array_equal(runs[0], base)
    dv = runs[1][:, 3] - base[:, 3]
    assert dv[-1] > 0.0 and np.all(dv[1:] > 0.0)
    psi = base[:, 4]
    cross = -(runs[1][:, 0] - base[:, 0]) * np.sin(psi) + (runs[1][:, 2] - base[:, 2]) * np.cos(psi)
    assert cross[100] > 0.0


@pytest.mark.integration  # compiles the kernel of a shape effect
@pytest.mark.kernels(
    *kernels((), "simulate", "moments"),
    *kernels((SELECT_SPEC,), "simulate"),
    *probe_kernels(library=False),
)
def test_the_selection_finds_a_planted_shape_and_nothing_in_noise(small_case) -> None:
    """A yaw moment N = 0.5 rho L^2 d U^2 f(beta) (f oscillating, up to 0.01) planted in
    noisy windows: the selection on the linearised trajectory columns picks N(beta) first,
    with a held-out gain, fewer effective degrees of freedom than coefficients and a dBIC far
    below the null of the same statistic on noise-only copies; on the noise-only windows it
    picks nothing."""
    from sweep.diagnose.discover import null_sets
    from sweep.diagnose.linearised import Linearised
    from sweep.diagnose.scoring import n_effective
    from sweep.diagnose.shapes import ShapeColumns
    from sweep.identification.vector import with_effects

    ship, windows, noise = small_case
    eff = get_effect(SELECT_SPEC)
    groups = parse(SELECT_SPEC)
    g = groups[0]
    centres = g.lo + (np.arange(g.n) - 1.0) * (g.hi - g.lo) / (g.n - 3)
    values = np.zeros(len(eff.params))
    values[[eff.param_names.index(f"s0_N{j}") for j in range(6)]] = -0.01 * np.sin(3 * centres)
    truth = with_effects(ship, (eff,), [float(v) for v in values])
    data = noisy_windows(truth, windows, noise, 8)
    folds = ([0, 2], [1, 3])
    n_eff = n_effective(data, "J2")
    lin = Linearised(ship, data, folds, ())
    cols = ShapeColumns(lin, groups)
    assert cols.lib.shape == (4, 7007, 54) and cols.lib.dtype == np.float32
    r = lin.residuals(data)
    sel = cols.select(r, n_eff)
    assert sel.groups[0].text == "N~beta[-2.4:0.35]/6"
    assert sel.heldout_gain[0] > 0.2
    # the choice restricted to its own groups (the backward check's refit) is the same fit
    again = cols.restricted(r, n_eff, list(zip(sel.groups, sel.kappas, strict=True)))
    assert again.spec == sel.spec and again.kappas == sel.kappas
    np.testing.assert_allclose(again.values(), sel.values(), rtol=1e-9)
    assert again.heldout_gain == pytest.approx(sel.heldout_gain)
    assert again.dbic == pytest.approx(sel.dbic) and again.edf == pytest.approx(sel.edf)
    assert 1.0 < sel.edf[0] < 6.0
    # every unit alone: the planted one leads, with the selection's first gain
    singles = cols.singles(r)
    assert singles[0][1] == sel.groups[0] and singles[0][0] == pytest.approx(sel.heldout_gain[0])
    assert [s[0] for s in singles] == sorted((s[0] for s in singles), reverse=True)
    # made to enter first: the planted one gives the same selection; another enters first
    # only when it lowers the dBIC on its own (Y~rp, 16 % of the held-out J, does not)
    same = cols.select(r, n_eff, first=sel.groups[0])
    assert same.spec == sel.spec and same.heldout_gain == pytest.approx(sel.heldout_gain)
    other = singles[1][1]
    assert singles[1][0] > 0.1
    assert cols.select(r, n_eff, first=other).groups[:1] in ([], [other])
    assert sel.spec.startswith("shape:N~beta[-2.4:0.35]/6")
    k = 6 * len(sel.groups)
    assert len(sel.values()) == k and sel.penalty().shape == (k, k)
    R = np.stack(
        [lin.residuals(r) for r in null_sets(ship, windows, noise, np.random.default_rng(2), 20)],
        axis=-1,
    )
    null = cols.null_dbic(R, n_eff)
    assert null.shape == (20,)
    assert sel.dbic < min(float(np.quantile(null, 0.05)), 0.0) - 30.0
    # noise only: the same selection on noisy copies of the truth-free windows picks nothing
    quiet_data = [
        Recording(
            w.name, None, w.t, w.x + noise.draw(np.random.default_rng(5), w.x.shape[0]), w.u, w.w
        )
        for w in windows
    ]
    quiet_lin = Linearised(ship, quiet_data, folds, ())
    quiet = ShapeColumns(quiet_lin, groups).select(quiet_lin.residuals(quiet_data), n_eff)
    assert quiet.groups == [] and quiet.dbic == 0.0


#: a yaw moment beyond a drift angle: a kink between the knots of SELECT_SPEC's spline
HINGE_SPEC = "shape:N~beta[-2.4:0.35]:up(0.12)"


@pytest.mark.integration  # compiles the kernel of a shape effect
@pytest.mark.kernels(
    *kernels((), "simulate", "moments"),
    *kernels((HINGE_SPEC,), "simulate"),
    *probe_kernels(library=False),
)
def test_a_kink_between_knots_is_named_by_its_hinge_on_the_trajectories(small_case) -> None:
    """A yaw moment that sets in at beta = 0.12 rad, within the last knot interval of the
    selection's spline (0.92 rad wide): the spline rounds the kink off, the closed forms are
    compared on the trajectory columns of 40 basis functions, and the hinge at a corner near
    0.12 keeps (nearly) all of the spline's held-out gain."""
    from sweep.diagnose.linearised import Linearised
    from sweep.diagnose.scoring import n_effective
    from sweep.diagnose.shapes import ShapeColumns, ShapeSelection
    from sweep.diagnose.shaping import named_form, sample_values
    from sweep.identification.vector import with_effects

    ship, windows, noise = small_case
    truth = with_effects(ship, (get_effect(HINGE_SPEC),), [0.0, 0.01])
    data = noisy_windows(truth, windows, noise, 8)
    lin = Linearised(ship, data, ([0, 2], [1, 3]), ())
    cols = ShapeColumns(lin, parse(SELECT_SPEC))
    r = lin.residuals(data)
    sel = cols.select(r, n_effective(data, "J2"))
    assert sel.groups[0].text == "N~beta[-2.4:0.35]/6"
    named, form, start = named_form(cols, sel, r, sample_values(data, ship, sel.groups))
    hinge = named[0]
    assert hinge is not None and hinge.family == "hinge" and hinge.form.startswith("up(")
    assert abs(float(hinge.form[3:-1]) - 0.12) < 0.05
    assert hinge.share is not None and hinge.share > 0.9
    assert form is not None and form.name.startswith("shape:YN~beta[-2.4:0.35]:up(")  # with Y
    assert len(start) == len(form.params)
    # two chosen groups of one variable in one component, a shape and a share of Y_H: their
    # fine structures are the same groups, simulated once, and each form takes one group's place
    g = sel.groups[0]
    both = [g, replace(g, multiplier="Y_H")]
    sel2 = ShapeSelection(
        both,
        [sel.coefficients[0], [0.0] * g.n],
        [sel.penalties[0]] * 2,
        [sel.heldout_gain[0]] * 2,
        [sel.edf[0]] * 2,
        sel.dbic,
        kappas=[sel.kappas[0]] * 2,
    )
    named2, form2, start2 = named_form(
        ShapeColumns(lin, both), sel2, r, sample_values(data, ship, both)
    )
    assert named2[0] is not None and named2[0].form.startswith("up(")
    assert form2 is not None and len(start2) == len(form2.params)


FORM_SPEC = "shape:N~beta[-0.5:0.5]:up(0.1)*Y_H+Y~delta[-0.6:0.6]:step(0.1,0.05)+X~u[-0.2:1]:odd"


def test_a_closed_form_group_round_trips_and_adds_a_plus_b_g() -> None:
    """A closed-form group: two coefficients per component (a, b), f = a + b g / g_max with
    z held within its range, in numpy and in the generated hook; named by its spec."""
    groups = parse(FORM_SPEC)
    assert shape_name(groups) == FORM_SPEC and is_closed_form(FORM_SPEC)
    assert not is_closed_form(HOOK_SPEC) and not is_closed_form("rudder_offset")
    assert groups[0] == Group("N", "beta", -0.5, 0.5, 2, "Y_H", "", "up(0.1)")
    assert form_scale(groups[0]) == pytest.approx(0.4)
    assert parse_form("step(0.1,0.05)") == Form("step", (0.1, 0.05))
    eff = get_effect(FORM_SPEC)
    assert eff.param_names == ("s0_N0", "s0_N1", "s1_Y0", "s1_Y1", "s2_X0", "s2_X1")
    assert eff.description.startswith("closed form of a missing force")
    assert pickle.loads(pickle.dumps(eff)) is eff
    z = np.array([-2.0, 0.0, 0.3, 0.5, 3.0])
    np.testing.assert_allclose(
        curve(groups[0], [0.1, 0.8], z),
        0.1 + 0.8 * np.maximum(np.clip(z, -0.5, 0.5) - 0.1, 0) / 0.4,
    )
    assert groups[0].closed("N", 0.1, 0.8) == "N += (0.1 + 2 max(beta - 0.1, 0)) Y_H L_pp  [N m]"
    p = efd_parameters()
    th, sh = p.theta, p.ship
    q = 0.5 * sh.rho * sh.L_pp * sh.d
    u, v_m, r, delta = 0.5, -0.15, 0.02, 0.3
    e = eff.param_type(0.1, 0.8, -0.2, 0.5, 0.03, -0.4)
    assert eff.force_at is not None
    X, Y, N = eff.force_at(12.0, 1.0, 2.0, u, v_m, r, 0.3, delta, 10.0, 1.0, 0.5, e, th, sh)
    beta = np.arctan2(-v_m, u)
    Y_H = hull_forces(u, v_m, r, th, sh)[1]
    assert pytest.approx((0.1 + 0.8 * max(beta - 0.1, 0.0) / 0.4) * Y_H * sh.L_pp, rel=1e-12) == N
    assert pytest.approx(q * (u * u + v_m * v_m) * (0.03 - 0.4 * u * abs(u)), rel=1e-12) == X
    assert Y != 0.0
    with pytest.raises(ValueError, match="only splines have a probe"):
        probe_effect(FORM_SPEC)
    for bad, why in (
        ("shape:N~beta[-0.5:0.5]:up(0.9)", "is 0 over"),
        ("shape:N~beta[-0.5:0.5]:absup(0.6)", "is 0 over"),
        ("shape:N~beta[-0.5:0.5]:oddup(-0.1)", "must not be negative"),
        ("shape:N~beta[-0.5:0.5]:warp", "unknown closed form"),
        ("shape:N~beta[-0.5:0.5]:step(0.1)", "takes 2 number"),
        ("shape:N~beta[-0.5:0.5]:up(x)", "not numbers"),
    ):
        with pytest.raises(KeyError, match=why):
            get_effect(bad)


SYMMETRIC_SPEC = "shape:Y~v[-0.1:0.08]:oddup(0.02)+N~delta[-0.6:0.6]:absup(0.3)"


def test_symmetric_hinges_act_on_both_sides_alike_in_numpy_and_in_the_hook() -> None:
    """sign(z) max(|z| - c, 0) and max(|z| - c, 0): the hook's force is the numpy curve."""
    groups = parse(SYMMETRIC_SPEC)
    assert shape_name(groups) == SYMMETRIC_SPEC
    z = np.array([-0.3, -0.05, 0.0, 0.01, 0.05, 0.3])
    np.testing.assert_allclose(
        curve(groups[0], [0.0, 1.0], z),
        np.copysign(np.maximum(np.abs(np.clip(z, -0.1, 0.08)) - 0.02, 0.0), z) / 0.08,
    )
    assert groups[1].closed("N", 0.0, 0.3) == (
        "N += 0.5 rho L_pp^2 d U_R^2 (0 + 1 max(|delta| - 0.3, 0))  [N m]"
    )
    eff = get_effect(SYMMETRIC_SPEC)
    p = efd_parameters()
    th, sh = p.theta, p.ship
    q = 0.5 * sh.rho * sh.L_pp * sh.d
    e = eff.param_type(0.001, 0.02, -0.003, 0.01)
    assert eff.force_at is not None
    for v_m, delta in ((0.06, 0.5), (-0.06, -0.5), (0.01, 0.1)):
        u, r = 0.4, 0.01
        X, Y, N = eff.force_at(12.0, 1.0, 2.0, u, v_m, r, 0.3, delta, 10.0, 1.0, 0.5, e, th, sh)
        U2 = u * u + v_m * v_m
        g_Y = math.copysign(max(abs(v_m) - 0.02, 0.0), v_m) / 0.08
        g_N = max(abs(delta) - 0.3, 0.0) / 0.3
        assert X == 0.0
        assert pytest.approx(q * U2 * (0.001 + 0.02 * g_Y), rel=1e-12) == Y
        u_R, v_R = rudder_inflow_at(u, v_m, r, 10.0, th, sh)
        UR2 = u_R * u_R + v_R * v_R
        assert pytest.approx(q * sh.L_pp * UR2 * (-0.003 + 0.01 * g_N), rel=1e-12) == N


def test_the_backward_check_drops_a_group_that_adds_less_than_its_share() -> None:
    """A group stays when the shape with it scores (its typical held-out window's lead score) at
    least MIN_GAIN more than the best shape without it; else the group whose absence costs
    least goes."""
    from sweep.diagnose.pruning import group_to_drop
    from sweep.diagnose.shapes import MIN_GAIN

    assert group_to_drop(10.0, [2.0, 5.0]) is None  # each group adds far more than 15 %
    assert group_to_drop(10.0, [9.0, 3.0]) == 0  # the second group carries the gain alone
    assert group_to_drop(10.0, [3.0, 10.0 / (1.0 + MIN_GAIN) + 1e-9]) == 1
    assert group_to_drop(10.0, [3.0, 10.0 / (1.0 + MIN_GAIN) - 1e-6]) is None
    assert group_to_drop(4.0, [5.0, 1.0]) == 0  # a group that makes the held-out runs worse
    assert group_to_drop(-1.0, [-3.0, -2.0]) is None  # nothing gains: left to the verdict
    assert group_to_drop(5.0, []) is None
    assert group_to_drop(5.0, [float("nan"), 4.5]) == 1  # a failed fit without a group: it stays
    assert group_to_drop(float("nan"), [1.0, 0.5]) == 0  # the whole shape's fit failed


def test_the_lead_goes_to_a_single_group_that_gains_its_share_more_by_output_error() -> None:
    """Another single group leads a shape only when its lead score (the typical held-out
    window's) is at least MIN_GAIN above the selection's own first group's."""
    from sweep.diagnose.pruning import lead_to_take
    from sweep.diagnose.shapes import MIN_GAIN

    assert lead_to_take([5.0, 9.0, 3.0], 1) is None  # the first is the best
    assert lead_to_take([-9.2, 142.8, 3.0], 0) == 1  # linearised first, worse than none
    assert lead_to_take([10.0, 10.0 * (1.0 + MIN_GAIN) - 1e-6], 0) is None
    assert lead_to_take([10.0, 10.0 * (1.0 + MIN_GAIN) + 1e-6], 0) == 1
    assert lead_to_take([-3.0, -1.0], 0) is None  # nothing gains: left to the candidates'
    assert lead_to_take([-3.0, 0.5], 0) == 1
    assert lead_to_take([1.0, float("nan"), float("inf")], 0) is None  # failed fits never lead
    assert lead_to_take([float("nan"), 2.0], 0) == 1


def test_the_lead_is_judged_by_the_typical_held_out_window_not_the_sum() -> None:
    """A group that makes most held-out runs a hundred times better and two worse (they leave
    the range its half of the runs taught it) leads one that makes every run a few times
    better, though the latter takes more off the summed J, which the runs the base fits worst
    decide."""
    from sweep.diagnose.pruning import lead_score, lead_to_take
    from sweep.diagnose.scoring import typical_change

    control = np.array([66.1, 19.1, 52.1, 155.3, 32.0, 28.3, 94.8, 190.1, 47.8, 111.2, 2.5, 27.9])
    many = control / 150.0
    many[2:4] = control[2:4] * np.array([3.4, 1.6])  # two runs worse
    every = control / np.array([11, 27, 0.44, 2.5, 8.3, 32, 5, 3.6, 1.8, 2.3, 1.4, 12])
    assert control.sum() - every.sum() > control.sum() - many.sum()  # the sum prefers `every`
    scores = [lead_score(typical_change(j, control)) for j in (every, many)]
    assert lead_to_take(scores, 0) == 1
    assert lead_score(typical_change(control, control)) == pytest.approx(0.0, abs=1e-12)
    assert lead_score(typical_change(control / 10.0, control)) == pytest.approx(np.log(10.0))
    assert np.isnan(lead_score(float("nan")))


def test_a_shape_the_output_error_fitted_is_named_from_that_fit() -> None:
    """The selection's coefficients become those of its fit by output error, group by group,
    when the lead check or the backward check fitted it (a single group or several); one that
    neither fitted keeps its linearised coefficients."""
    from mmg.shapes import Group, shape_effect
    from sweep.diagnose.pruning import fitted_coefficients
    from sweep.diagnose.scoring import CandidateScore
    from sweep.diagnose.shapes import ShapeSelection

    g1, g2 = Group("X", "beta", -1.5, 1.5, 6), Group("N", "rp", -1.0, 1.0, 4)

    def selection(groups: list[Group]) -> ShapeSelection:
        n = [g.n for g in groups]
        return ShapeSelection(
            groups=groups,
            coefficients=[[0.1 * (i + 1)] * k for i, k in enumerate(n)],
            penalties=[np.eye(k) for k in n],
            heldout_gain=[0.5] * len(groups),
            edf=[3.0] * len(groups),
            dbic=-40.0,
        )

    def fitted(groups: list[Group], values: list[float]) -> tuple[str, CandidateScore]:
        eff = shape_effect(groups)
        params = dict(zip([p.name for p in eff.params], values, strict=True))
        return selection(groups).spec, CandidateScore(eff.name, "", "", params, 1, 1, 0.6, -50)

    oe = [0.3, -0.2, 0.1, 0.0, -0.1, 0.4]
    both = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, -1.0, -2.0, -3.0, -4.0]
    fits = dict([fitted([g2], [9.0] * 4), fitted([g1], oe), fitted([g1, g2], both)])
    named = fitted_coefficients(selection([g1]), fits)
    assert named.coefficients == [oe]
    assert named.groups == [g1] and named.dbic == -40.0  # the rest as selected
    assert fitted_coefficients(selection([g1, g2]), fits).coefficients == [both[:6], both[6:]]
    other = selection([Group("Y", "beta", -1.5, 1.5, 6)])
    assert fitted_coefficients(other, fits) is other
    assert fitted_coefficients(selection([g2, g1]), fits).coefficients == [[0.1] * 4, [0.2] * 6]


def test_the_in_sample_share_read_back_from_a_dbic_is_the_share_that_made_it():
    """:func:`insample_share` inverts the linearised dBIC of a gain and its degrees of freedom."""
    from sweep.diagnose.shapes import _dbic, insample_share

    for share, edf in ((0.022, [5.9]), (0.169, [3.0, 3.4]), (0.0004, [2.6])):
        dbic = _dbic(0.613, share * 0.613, edf, 840.0)
        assert insample_share(dbic, edf, 840.0) == pytest.approx(share, rel=1e-9)
