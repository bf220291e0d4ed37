"""Naming a learned shape afterwards: the closed forms closest to it (sweep.diagnose.naming)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mmg.shapes import FORMS, SYMMETRIC, Form, Group, basis, curve, parse_form
from sweep.diagnose.naming import CLOSE, closest_forms, families, form_group


def _coefficients(group: Group, f) -> list[float]:
    """The spline coefficients that fit f on the group's range (least squares)."""
    z = np.linspace(group.lo, group.hi, 400)
    c, *_ = np.linalg.lstsq(basis(group, z), f(z), rcond=None)
    return [float(v) for v in c]


@pytest.mark.parametrize(
    ("f", "family", "formula"),
    [
        (lambda z: 0.02 * np.maximum(z - 0.2, 0.0), "hinge", "max(beta - 0.2, 0)"),
        (lambda z: -0.01 * np.sin(3 * z), "harmonic", "sin(3 beta)"),
        (lambda z: 0.3 + 0.05 * z * np.abs(z), "odd square", "beta|beta|"),
        # a threshold reached on both sides of the ship: a side force beyond |beta| = 0.35
        (
            lambda z: np.copysign(np.maximum(np.abs(z) - 0.35, 0.0), z),
            "symmetric hinge",
            "sign(beta) max(|beta| - 0.35, 0)",
        ),
        (
            lambda z: 0.1 - 0.02 * np.maximum(np.abs(z) - 0.5, 0.0),
            "symmetric hinge",
            "max(|beta| - 0.5, 0)",
        ),
    ],
)
def test_a_shape_is_named_by_the_closed_form_it_was_made_of(f, family, formula):
    group = Group("N", "beta", -1.0, 1.4, 12)
    best = closest_forms(group, _coefficients(group, f))[0]
    assert (best.family, best.formula) == (family, formula)
    assert best.r2 > 0.99 >= CLOSE


def test_a_force_that_comes_and_goes_in_time_is_named_by_its_wave() -> None:
    """A shape of time sin(2 pi t / 40 s + 0.5) over 400 s (a knot every 10.7 s) is named a wave
    of about that period and phase; waves are tried for time only, from one cycle over the
    range to a period of three knot intervals."""
    from sweep.diagnose.naming import waves

    group = Group("x", "t", 5.0, 405.0, 40)
    best = closest_forms(group, _coefficients(group, lambda t: np.sin(2 * np.pi * t / 40 + 0.5)))[0]
    assert best.family == "wave" and best.r2 > 0.8
    T, phi = parse_form(best.form).args
    assert abs(1.0 / T - 1.0 / 40.0) <= 0.5 / 400.0 and abs(np.sin(phi - 0.5)) < 0.3
    ws = waves(5.0, 405.0)
    assert {w.args[0] for w in ws} >= {400.0, 40.0} and min(w.args[0] for w in ws) >= 32.4
    assert not any(f.key == "wave" for f in families(-1.0, 1.0, True))


def test_a_shape_of_no_simple_family_is_not_close_to_any():
    group = Group("Y", "beta", -1.0, 1.0, 16)
    rng = np.random.default_rng(1)
    c = rng.normal(size=16)  # a wiggle: no single family keeps 90 % of it
    assert closest_forms(group, [float(v) for v in c])[0].r2 < CLOSE
    assert closest_forms(Group("X", "1", multiplier="ast"), [0.1]) == []


def test_the_closest_form_becomes_a_group_with_the_same_curve():
    """The named form as an effect's group (a, b with b times g_max) draws the closed form the
    naming fitted: a + b g over the range, held beyond it."""
    group = Group("N", "beta", -1.0, 1.4, 12, "Y_H")
    best = closest_forms(group, _coefficients(group, lambda z: 0.02 * np.maximum(z - 0.2, 0.0)))[0]
    named, ab = form_group(group, "N", best)
    assert named.text == "N~beta[-1:1.4]:up(0.2)*Y_H"
    z = np.linspace(-1.5, 2.0, 50)
    want = best.a + best.b * np.maximum(np.clip(z, -1.0, 1.4) - 0.2, 0.0)
    np.testing.assert_allclose(curve(named, ab, z), want, atol=1e-12)


def test_symmetric_hinges_are_tried_only_where_the_range_takes_both_signs():
    """Corners at 20-80 % of the smaller side's size; none for a range of one sign."""
    both = [f.text for f in families(-1.0, 1.4, angle=False) if f.key in SYMMETRIC]
    assert both == [f"{k}({c})" for c in ("0.2", "0.35", "0.5", "0.65", "0.8") for k in SYMMETRIC]
    assert not [f for f in families(0.1, 1.4, angle=False) if f.key in SYMMETRIC]


def test_forms_are_fitted_where_the_training_samples_lie():
    """A shape that is a hinge where the samples are and turns down beyond them, at the end of
    its range that no sample reaches: fitted at the samples' quantiles it is named a hinge that
    keeps nearly all of it; on an even grid of the range the end weighs as much as the middle
    and no form comes close."""
    group = Group("N", "beta", -1.0, 1.4, 12)

    def f(z):
        return 0.02 * np.maximum(z - 0.2, 0.0) - 0.1 * np.maximum(z - 1.0, 0.0)

    coef = _coefficients(group, f)
    samples = np.random.default_rng(3).uniform(-1.0, 0.95, 20_000)
    at = np.quantile(samples, np.linspace(0.0, 1.0, 201))
    on_data = closest_forms(group, coef, at=at)[0]
    assert (on_data.family, on_data.formula) == ("hinge", "max(beta - 0.2, 0)")
    assert on_data.r2 > 0.99
    assert closest_forms(group, coef)[0].r2 < CLOSE


def test_a_closed_sway_force_or_yaw_moment_is_completed_by_the_other():
    """A force acting at a point of the hull drives the sway force and the yaw moment: the
    closed form of a lone N (or Y) group gets the other component in the same form, started at
    neutral; a surge force, or one whose other component has a group of its own, is kept."""
    from sweep.diagnose.shaping import with_sibling

    n = Group("N", "beta", -1.0, 1.4, 2, "X_P", form="sin(1)")
    x = Group("X", "U", 0.0, 0.4, 2, form="lin")
    groups, start = with_sibling([x, n], [0.1, 0.2, 0.3, 0.4])
    assert [g.text for g in groups] == [x.text, "YN~beta[-1:1.4]:sin(1)*X_P"]
    assert start == [0.1, 0.2, 0.0, 0.0, 0.3, 0.4]
    y = replace(n, components="Y")
    assert with_sibling([y], [0.5, 0.6])[1] == [0.5, 0.6, 0.0, 0.0]
    # the other component already has a group in this variable, multiplier and scaling
    other = replace(n, form="abs")
    assert with_sibling([n, replace(other, components="Y")], [1, 2, 3, 4])[0][0] == n


def test_corners_lie_at_the_samples_quantiles_too():
    """With the training samples given, hinges and steps are tried at their quantiles as well
    as at shares of the range; symmetric forms at the quantiles of the samples' sizes."""
    samples = np.random.default_rng(4).normal(0.0, 0.1, 5000)
    plain = {f.text for f in families(-3.0, 3.0, angle=True)}
    given = {f.text for f in families(-3.0, 3.0, angle=True, at=samples)}
    assert plain < given
    q95 = float(f"{np.quantile(samples, 0.95):.3g}")
    assert f"up({q95:g})" in given and f"up({q95:g})" not in plain
    s50 = float(f"{np.quantile(np.abs(samples), 0.5):.3g}")
    assert {f"absup({s50:g})", f"oddup({s50:g})", f"absstep({s50:g},0.06)"} <= given
    # the ends of the range are no corners
    assert not [f for f in families(-1.0, 1.0, angle=False, at=[-1.0, 1.0]) if "(-1)" in f.text]


def test_forms_with_fewer_constants_chosen_from_the_data_come_first():
    """The families in order of how many numbers they take from the data (the naming's tie
    prefers fewer, then the larger gain): powers, then (for an angle) harmonics and their odd
    squares, then hinges (a corner), then steps (a corner and a width), whatever the corner,
    in both the fine and the coarse families; a product's count is the sum of its factors'."""
    from sweep.diagnose.naming import Product, complexity

    samples = np.random.default_rng(5).normal(0.0, 0.3, 2000)
    rank = {"lin": 0, "sq": 0, "odd": 0, "cube": 0, "abs": 0, "sin": 1, "cos": 1}
    rank |= {"sinodd": 1, "cosodd": 1}
    rank |= {"up": 2, "down": 2, "absup": 2, "oddup": 2, "step": 3, "absstep": 3}
    for fine in (True, False):
        forms = families(-3.0, 3.0, angle=True, at=samples, fine=fine)
        order = [rank[f.key] for f in forms]
        assert order == sorted(order)
        assert set(order) == {0, 1, 2, 3}
        assert [complexity(f) for f in forms] == sorted(complexity(f) for f in forms)
        assert {f.text for f in forms} >= {"sin(1)", "sinodd(1)", "cosodd(1)"}
    assert 1 not in {rank[f.key] for f in families(-3.0, 3.0, angle=False)}
    assert complexity(Form("sin", (3.0,))) == complexity(Form("odd")) == 0
    assert complexity(Form("up", (0.2,))) == 1 and complexity(Form("step", (0.1, 0.05))) == 2
    assert complexity(Product(Form("up", (0.2,)), Form("step", (0.1, 0.05)))) == 3


@pytest.mark.parametrize("form", ["lin", "sq", "up(0.3)", "absstep(0.5,0.05)", "sin(2)"])
def test_a_form_in_a_fine_basis_is_the_form(form):
    """form_transform: the constant is all ones; a form projected on 40 basis functions draws
    the form (within what 40 cubic pieces over the range can draw of a kink or a steep step)."""
    from mmg.shapes import parse_form
    from sweep.diagnose.naming import form_transform

    group = Group("N", "beta", -1.0, 1.4, 40)
    g = parse_form(form)
    W = form_transform(group, g)
    assert W is not None and W.shape == (40, 2)
    np.testing.assert_array_equal(W[:, 0], 1.0)
    z = np.linspace(-1.0, 1.4, 500)
    want = g(z) / np.max(np.abs(g(np.linspace(-1.0, 1.4, 201))))
    drawn = basis(group, z) @ W[:, 1]
    tol = 0.1 if form.startswith("absstep") else 0.01 if form.startswith("up") else 1e-4
    assert np.max(np.abs(drawn - want)) < tol
    assert form_transform(group, parse_form("up(2)")) is None  # 0 over the range


def test_the_spline_s_closest_form_is_a_candidate_of_the_coarse_families():
    """closest_form: each chosen group's form closest to its spline among the coarse families
    (corners at shares of the range, one step width, no symmetric step), as an effect with its
    coefficients, the lone yaw moment completed by its sway force."""
    from sweep.diagnose.shapes import ShapeSelection
    from sweep.diagnose.shaping import closest_form

    coarse = families(-1.0, 1.4, angle=False, fine=False)
    assert not [f for f in coarse if f.key == "absstep"]
    assert [f.text for f in coarse if f.key == "up"] == [
        f"up({c})" for c in ("-0.52", "-0.16", "0.2", "0.56", "0.92")
    ]
    group = Group("N", "beta", -1.0, 1.4, 12)
    coef = _coefficients(group, lambda z: 0.01 + 0.02 * np.maximum(z - 0.2, 0.0))
    selection = ShapeSelection([group], [coef], [np.zeros((12, 12))], [0.5], [3.0], -50.0)
    effect, start = closest_form(selection)
    assert effect is not None and effect.name == "shape:YN~beta[-1:1.4]:up(0.2)"
    np.testing.assert_allclose(start, [0.0, 0.0, 0.01, 0.02 * 1.2], atol=1e-4)


@pytest.mark.parametrize("key", sorted(FORMS))
def test_every_closed_form_computes_the_same_in_numpy_and_in_the_hook_code(key: str) -> None:
    """Each closed form's numpy value (:meth:`Form.__call__`) and its hook code (evaluated as
    Python, as the kernel compiles it) agree over a range that crosses 0."""
    import math

    args = {0: (), 1: (0.3,), 2: (0.2, 0.1)}[FORMS[key][0]]
    if key == "wave":  # a period, a phase
        args = (1.7, 0.4)
    form = Form(key, args)
    for z in np.linspace(-2.5, 2.5, 41):
        got = eval(form.code("z"), {"math": math, "z": float(z)})  # the generated code itself
        assert got == pytest.approx(float(form(z)), rel=1e-12, abs=1e-15), (key, z)
