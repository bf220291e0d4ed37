"""Name a learned shape afterwards: the simple closed forms closest to it.

A learned shape f(z) (:mod:`mmg.shapes`) is compared, over the range it was learnt on, with
families a naval architect writes forces in: a constant, powers z, z^2, z^3 and their abs forms
z|z|, |z|; hinges max(z - c, 0) and max(c - z, 0) and steps tanh((z - c) / w) at interior
points c; for a variable that takes both signs, the symmetric hinges max(|z| - c, 0) and
sign(z) max(|z| - c, 0) (a threshold reached on both sides of the ship at once); and, for an
angle, sin(k z) and cos(k z), k = 1, 2, 3. Each family is fitted as
a + b g(z) by least squares at the values z took on the training samples (where the shape acts
on the data; an even grid of z over the range when none are given); the share of the shape's
variance there that it keeps (R^2) ranks them. Over an even grid, the range's ends, which few
samples reach and where the spline is least determined, weigh as much as its middle.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mmg.shapes import SYMMETRIC, VARIABLES, Form, Group, curve, form_scale

FloatArray = NDArray[np.float64]

#: a shape is "close to" a closed form that keeps at least this share of its variance
CLOSE = 0.9
#: points of the grid the families are fitted on
GRID = 201


@dataclass(frozen=True)
class ClosedForm:
    """A closed form fitted to a shape: f(z) ~ a + b g(z), the share of the shape's variance it
    keeps (``r2``), its formula in the variable's symbol and g as a spec writes it (``form``,
    :func:`mmg.shapes.parse_form`)."""

    family: str
    formula: str
    a: float
    b: float
    r2: float
    form: str = ""


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
    "sin": "harmonic",
    "cos": "harmonic",
}


def _round(x: float) -> float:
    """A corner or width to 3 significant digits (as the formula shows it)."""
    return float(f"{x:.3g}")


def families(lo: float, hi: float, angle: bool) -> list[Form]:
    """Every closed form tried over [lo, hi]: powers and abs forms; hinges and steps at 20, 35,
    50, 65 and 80 % of the range (a step 10 % of the range wide); where the range takes both
    signs, the symmetric hinges at 20, 35, 50, 65 and 80 % of the smaller side's size
    min(-lo, hi) (beyond it a hinge acts on one side only: an ordinary hinge); for an angle,
    harmonics."""
    out = [Form(k) for k in ("lin", "sq", "odd", "cube", "abs")]
    width = hi - lo
    side = min(-lo, hi)
    for q in (0.2, 0.35, 0.5, 0.65, 0.8):
        c = _round(lo + q * width)
        out += [Form("up", (c,)), Form("down", (c,)), Form("step", (c, _round(0.1 * width)))]
        if side > 0.0:
            out += [Form(k, (_round(q * side),)) for k in SYMMETRIC]
    if angle:
        out += [Form(k, (float(m),)) for m in (1, 2, 3) for k in ("sin", "cos")]
    return out


def closest_forms(
    group: Group,
    coefficients: list[float],
    top: int = 3,
    at: Sequence[float] | FloatArray | None = None,
) -> list[ClosedForm]:
    """The ``top`` closed forms closest to one component's shape of ``group`` (its n
    coefficients), best first (none for a constant group or a memory: a share of a gap on an
    asinh scale is stated as the steps it lets the control take, not as a form in z). ``at``:
    values of the group's variable where the forms are fitted, e.g. at quantiles of the
    training samples (held within the range, as the shape holds them); None or no finite
    value: an even grid of :data:`GRID` points over the range."""
    if group.variable == "1" or group.control:
        return []
    var = VARIABLES[group.variable]
    z = np.linspace(group.lo, group.hi, GRID)
    if at is not None:
        given = np.asarray(at, dtype=np.float64)
        given = given[np.isfinite(given)]
        if given.size:
            z = np.clip(given, group.lo, group.hi)
    f = curve(group, coefficients, z)
    total = float(((f - f.mean()) ** 2).sum())
    if total <= 0.0:
        return []
    out = []
    for form in families(group.lo, group.hi, var.unit == "rad"):
        g = form(z)
        if float(np.ptp(g)) <= 0.0:
            continue
        G = np.column_stack([np.ones_like(z), g])
        coef, *_ = np.linalg.lstsq(G, f, rcond=None)
        r2 = 1.0 - float(((f - G @ coef) ** 2).sum()) / total
        out.append(
            ClosedForm(
                FAMILY[form.key],
                form.formula(var.symbol),
                float(coef[0]),
                float(coef[1]),
                r2,
                form.text,
            )
        )
    out.sort(key=lambda c: -c.r2)
    return out[:top]


def form_group(group: Group, component: str, closed: ClosedForm) -> tuple[Group, list[float]]:
    """The closed-form group of one component of a spline ``group`` named by ``closed``, and
    its coefficients (a, b) as the effect takes them (b times g_max: :func:`form_scale`)."""
    named = Group(
        component,
        group.variable,
        group.lo,
        group.hi,
        2,
        group.multiplier,
        group.scale,
        closed.form,
    )
    return named, [closed.a, closed.b * form_scale(named)]


__all__ = ["CLOSE", "FAMILY", "ClosedForm", "closest_forms", "families", "form_group"]
