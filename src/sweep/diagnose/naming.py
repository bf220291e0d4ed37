"""Name a learned shape afterwards: the simple closed forms closest to it.

A learned shape f(z) (:mod:`mmg.shapes`) is compared, over the range it was learnt on, with
families a naval architect writes forces in: a constant, powers z, z^2, z^3 and their abs forms
z|z|, |z|; hinges max(z - c, 0) and max(c - z, 0) and steps tanh((z - c) / w) at interior
points c; and, for an angle, sin(k z) and cos(k z), k = 1, 2, 3. Each family is fitted as
a + b g(z) by least squares on an even grid of z; the share of the shape's variance it keeps
(R^2) ranks them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mmg.shapes import VARIABLES, Group, curve

FloatArray = NDArray[np.float64]

#: a shape is "close to" a closed form that keeps at least this share of its variance
CLOSE = 0.9
#: points of the grid the families are fitted on
GRID = 201


@dataclass(frozen=True)
class ClosedForm:
    """A closed form fitted to a shape: f(z) ~ a + b g(z), the share of the shape's variance it
    keeps (``r2``), and its formula in the variable's symbol."""

    family: str
    formula: str
    a: float
    b: float
    r2: float


Basis = Callable[[FloatArray], FloatArray]


def _hinge(c: float, sign: float) -> Basis:
    return lambda x: np.maximum(sign * (x - c), 0.0)


def _step(c: float, w: float) -> Basis:
    return lambda x: np.tanh((x - c) / w)


def _harmonic(f: Callable[[FloatArray], FloatArray], k: int) -> Basis:
    return lambda x: f(k * x)


def _families(
    symbol: str, lo: float, hi: float, angle: bool
) -> list[tuple[str, str, Callable[[FloatArray], FloatArray]]]:
    """(family, formula of g, g) of every family over [lo, hi]."""
    z = symbol
    out: list[tuple[str, str, Callable[[FloatArray], FloatArray]]] = [
        ("linear", z, lambda x: x),
        ("square", f"{z}^2", lambda x: x * x),
        ("odd square", f"{z}|{z}|", lambda x: x * np.abs(x)),
        ("cube", f"{z}^3", lambda x: x**3),
        ("abs", f"|{z}|", lambda x: np.abs(x)),
    ]
    width = hi - lo
    for q in (0.2, 0.35, 0.5, 0.65, 0.8):
        c = lo + q * width
        w = 0.1 * width
        out.append(("hinge", f"max({z} - {c:.3g}, 0)", _hinge(c, 1.0)))
        out.append(("hinge", f"max({c:.3g} - {z}, 0)", _hinge(c, -1.0)))
        out.append(("step", f"tanh(({z} - {c:.3g}) / {w:.3g})", _step(c, w)))
    if angle:
        for k in (1, 2, 3):
            out.append(("harmonic", f"sin({k} {z})", _harmonic(np.sin, k)))
            out.append(("harmonic", f"cos({k} {z})", _harmonic(np.cos, k)))
    return out


def closest_forms(group: Group, coefficients: list[float], top: int = 3) -> list[ClosedForm]:
    """The ``top`` closed forms closest to one component's shape of ``group`` (its n
    coefficients), best first (none for a constant group)."""
    if group.variable == "1":
        return []
    var = VARIABLES[group.variable]
    z = np.linspace(group.lo, group.hi, GRID)
    f = curve(group, coefficients, z)
    total = float(((f - f.mean()) ** 2).sum())
    if total <= 0.0:
        return []
    out = []
    for family, formula, g in _families(var.symbol, group.lo, group.hi, var.unit == "rad"):
        G = np.column_stack([np.ones_like(z), g(z)])
        coef, *_ = np.linalg.lstsq(G, f, rcond=None)
        r2 = 1.0 - float(((f - G @ coef) ** 2).sum()) / total
        out.append(ClosedForm(family, formula, float(coef[0]), float(coef[1]), r2))
    out.sort(key=lambda c: -c.r2)
    return out[:top]


__all__ = ["CLOSE", "ClosedForm", "closest_forms"]
