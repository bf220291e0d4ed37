"""Name a learned shape afterwards: the simple closed forms closest to it.

A learned shape f(z) (:mod:`mmg.shapes`) is compared, over the range it was learnt on, with
families a naval architect writes forces in (:func:`families`): a constant, powers z, z^2,
z^3 and their abs forms z|z|, |z|; hinges max(z - c, 0) and max(c - z, 0) and steps
tanh((z - c) / w) at interior corners c (shares of the range and quantiles of the training
samples); for a variable that takes both signs, the symmetric hinges max(|z| - c, 0) and
sign(z) max(|z| - c, 0) and the symmetric step tanh((|z| - c) / w) (a threshold reached on
both sides of the ship at once); and, for an angle, sin(k z) and cos(k z), k = 1, 2, 3, and
the odd squares sin(z)|sin(z)| and cos(z)|cos(z)| (a cross-flow in the drift angle).

Two comparisons use them. :func:`closest_forms` fits each family as a + b g(z) by least
squares to the shape at the values z took on the training samples (an even grid of z over the
range when none are given) and ranks them by the share of the shape's variance there that they
keep (R^2): the report's "closest forms". The diagnosis names a shape on the trajectories
instead (:func:`sweep.diagnose.shaping.named_form`): :func:`form_transform` draws each form on
a fine spline basis, so that its trajectory columns are those of the basis functions combined,
and the forms are ranked by their held-out gain.

A surface (a shape of two variables) is named by a product of one closed form of each
variable, g1(z) g2(z2) (:class:`Product`, :func:`products`): on the trajectories, drawn in the
surface's basis (:func:`product_transform`), and by its likeness to the fitted surface where
the training runs went (:func:`closest_products`, :func:`product_r2`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from mmg.shapes import (
    CONTROLS,
    FORM_GRID,
    MAX_BASIS,
    MEMORY_FORMS,
    SYMMETRIC,
    VARIABLES,
    Form,
    Group,
    basis,
    basis2,
    curve,
    form_scale,
    memory_coefficients,
    memory_steps,
    surface,
)

FloatArray = NDArray[np.float64]

#: a shape is "close to" a closed form that keeps at least this share of its variance
CLOSE = 0.9
#: points of the grid the families are fitted on
GRID = 201


@dataclass(frozen=True)
class ClosedForm:
    """A closed form fitted to a shape: f(z) ~ a + b g(z), the share of the shape's variance it
    keeps (``r2``), its formula in the variable's symbol and g as a spec writes it (``form``,
    :func:`mmg.shapes.parse_form`); ``share``: where it was compared on the trajectories
    (:func:`sweep.diagnose.shaping.named_form`), the share of the shape's linearised held-out
    gain it keeps in the shape's place (None where not)."""

    family: str
    formula: str
    a: float
    b: float
    r2: float
    form: str = ""
    share: float | None = None


#: the family of each closed form (:data:`mmg.shapes.FORMS`)
FAMILY = {
    "lin": "linear",
    "sq": "square",
    "odd": "odd square",
    "cube": "cube",
    "abs": "abs",
    "up": "hinge",
    "down": "hinge",
    "absup": "symmetric hinge",
    "oddup": "symmetric hinge",
    "step": "step",
    "absstep": "symmetric step",
    "sin": "harmonic",
    "cos": "harmonic",
    "sinodd": "odd square of a harmonic",
    "cosodd": "odd square of a harmonic",
    "wave": "wave",
}

#: closed forms whose numbers are fixed multiples, not taken from the data (a harmonic's k)
FIXED_NUMBERS = ("sin", "cos", "sinodd", "cosodd")


def complexity(form: Form | Product) -> int:
    """How many of a closed form's numbers are taken from the data: 0 for powers, abs forms and
    harmonics (k a fixed multiple), 1 for a hinge (its corner), 2 for a step (a corner and a
    width); a product's the sum of its factors'. Among forms that gain as much, the one of
    fewer such numbers is the name, then the one that gains most."""
    if isinstance(form, Product):
        return complexity(form.first) + complexity(form.second)
    return 0 if form.key in FIXED_NUMBERS else len(form.args)


def _round(x: float) -> float:
    """A corner or width to 3 significant digits (as the formula shows it)."""
    return float(f"{x:.3g}")


#: interior corners of hinges and steps, as shares of the range (of the smaller side's size for
#: the symmetric forms)
RANGE_CORNERS = (0.2, 0.35, 0.5, 0.65, 0.8)
#: ... and as quantiles of the training samples (of their sizes |z| for the symmetric forms):
#: where the data are dense, a corner between two range shares is found too
SAMPLE_CORNERS = tuple(q / 20 for q in range(1, 20))
#: widths of a step, as shares of the range (of the smaller side's size for a symmetric step)
STEP_WIDTHS = (0.1, 0.02)


def _corners(
    shares: Sequence[float],
    size: float,
    start: float,
    within: tuple[float, float],
    samples: FloatArray | None,
) -> list[float]:
    """Corners start + share x size, and the samples' :data:`SAMPLE_CORNERS` quantiles, rounded
    (:func:`_round`), strictly inside ``within``, without repeats, in ascending order."""
    cs = [start + q * size for q in shares]
    if samples is not None and samples.size:
        cs += [float(v) for v in np.quantile(samples, SAMPLE_CORNERS)]
    lo, hi = within
    return sorted({_round(c) for c in cs if lo < _round(c) < hi})


#: the variables whose closed forms include waves of a period of their own (:func:`waves`): a
#: force that comes and goes in time
WAVE_VARIABLES = ("t",)
#: a wave's shortest period, in knot intervals of the naming's grid (:data:`MAX_BASIS` basis
#: functions over the range): a shorter one is not resolved by the columns it is compared on
WAVE_KNOTS = 3
#: a wave's phases tried: this many over [0, pi) (its coefficient b takes either sign)
WAVE_PHASES = 6


def waves(lo: float, hi: float) -> list[Form]:
    """Waves sin(2 pi z / T + phi) over [lo, hi]: k half-cycles over the range (T = 2 (hi - lo)
    / k), from one whole cycle (k = 2) to the shortest period of :data:`WAVE_KNOTS` knot
    intervals, each at :data:`WAVE_PHASES` phases; a period and a phase are numbers taken from
    the data, refined by output error (:func:`sweep.diagnose.corners.fit_numbers`)."""
    width = hi - lo
    shortest = WAVE_KNOTS * width / (MAX_BASIS - 3)
    return [
        Form("wave", (_round(2.0 * width / k), _round(np.pi * m / WAVE_PHASES)))
        for k in range(2, int(2.0 * width / shortest + 1e-9) + 1)
        for m in range(WAVE_PHASES)
    ]


def families(
    lo: float,
    hi: float,
    angle: bool,
    at: Sequence[float] | FloatArray | None = None,
    fine: bool = True,
    wave: bool = False,
) -> list[Form]:
    """Every closed form tried over [lo, hi], simpler families first (a form whose constants
    are fixed before a corner or a width is chosen from the data comes before one that has
    them): powers and abs forms; for an angle, harmonics; hinges at :data:`RANGE_CORNERS` of the
    range and, where the range takes both signs, the symmetric hinges at the same shares of the
    smaller side's size min(-lo, hi) (beyond it a threshold acts on one side only: an ordinary
    hinge); then steps, a corner and a width. ``fine`` adds corners at the training samples'
    :data:`SAMPLE_CORNERS` quantiles (given their values ``at``; of their sizes |z| for the
    symmetric forms), the narrower steps of :data:`STEP_WIDTHS` and the symmetric steps;
    an angle's harmonics come with the odd squares of the first, sin(z)|sin(z)| and
    cos(z)|cos(z)| (a cross-flow force in the drift angle, a wind force in its angle);
    without it, steps are 10 % of the range wide (the forms fitted to a spline,
    :func:`sweep.diagnose.shaping.closest_form`). ``wave``: the waves of :func:`waves` last
    (a period and a phase each)."""
    out = [Form(k) for k in ("lin", "sq", "odd", "cube", "abs")]
    if angle:
        out += [Form(k, (float(m),)) for m in (1, 2, 3) for k in ("sin", "cos")]
        out += [Form(k, (1.0,)) for k in ("sinodd", "cosodd")]
    width = hi - lo
    side = min(-lo, hi)
    hinges: list[Form] = []
    steps: list[Form] = []
    if not fine:
        for q in RANGE_CORNERS:
            c = _round(lo + q * width)
            hinges += [Form("up", (c,)), Form("down", (c,))]
            steps.append(Form("step", (c, _round(0.1 * width))))
            if side > 0.0:
                hinges += [Form(k, (_round(q * side),)) for k in SYMMETRIC]
    else:
        z = None
        if at is not None:
            given = np.asarray(at, dtype=np.float64)
            z = np.clip(given[np.isfinite(given)], lo, hi)
        for c in _corners(RANGE_CORNERS, width, lo, (lo, hi), z):
            hinges += [Form("up", (c,)), Form("down", (c,))]
            steps += [Form("step", (c, _round(w * width))) for w in STEP_WIDTHS]
        if side > 0.0:
            sizes = None if z is None else np.abs(z)
            for c in _corners(RANGE_CORNERS, side, 0.0, (0.0, side), sizes):
                hinges += [Form(k, (c,)) for k in SYMMETRIC]
                steps += [Form("absstep", (c, _round(w * side))) for w in STEP_WIDTHS]
    return out + hinges + steps + (waves(lo, hi) if wave else [])


def group_families(
    group: Group, at: Sequence[float] | FloatArray | None = None, fine: bool = True
) -> list[Form]:
    """:func:`families` over the range of ``group``'s variable, as its variable takes them:
    an angle's with its harmonics, time's with its waves (:data:`WAVE_VARIABLES`)."""
    angle = VARIABLES[group.variable].unit == "rad"
    wave = group.variable in WAVE_VARIABLES
    return families(group.lo, group.hi, angle, at, fine, wave)


def fit_points(group: Group, at: Sequence[float] | FloatArray | None) -> FloatArray:
    """Where forms are fitted: ``at`` held within the range (its finite values), else an even
    grid of :data:`GRID` points over the range."""
    z = np.linspace(group.lo, group.hi, GRID)
    if at is not None:
        given = np.asarray(at, dtype=np.float64)
        given = given[np.isfinite(given)]
        if given.size:
            z = np.clip(given, group.lo, group.hi)
    return z


def fitted_form(
    group: Group, coefficients: Sequence[float], form: Form, z: FloatArray
) -> ClosedForm | None:
    """``form`` fitted as a + b g(z) by least squares to one component's shape of ``group``
    at the points z, with the share of the shape's variance there that it keeps (None where
    the shape or the form is flat)."""
    f = curve(group, coefficients, z)
    total = float(((f - f.mean()) ** 2).sum())
    g = form(z)
    if total <= 0.0 or float(np.ptp(g)) <= 0.0:
        return None
    G = np.column_stack([np.ones_like(z), g])
    coef, *_ = np.linalg.lstsq(G, f, rcond=None)
    r2 = 1.0 - float(((f - G @ coef) ** 2).sum()) / total
    symbol = VARIABLES[group.variable].symbol
    return ClosedForm(
        FAMILY[form.key], form.formula(symbol), float(coef[0]), float(coef[1]), r2, form.text
    )


def closest_forms(
    group: Group,
    coefficients: list[float],
    top: int = 3,
    at: Sequence[float] | FloatArray | None = None,
    fine: bool = True,
) -> list[ClosedForm]:
    """The ``top`` closed forms closest to one component's shape of ``group`` (its n
    coefficients), best first (none for a constant group or a memory: a share of a gap on an
    asinh scale is stated as the steps it lets the control take, not as a form in z). ``at``:
    values of the group's variable where the forms are fitted, e.g. at quantiles of the
    training samples (held within the range, as the shape holds them); None or no finite
    value: an even grid of :data:`GRID` points over the range. ``fine``: the families of
    :func:`families`."""
    if group.variable == "1" or group.control:
        return []
    z = fit_points(group, at)
    out = [
        c
        for form in group_families(group, at, fine)
        if (c := fitted_form(group, coefficients, form, z)) is not None
    ]
    out.sort(key=lambda c: -c.r2)
    return out[:top]


def closest_products(
    group: Group,
    coefficients: Sequence[float] | FloatArray,
    z: FloatArray,
    z2: FloatArray,
    top: int = 3,
) -> list[ClosedForm]:
    """The ``top`` products of closed forms g1(z) g2(z2) closest to one component's surface of
    a shape of two variables ``group`` (its n n2 ``coefficients``), best first: every pair of
    the coarse families of each variable (:func:`families`, ``fine`` off: corners at shares of
    its range) fitted as a + b g1(z) g2(z2) by least squares to the surface at the pairs
    (z, z2) the training runs took (held within the rectangle, as the surface holds them), and
    ranked by the share of the surface's variance there that they keep (R^2; ``form`` is
    ``g1&g2``, ``b`` the coefficient of g1 g2 itself). None for a surface that is flat there
    or a spline of one variable. A product is the simplest name of an interaction, a force
    that one variable scales and another shapes (a yaw moment in u|u| times a function of
    the wind's angle), and, unlike the surface, it says what happens where the training runs
    did not go."""
    if not group.tensor or group.form or len(coefficients) != group.size:
        return []
    z = np.clip(np.asarray(z, dtype=np.float64), group.lo, group.hi)
    z2 = np.clip(np.asarray(z2, dtype=np.float64), group.lo2, group.hi2)
    f = surface(group, coefficients, z, z2)
    fc = f - f.mean()
    total = float((fc * fc).sum())
    if z.size < 3 or float(np.ptp(f)) <= 1e-12 * max(1.0, float(np.max(np.abs(f)))):
        return []  # flat where the runs went
    first = families(group.lo, group.hi, VARIABLES[group.variable].unit == "rad", fine=False)
    second = families(group.lo2, group.hi2, VARIABLES[group.variable2].unit == "rad", fine=False)
    G1 = np.column_stack([form(z) for form in first])
    G2 = np.column_stack([form(z2) for form in second])
    G = G1[:, :, None] * G2[:, None, :]  # (K, m1, m2): every product at every sample
    Gc = G - G.mean(axis=0)
    var = (Gc * Gc).sum(axis=0)
    cov = np.einsum("k,kij->ij", fc, Gc)
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = np.where(var > 1e-12 * total, cov * cov / (var * total), 0.0)
        b = np.where(var > 1e-12 * total, cov / var, 0.0)
    a = f.mean() - b * G.mean(axis=0)
    s1, s2 = VARIABLES[group.variable].symbol, VARIABLES[group.variable2].symbol
    out: list[ClosedForm] = []
    for k in np.argsort(-r2, axis=None)[: max(top, 0)]:
        i, j = np.unravel_index(k, r2.shape)
        if r2[i, j] <= 0.0:
            break
        g1, g2 = first[i], second[j]
        out.append(
            ClosedForm(
                f"{FAMILY[g1.key]} x {FAMILY[g2.key]}",
                f"{g1.formula(s1)} {g2.formula(s2)}",
                float(a[i, j]),
                float(b[i, j]),
                float(r2[i, j]),
                f"{g1.text}&{g2.text}",
            )
        )
    return out


@dataclass(frozen=True)
class Product:
    """A product of two closed forms g1(z) g2(z2), the name of a surface (a shape of two
    variables): as a spec writes it, ``g1&g2``."""

    first: Form
    second: Form

    @property
    def text(self) -> str:
        """As a spec writes it: ``odd&sin(1)``."""
        return f"{self.first.text}&{self.second.text}"

    @property
    def family(self) -> str:
        """The families of its factors: ``odd square x harmonic``."""
        return f"{FAMILY[self.first.key]} x {FAMILY[self.second.key]}"

    def formula(self, z: str, z2: str) -> str:
        """g1 g2 in the variables' symbols."""
        return f"{self.first.formula(z)} {self.second.formula(z2)}"


#: points along each variable of the grid over a surface's rectangle on which a product of
#: closed forms is drawn in the surface's basis (:func:`product_transform`)
PRODUCT_GRID = 41


def products(group: Group) -> list[Product]:
    """Every product of the coarse families (:func:`families`, ``fine`` off) of a surface's two
    variables over their ranges."""
    first = families(group.lo, group.hi, VARIABLES[group.variable].unit == "rad", fine=False)
    second = families(group.lo2, group.hi2, VARIABLES[group.variable2].unit == "rad", fine=False)
    return [Product(a, b) for a in first for b in second]


def product_r2(
    group: Group,
    coefficients: Sequence[float] | FloatArray,
    product: Product,
    z: FloatArray,
    z2: FloatArray,
) -> float:
    """The share of the surface ``group``'s variance (its ``coefficients``) at the training
    samples' pairs (z, z2) that ``product``, fitted as a + b g1 g2 by least squares, keeps
    (R^2; 0 where the surface or the product is flat there)."""
    z = np.clip(np.asarray(z, dtype=np.float64), group.lo, group.hi)
    z2 = np.clip(np.asarray(z2, dtype=np.float64), group.lo2, group.hi2)
    f = surface(group, coefficients, z, z2)
    g = product.first(z) * product.second(z2)
    total = float(((f - f.mean()) ** 2).sum())
    if z.size < 3 or total <= 0.0 or float(np.ptp(g)) <= 0.0:
        return 0.0
    G = np.column_stack([np.ones_like(g), g])
    coef, *_ = np.linalg.lstsq(G, f, rcond=None)
    return 1.0 - float(((f - G @ coef) ** 2).sum()) / total


def product_transform(
    group: Group, product: Product, z: FloatArray, z2: FloatArray
) -> FloatArray | None:
    """(n n2, 2) the constant and g1(z) g2(z2) / g_max of ``product`` in the basis of the
    surface ``group`` (as :func:`form_transform` for one variable): g projected by least
    squares at the training samples' pairs (z, z2) and at an even grid over the rectangle, so
    that every basis function is held. None where the product is flat."""
    grid = np.linspace(0.0, 1.0, PRODUCT_GRID)
    G1, G2 = np.meshgrid(
        group.lo + grid * (group.hi - group.lo), group.lo2 + grid * (group.hi2 - group.lo2)
    )
    x = np.concatenate([G1.ravel(), np.clip(z, group.lo, group.hi)])
    x2 = np.concatenate([G2.ravel(), np.clip(z2, group.lo2, group.hi2)])
    g = product.first(x) * product.second(x2)
    g_max = float(
        np.max(np.abs(product.first(np.linspace(group.lo, group.hi, FORM_GRID))))
        * np.max(np.abs(product.second(np.linspace(group.lo2, group.hi2, FORM_GRID))))
    )  # (as mmg.shapes.form_scale takes it)
    if g_max <= 0.0 or float(np.ptp(g)) <= 0.0:
        return None
    d, *_ = np.linalg.lstsq(basis2(group, x, x2), g / g_max, rcond=None)
    return np.column_stack([np.ones(group.size), d])


#: values of a memory's coefficient tried when a closed form is fitted to a memory's spline
MEMORY_GRID = 1001


def memory_forms(group: Group, coefficients: Sequence[float]) -> list[ClosedForm]:
    """The closed forms of a memory (:data:`mmg.shapes.MEMORY_FORMS`: a lag, a rate limit,
    play) fitted to a memory group's spline share f(z), best first: each form's coefficient c
    in [0, 1] chosen on a grid of :data:`MEMORY_GRID` values to match f at an even grid of z
    over the range (the asinh scale of the gap: small gaps as densely as large ones), and the
    share of the memory it keeps, 1 - sum (f - f_form)^2 / sum f^2 (``r2``; ``a`` is c; of a
    gap signed away from the control's zero ``a`` is the moves away's c, ``b`` the moves back's,
    each chosen on its own side of the gap). A
    form that keeps none of it (its best c is 0, the paper's model) names nothing and is left
    out; none for a spline that leaves no gap open."""
    if not group.control or group.form:
        return []
    z = np.linspace(group.lo, group.hi, GRID)
    f = curve(group, coefficients, z)
    total = float((f * f).sum())
    if total <= 0.0:
        return []
    e = np.sinh(z) * CONTROLS[group.control].quantum
    trials = np.linspace(0.0, 1.0, MEMORY_GRID)
    k = memory_coefficients(group.variable)
    # of a gap signed away from the control's zero, the moves away (e > 0) and back apart
    sides = [e > 0.0, e <= 0.0] if k == 2 else [np.ones(e.size, dtype=bool)]
    out = []
    for key, (meaning, _, _) in MEMORY_FORMS.items():
        named = replace(group, n=k, form=key)
        sse = np.array(
            [((f - memory_steps(named, [c] * k, e)[0]) ** 2) for c in trials]
        )  # (trials, points)
        per_side = [sse[:, m].sum(axis=1) for m in sides]
        cs = [float(trials[int(np.argmin(v))]) for v in per_side]
        least = float(sum(v.min() for v in per_side))
        if least >= total:
            continue
        b = cs[1] if k == 2 else 0.0
        out.append(
            ClosedForm(meaning, named.formula(group.control), cs[0], b, 1.0 - least / total, key)
        )
    out.sort(key=lambda c: -c.r2)
    return out


def memory_named(group: Group, form: ClosedForm) -> tuple[Group, list[float]]:
    """The memory ``group``'s closed form ``form`` (of :func:`memory_forms`) as a group, and
    its coefficients as a start: c, and of a gap signed away from the control's zero the
    moves back's c too."""
    k = memory_coefficients(group.variable)
    return replace(group, n=k, form=form.form), [form.a, form.b][:k]


def form_transform(
    group: Group, form: Form, at: Sequence[float] | FloatArray | None = None
) -> FloatArray | None:
    """(n, 2) the constant and g(z) / g_max of ``form`` in the spline basis of ``group`` (its
    n coefficients each): the constant is all ones (the basis sums to 1 over the range); g is
    projected by least squares at ``at`` (the training samples' quantiles) and at an even grid
    of the range, so that every basis function is held. A closed form's trajectory columns are
    then the group's columns times these (:meth:`sweep.diagnose.shapes.ShapeColumns._fit`).
    None where the form is flat over the range."""
    z = np.concatenate([np.linspace(group.lo, group.hi, GRID), fit_points(group, at)])
    g = form(z)
    g_max = float(np.max(np.abs(form(np.linspace(group.lo, group.hi, FORM_GRID)))))
    if g_max <= 0.0 or float(np.ptp(g)) <= 0.0:
        return None
    d, *_ = np.linalg.lstsq(basis(group, z), g / g_max, rcond=None)
    return np.column_stack([np.ones(group.n), d])


def form_group(group: Group, component: str, closed: ClosedForm) -> tuple[Group, list[float]]:
    """The closed-form group of one component of a spline ``group`` named by ``closed`` (of a
    surface, a product of two closed forms: :func:`closest_products`), and its coefficients
    (a, b) as the effect takes them (b times g_max: :func:`form_scale`)."""
    named = Group(
        component,
        group.variable,
        group.lo,
        group.hi,
        2,
        group.multiplier,
        group.scale,
        closed.form,
        # a product of closed forms: the second variable's range, no basis
        group.variable2,
        group.lo2,
        group.hi2,
        1,
    )
    return named, [closed.a, closed.b * form_scale(named)]


__all__ = [
    "CLOSE",
    "FAMILY",
    "ClosedForm",
    "Product",
    "closest_forms",
    "closest_products",
    "families",
    "fitted_form",
    "form_group",
    "form_transform",
    "group_families",
    "memory_forms",
    "memory_named",
    "product_r2",
    "product_transform",
    "products",
    "waves",
]
