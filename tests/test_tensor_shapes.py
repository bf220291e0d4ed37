"""Shapes of two variables (an interaction): the tensor-product spline group of
:mod:`mmg.shapes`, its name, basis, penalty and hook."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from mmg import efd_parameters, get_effect
from mmg.shapes import (
    Group,
    basis2,
    difference_penalty,
    form_scale,
    groups_of,
    numbers,
    parse,
    parse_form,
    penalty,
    probe_effect,
    probe_rows,
    shape_effect,
    surface,
)
from mmg.wind import apparent_wind
from sweep.diagnose.naming import Product, closest_products, form_group, product_r2
from tests.conftest import noisy_windows

#: a yaw moment in the surge velocity and the apparent-wind angle, with the wind's scaling
SPEC = "shape:N~u&gammaA[-0.1:0.4&-3.1:3.1]/5x7@UA2"


def test_a_shape_of_two_variables_round_trips_through_its_name() -> None:
    (g,) = parse(SPEC)
    assert (g.variable, g.variable2, g.n, g.n2, g.lo2, g.hi2) == ("u", "gammaA", 5, 7, -3.1, 3.1)
    assert g.tensor and g.size == 35
    assert "shape:" + g.text == SPEC
    assert g.structure == "N~u&gammaA@UA2"
    assert "f_N0(u, gamma_A)" in g.formula("N")
    eff = shape_effect(SPEC)
    assert len(eff.params) == 35 and eff.params[34].name == "s0_N34"
    assert get_effect(SPEC) is eff
    assert pickle.loads(pickle.dumps(eff)).name == SPEC
    # its numbers: both knot ranges and knots per unit
    assert [f for f, _ in numbers(groups_of(eff))] == [
        "k0_lo",
        "k0_hi",
        "k0_h",
        "k0_lo2",
        "k0_hi2",
        "k0_h2",
    ]
    # with a one-variable group beside it
    two = parse("YN~beta[-0.5:0.5]/6+X~U&n[0:0.4&-10:10]/4x4*v")
    assert [g.size for g in two] == [6, 16] and two[1].multiplier == "v"


@pytest.mark.parametrize(
    "spec, words",
    [
        ("N~u&u[0:1&0:1]/4x4", "needs two"),
        ("N~u&ed[0:1&0:1]/4x4", "two force variables"),
        ("N~u&gammaA[0:1&1:1]/4x4", "is empty"),
        ("N~u&gammaA[0:1&-1:1]/4x3", "need 4 to 40"),
        ("N~u&gammaA[0:1&-1:1]/20x20", "at most 100"),
        ("N~u&gammaA[0:1]/4x4", "written"),
        ("N~u[0:1]/4x4", "written"),
        ("N~u&warp[0:1&0:1]/4x4", "unknown shape variable"),
    ],
)
def test_malformed_shapes_of_two_variables_are_one_line_errors(spec: str, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        parse(spec)


def test_the_basis_of_two_variables_sums_to_one_and_is_held_outside_its_rectangle() -> None:
    (g,) = parse(SPEC)
    rng = np.random.default_rng(0)
    z, z2 = rng.uniform(-0.5, 0.8, 200), rng.uniform(-4.0, 4.0, 200)
    B = basis2(g, z, z2)
    assert B.shape == (200, 35)
    np.testing.assert_allclose(B.sum(axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(basis2(g, [0.9], [5.0]), basis2(g, [0.4], [3.1]), rtol=1e-12)
    # column i n2 + j is the product of the one-variable bases
    one = Group("N", "u", g.lo, g.hi, g.n)
    two = Group("N", "gammaA", g.lo2, g.hi2, g.n2)
    from mmg.shapes import basis

    want = basis(one, z)[:, 2] * basis(two, z2)[:, 4]
    np.testing.assert_allclose(B[:, 2 * 7 + 4], want, rtol=1e-12)


def test_the_penalty_of_two_variables_leaves_bilinear_surfaces_free() -> None:
    (g,) = parse(SPEC)
    P = penalty(g)
    i, j = np.meshgrid(np.arange(5.0), np.arange(7.0), indexing="ij")
    for c in (np.ones_like(i), i, j, i * j):
        assert c.ravel() @ P @ c.ravel() == pytest.approx(0.0, abs=1e-9)
    bent = (i * i).ravel()
    assert bent @ P @ bent > 1.0
    np.testing.assert_allclose(
        P, np.kron(difference_penalty(5), np.eye(7)) + np.kron(np.eye(5), difference_penalty(7))
    )


def test_the_hook_adds_the_surface_times_its_scaling() -> None:
    """The generated hook (called from Python) against numpy: the surface of the coefficients
    times the wind's scaling in N, (rho_A A_L / rho L_pp d) U_A^2 with 0.5 rho L_pp^2 d."""
    p = efd_parameters()
    th, sh = p.theta, p.ship
    eff = get_effect(SPEC)
    (g,) = groups_of(eff)
    assert eff.force_at is not None
    rng = np.random.default_rng(1)
    coef = rng.normal(size=35)
    e = eff.param_type(**{f"s0_N{j}": float(c) for j, c in enumerate(coef)})
    for u, v_m, psi, U_T, gamma_T in [(0.3, -0.05, 0.4, 2.0, 1.0), (-0.05, 0.1, -2.0, 5.0, 3.0)]:
        args = (12.0, 1.0, 2.0, u, v_m, 0.01, psi, 0.1, 10.0, U_T, gamma_T, e, th, sh)
        fx, fy, fn = eff.force_at(*args)
        uA, vA = apparent_wind(
            u, v_m, math.sin(psi), math.cos(psi), U_T, math.sin(gamma_T), math.cos(gamma_T)
        )
        gamma_A = math.atan2(vA, uA)
        wL = sh.rho_A * sh.A_L / (sh.rho * sh.L_pp * sh.d)
        scale = 0.5 * sh.rho * sh.L_pp**2 * sh.d * wL * (uA * uA + vA * vA)
        want = scale * float(surface(g, coef, [u], [gamma_A])[0])
        assert (fx, fy) == (0.0, 0.0)
        assert fn == pytest.approx(want, rel=1e-9)


#: the same yaw moment named: u|u| times sin(gamma_A), with the wind's scaling
PRODUCT = "shape:N~u&gammaA[-0.1:0.4&-3.1:3.1]:odd&sin(1)@UA2"


def test_a_product_of_closed_forms_round_trips_and_its_hook_matches_numpy() -> None:
    """A surface named afterwards: a + b g1(u) g2(gamma_A) / g_max, both held in their ranges;
    the hook (called from Python) against numpy's :func:`surface`."""
    (g,) = parse(PRODUCT)
    assert g.tensor and g.form == "odd&sin(1)" and (g.n, g.n2, g.size) == (2, 1, 2)
    assert "shape:" + g.text == PRODUCT
    # g_max: the largest |u|u|| on [-0.1, 0.4] times the largest |sin| on [-3.1, 3.1]
    assert form_scale(g) == pytest.approx(0.16 * 1.0, rel=1e-4)
    assert [f for f, _ in numbers([g])] == ["k0_lo", "k0_hi", "k0_a0", "k0_gs", "k0_lo2", "k0_hi2"]
    closed = g.closed("N", 0.1, 0.5)
    assert "u|u| sin(1 gamma_A)" in closed and "U_A^2" in closed
    # held at the edges of its rectangle
    inside = surface(g, [0.1, 0.5], [0.4, 0.4], [1.0, 1.0])
    outside = surface(g, [0.1, 0.5], [0.9, 0.4], [1.0, 1.0])
    assert inside[0] == pytest.approx(0.1 + 0.5 * 0.16 * math.sin(1.0) / form_scale(g))
    assert outside[0] == inside[0]
    p = efd_parameters()
    th, sh = p.theta, p.ship
    eff = get_effect(PRODUCT)
    assert eff.force_at is not None and [q.name for q in eff.params] == ["s0_N0", "s0_N1"]
    e = eff.param_type(s0_N0=0.02, s0_N1=-0.7)
    for u, v_m, psi, U_T, gamma_T in [(0.3, -0.05, 0.4, 2.0, 1.0), (-0.2, 0.1, -2.0, 5.0, 3.0)]:
        args = (12.0, 1.0, 2.0, u, v_m, 0.01, psi, 0.1, 10.0, U_T, gamma_T, e, th, sh)
        fx, fy, fn = eff.force_at(*args)
        uA, vA = apparent_wind(
            u, v_m, math.sin(psi), math.cos(psi), U_T, math.sin(gamma_T), math.cos(gamma_T)
        )
        wL = sh.rho_A * sh.A_L / (sh.rho * sh.L_pp * sh.d)
        scale = 0.5 * sh.rho * sh.L_pp**2 * sh.d * wL * (uA * uA + vA * vA)
        want = scale * float(surface(g, [0.02, -0.7], [u], [math.atan2(vA, uA)])[0])
        assert (fx, fy) == (0.0, 0.0)
        assert fn == pytest.approx(want, rel=1e-9)


def test_a_surface_is_named_by_the_product_of_closed_forms_closest_to_it() -> None:
    """A surface fitted to u|u| sin(gamma_A) at samples where the runs went (u ahead mostly,
    the wind from every side) is named odd square times harmonic, and the named group takes
    the coefficients that reproduce it."""
    (g,) = parse(SPEC)
    rng = np.random.default_rng(3)
    z, z2 = rng.uniform(-0.05, 0.4, 3000), rng.uniform(-3.1, 3.1, 3000)
    truth = 0.3 - 2.0 * z * np.abs(z) * np.sin(z2)
    coef = np.linalg.lstsq(basis2(g, z, z2), truth, rcond=None)[0].astype(np.float64)
    best = closest_products(g, coef, z, z2, top=3)
    assert best[0].form == "odd&sin(1)" and best[0].r2 > 0.98
    assert best[0].family == "odd square x harmonic"
    assert best[0].r2 >= best[1].r2 >= best[2].r2
    # one product's share, as the naming on the trajectories states it
    top = Product(parse_form("odd"), parse_form("sin(1)"))
    assert product_r2(g, coef, top, z, z2) == pytest.approx(best[0].r2, rel=1e-9)
    named, ab = form_group(g, "N", best[0])
    assert named.text == "N~u&gammaA[-0.1:0.4&-3.1:3.1]:odd&sin(1)@UA2"
    np.testing.assert_allclose(surface(named, ab, z, z2), truth, atol=0.02)
    # a flat surface, or a shape of one variable, names nothing
    assert closest_products(g, np.full(35, 0.2), z, z2) == []
    (one,) = parse("N~u[-0.1:0.4]/6")
    assert closest_products(one, np.zeros(6), z, z2) == []


@pytest.mark.parametrize(
    "spec, words",
    [
        ("N~u&gammaA[0:1&-1:1]:odd", "is a product"),
        ("N~u[0:1]:odd&sin(1)", "one variable is one form"),
        ("N~u&gammaA[0:1&-1:1]:odd&up(5)", "is 0 over"),
        ("N~u&gammaA[0:1&-1:1]:odd&warp", "unknown closed form"),
    ],
)
def test_malformed_products_of_closed_forms_are_one_line_errors(spec: str, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        parse(spec)


def test_the_probe_of_a_shape_of_two_variables_gives_the_force_of_each_coefficient() -> None:
    """A probe with a shape of two variables beside a shape of one: each lane's row (G, C, J,
    A, L, U, H, J2, L2, U2, H2) gives exactly the force of the shape effect with that one
    coefficient at A, B_i(z) B_j(z2) for the surface's coefficient i n2 + j; A = 0 gives
    nothing."""
    p = efd_parameters()
    spec = SPEC + "+YN~beta[-0.6:0.6]/5"
    eff = get_effect(spec)
    probe = probe_effect(spec)
    assert probe.param_names[-4:] == ("J2", "L2", "U2", "H2")
    k = len(eff.params)
    rows = probe_rows(eff, 0.7)
    assert rows.shape == (k, 11)
    g0 = parse(spec)[0]
    assert rows[g0.n2 + 2].tolist()[7:10] == [2.0, g0.lo2, g0.hi2]  # i = 1, j = 2
    assert rows[-1].tolist()[7:] == [0.0, 0.0, 1.0, 1.0]  # a one-variable group's lane
    assert eff.force_at is not None and probe.force_at is not None
    for u, v_m, psi in ((0.5, -0.08, 0.3), (-0.3, 0.05, 2.5), (0.2, 0.0, -1.0)):
        args = (12.0, 1.0, 2.0, u, v_m, 0.02, psi, 0.1, 10.0, 1.0, 0.5)
        for i, row in enumerate(rows):
            values = np.zeros(k)
            values[i] = 0.7
            want = eff.force_at(*args, eff.param_type(*values), p.theta, p.ship)
            got = probe.force_at(*args, probe.param_type(*row), p.theta, p.ship)
            assert got == pytest.approx(want, rel=1e-12, abs=1e-300), (i, u)
        off = probe.param_type(*rows[3][:3], 0.0, *rows[3][4:])
        assert probe.force_at(*args, off, p.theta, p.ship) == (0.0, 0.0, 0.0)


def test_the_pairs_of_a_chosen_group_are_its_variable_with_each_other_both_scalings() -> None:
    """The interactions of a chosen group's variable with each other variable (no gap of a
    control), in its components and multiplier, with its scaling and, where the other
    variable's own scaling differs (and no force multiplies), with the other's."""
    from sweep.diagnose.shapes import PAIR_BASIS, pair_groups

    ranges = {"u": (-0.1, 0.4), "gammaA": (-3.0, 3.0), "beta": (-0.5, 0.5), "ed": (-4.0, 4.0)}
    variables = ("u", "gammaA", "beta", "ed", "psi")  # psi has no range here
    first = Group("N", "u", -0.1, 0.4, 8)
    got = [g.text for g in pair_groups(ranges, first, variables)]
    n = f"{PAIR_BASIS}x{PAIR_BASIS}"
    assert got == [
        f"N~u&gammaA[-0.1:0.4&-3:3]/{n}",
        f"N~gammaA&u[-3:3&-0.1:0.4]/{n}",  # the wind's scaling U_A^2
        f"N~u&beta[-0.1:0.4&-0.5:0.5]/{n}",  # beta's scaling is u's, U^2: one surface
    ]
    share = Group("X", "beta", -0.5, 0.5, 8, "X_P")
    assert [g.text for g in pair_groups(ranges, share, variables)] == [
        f"X~beta&u[-0.5:0.5&-0.1:0.4]/{n}*X_P",
        f"X~beta&gammaA[-0.5:0.5&-3:3]/{n}*X_P",
    ]
    assert pair_groups(ranges, Group("X", "1", multiplier="ast"), variables) == []
    assert pair_groups(ranges, Group("D", "ed", -4.0, 4.0, 16), variables) == []
    assert pair_groups(ranges, parse(SPEC)[0], variables) == []


def test_the_report_states_a_surface_as_a_table_of_both_variables() -> None:
    """A learned surface f = c B_i(u) B_j(gamma_A) summed to a plane in u: the report's entry
    gives f on a 9 x 5 grid of both ranges, and its table one row per value of u."""
    from sweep.diagnose.report import _surface_entry, _surface_md

    group = parse(SPEC)[0]
    # coefficients of f = u: the B-spline coefficients of a straight line are its values at
    # the knots' centres, whatever the second variable
    centres = group.lo + (np.arange(group.n) - 1.0) * (group.hi - group.lo) / (group.n - 3)
    coef = [float(c) for c in np.repeat(centres, group.n2)]
    entry = _surface_entry(group, "N", 0, coef)
    assert entry["variable2"] == "gammaA" and len(entry["z2"]) == 5
    f = np.asarray(entry["surface"])
    assert f.shape == (9, 5)
    np.testing.assert_allclose(f, np.repeat(np.asarray(entry["z"])[:, None], 5, axis=1), atol=1e-12)
    md = _surface_md(entry)
    assert md[0].startswith("| u [m/s] \\ gammaA [rad] | -3.1 |") and len(md) == 2 + 9 + 1
    assert md[2].startswith("| -0.1 | -0.1 |")


#: a planted interaction: a yaw moment in u^2 times sin(gamma_A), with the wind's scaling
PLANTED_PRODUCT = "shape:N~u&gammaA[0:0.5&-3.1:3.1]:sq&sin(1)@UA2"


@pytest.mark.slow  # compiles a probe of the candidates with a surface among them (2-3 min)
@pytest.mark.integration
def test_a_planted_interaction_is_named_by_a_product_on_the_trajectories(small_case) -> None:
    """A yaw moment in u^2 sin(gamma_A) planted in noisy windows: the surface chosen on the
    linearised columns is named, on the trajectories, by a product of closed forms that keeps
    its held-out gain and follows the planted force where the runs went (four windows of
    100 s with u in 0-0.28 m/s do not tell u^2 sin(gamma_A) from u gamma_A: both are kept
    as well)."""
    from sweep.diagnose.linearised import Linearised
    from sweep.diagnose.scoring import n_effective
    from sweep.diagnose.shapes import ShapeColumns, jointly_sampled
    from sweep.diagnose.shaping import named_form
    from sweep.identification.vector import with_effects

    ship, windows, noise = small_case
    truth = with_effects(ship, (get_effect(PLANTED_PRODUCT),), [0.0, 0.15])
    data = noisy_windows(truth, windows, noise, 8)
    lin = Linearised(ship, data, ([0, 2], [1, 3]), ())
    (g,) = parse("N~u&gammaA[0:0.5&-3.1:3.1]/6x6@UA2")
    cols = ShapeColumns(lin, [g])
    r = lin.residuals(data)
    sel = cols.select(r, n_effective(data, "J2"))
    assert [h.text for h in sel.groups] == [g.text]
    z, z2 = jointly_sampled(data, ship, "u", "gammaA")
    named, form, start = named_form(cols, sel, r, None, {("u", "gammaA"): (z, z2)})
    product = named[0]
    assert product is not None and "&" in product.form and " x " in product.family
    assert product.share is not None and product.share > 0.9
    assert form is not None and form.name.startswith("shape:YN~u&gammaA[0:0.5&-3.1:3.1]:")
    assert len(start) == len(form.params) == 4
    (planted,) = parse(PLANTED_PRODUCT)
    (got,) = parse(form.name)
    f_planted = surface(planted, [0.0, 1.0], z, z2)
    assert np.corrcoef(surface(got, [0.0, 1.0], z, z2), f_planted)[0, 1] > 0.9
