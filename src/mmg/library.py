"""The library of candidate force terms from which missing physics is discovered.

Every term adds a force or moment at midship, linear in one dimensionless coefficient C, written
like the MMG model's own terms (paper Eqs. (4)-(28)):

    X = 0.5 rho L_pp d C g,   Y = 0.5 rho L_pp d C g,   N = 0.5 rho L_pp^2 d C g

with g [m^2/s^2] a function of the state (through the water), the controls, the true wind, the
heading, the position and the time (:class:`Term` lists the names an expression may use).
``X_...``, ``Y_...`` and ``N_...`` are the equations a term enters. Terms with a *shape*
(:class:`Shape`: a time constant, or the centre and width of a step) are searched on a grid of
shapes (:func:`library_columns`) and then fitted within a box around the chosen point
(:func:`shape_box`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: speed that keeps third-order terms finite at rest [m/s] (a few per cent of the service speed)
U_0 = 0.05
#: reference speed of terms with no velocity in them (heading, position, time, constant) [m/s]
U_REF = 1.0
#: reference time of the time terms [s] (about the length of a recorded run)
T_REF = 1000.0


@dataclass(frozen=True)
class Shape:
    """A shape parameter of a library term: a time constant, or the centre or width of a step
    in a variable. The term is linear in its coefficient, not in its shape: the proposal searches
    the shape on a grid (:func:`library_columns`), the trajectory fits then move it within a box
    around the grid point (:func:`shape_box`)."""

    name: str  # placeholder in the term's expression and formula, e.g. ``tau``
    unit: str
    role: str  # "time constant", "centre" or "width"
    variable: str = ""  # x0 or y0 for a centre or width
    default: float = 1.0  # value of a term rebuilt by name alone (a parameter file sets its own)
    lower: float = -1e4  # ... and its search interval then
    upper: float = 1e4


#: the time constant of a transient term [s]
TAU = Shape("tau", "s", "time constant", default=300.0, lower=1.0, upper=1e5)
#: time constants of the grid [s], half a decade apart
TAU_GRID = (100.0, 300.0, 1000.0)
#: centres of a step at these quantiles of the variable over the training windows ...
CENTRE_QUANTILES = (0.1, 0.3, 0.5, 0.7, 0.9)
#: ... and widths at these shares of its 5-95 % range
WIDTH_SHARES = (0.1, 0.3)


def _across(variable: str) -> tuple[Shape, Shape]:
    return (
        Shape("c", "m", "centre", variable, default=0.0),
        Shape("W", "m", "width", variable, default=10.0, lower=1e-3, upper=1e4),
    )


@dataclass(frozen=True)
class Term:
    """One library term: ``id`` (equation_name), its expression g, formula and kind.

    ``expr`` is one scalar Python expression, compiled into the hook of a generated effect
    (:mod:`mmg.discovered`), over these names: u, v_m [m/s], r [rad/s], psi [rad], delta [rad],
    n_p [rev/s], x0, y0 [m], t [s] (the recording's clock: the file's time column), T_ref
    (:data:`T_REF`), U2 = u^2 + v_m^2, Ue = sqrt(U2 + U_0^2), rL = r L_pp, nD = n_p D_p [m/s],
    uA, vA (apparent wind [m/s], see :func:`mmg.wind.apparent_wind`),
    wT = rho_A A_T / (rho L_pp d), wL = rho_A A_L / (rho L_pp d), Lp = L_pp,
    ast = 1 if u < 0 (astern) else 0, rev = 1 if n_p < 0 else 0, U_ref, abs and math (its sin and
    cos compile to the vectorisable ones of :mod:`mmg.trig`).

    Kinds: hull terms are products of u, v_m and r L_pp (third-order ones divided by U_e, which
    keeps them finite at rest); propeller terms use n_p D_p; rudder terms delta; wind terms the
    apparent wind scaled to the above-water areas; heading and position terms a force fixed to
    the basin (linear in x0, y0, or a step tanh((y0 - c) / W)); time terms a force that builds up
    or dies away over a run (polynomials of t / T_ref, exp(-t / tau), 1 - exp(-t / tau)).

    ``parts``, when given, are the (equation, expression, formula) of a term that enters several
    equations with one coefficient (then ``expr`` and ``formula`` describe it as a whole; e.g.
    ``E_x0``, a steady force along the basin's x0 axis resolved on the ship's axes).
    ``shape``: its shape parameters, written ``{name}`` in the expression and formula; they are
    parameters of the generated effect beside the coefficient (``tau_N_bt``, ``c_Y_Usy``)."""

    id: str
    expr: str
    formula: str  # g in the paper's notation
    kind: str  # hull, propeller, rudder, wind, quadrant, heading, position, time
    parts: tuple[tuple[str, str, str], ...] = ()
    shape: tuple[Shape, ...] = ()

    @property
    def components(self) -> tuple[tuple[str, str, str], ...]:
        """(equation, expression, formula) of every equation the term enters."""
        return self.parts or ((self.id[0], self.expr, self.formula),)

    @property
    def equation(self) -> str:
        """The equations the term enters: ``X``, ``Y``, ``N`` or several (``XY``)."""
        return "".join(e for e, _, _ in self.components)

    @property
    def coefficient(self) -> str:
        """Name of the term's coefficient (a parameter of the generated effect)."""
        return f"C_{self.id}"

    def shape_param(self, name: str) -> str:
        """Name of the shape parameter ``name`` (its placeholder, e.g. ``tau``) of this term in
        the generated effect, e.g. ``tau_N_bt``."""
        return f"{name}_{self.id}"

    def written(self, text: str, prefix: str = "") -> str:
        """``text`` with the shape placeholders replaced by the parameter names (after
        ``prefix``, e.g. ``e.`` in the generated code)."""
        if not self.shape:
            return text
        return text.format(**{s.name: prefix + self.shape_param(s.name) for s in self.shape})

    def force_formula(self) -> str:
        """The term as a force in the paper's notation, with units."""
        out = []
        for eq, _, formula in self.components:
            scale = "0.5 rho L_pp^2 d" if eq == "N" else "0.5 rho L_pp d"
            unit = "N m" if eq == "N" else "N"
            out.append(f"{eq} += {scale} {self.coefficient} {self.written(formula)}  [{unit}]")
        return ", ".join(out)


def _t(
    eqs: str, name: str, expr: str, formula: str, kind: str, shape: tuple[Shape, ...] = ()
) -> list[Term]:
    return [Term(f"{e}_{name}", expr, formula, kind, shape=shape) for e in eqs]


_TERMS: list[Term] = [
    # hull: second order (u, v_m, r L) with |.| forms, and third order / U_e
    *_t("X", "uau", "u * abs(u)", "u|u|", "hull"),
    *_t("X", "uuu", "u * u * u / Ue", "u^3 / U_e", "hull"),
    # resistance beyond the quadratic law (a resistance curve in u: wave making grows with speed)
    *_t("X", "uuau", "u * u * abs(u) / U_ref", "u^2 |u| / U_ref", "hull"),
    *_t("X", "uuuau", "u * u * u * abs(u) / (U_ref * U_ref)", "u^3 |u| / U_ref^2", "hull"),
    *_t("XYN", "vv", "v_m * v_m", "v_m^2", "hull"),
    *_t("XYN", "vr", "v_m * rL", "v_m r L_pp", "hull"),
    *_t("XYN", "rr", "rL * rL", "(r L_pp)^2", "hull"),
    *_t("YN", "uv", "u * v_m", "u v_m", "hull"),
    *_t("YN", "ur", "u * rL", "u r L_pp", "hull"),
    *_t("XYN", "uav", "u * abs(v_m)", "u |v_m|", "hull"),
    *_t("YN", "vav", "v_m * abs(v_m)", "v_m |v_m|", "hull"),
    *_t("YN", "rar", "rL * abs(rL)", "r L_pp |r L_pp|", "hull"),
    *_t("YN", "var", "v_m * abs(rL)", "v_m |r L_pp|", "hull"),
    *_t("YN", "avr", "abs(v_m) * rL", "|v_m| r L_pp", "hull"),
    *_t("YN", "vvv", "v_m * v_m * v_m / Ue", "v_m^3 / U_e", "hull"),
    *_t("YN", "rrr", "rL * rL * rL / Ue", "(r L_pp)^3 / U_e", "hull"),
    *_t("YN", "vvr", "v_m * v_m * rL / Ue", "v_m^2 r L_pp / U_e", "hull"),
    *_t("YN", "vrr", "v_m * rL * rL / Ue", "v_m (r L_pp)^2 / U_e", "hull"),
    *_t("YN", "s3b", "v_m * (3.0 * U2 - 4.0 * v_m * v_m) / Ue", "-U^2 sin(3 beta)", "hull"),
    # propeller
    *_t("XYN", "nn", "nD * abs(nD)", "n_p |n_p| D_p^2", "propeller"),
    *_t("XYN", "nu", "nD * u", "n_p D_p u", "propeller"),
    *_t("YN", "nv", "abs(nD) * v_m", "|n_p| D_p v_m", "propeller"),
    *_t("YN", "nr", "abs(nD) * rL", "|n_p| D_p r L_pp", "propeller"),
    # rudder
    *_t("YN", "duu", "delta * u * abs(u)", "delta u|u|", "rudder"),
    *_t("YN", "dnn", "delta * nD * nD", "delta (n_p D_p)^2", "rudder"),
    *_t("YN", "dddu", "delta * delta * delta * u * abs(u)", "delta^3 u|u|", "rudder"),
    # ... and in the propeller slipstream (the rudder's lift curve bends off the straight line
    # at large angles, by the flow the propeller drives as by the ship's speed)
    *_t("YN", "dddnn", "delta * delta * delta * nD * nD", "delta^3 (n_p D_p)^2", "rudder"),
    # ... and the lateral part of a force normal to the rudder: a normal force growing like
    # sin(delta), turned through delta, acts across the ship as sin(delta) cos(delta) (the
    # shape of F_N cos(delta) in Eqs. (15)-(16) at a fixed inflow), by the slipstream or the speed
    *_t(
        "YN",
        "scdnn",
        "math.sin(delta) * math.cos(delta) * nD * nD",
        "sin(delta) cos(delta) (n_p D_p)^2",
        "rudder",
    ),
    *_t(
        "YN",
        "scduu",
        "math.sin(delta) * math.cos(delta) * u * abs(u)",
        "sin(delta) cos(delta) u|u|",
        "rudder",
    ),
    *_t("X", "dduu", "delta * delta * u * abs(u)", "delta^2 u|u|", "rudder"),
    *_t("X", "ddnn", "delta * delta * nD * nD", "delta^2 (n_p D_p)^2", "rudder"),
    # quadrants: astern (u < 0) and reversed propeller (n_p < 0)
    *_t("X", "ast_uu", "ast * u * u", "[u < 0] u^2", "quadrant"),
    *_t("XYN", "rev_nn", "rev * nD * nD", "[n_p < 0] (n_p D_p)^2", "quadrant"),
    *_t("YN", "ast_vav", "ast * v_m * abs(v_m)", "[u < 0] v_m |v_m|", "quadrant"),
    *_t("YN", "ast_rar", "ast * rL * abs(rL)", "[u < 0] r L_pp |r L_pp|", "quadrant"),
    # apparent wind (sign of the scaled apparent wind components)
    *_t("X", "wuu", "wT * uA * abs(uA)", "(rho_A A_T / rho L_pp d) u_A|u_A|", "wind"),
    *_t("YN", "wvv", "wL * vA * abs(vA)", "(rho_A A_L / rho L_pp d) v_A|v_A|", "wind"),
    *_t("YN", "wuv", "wL * uA * vA", "(rho_A A_L / rho L_pp d) u_A v_A", "wind"),
    # a force fixed to the basin: constant, with the heading, with the position (and speed)
    *_t("XYN", "one", "1.0", "U_ref^2", "heading"),
    *_t("XYN", "cpsi", "math.cos(psi)", "U_ref^2 cos(psi)", "heading"),
    *_t("XYN", "spsi", "math.sin(psi)", "U_ref^2 sin(psi)", "heading"),
    *_t("XYN", "x", "x0 / Lp", "U_ref^2 x0 / L_pp", "position"),
    *_t("XYN", "y", "y0 / Lp", "U_ref^2 y0 / L_pp", "position"),
    *_t("XYN", "Uy", "U2 * y0 / Lp", "U^2 y0 / L_pp", "position"),
    *_t("XYN", "Ux", "U2 * x0 / Lp", "U^2 x0 / L_pp", "position"),
    # a force that changes over the run (on the recording's clock)
    *_t("XYN", "t", "t / T_ref", "U_ref^2 t / T_ref", "time"),
    *_t("XYN", "tt", "(t / T_ref) ** 2", "U_ref^2 (t / T_ref)^2", "time"),
    # ... and a transient after the start of the run with its own time constant tau (a shape
    # parameter: searched on a grid half a decade apart, then fitted with the coefficient): one
    # dying away (settling) and one building up to a steady level (a circulation developing in
    # the basin), which is a single term, not a constant minus a decay, for the sparse selection
    *_t("XYN", "et", "math.exp(-t / {tau})", "U_ref^2 exp(-t / {tau})", "time", (TAU,)),
    *_t("XYN", "bt", "1.0 - math.exp(-t / {tau})", "U_ref^2 (1 - exp(-t / {tau}))", "time", (TAU,)),
    # a force fixed to the basin that changes sign across a line (a bank, the edge of a shallow
    # patch): a step of width W centred at c, saturating on either side, alone and times U^2
    *_t(
        "XYN",
        "sx",
        "math.tanh((x0 - {c}) / {W})",
        "U_ref^2 tanh((x0 - {c}) / {W})",
        "position",
        _across("x0"),
    ),
    *_t(
        "XYN",
        "sy",
        "math.tanh((y0 - {c}) / {W})",
        "U_ref^2 tanh((y0 - {c}) / {W})",
        "position",
        _across("y0"),
    ),
    *_t(
        "XYN",
        "Usx",
        "U2 * math.tanh((x0 - {c}) / {W})",
        "U^2 tanh((x0 - {c}) / {W})",
        "position",
        _across("x0"),
    ),
    *_t(
        "XYN",
        "Usy",
        "U2 * math.tanh((y0 - {c}) / {W})",
        "U^2 tanh((y0 - {c}) / {W})",
        "position",
        _across("y0"),
    ),
    # a steady force fixed to the basin, along x0 or y0, on the ship's axes (Eq. (1)'s rotation)
    Term(
        "E_x0",
        "",
        "U_ref^2 along x0",
        "heading",
        (
            ("X", "math.cos(psi)", "U_ref^2 cos(psi)"),
            ("Y", "-math.sin(psi)", "U_ref^2 (-sin(psi))"),
        ),
    ),
    Term(
        "E_y0",
        "",
        "U_ref^2 along y0",
        "heading",
        (("X", "math.sin(psi)", "U_ref^2 sin(psi)"), ("Y", "math.cos(psi)", "U_ref^2 cos(psi)")),
    ),
]

#: terms of earlier versions of the library, kept so that parameter files and reports that name
#: them still load, but no longer searched: the transients at fixed time constants, now one
#: term each with tau as its shape (``X_bt`` at tau = 300 s is ``X_b300``)
_FORMER: list[Term] = [
    Term(f"{e}_{k}{tau}", expr.format(tau=f"{tau}.0"), formula.format(tau=f"{tau} s"), "time")
    for e in "XYN"
    for k, expr, formula in (
        ("e", "math.exp(-t / {tau})", "U_ref^2 exp(-t / {tau})"),
        ("b", "1.0 - math.exp(-t / {tau})", "U_ref^2 (1 - exp(-t / {tau}))"),
    )
    for tau in (100, 300, 1000)
]

#: every library term by id
TERMS: dict[str, Term] = {t.id: t for t in (*_TERMS, *_FORMER)}
if len(TERMS) != len(_TERMS) + len(_FORMER):  # pragma: no cover - a typo in the tables above
    raise RuntimeError("duplicate library term ids")
#: the terms discovery searches (all but the former ones), in table order
SEARCHED: tuple[str, ...] = tuple(t.id for t in _TERMS)


def term(term_id: str) -> Term:
    """A library term by id; ValueError naming the known ids for an unknown one."""
    try:
        return TERMS[term_id]
    except KeyError:
        raise ValueError(
            f"unknown library term {term_id!r}; known terms: {', '.join(TERMS)}"
        ) from None


@dataclass(frozen=True)
class Column:
    """One column of the proposal's regression: a term, at one grid point of its shape."""

    term: str
    shape: tuple[tuple[str, float], ...] = ()  # (placeholder name, value)

    @property
    def label(self) -> str:
        """``Y_Usy(c=2.1 m, W=1.5 m)``; a term without shape: its id."""
        if not self.shape:
            return self.term
        units = {s.name: s.unit for s in term(self.term).shape}
        return f"{self.term}(" + ", ".join(f"{n}={v:.4g} {units[n]}" for n, v in self.shape) + ")"

    def values(self) -> dict[str, float]:
        """The shape values by parameter name in the generated effect (``tau_N_bt``)."""
        t = term(self.term)
        return {t.shape_param(n): float(v) for n, v in self.shape}


def shape_grid(t: Term, spans: Mapping[str, Any]) -> list[tuple[tuple[str, float], ...]]:
    """The grid points of a term's shape (empty tuple for a term without one). ``spans``: the
    values of x0 and y0 over the data, for the centres and widths of steps."""
    if not t.shape:
        return [()]
    names = {s.role: s.name for s in t.shape}
    if set(names) == {"time constant"}:
        return [((names["time constant"], tau),) for tau in TAU_GRID]
    variable = next(s.variable for s in t.shape if s.role == "centre")
    z = np.asarray(spans[variable], dtype=np.float64)
    q = np.quantile(z, [*CENTRE_QUANTILES, 0.05, 0.95])
    width = max(float(q[-1] - q[-2]), 1e-3)
    return [
        ((names["centre"], float(c)), (names["width"], share * width))
        for c in q[: len(CENTRE_QUANTILES)]
        for share in WIDTH_SHARES
    ]


def shape_box(t: Term, values: Mapping[str, float]) -> dict[str, tuple[float, float]]:
    """Search interval of each shape parameter of ``t`` around the values ``values`` (by
    placeholder name) that the proposal chose: a time constant or a width within a factor 4,
    a centre within 3 widths."""
    out: dict[str, tuple[float, float]] = {}
    width = next((values[s.name] for s in t.shape if s.role == "width"), 0.0)
    for s in t.shape:
        v = float(values[s.name])
        if s.role == "centre":
            out[s.name] = (v - 3.0 * width, v + 3.0 * width)
        else:
            out[s.name] = (max(v / 4.0, s.lower), min(v * 4.0, s.upper))
    return out


def chosen_shapes(columns: Sequence[Column]) -> dict[str, dict[str, float]]:
    """{term: {placeholder: value}} of the columns whose term has a shape: how a selection
    hands the grid points it chose to :func:`mmg.discovered.with_bounds`."""
    return {c.term: dict(c.shape) for c in columns if c.shape}


def library_columns(term_ids: Sequence[str], spans: Mapping[str, Any]) -> list[Column]:
    """Every column of the proposal's regression: each term, at every grid point of its shape."""
    return [Column(i, g) for i in term_ids for g in shape_grid(term(i), spans)]
