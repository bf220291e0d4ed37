"""Shapes of a missing force: sums of penalised cubic splines of physical variables.

A *shape effect* models a force the MMG model lacks as a sum of groups; each group is a smooth
function f of one variable z, times the variable's MMG scaling and an optional multiplier:

    X += 0.5 rho L_pp d S m f_X(z),  Y += 0.5 rho L_pp d S m f_Y(z),
    N += 0.5 rho L_pp^2 d S m f_N(z),    f_C(z) = sum_j c_Cj B_j(z)

with S [m^2/s^2] the scaling (U^2, the rudder inflow U_R^2, (n_p D_p)^2, the apparent wind or
U_ref^2: :data:`SCALES`), m a dimensionless multiplier (another variable, a quadrant indicator,
or 1) and B_j cubic B-splines on a uniform knot grid over [lo, hi]. z is clamped to [lo, hi]
before the basis is evaluated, so a shape is held constant outside the range it was learnt on
(all but a harmonic closed form of an angle, a function on the circle: :func:`on_circle`).

A *memory* group (``D~ed[lo:hi]/n``, ``P~en[lo:hi]/n``: :data:`CONTROLS`) changes a control
instead of a force, in the effect's ``inputs`` hook: the acting rudder angle is
delta = delta_log - e_delta f_D(z), e_delta = delta_log - delta_prev the gap to the acting angle
of the step before and z = asinh(e_delta / 1 deg); f, searched in [0, 1], is the share of the
gap left open in one step (a lag, a rate limit or play, :func:`memory_steps`).

A group may instead multiply an *existing force* of the model (the hull's sway force Y_H, the
rudder's normal force F_N, ...: :data:`FORCES`): then C += f_C(z) F (times L_pp, or divided by
it, between a force and a moment), and f is a dimensionless share of that force.

A *share* group (``S~alphaR[lo:hi]/n*F_R``: :data:`SHARES`) changes a sub-model's whole force
by one shape: (X, Y, N) += f_S(z) (X_R, Y_R, N_R), the rudder's three components scaled alike
(a change of that force component of the model: a rudder whose normal force loses a share at
large angles of attack, a hull whose forces change with the drift angle).

The effect's name is its spec (:func:`parse`, :func:`shape_name`), e.g.
``shape:YN~beta[-0.6:0.6]/8+N~beta[-0.6:0.6]/6*Y_H+X~1*ast``:

    name   := "shape:" group ("+" group)*
    group  := comps "~" var "[" lo ":" hi "]/" n ["*" mult] ["@" scale]
            | comps "~" var "[" lo ":" hi "]:" form ["*" mult] ["@" scale]
            | comps "~1" ["*" mult] ["@" scale]
    comps  := X, Y, N or several in this order (one shape per component); D with the
              rudder's gap ed, P with the propeller's gap en (a memory, below); S with a
              sub-model's force as the multiplier (a share of it, above)
    form   := a closed form g of :data:`FORMS`, e.g. ``up(0.3)``, ``odd``, ``sin(2)``
    mult   := a variable, a quadrant indicator, a force of the model (:data:`FORCES`), or a
              force in one quadrant (``X_P*pos``: the branch n_p >= 0 of the thrust)

A group with a closed form (``N~beta[-0.6:0.6]:up(0.3)``) is f_C(z) = a_C + b_C g(z) / g_max:
the name a learned shape is given afterwards (:mod:`sweep.diagnose.naming`), fitted as an
ordinary effect with two coefficients per component (``s<g>_<C>0`` = a, ``s<g>_<C>1`` = b);
g_max = max |g| over [lo, hi], so that b is the form's largest contribution over the range.

``~1`` is a constant (one coefficient per component): ``X~1*ast`` is a 0/1 group, a surge
force present only going astern. The parameters are the spline coefficients, named
``s<g>_<C><j>`` (group g, component C, basis function j), neutral 0 and searched in
[-:data:`DEFAULT_BOUND`, +:data:`DEFAULT_BOUND`].

Like :mod:`mmg.discovered`, a module is generated with the parameter NamedTuple and a
``force_at`` hook (free of branches per group: min/max and selects only, so that the kernel's
lane loop stays vectorised), imported from ``<kernel dir>/effects`` (named by a hash of its
text). Its code is that of the groups' structure (:func:`structure_text`): the knot ranges and
a closed form's numbers are read from the parameters after the coefficients (:func:`numbers`,
:func:`shape_kernel`), so that shapes of one structure learnt over other ranges, on other data,
run one compiled kernel; the shape effect's own hooks call it with its numbers written in
(:meth:`ShapeEffect.kernel_form`). :func:`shape_effect` keeps the effect under its name; any
process rebuilds it from the name (:func:`mmg.get_effect`, :class:`ShapeEffect` pickles by
name). In numpy: :func:`basis`,
:func:`curve` (a shape for given coefficients) and :func:`penalty` (the second-difference
penalty of P-splines, per group).
"""

from __future__ import annotations

import hashlib
import math
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg._generated import generated_module, with_numbers
from mmg.effect import Effect, EffectParam, KernelForm
from mmg.library import T_REF, U_0, U_REF

FloatArray = NDArray[np.float64]

#: names of shape effects start with this (the rest is the spec of the groups)
SHAPE_PREFIX = "shape:"
#: the name of an effect's probe (:func:`probe_effect`) is the effect's name and this
PROBE_SUFFIX = "#probe"
#: search interval of a spline coefficient, [-DEFAULT_BOUND, DEFAULT_BOUND] (dimensionless: a
#: non-dimensional force in the group's scaling, or a share of the multiplying force)
DEFAULT_BOUND = 1.0
#: a probe's knot range [L, U] lies within [-PROBE_RANGE, PROBE_RANGE] (any variable's unit)
PROBE_RANGE = 1e12
#: the fewest basis functions of a spline (one cubic piece) and the most
MIN_BASIS = 4
MAX_BASIS = 40
#: the most basis functions of a shape of two variables, per component (n x n2)
MAX_TENSOR = 100


@dataclass(frozen=True)
class Variable:
    """A variable a shape can be a function of, or multiply by.

    ``code``: its value in the generated hook [``unit``]; ``factor``: its dimensionless value as
    a multiplier ("" if it cannot multiply); ``scale``: the default scaling of its shapes
    (a key of :data:`SCALES`, "" for a gap); ``control``: for the gap of a control, the
    control's letter (a key of :data:`CONTROLS`): its shapes are memories of that control;
    ``away``: the gap is signed away from the control's zero (positive where the control moves
    away from midships or from rest, negative where it moves back: :func:`away_sign`)."""

    symbol: str
    unit: str
    meaning: str
    code: str
    factor: str
    scale: str
    factor_formula: str = ""
    control: str = ""
    away: bool = False


#: the speed below which v'_m = v_m / U is taken at this U [m/s] (v_m is as small: v'_m -> 0
#: at rest), as written in the hook and as :func:`variable_values` takes it
V_PRIME_FLOOR = "1e-9"

#: the variables of shapes, by their name in a spec. u, v_m are velocities through the water.
VARIABLES: dict[str, Variable] = {
    "beta": Variable("beta", "rad", "drift angle atan2(-v_m, u)", "beta", "beta", "U2"),
    "rp": Variable("r'", "-", "yaw rate r L_pp / U_e", "rL / Ue", "rL / Ue", "U2", "r L_pp / U_e"),
    "U": Variable("U", "m/s", "speed through the water", "U", "U / Ue", "U2", "U / U_e"),
    "u": Variable("u", "m/s", "surge velocity", "u", "u / Ue", "U2", "u / U_e"),
    "v": Variable("v_m", "m/s", "sway velocity at midship", "v_m", "v_m / Ue", "U2", "v_m / U_e"),
    "vp": Variable(
        "v'_m",
        "-",
        "non-dimensional sway velocity v_m / U (the paper's v'_m of Eq. (6); -sin beta; 0 at rest)",
        f"v_m / max(U, {V_PRIME_FLOOR})",
        "",  # as a multiplier it would be v_m / U_e: the multiplier ``v``
        "U2",
    ),
    "delta": Variable("delta", "rad", "rudder angle", "delta", "delta", "UR2"),
    "alphaR": Variable(
        "alpha_R",
        "rad",
        "rudder's effective inflow angle delta - atan2(v_R, u_R) (Eqs. (17)-(21))",
        "alpha_R",
        "alpha_R",
        "UR2",
    ),
    "JP": Variable("J_P", "-", "advance ratio (1 - w_P) u / (n_p D_p)", "J_P", "", "nD2"),
    "n": Variable("n_p", "rev/s", "propeller speed", "n_p", "nD / Ue", "nD2", "n_p D_p / U_e"),
    "gammaA": Variable(
        "gamma_A", "rad", "apparent-wind angle (0: head wind)", "gamma_A", "gamma_A", "UA2"
    ),
    "UA": Variable(
        "U_A", "m/s", "apparent-wind speed", "U_A", f"U_A / {U_REF!r}", "UA2", "U_A / U_ref"
    ),
    "psi": Variable("psi", "rad", "heading wrapped to [-pi, pi)", "psi_w", "psi_w", "ref"),
    "x0": Variable("x0", "m", "position of midship along x0", "x0", "x0 / Lp", "ref", "x0 / L_pp"),
    "y0": Variable("y0", "m", "position of midship along y0", "y0", "y0 / Lp", "ref", "y0 / L_pp"),
    "t": Variable(
        "t", "s", "time on the recording's clock", "t", f"t / {T_REF!r}", "ref", "t / T_ref"
    ),
    "ed": Variable(
        "z_delta",
        "-",
        "gap of the rudder, e_delta = delta_log - delta_prev (the logged angle less the acting "
        "one of the step before), as z_delta = asinh(e_delta / 1 deg)",
        "z_ed",
        "",
        "",
        control="D",
    ),
    "en": Variable(
        "z_n",
        "-",
        "gap of the propeller, e_n = n_log - n_prev (the logged rate less the acting one of "
        "the step before), as z_n = asinh(e_n / 0.5 rev/s)",
        "z_en",
        "",
        "",
        control="P",
    ),
    "eda": Variable(
        "z_delta,a",
        "-",
        "gap of the rudder signed away from midships: e_delta as above, positive where the rudder "
        "moves away from midships (e_delta and delta_prev of one sign, or delta_prev = 0), "
        "negative where it moves back, as z = asinh(+-|e_delta| / 1 deg)",
        "z_eda",
        "",
        "",
        control="D",
        away=True,
    ),
    "ena": Variable(
        "z_n,a",
        "-",
        "gap of the propeller signed away from rest: e_n as above, positive where the propeller "
        "speeds up (e_n and n_prev of one sign, or n_prev = 0), negative where it slows down, "
        "as z = asinh(+-|e_n| / 0.5 rev/s)",
        "z_ena",
        "",
        "",
        control="P",
        away=True,
    ),
}


@dataclass(frozen=True)
class Control:
    """A control whose memory a shape can learn: the component's letter is its key in
    :data:`CONTROLS`. ``quantum``: the gap's scale in z = asinh(e / quantum) [``unit``]."""

    symbol: str
    unit: str
    meaning: str
    log: str  # the logged value's argument of the inputs hook
    prev: str  # the acting value of the step before
    quantum: float
    column: int  # its column in a recording's controls (delta, n_p)


#: the components of groups in a probe's order: forces X, Y, N, memories of D (rudder angle)
#: and P (propeller speed), S a share of a sub-model's force (all three of its components),
#: x and y a force fixed to the basin, along its x0 and its y0 axis (turned into the ship's
#: axes by the heading: X = F_x0 cos psi + F_y0 sin psi, Y = -F_x0 sin psi + F_y0 cos psi)
COMPONENTS = "XYNDPSxy"
#: the components of a force fixed to the basin, and the basin's axis of each
BASIN = {"x": "x0", "y": "y0"}

#: the controls of memory shapes. A group ``D~ed[lo:hi]/n`` makes the acting rudder angle
#: delta = delta_log - e_delta f_D(z_delta): f is the share of the gap e_delta that the rudder
#: leaves open in one time step (0: no memory, the paper's model; a constant exp(-dt / T): a
#: first-order lag; 1 - R dt / |e| beyond R dt: a rate limit R; 1 below a play b). The gap is
#: taken on the scale z = asinh(e / quantum): a quantum's resolution near 0 (the log's own steps
#: are 0.56 deg and 0.08 rev/s), logarithmic beyond, so one knot grid spans a play of a degree
#: and a reversal of 70 deg.
CONTROLS: dict[str, Control] = {
    "D": Control("delta", "rad", "rudder angle", "delta_log", "delta_prev", math.radians(1.0), 0),
    "P": Control("n_p", "rev/s", "propeller speed", "n_log", "n_prev", 0.5, 1),
}
#: closed forms of a memory (``D~ed[lo:hi]:rate``): the step s a control takes in one time step
#: towards its log, as a function of the gap e, in the families a steering gear or an engine
#: governor is written in, each of one coefficient c in [0, 1] (0: no memory, the paper's model,
#: for gaps up to the range's largest; a rate limit at 0 still stops a larger step at e_max) and
#: the range's largest gap e_max = quantum sinh(max(-lo, hi)): key -> (meaning, formula,
#: code). ``lag``: linear, s = (1 - c) e (a first-order lag, c = exp(-dt / T)); ``rate``: a
#: saturation, s = clip(e, -m, m), m = (1 - c) e_max (a rate limit m / dt); ``play``: a dead
#: zone, s = sign(e) max(|e| - b, 0), b = c e_max (play of b). In the formulas {x} is the
#: control, {prev} its acting value of the step before, {e} the gap, {c} the coefficient; in the
#: code ``gap``, ``c`` and ``emax``. Of a gap signed away from the control's zero (``eda``,
#: ``ena``) a closed form has two coefficients, c for the moves away from the zero and another
#: for the moves back (:func:`memory_coefficients`): a steering gear working against the
#: rudder's load, slower away from midships than back, is a rate limit of two rates.
MEMORY_FORMS: dict[str, tuple[str, str, str]] = {
    "lag": (
        "a first-order lag",
        "{x} = {prev} + (1 - {c}) {e}",
        "gap * c",
    ),
    "rate": (
        "a rate limit",
        "{x} = {prev} + clip({e}, -m, m),  m = (1 - {c}) e_max",
        "gap - min(max(gap, -(1.0 - c) * emax), (1.0 - c) * emax)",
    ),
    "play": (
        "play (a dead zone of the gap)",
        "{x} = {prev} + sign({e}) max(|{e}| - b, 0),  b = {c} e_max",
        "gap - math.copysign(max(abs(gap) - c * emax, 0.0), gap)",
    ),
}
#: quadrant indicators (multipliers only): [u < 0], [u >= 0], [n_p < 0], [n_p >= 0]
INDICATORS: dict[str, tuple[str, str]] = {
    "ast": ("[u < 0]", "1.0 if u < 0.0 else 0.0"),
    "ahd": ("[u >= 0]", "0.0 if u < 0.0 else 1.0"),
    "rev": ("[n_p < 0]", "1.0 if n_p < 0.0 else 0.0"),
    "pos": ("[n_p >= 0]", "0.0 if n_p < 0.0 else 1.0"),
}
#: forces of the model a shape can multiply: name -> (meaning, is a moment)
FORCES: dict[str, tuple[str, bool]] = {
    "X_H": ("hull surge force", False),
    "Y_H": ("hull sway force", False),
    "N_H": ("hull yaw moment", True),
    "X_P": ("propeller thrust (surge force)", False),
    "Y_P": ("propeller sway force", False),
    "N_P": ("propeller yaw moment", True),
    "X_R": ("rudder surge force", False),
    "Y_R": ("rudder sway force", False),
    "N_R": ("rudder yaw moment", True),
    "F_N": ("rudder normal force", False),
    "X_A": ("wind surge force", False),
    "Y_A": ("wind sway force", False),
    "N_A": ("wind yaw moment", True),
}
#: sub-models' forces a share group (component S) scales as a whole: name -> (meaning, its
#: surge force, sway force, yaw moment among :data:`FORCES`)
SHARES: dict[str, tuple[str, str, str, str]] = {
    "F_H": ("hull forces", "X_H", "Y_H", "N_H"),
    "F_P": ("propeller forces", "X_P", "Y_P", "N_P"),
    "F_R": ("rudder forces", "X_R", "Y_R", "N_R"),
    "F_A": ("wind forces", "X_A", "Y_A", "N_A"),
}
#: scalings S [m^2/s^2]: name -> (formula in X, in Y and N, code in X, in Y and N)
SCALES: dict[str, tuple[str, str, str, str]] = {
    "U2": ("U^2", "U^2", "U2", "U2"),
    "UR2": ("U_R^2", "U_R^2", "UR2", "UR2"),
    "nD2": ("(n_p D_p)^2", "(n_p D_p)^2", "nD * nD", "nD * nD"),
    "UA2": (
        "(rho_A A_T / rho L_pp d) U_A^2",
        "(rho_A A_L / rho L_pp d) U_A^2",
        "wT * UA2",
        "wL * UA2",
    ),
    "ref": ("U_ref^2", "U_ref^2", "1.0", "1.0"),
}

_TWO_PI = 2.0 * math.pi

#: a force fixed to the basin on the ship's axes: per component (along x0, along y0) the
#: factors of its X and Y in the hook's names (X = F_x0 cos psi + F_y0 sin psi,
#: Y = -F_x0 sin psi + F_y0 cos psi)
BASIN_AXES = {"x": ("cos_psi", "-sin_psi"), "y": ("sin_psi", "cos_psi")}


def _turned(component: str) -> str:
    """How the basin's force of ``component`` acts on the ship's axes, as a formula says it:
    " (X += F_x0 cos psi, Y -= F_x0 sin psi)"."""
    force = f"F_{BASIN[component]}"
    parts = []
    for axis, factor in zip("XY", BASIN_AXES[component], strict=True):
        sign = "-" if factor.startswith("-") else "+"
        parts.append(f"{axis} {sign}= {force} {factor.lstrip('-').replace('_', ' ')}")
    return f" ({', '.join(parts)})"


#: what the hook computes before the groups, in this order: (names it provides, code lines);
#: a block is written when a group's code (or a later block that is written) uses a name of it
_PRELUDE: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = (
    (("U",), ("U = math.sqrt(U2)",)),
    (("rL",), ("rL = r * Lp",)),
    (("nD",), ("nD = n_p * sh.D_p",)),
    (("beta",), ("beta = _atan2(-v_m, u)",)),
    (("sin_d", "cos_d"), ("sin_d, cos_d = _sincos(delta)",)),
    (
        ("u_R", "v_R", "UR2"),
        ("u_R, v_R = rudder_inflow_at(u, v_m, r, n_p, th, sh)", "UR2 = u_R * u_R + v_R * v_R"),
    ),
    (("alpha_R",), ("alpha_R = delta - _atan2(v_R, u_R)",)),
    (("J_P",), ("J_P = advance_ratio(u, n_p, sh) * wake_factor(u, v_m, r, th, sh)",)),
    (("sin_psi", "cos_psi"), ("sin_psi, cos_psi = _sincos(psi)",)),
    (
        ("uA", "vA", "UA2", "wT", "wL"),
        (
            "sin_g, cos_g = _sincos(gamma_T)",
            "uA, vA = apparent_wind(u, v_m, sin_psi, cos_psi, U_T, sin_g, cos_g)",
            "UA2 = uA * uA + vA * vA",
            "wT = sh.rho_A * sh.A_T / (sh.rho * Lp * sh.d)",
            "wL = sh.rho_A * sh.A_L / (sh.rho * Lp * sh.d)",
        ),
    ),
    (("gamma_A",), ("gamma_A = _atan2(vA, uA)",)),
    (("U_A",), ("U_A = math.sqrt(UA2)",)),
    (("psi_w",), (f"psi_w = psi - {_TWO_PI!r} * np.floor((psi + {math.pi!r}) * {1 / _TWO_PI!r})",)),
    (("X_H", "Y_H", "N_H"), ("X_H, Y_H, N_H = hull_forces(u, v_m, r, th, sh)",)),
    (
        ("X_P", "Y_P", "N_P"),
        (
            "J_s = advance_ratio(u, n_p, sh)",
            "w_1 = wake_factor(u, v_m, r, th, sh)",
            "X_P, Y_P, N_P, _ = propeller_forces(u, n_p, J_s, w_1, th, sh)",
        ),
    ),
    (
        ("X_R", "Y_R", "N_R", "F_N"),
        (
            "X_R, Y_R, N_R = rudder_forces(u_R, v_R, sin_d, cos_d, th, sh)",
            "# Eqs. (17), (20): F_N = 0.5 rho A_R f_alpha U_R^2 sin(alpha_R)",
            "f_a = 0.5 * sh.rho * sh.A_R * lift_gradient(sh)",
            "F_N = f_a * math.sqrt(UR2) * (u_R * sin_d - v_R * cos_d)",
        ),
    ),
    (("X_A", "Y_A", "N_A"), ("X_A, Y_A, N_A = wind_forces(uA, vA, th, sh)",)),
)


def _num(v: float) -> str:
    """A number as a spec writes it: 6 significant digits, no ``+`` (the groups' separator)."""
    return f"{float(v):.6g}".replace("e+", "e")


@dataclass(frozen=True)
class Form:
    """A closed form g(z) a group can take instead of a spline: ``key`` (of :data:`FORMS`) and
    its numbers ``args`` (a corner c, a width w, a multiple k), in the variable's unit."""

    key: str
    args: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.key not in FORMS:
            raise ValueError(f"unknown closed form {self.key!r}; known: {', '.join(FORMS)}")
        want = FORMS[self.key][0]
        if len(self.args) != want:
            raise ValueError(f"closed form {self.key!r} takes {want} number(s), got {self.args}")
        if not all(math.isfinite(a) for a in self.args):
            raise ValueError(f"closed form {self.key!r}: its numbers must be finite")
        if self.key in STEPS and self.args[1] <= 0.0:
            raise ValueError(f"closed form {self.key!r}: its width must be positive")
        if self.key in (*SYMMETRIC, "absstep") and self.args[0] < 0.0:
            raise ValueError(f"closed form {self.key!r}: its corner |z| must not be negative")
        if self.key in WAVES and self.args[0] <= 0.0:
            raise ValueError(f"closed form {self.key!r}: its period must be positive")

    @property
    def text(self) -> str:
        """As a spec writes it: ``key`` or ``key(a,b)``."""
        return self.key + (f"({','.join(_num(a) for a in self.args)})" if self.args else "")

    def formula(self, z: str) -> str:
        """g in the variable's symbol ``z``."""
        return FORMS[self.key][1].format(z=z, a=[_num(a) for a in self.args])

    def code(self, z: str, args: Sequence[str] | None = None) -> str:
        """g in the generated hook, of the variable named ``z`` (branch-free); its numbers are
        the expressions ``args`` (the kernel's parameters), else written in."""
        a = [repr(float(x)) for x in self.args] if args is None else list(args)
        return FORMS[self.key][2].format(z=z, a=a)

    def __call__(self, z: Any) -> FloatArray:
        """g at z (numpy, the same arithmetic as :meth:`code`)."""
        x = np.asarray(z, dtype=np.float64)
        a = self.args
        values = {
            "lin": lambda: x,
            "sq": lambda: x * x,
            "odd": lambda: x * np.abs(x),
            "cube": lambda: x * x * x,
            "abs": lambda: np.abs(x),
            "up": lambda: np.maximum(x - a[0], 0.0),
            "down": lambda: np.maximum(a[0] - x, 0.0),
            "absup": lambda: np.maximum(np.abs(x) - a[0], 0.0),
            "oddup": lambda: np.copysign(np.maximum(np.abs(x) - a[0], 0.0), x),
            "step": lambda: np.tanh((x - a[0]) / a[1]),
            "absstep": lambda: np.tanh((np.abs(x) - a[0]) / a[1]),
            "sin": lambda: np.sin(a[0] * x),
            "cos": lambda: np.cos(a[0] * x),
            "sinodd": lambda: np.sin(a[0] * x) * np.abs(np.sin(a[0] * x)),
            "cosodd": lambda: np.cos(a[0] * x) * np.abs(np.cos(a[0] * x)),
            "wave": lambda: np.sin(_TWO_PI * x / a[0] + a[1]),
        }
        return np.asarray(values[self.key](), dtype=np.float64)


#: closed forms g(z): key -> (how many numbers, formula, code); {z} the variable, {a[i]} its
#: numbers. A naval architect's families: powers and their abs forms, hinges (a threshold),
#: a smooth step (a saturation), harmonics (of an angle) and their odd squares (a cross-flow,
#: v_m|v_m| = U^2 sin(beta)|sin(beta)|; a wind force's coefficient in gamma_A). A threshold
#: in a variable that changes sign with the side of the ship (drift angle, sway, yaw rate,
#: rudder angle) is reached on both sides at once: the symmetric hinges ``absup`` (even, e.g. a
#: share of a force beyond |beta| = c) and ``oddup`` (odd, e.g. a side force beyond it, on the
#: side it comes from), and the symmetric step ``absstep`` (even, e.g. a share of a force lost
#: beyond |alpha_R| = c). A ``wave`` has a period T and a phase phi of its own (a + b sin(2 pi z
#: / T + phi)): a force that comes and goes in time (a basin's sloshing, a wave group).
FORMS: dict[str, tuple[int, str, str]] = {
    "lin": (0, "{z}", "{z}"),
    "sq": (0, "{z}^2", "{z} * {z}"),
    "odd": (0, "{z}|{z}|", "{z} * abs({z})"),
    "cube": (0, "{z}^3", "{z} * {z} * {z}"),
    "abs": (0, "|{z}|", "abs({z})"),
    "up": (1, "max({z} - {a[0]}, 0)", "max({z} - {a[0]}, 0.0)"),
    "down": (1, "max({a[0]} - {z}, 0)", "max({a[0]} - {z}, 0.0)"),
    "absup": (1, "max(|{z}| - {a[0]}, 0)", "max(abs({z}) - {a[0]}, 0.0)"),
    "oddup": (
        1,
        "sign({z}) max(|{z}| - {a[0]}, 0)",
        "math.copysign(max(abs({z}) - {a[0]}, 0.0), {z})",
    ),
    "step": (2, "tanh(({z} - {a[0]}) / {a[1]})", "math.tanh(({z} - {a[0]}) / {a[1]})"),
    "absstep": (
        2,
        "tanh((|{z}| - {a[0]}) / {a[1]})",
        "math.tanh((abs({z}) - {a[0]}) / {a[1]})",
    ),
    "sin": (1, "sin({a[0]} {z})", "math.sin({a[0]} * {z})"),
    "cos": (1, "cos({a[0]} {z})", "math.cos({a[0]} * {z})"),
    "sinodd": (
        1,
        "sin({a[0]} {z})|sin({a[0]} {z})|",
        "math.sin({a[0]} * {z}) * abs(math.sin({a[0]} * {z}))",
    ),
    "cosodd": (
        1,
        "cos({a[0]} {z})|cos({a[0]} {z})|",
        "math.cos({a[0]} * {z}) * abs(math.cos({a[0]} * {z}))",
    ),
    "wave": (
        2,
        "sin(2 pi {z} / {a[0]} + {a[1]})",
        "math.sin(" + repr(2.0 * math.pi) + " * {z} / {a[0]} + {a[1]})",
    ),
}
#: the symmetric hinges: their corner is a size |z| (not negative)
SYMMETRIC = ("absup", "oddup")
#: the steps: (corner, width), the width positive
STEPS = ("step", "absstep")
#: points over [lo, hi] on which a closed form's largest |g| is taken
FORM_GRID = 201

_FORM = re.compile(r"^(?P<k>[a-z]+)(?:\((?P<a>[^)]*)\))?$")


def parse_form(text: str) -> Form:
    """The closed form of a spec's ``key`` or ``key(a,b)``; ValueError when malformed (a
    product of two, ``odd&sin(1)``, is :func:`parse_forms`')."""
    m = _FORM.match(text.strip())
    if m is None:
        raise ValueError(f"closed form {text!r}: expected e.g. 'odd', 'up(0.3)', 'step(0.2,0.05)'")
    try:
        args = tuple(float(a) for a in m["a"].split(",")) if m["a"] else ()
    except ValueError:
        raise ValueError(f"closed form {text!r}: its numbers are not numbers") from None
    return Form(m["k"], args)


def parse_forms(text: str) -> tuple[Form, ...]:
    """The closed forms of a spec's form: one (``odd``), or the two factors of a product over a
    shape of two variables (``odd&sin(1)``: g(z, z2) = g1(z) g2(z2)); ValueError when
    malformed."""
    parts = text.split("&")
    if len(parts) > 2:
        raise ValueError(f"closed form {text!r}: a product has two factors, 'odd&sin(1)'")
    return tuple(parse_form(p) for p in parts)


#: closed forms periodic in their variable: harmonics and their odd squares
HARMONICS = ("sin", "cos", "sinodd", "cosodd")
#: closed forms of a period of their own: (period, phase)
WAVES = ("wave",)


def on_circle(variable: str, form: Form) -> bool:
    """Whether the closed form ``form`` of ``variable`` acts at every value of it, not held at
    the ends of its range: a harmonic of an angle (or its odd square) is a function on the
    circle, bounded by its amplitude, as an angle's force coefficients are (a wind force's in
    gamma_A, a cross-flow's in beta); so is a wave of any variable (a period of its own: it comes
    and goes beyond the range as within it). Its g_max is still taken over the range it was
    learnt on. Every other closed form, and every spline, is held constant beyond that range."""
    if form.key in WAVES:
        return True
    var = VARIABLES.get(variable)
    return form.key in HARMONICS and var is not None and var.unit == "rad" and not var.control


def _form_at(variable: str, form: Form, z: Any, lo: float, hi: float) -> Any:
    """Where the closed form ``form`` of ``variable`` is evaluated for the values z: z itself on
    the circle (:func:`on_circle`), else z held within [lo, hi]."""
    return z if on_circle(variable, form) else np.clip(z, lo, hi)


def _form_input(name: str, variable: str, form: Form, lo: str, hi: str) -> str:
    """The hook's line that sets ``name`` to the variable a closed form is evaluated at: as
    :func:`_form_at`, with the range's bounds the kernel's parameters ``lo`` and ``hi``."""
    code = VARIABLES[variable].code
    if on_circle(variable, form):
        return f"    {name} = {code}"
    return f"    {name} = min(max({code}, {lo}), {hi})"


def form_scale(group: Group) -> float:
    """g_max of a closed-form group: the largest |g| over its range (0 for a spline group); of
    a product g1(z) g2(z2), the product of each factor's largest |g| over its range."""
    if not group.form or group.control:
        return 0.0
    forms = parse_forms(group.form)
    ranges = [(group.lo, group.hi), (group.lo2, group.hi2)][: len(forms)]
    out = 1.0
    for form, (lo, hi) in zip(forms, ranges, strict=True):
        out *= float(np.max(np.abs(form(np.linspace(lo, hi, FORM_GRID)))))
    return out


@dataclass(frozen=True)
class Group:
    """One group of a shape effect: f_C(variable) for each component C in ``components`` (forces
    X, Y, N on the ship's axes; x, y a force fixed to the basin, along x0 and y0; D, P a memory
    of a control; S a share of a sub-model's force: :data:`COMPONENTS`).

    ``variable`` is a key of :data:`VARIABLES` or ``"1"`` (a constant, ``n`` = 1);
    ``lo``, ``hi`` the knot range in the variable's unit, ``n`` the number of basis functions;
    ``multiplier`` "" or a key of :data:`VARIABLES`, :data:`INDICATORS` or :data:`FORCES`
    (a key of :data:`SHARES` with the component S alone), or a force in one quadrant
    (``X_P*pos``: the thrust where n_p >= 0, the branch of Eq. (5) and not the reversed
    propeller's Eq. (11));
    ``scale`` "" (the variable's default) or a key of :data:`SCALES`; ``form`` "" (a spline)
    or a closed form (:func:`parse_form`, ``n`` = 2: a + b g / g_max).

    A *tensor* group (``variable2`` given) is a shape of two variables, an interaction:
    f_C(z, z2) = sum_ij c_C,ij B_i(z) B_j(z2), ``n`` x ``n2`` cubic B-splines over [lo, hi] x
    [lo2, hi2] (both clamped), coefficient i n2 + j of each component, of two force variables
    (no memory), with the scaling of the first unless ``scale`` says otherwise. Its closed
    form is a product of one closed form of each variable (``form`` "g1&g2", ``n`` = 2,
    ``n2`` = 1): f = a + b g1(z) g2(z2) / (g1_max g2_max), each variable held within its
    range, a surface named afterwards."""

    components: str
    variable: str
    lo: float = 0.0
    hi: float = 0.0
    n: int = 1
    multiplier: str = ""
    scale: str = ""
    form: str = ""
    variable2: str = ""
    lo2: float = 0.0
    hi2: float = 0.0
    n2: int = 1

    def __post_init__(self) -> None:
        c = self.components
        var = VARIABLES.get(self.variable)
        if var is not None and var.control:  # a memory of a control: that control alone
            if c != var.control:
                raise ValueError(
                    f"{self.variable} is the gap of the {CONTROLS[var.control].meaning}: its "
                    f"shape's component is {var.control}, not {c!r}"
                )
            if self.multiplier or self.scale:
                raise ValueError(f"{self.variable}: a memory shape takes no multiplier or scale")
            if self.form and self.form not in MEMORY_FORMS:
                raise ValueError(
                    f"{self.variable}: a memory's closed form is one of "
                    f"{', '.join(MEMORY_FORMS)}, not {self.form!r}"
                )
        elif c == "S" or self.multiplier in SHARES:
            if c != "S" or self.multiplier not in SHARES:
                raise ValueError(
                    f"components {c!r} times {self.multiplier or 'nothing'}: a share group is "
                    f"S times a sub-model's force, one of {', '.join(SHARES)}"
                )
            if self.scale:
                raise ValueError(f"a share of {self.multiplier} takes no scale")
        elif c and set(c) <= set(BASIN):
            if c not in ("x", "y", "xy"):
                raise ValueError(f"components {c!r}: a force fixed to the basin is x, y or xy")
            if self.force:
                raise ValueError(
                    f"components {c!r}: a force fixed to the basin is not a share of the "
                    f"force {self.force} (the ship's axes: X, Y, N)"
                )
        elif not c or any(x not in "XYN" for x in c) or "".join(sorted(c, key="XYN".index)) != c:
            raise ValueError(
                f"components {c!r}: one or more of X, Y, N, in this order (or x, y: a force "
                "fixed to the basin, along x0 and y0; D, P with the gap of the rudder, ed, and "
                "of the propeller, en; S with a sub-model's force)"
            )
        if len(set(c)) != len(c):
            raise ValueError(f"components {c!r}: repeated")
        if self.variable == "1":
            if self.n != 1 or self.form:
                raise ValueError("a constant group (~1) has one coefficient per component")
        elif self.variable not in VARIABLES:
            names = ", ".join(VARIABLES)
            raise ValueError(f"unknown shape variable {self.variable!r}; known: {names}, 1")
        else:
            # the range as the name writes it: a group built from measured quantiles is then
            # the very group its name rebuilds, in this process and any other (one kernel,
            # compiled once, the same force everywhere)
            object.__setattr__(self, "lo", float(_num(self.lo)))
            object.__setattr__(self, "hi", float(_num(self.hi)))
            if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.lo < self.hi):
                raise ValueError(f"{self.variable}: knot range [{self.lo}, {self.hi}] is empty")
            if self.form and self.control:
                k = memory_coefficients(self.variable)
                if self.n != k:
                    raise ValueError(
                        f"{self.variable}: a memory's closed form has {k} coefficient(s)"
                    )
            elif self.form:
                forms = parse_forms(self.form)
                if len(forms) != (2 if self.variable2 else 1):
                    raise ValueError(
                        f"{self.variable}: the closed form {self.form!r} of a shape of "
                        + (
                            "two variables is a product, e.g. 'odd&sin(1)'"
                            if self.variable2
                            else "one variable is one form, e.g. 'odd'"
                        )
                    )
                object.__setattr__(self, "form", "&".join(f.text for f in forms))
                if self.n != 2:
                    raise ValueError(f"{self.variable}: a closed form has 2 coefficients (a, b)")
                # (a product's g_max needs its second range: _check_tensor)
                if not self.variable2 and form_scale(self) <= 0.0:
                    raise ValueError(
                        f"{self.variable}: the closed form {self.form} is 0 over "
                        f"[{self.lo}, {self.hi}]"
                    )
            elif not MIN_BASIS <= self.n <= MAX_BASIS:
                raise ValueError(f"{self.variable}: {self.n} basis functions, need 4 to 40")
        if self.variable2:
            self._check_tensor()
        m = self.multiplier
        known = [k for k, v in VARIABLES.items() if v.factor] + [*INDICATORS, *FORCES, *SHARES]
        if "*" in m:
            force, indicator = m.split("*", 1)
            if force not in FORCES or indicator not in INDICATORS:
                raise ValueError(
                    f"multiplier {m!r}: a force of the model times a quadrant indicator, e.g. "
                    f"'X_P*pos' (forces {', '.join(FORCES)}; indicators {', '.join(INDICATORS)})"
                )
        elif m and m not in known:
            raise ValueError(f"unknown multiplier {m!r}; known: {', '.join(known)}")
        if self.scale and self.scale not in SCALES:
            raise ValueError(f"unknown scale {self.scale!r}; known: {', '.join(SCALES)}")
        if self.scale and self.force:
            raise ValueError(f"a shape times the force {m} takes no scale")
        default = VARIABLES[self.variable].scale if self.variable != "1" else "U2"
        if self.scale == default:  # one spelling of each group: the default scale is implied
            object.__setattr__(self, "scale", "")

    def _check_tensor(self) -> None:
        """A tensor group's second variable, range and basis: ValueError when not one."""
        v2 = VARIABLES.get(self.variable2)
        if v2 is None:
            names = ", ".join(VARIABLES)
            raise ValueError(f"unknown shape variable {self.variable2!r}; known: {names}")
        if self.variable == "1" or self.control or v2.control:
            raise ValueError(
                "a shape of two variables is of two force variables (no constant, no gap)"
            )
        if self.variable2 == self.variable:
            raise ValueError(f"a shape of two variables needs two: {self.variable} twice")
        object.__setattr__(self, "lo2", float(_num(self.lo2)))
        object.__setattr__(self, "hi2", float(_num(self.hi2)))
        if not (math.isfinite(self.lo2) and math.isfinite(self.hi2) and self.lo2 < self.hi2):
            raise ValueError(f"{self.variable2}: knot range [{self.lo2}, {self.hi2}] is empty")
        if self.form:  # a product of two closed forms: (a, b), no basis of the second
            if self.n2 != 1:
                raise ValueError(
                    f"{self.variable}&{self.variable2}: a product of closed forms has no basis "
                    "functions of its second variable"
                )
            if form_scale(self) <= 0.0:
                raise ValueError(
                    f"{self.variable}&{self.variable2}: the closed form {self.form} is 0 over "
                    f"[{self.lo}, {self.hi}] x [{self.lo2}, {self.hi2}]"
                )
            return
        if not MIN_BASIS <= self.n2 <= MAX_BASIS:
            raise ValueError(f"{self.variable2}: {self.n2} basis functions, need 4 to 40")
        if self.n * self.n2 > MAX_TENSOR:
            raise ValueError(
                f"{self.variable}&{self.variable2}: {self.n} x {self.n2} basis functions, at "
                f"most {MAX_TENSOR} per component"
            )

    @property
    def tensor(self) -> bool:
        """Whether this is a shape of two variables."""
        return bool(self.variable2)

    @property
    def size(self) -> int:
        """Coefficients per component: n, or n n2 for a shape of two variables (2 for a product
        of closed forms)."""
        return self.n * self.n2 if self.tensor else self.n

    @property
    def text(self) -> str:
        """The group as a spec writes it (canonical)."""
        if self.variable == "1":
            out = f"{self.components}~1"
        elif self.tensor:
            out = (
                f"{self.components}~{self.variable}&{self.variable2}[{_num(self.lo)}:"
                f"{_num(self.hi)}&{_num(self.lo2)}:{_num(self.hi2)}]"
                + (f":{self.form}" if self.form else f"/{self.n}x{self.n2}")
            )
        elif self.form:
            out = f"{self.components}~{self.variable}[{_num(self.lo)}:{_num(self.hi)}]:{self.form}"
        else:
            out = f"{self.components}~{self.variable}[{_num(self.lo)}:{_num(self.hi)}]/{self.n}"
        if self.multiplier:
            out += f"*{self.multiplier}"
        if self.scale:
            out += f"@{self.scale}"
        return out

    @property
    def structure(self) -> str:
        """The group as a spec writes it without its knot range and number of basis functions
        (``XYN~beta*Y_H``): what the code of its probe depends on (:func:`probe_effect`)."""
        return re.sub(r"\[[^\]]*\](/\d+(x\d+)?)?", "", self.text)

    @property
    def control(self) -> str:
        """The letter of the control whose memory this group is ("" for a force)."""
        return VARIABLES[self.variable].control if self.variable != "1" else ""

    @property
    def force(self) -> str:
        """The force of the model this group multiplies (a key of :data:`FORCES`), "" if none."""
        force = self.multiplier.split("*", 1)[0]
        return force if force in FORCES else ""

    @property
    def quadrant(self) -> str:
        """The quadrant indicator the group's force is restricted to (a key of
        :data:`INDICATORS`, ``X_P*pos``: the thrust where n_p >= 0), "" if none."""
        return self.multiplier.split("*", 1)[1] if "*" in self.multiplier else ""

    @property
    def scale_name(self) -> str:
        """The scaling used: "" (times a force, or a memory), the given one, or the variable's
        default."""
        if self.force or self.multiplier in SHARES or self.control:
            return ""
        if self.scale:
            return self.scale
        return VARIABLES[self.variable].scale if self.variable != "1" else "U2"

    def param_names(self, g: int) -> list[str]:
        """The coefficients' names when this is group ``g``: components major."""
        return [f"s{g}_{c}{j}" for c in self.components for j in range(self.size)]

    def formula(self, component: str, g: int = 0) -> str:
        """What the group adds to ``component``, in the paper's notation, with units."""
        arg = "" if self.variable == "1" else f"({VARIABLES[self.variable].symbol})"
        if self.tensor:
            arg = f"({VARIABLES[self.variable].symbol}, {VARIABLES[self.variable2].symbol})"
        f = f"f_{component}{g}{arg}"
        if self.control:
            k = CONTROLS[self.control]
            e = f"e_{k.log.removesuffix('_log')}"
            if self.form:
                away = VARIABLES[self.variable].away
                body = MEMORY_FORMS[self.form][1].format(
                    x=k.symbol, prev=k.prev, e=e, c="c" if away else f"s{g}_{component}0"
                )
                if away:
                    body += (
                        f",  c = s{g}_{component}0 where {e} moves {k.symbol} away from 0 "
                        f"({e} {k.prev} > 0, or {k.prev} = 0), else s{g}_{component}1"
                    )
                return f"{body},  e_max = {_num(memory_range(self))} {k.unit}  [{k.unit}]"
            return f"{k.symbol} = {k.log} - {e} {f}  [{k.unit}]"
        unit = "N m" if component == "N" else "N"
        m = self.multiplier
        if m in SHARES:
            xyn = ", ".join(SHARES[m][1:])
            return f"(X, Y, N) += {f} ({xyn})  [N, N, N m]"
        if self.force:
            force = self.force
            lever = ""
            if component == "N" and not FORCES[force][1]:
                lever = " L_pp"
            elif component != "N" and FORCES[force][1]:
                lever = " / L_pp"
            where = f" {INDICATORS[self.quadrant][0]}" if self.quadrant else ""
            return f"{component} += {f} {force}{where}{lever}  [{unit}]"
        turned = ""
        if component in BASIN:  # a force fixed to the basin, along its axis
            unit, turned = "N", _turned(component)
            component = f"F_{BASIN[component]}"
        q = "0.5 rho L_pp^2 d" if component == "N" else "0.5 rho L_pp d"
        mult = ""
        if m in INDICATORS:
            mult = " " + INDICATORS[m][0]
        elif m:
            mult = f" ({VARIABLES[m].factor_formula or VARIABLES[m].symbol})"
        scale = SCALES[self.scale_name][0 if component in ("X", "F_x0") else 1]
        return f"{component} += {q} {scale} {f}{mult}  [{unit}]{turned}"

    def memory_closed(self, c: float, dt: float, back: float = 0.0) -> str:
        """A memory's closed form for its coefficient ``c`` in the control's terms, at time
        steps of ``dt`` [s]: the lag's time constant, the rate limit or the play (a rudder's in
        degrees); of a gap signed away from the control's zero ``c`` moving away and ``back``
        moving back (0: as logged)."""
        if not (self.control and self.form):
            raise ValueError(f"{self.text} is not a memory's closed form")
        k = CONTROLS[self.control]
        deg = k.unit == "rad"
        unit = "deg" if deg else k.unit
        size = math.degrees(memory_range(self)) if deg else memory_range(self)
        what = k.meaning
        if VARIABLES[self.variable].away:
            zero = "midships" if self.control == "D" else "rest"
            out = self._memory_closed(c, dt, what, size, unit).removesuffix(" either way")
            if back <= 0.0:
                return f"{out} moving away from {zero} (as logged moving back)"
            then = self._memory_closed(back, dt, what, size, unit).removesuffix(" either way")
            return f"{out} moving away from {zero}; moving back, {then}"
        return self._memory_closed(c, dt, what, size, unit)

    def _memory_closed(self, c: float, dt: float, what: str, size: float, unit: str) -> str:
        """:meth:`memory_closed` of either sign of the gap."""
        if self.form == "lag":
            if c <= 0.0:
                return f"no lag of the {what} (c = 0)"
            if c >= 1.0:
                return f"the {what} does not move (c = 1)"
            T = -dt / math.log(c)
            return (
                f"a first-order lag of the {what}: T = {T:.3g} s "
                f"({1.0 - c:.3g} of the gap closed in each step of {dt:.3g} s)"
            )
        if self.form == "rate":
            m = (1.0 - c) * size
            return f"a rate limit of the {what}: {m / dt:.3g} {unit}/s ({m:.3g} {unit} a step)"
        return f"play of the {what}: {c * size:.3g} {unit} either way"

    def closed(self, component: str, a: float, b: float, g: int = 0) -> str:
        """:meth:`formula` of a closed-form group with f written out for its coefficients
        (a, b): f = a + (b / g_max) g(z)."""
        if not self.form:
            raise ValueError(f"{self.text} is a spline, not a closed form")
        if self.control:
            raise ValueError(f"{self.text} is a memory: its closed form is memory_closed's")
        z = VARIABLES[self.variable].symbol
        forms = parse_forms(self.form)
        form = forms[0].formula(z)
        arg = f"({z})"
        if self.tensor:
            z2 = VARIABLES[self.variable2].symbol
            form = f"{form} {forms[1].formula(z2)}"
            arg = f"({z}, {z2})"
        k = b / form_scale(self)
        body = f"({a:.4g} {'-' if k < 0 else '+'} {abs(k):.4g} {form})"
        return self.formula(component, g).replace(f"f_{component}{g}{arg}", body, 1)


_GROUP = re.compile(
    r"^(?P<c>[XYNDPSxy]+)~(?:(?P<one>1)|(?P<v>\w+)(?:&(?P<v2>\w+))?"
    r"\[(?P<lo>[^:\]]+):(?P<hi>[^\]&]+)(?:&(?P<lo2>[^:\]]+):(?P<hi2>[^\]]+))?\]"
    r"(?:/(?P<n>\d+)(?:x(?P<n2>\d+))?|:(?P<f>[a-z]+(?:\([^)]*\))?(?:&[a-z]+(?:\([^)]*\))?)?)))"
    r"(?:\*(?P<m>\w+(?:\*\w+)?))?(?:@(?P<s>\w+))?$"
)


def parse(spec: str) -> tuple[Group, ...]:
    """The groups of a spec (with or without the ``shape:`` prefix); ValueError when malformed."""
    body = spec[len(SHAPE_PREFIX) :] if spec.startswith(SHAPE_PREFIX) else spec
    groups = []
    for part in body.split("+"):
        m = _GROUP.match(part.strip())
        if m is None:
            raise ValueError(
                f"shape group {part!r}: expected e.g. 'Y~beta[-0.6:0.6]/8', 'N~U[0:1]/6*v' or "
                "'X~1*ast'"
            )
        try:
            lo, hi = (0.0, 0.0) if m["one"] else (float(m["lo"]), float(m["hi"]))
        except ValueError:
            raise ValueError(f"shape group {part!r}: the knot range is not two numbers") from None
        var = VARIABLES.get(m["v"] or "")
        memory = var is not None and bool(var.control)
        n = (memory_coefficients(m["v"]) if memory else 2) if m["f"] else int(m["n"] or 1)
        # two variables take two ranges and, unless named, n x n2 basis functions
        basis_of_two = bool(m["n2"]) if m["f"] is None else bool(m["v2"])
        if bool(m["v2"]) != bool(m["lo2"]) or bool(m["v2"]) != basis_of_two:
            raise ValueError(
                f"shape group {part!r}: a shape of two variables is written "
                "'N~u&gammaA[lo:hi&lo2:hi2]/n x n2' (e.g. 'N~u&gammaA[0:0.4&-3.1:3.1]/5x8'), "
                "named 'N~u&gammaA[0:0.4&-3.1:3.1]:odd&sin(1)'"
            )
        second: dict[str, Any] = {}
        if m["v2"]:
            try:
                second = {
                    "variable2": m["v2"],
                    "lo2": float(m["lo2"]),
                    "hi2": float(m["hi2"]),
                    "n2": int(m["n2"] or 1),
                }
            except ValueError:
                raise ValueError(f"shape group {part!r}: the knot range is not numbers") from None
        groups.append(
            Group(
                m["c"],
                m["one"] or m["v"],
                lo,
                hi,
                n,
                m["m"] or "",
                m["s"] or "",
                m["f"] or "",
                **second,
            )
        )
    if len({g.text for g in groups}) != len(groups):
        raise ValueError(f"repeated shape group in {spec!r}")
    return tuple(groups)


def shape_name(groups: Sequence[Group]) -> str:
    """The effect's name: ``shape:`` and the groups' specs joined by ``+`` (canonical)."""
    if not groups:
        raise ValueError("a shape effect needs at least one group")
    return SHAPE_PREFIX + "+".join(g.text for g in groups)


# ---------------------------------------------------------------------------------------------
# the basis and the penalty in numpy


def cardinal_bspline(x: Any) -> FloatArray:
    """The cardinal cubic B-spline at x (support [-2, 2]): ((2 - |x|)_+^3 - 4 (1 - |x|)_+^3) / 6;
    2/3 at 0, 1/6 at +-1. The same arithmetic as the generated hook's."""
    a = np.abs(np.asarray(x, dtype=np.float64))
    p = np.maximum(2.0 - a, 0.0)
    m = np.maximum(1.0 - a, 0.0)
    return np.asarray((p * p * p - 4.0 * m * m * m) / 6.0)


def basis(group: Group, z: Any) -> FloatArray:
    """(len(z), n) basis functions of ``group`` at the variable's values z (its unit).

    z is clamped to [lo, hi]; with h = (hi - lo) / (n - 3) and s = (z - lo) / h, basis function
    j is the cardinal B-spline at s - (j - 1): the knots lie at lo + k h (k = -3 .. n), the basis
    sums to 1 on [lo, hi]. A constant group's basis is 1."""
    z = np.atleast_1d(np.asarray(z, dtype=np.float64))
    if group.tensor:
        raise ValueError(f"{group.text} is a shape of two variables: its basis is basis2's")
    if group.variable == "1":
        return np.ones((z.size, 1))
    if group.control and group.form:
        raise ValueError(f"{group.text}: a memory's closed form is no sum of basis functions")
    if group.form:  # a + b g / g_max
        form = parse_form(group.form)
        g = form(_form_at(group.variable, form, z, group.lo, group.hi)) / form_scale(group)
        return np.column_stack([np.ones_like(z), g])
    return _spline_basis(group.lo, group.hi, group.n, z)


def _spline_basis(lo: float, hi: float, n: int, z: FloatArray) -> FloatArray:
    """(len(z), n) cubic B-splines on the uniform grid of n basis functions over [lo, hi], z
    clamped to it (as :func:`basis`)."""
    h = (hi - lo) / (n - 3)
    s = (np.clip(z, lo, hi) - lo) / h
    return cardinal_bspline(s[:, None] - (np.arange(n)[None, :] - 1.0))


def basis2(group: Group, z: Any, z2: Any) -> FloatArray:
    """(N, n n2) basis functions of a shape of two variables at N pairs (z, z2) (their units):
    B_i(z) B_j(z2) in column i n2 + j, each variable clamped to its range (the products sum to
    1 over the rectangle); of a product of closed forms (N, 2): 1 and g1(z) g2(z2) / g_max."""
    if not group.tensor:
        raise ValueError(f"{group.text} is a shape of one variable: its basis is basis's")
    z = np.atleast_1d(np.asarray(z, dtype=np.float64))
    z2 = np.atleast_1d(np.asarray(z2, dtype=np.float64))
    if group.form:  # a product of closed forms: a + b g1 g2 / g_max
        g1, g2 = parse_forms(group.form)
        g = g1(_form_at(group.variable, g1, z, group.lo, group.hi)) * g2(
            _form_at(group.variable2, g2, z2, group.lo2, group.hi2)
        )
        return np.column_stack([np.ones_like(g), g / form_scale(group)])
    a = _spline_basis(group.lo, group.hi, group.n, z)
    b = _spline_basis(group.lo2, group.hi2, group.n2, z2)
    return np.asarray((a[:, :, None] * b[:, None, :]).reshape(z.size, -1))


def surface(group: Group, coefficients: Any, z: Any, z2: Any) -> FloatArray:
    """f(z, z2) of one component of a shape of two variables for its n n2 coefficients (of a
    product of closed forms its (a, b))."""
    return np.asarray(basis2(group, z, z2) @ np.asarray(coefficients, dtype=np.float64))


def curve(group: Group, coefficients: Any, z: Any) -> FloatArray:
    """f(z) of one component of ``group`` for its n coefficients: the dimensionless shape; the
    force is f times the group's scaling and multiplier (:meth:`Group.formula`). A memory's
    closed form: the share of the gap e = quantum sinh(z) it leaves open (:func:`memory_steps`)."""
    if group.control and group.form:
        e = np.sinh(np.atleast_1d(np.asarray(z, dtype=np.float64)))
        return memory_steps(group, coefficients, e * CONTROLS[group.control].quantum)[0]
    return np.asarray(basis(group, z) @ np.asarray(coefficients, dtype=np.float64))


def away_sign(gaps: Any, prev: Any) -> FloatArray:
    """Gaps e of a control signed away from its zero: +|e| where the control moves away from
    it (e and the acting value of the step before, ``prev``, of one sign, or ``prev`` = 0),
    -|e| where it moves back (the same arithmetic as the hook's)."""
    e = np.asarray(gaps, dtype=np.float64)
    side = np.where(np.asarray(prev, dtype=np.float64) != 0.0, prev, e)
    return np.asarray(np.copysign(np.abs(e), e * side), dtype=np.float64)


def memory_coefficients(variable: str) -> int:
    """Coefficients of a memory's closed form of the gap ``variable``: 1, or 2 of a gap signed
    away from the control's zero (the moves away, the moves back)."""
    return 2 if VARIABLES[variable].away else 1


def memory_range(group: Group) -> float:
    """The largest gap of a memory group's range, e_max = quantum sinh(max(-lo, hi)) [the
    control's unit]: the scale of a memory's closed form (:data:`MEMORY_FORMS`)."""
    return CONTROLS[group.control].quantum * math.sinh(max(-group.lo, group.hi))


def memory_steps(group: Group, coefficients: Any, gaps: Any) -> tuple[FloatArray, FloatArray]:
    """(share f, step e (1 - f)) of a memory group (:data:`CONTROLS`) at gaps e [the control's
    unit]: the share of the gap left open in one time step, and how far the control moves in
    it (the same arithmetic as the hook's). A closed form's share at a gap of 0 is its limit
    (play: 1, held; a rate limit: 0). Of a gap signed away from the control's zero
    (:attr:`Variable.away`) e is signed so (:func:`away_sign`), and a closed form takes its
    first coefficient where e > 0 (moving away), its second elsewhere (moving back)."""
    if not group.control:
        raise ValueError(f"{group.text} is a force, not a memory of a control")
    e = np.asarray(gaps, dtype=np.float64)
    if not group.form:
        f = curve(group, coefficients, np.arcsinh(e / CONTROLS[group.control].quantum))
        return f, np.asarray(e * (1.0 - f))
    cs = np.asarray(coefficients, dtype=np.float64).reshape(-1)
    c: Any = float(cs[0])
    if VARIABLES[group.variable].away:  # e signed away: the first moving away, the second back
        c = np.where(e > 0.0, cs[0], cs[1] if cs.size > 1 else 0.0)
    emax = memory_range(group)
    if group.form == "lag":
        step = (1.0 - c) * e
    elif group.form == "rate":
        m = (1.0 - c) * emax
        step = np.clip(e, -m, m)
    else:
        step = np.copysign(np.maximum(np.abs(e) - c * emax, 0.0), e)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(e != 0.0, 1.0 - step / np.where(e != 0.0, e, 1.0), 0.0)
    if group.form == "lag":
        f = np.where(e != 0.0, f, c)
    elif group.form == "play":
        f = np.where(e != 0.0, f, np.where(np.asarray(c) > 0.0, 1.0, 0.0))
    return np.asarray(f, dtype=np.float64), np.asarray(step, dtype=np.float64)


def difference_penalty(n: int, order: int = 2) -> FloatArray:
    """(n, n) D'D with D the ``order``-th difference matrix: the P-spline penalty
    sum_j (Delta^order c_j)^2 (its null space: polynomials of degree < order in j)."""
    if n <= order:
        return np.zeros((n, n))
    D = np.diff(np.eye(n), n=order, axis=0)
    return np.asarray(D.T @ D)


def penalty(group: Group, order: int = 2) -> FloatArray:
    """(k, k) penalty of a group's k coefficients: :func:`difference_penalty` for each
    component's shape, block-diagonal (components major, as the parameters); for a shape of two
    variables the second differences along each of them (the tensor-product P-spline's)."""
    P = difference_penalty(group.n, order)
    if group.tensor:  # the differences along each variable: P (x) I + I (x) P2
        P2 = difference_penalty(group.n2, order)
        P = np.kron(P, np.eye(group.n2)) + np.kron(np.eye(group.n), P2)
    return np.asarray(np.kron(np.eye(len(group.components)), P))


def variable_values(
    name: str, t: Any, x: Any, controls: Any, wind: Any, theta: Any, ship: Any
) -> FloatArray:
    """(N,) values of the variable ``name`` (a key of :data:`VARIABLES`) at N samples, as the
    hook computes them: t (N,) [s], x (N, 6) states (x0, u, y0, v_m, psi, r), controls (N, 2)
    (delta, n_p), wind (N, 2) (U_T, gamma_T), the model's parameters ``theta`` (a
    :class:`mmg.params.Theta`) and ``ship``. Still water (velocity through the water = over
    ground); a control's gap is the log's change from the sample before (0 at the first: the
    acting control of a model without memory). For the knot ranges of shapes over recorded
    windows."""
    from mmg.model import rudder_inflow_at
    from mmg.propeller import advance_ratio, wake_factor

    x = np.asarray(x, dtype=np.float64)
    c = np.asarray(controls, dtype=np.float64)
    w = np.asarray(wind, dtype=np.float64)
    u, v_m, r, psi = x[:, 1], x[:, 3], x[:, 5], x[:, 4]
    U2 = u * u + v_m * v_m
    gap = w[:, 1] - psi
    uA = w[:, 0] * np.cos(gap) + u  # mmg.wind.apparent_wind
    vA = w[:, 0] * np.sin(gap) + v_m
    rows = zip(u, v_m, r, c[:, 1], strict=True)
    if name == "alphaR":
        inflow = np.array([rudder_inflow_at(*p, theta, ship) for p in rows]).reshape(-1, 2)
        return np.asarray(c[:, 0] - np.arctan2(inflow[:, 1], inflow[:, 0]))
    var = VARIABLES.get(name)
    if var is not None and var.control:  # the log's own gaps: the acting control is the logged
        k = CONTROLS[var.control]  # one where no memory acts
        log = c[:, k.column]
        prev = np.concatenate([log[:1], log[:-1]])
        gaps = away_sign(log - prev, prev) if var.away else log - prev
        return np.asarray(np.arcsinh(gaps / k.quantum))
    if name == "JP":
        return np.array(
            [advance_ratio(a, n, ship) * wake_factor(a, b, q, theta, ship) for a, b, q, n in rows]
        )
    values = {
        "beta": lambda: np.arctan2(-v_m, u),
        "rp": lambda: r * ship.L_pp / np.sqrt(U2 + U_0 * U_0),
        "U": lambda: np.sqrt(U2),
        "u": lambda: u,
        "v": lambda: v_m,
        "vp": lambda: v_m / np.maximum(np.sqrt(U2), float(V_PRIME_FLOOR)),
        "delta": lambda: c[:, 0],
        "n": lambda: c[:, 1],
        "gammaA": lambda: np.arctan2(vA, uA),
        "UA": lambda: np.hypot(uA, vA),
        "psi": lambda: psi - _TWO_PI * np.floor((psi + math.pi) / _TWO_PI),
        "x0": lambda: x[:, 0],
        "y0": lambda: x[:, 2],
        "t": lambda: np.asarray(t, dtype=np.float64),
    }
    if name not in values:
        raise ValueError(f"unknown shape variable {name!r}; known: {', '.join(VARIABLES)}")
    return np.asarray(values[name](), dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# the generated effect


_TEMPLATE = '''\
"""Generated by mmg.shapes: the effect {name}. Do not edit."""
import math
from typing import NamedTuple

import numpy as np

from mmg._jit import subfunction
from mmg.model import rudder_inflow_at
from mmg.hull import hull_forces
from mmg.propeller import advance_ratio, propeller_forces, wake_factor
from mmg.rudder import lift_gradient, rudder_forces
from mmg.trig import atan2 as _atan2, sincos as _sincos
from mmg.wind import apparent_wind, wind_forces


class {ptype}(NamedTuple):
{fields}


@subfunction
def _b3(x):
    """The cardinal cubic B-spline at x (support [-2, 2]), free of branches."""
    a = abs(x)
    p = max(2.0 - a, 0.0)
    m = max(1.0 - a, 0.0)
    return (p * p * p - 4.0 * m * m * m) * {sixth!r}
{hooks}'''

_FORCE_HOOK = '''

@subfunction
def {func}(t, x0, y0, u, v_m, r, psi, delta, n_p, U_T, gamma_T, e, th, sh):
    """Forces of the shapes (u, v_m through the water)."""
    Lp = sh.L_pp
    q = 0.5 * sh.rho * Lp * sh.d
    U2 = u * u + v_m * v_m
    Ue = math.sqrt(U2 + {U_0!r} * {U_0!r})
{prelude}    X = 0.0
    Y = 0.0
    N = 0.0
{lines}
    return X, Y, N
'''

_INPUTS_HOOK = '''

@subfunction
def {func}(delta_log, n_log, delta_prev, n_prev, dt, e):
    """The acting controls of the memory shapes: each leaves a share of its gap open."""
    delta = delta_log
    n_p = n_log
{lines}
    return delta, n_p
'''


def _clamped(g: int, group: Group) -> str:
    """Group ``g``'s variable clamped to its knot range [lo, hi], in knot intervals from lo
    (0 .. n - 3): the range and the knots per unit 1 / h are the group's numbers in the
    parameters (``k<g>_lo``, ``k<g>_hi``, ``k<g>_h``: :func:`numbers`), not constants of the
    code, so one kernel serves every range."""
    code = VARIABLES[group.variable].code
    return f"(min(max({code}, e.k{g}_lo), e.k{g}_hi) - e.k{g}_lo) * e.k{g}_h"


def knots_per_unit(lo: float, hi: float, n: int) -> float:
    """1 / h, h = (hi - lo) / (n - 3) the knot spacing of n basis functions over [lo, hi] [the
    variable's unit], as the hook computes it (one expression, so that the hook, the probe
    and numpy agree to the last bit)."""
    return 1.0 / ((hi - lo) / (n - 3))


def numbers(groups: Sequence[Group]) -> list[tuple[str, float]]:
    """(field, value) of the numbers of ``groups`` that the code of their kernel reads from its
    parameters after the coefficients: a spline's knot range and knots per unit (``k<g>_lo``,
    ``k<g>_hi``, ``k<g>_h`` = (n - 3) / (hi - lo); a shape of two variables the same of the
    second, ``k<g>_lo2``, ...); a closed form's range, its numbers
    (``k<g>_a0``, ...) and 1 / g_max (``k<g>_gs``); a memory's closed form its range's largest
    gap e_max (``k<g>_em``, :func:`memory_range`); nothing for a constant."""
    out: list[tuple[str, float]] = []
    for g, group in enumerate(groups):
        if group.variable == "1":
            continue
        if group.form and group.control:  # a memory's closed form: the range's largest gap
            out.append((f"k{g}_em", memory_range(group)))
            continue
        out += [(f"k{g}_lo", float(group.lo)), (f"k{g}_hi", float(group.hi))]
        if group.form:
            args = [a for form in parse_forms(group.form) for a in form.args]
            out += [(f"k{g}_a{i}", float(a)) for i, a in enumerate(args)]
            out.append((f"k{g}_gs", 1.0 / form_scale(group)))
            if group.tensor:
                out += [(f"k{g}_lo2", group.lo2), (f"k{g}_hi2", group.hi2)]
            continue
        else:
            out.append((f"k{g}_h", knots_per_unit(group.lo, group.hi, group.n)))
        if group.tensor:
            h2 = knots_per_unit(group.lo2, group.hi2, group.n2)
            out += [(f"k{g}_lo2", group.lo2), (f"k{g}_hi2", group.hi2), (f"k{g}_h2", h2)]
    return out


def structure_text(group: Group) -> str:
    """The group as a spec writes it without its knot range and its closed form's numbers
    (``N~beta/23*Y_H``, ``YN~beta:oddup*Y_H``): what the code of its kernel depends on."""
    text = re.sub(r"\[[^\]]*\]", "", group.text)
    return re.sub(r"([a-z]+)\([^)]*\)", r"\1", text)  # (only a form's numbers are in brackets)


def _lane_clamped(group: Group, second: bool = False) -> str:
    """Like :func:`_clamped`, with the knot range [L, U] and the knots per unit H = 1 / h of the
    probe's lane (its parameters) instead of constants: a probe's code is then the same for
    every range and number of basis functions. ``second``: a shape of two variables' second
    variable, in the lane's [L2, U2] and H2."""
    if second:
        code = VARIABLES[group.variable2].code
        return f"(min(max({code}, e.L2), e.U2) - e.L2) * e.H2"
    code = VARIABLES[group.variable].code
    return f"(min(max({code}, e.L), e.U) - e.L) * e.H"


def _factors(group: Group) -> tuple[list[str], dict[str, str]]:
    """(lines that set ``mult``, the factor of each component's shape): the scaling (with q and
    L_pp) times the multiplier, or the multiplying force (and the lever L_pp)."""
    m = group.multiplier
    if m in SHARES:
        return [], {"S": m}
    if group.force:
        setup = []
        term = group.force
        if group.quadrant:  # the force in one quadrant: a branch of its sub-model
            setup = [f"    ind = {INDICATORS[group.quadrant][1]}"]
            term = f"{term} * ind"
        if FORCES[group.force][1]:  # a moment: divided by L_pp into a force
            return setup, {"X": f"{term} / Lp", "Y": f"{term} / Lp", "N": term}
        return setup, {"X": term, "Y": term, "N": f"{term} * Lp"}
    mult = INDICATORS[m][1] if m in INDICATORS else (VARIABLES[m].factor if m else "1.0")
    _, _, sx, syn = SCALES[group.scale_name]
    return [f"    mult = {mult}"], {
        "X": f"q * {sx} * mult",
        "Y": f"q * {syn} * mult",
        "N": f"q * Lp * {syn} * mult",
        "x": f"q * {sx} * mult",
        "y": f"q * {syn} * mult",
    }


def _group_lines(g: int, group: Group) -> list[str]:
    """The hook's code of group ``g``: the clamped variable, its basis, each component's sum."""
    lines = [f"    # {structure_text(group)}"]
    if group.variable == "1":
        b = ["1.0"]
    elif group.form:  # f = a + b g(z) / g_max, z held at the ends of its range (not on a circle)
        forms = parse_forms(group.form)
        lines.append(_form_input("z", group.variable, forms[0], f"e.k{g}_lo", f"e.k{g}_hi"))
        args = [f"e.k{g}_a{i}" for i in range(sum(len(f.args) for f in forms))]
        g1 = forms[0].code("z", args[: len(forms[0].args)])
        if group.tensor:  # a product g1(z) g2(z2), z2 held at the ends of its range too
            lines.append(_form_input("z2", group.variable2, forms[1], f"e.k{g}_lo2", f"e.k{g}_hi2"))
            g1 = f"({g1}) * ({forms[1].code('z2', args[len(forms[0].args) :])})"
        b = ["1.0", f"({g1}) * e.k{g}_gs"]
    elif group.tensor:  # sum_ij c_ij B_i(z) B_j(z2), the second variable's basis bb<j>
        lines += _basis_lines(g, group)
        code2 = VARIABLES[group.variable2].code
        clamped2 = f"(min(max({code2}, e.k{g}_lo2), e.k{g}_hi2) - e.k{g}_lo2) * e.k{g}_h2"
        lines += _spline_lines(clamped2, "bb", group.n2)
        b = [f"b{i} * bb{j}" for i in range(group.n) for j in range(group.n2)]
    else:
        lines += _basis_lines(g, group)
        b = [f"b{j}" for j in range(group.n)]
    setup, factor = _factors(group)
    lines += setup
    for c in group.components:
        terms = " + ".join(f"e.s{g}_{c}{j} * {bj}" for j, bj in enumerate(b))
        if c == "S":  # one share of the sub-model's three components
            lines.append(f"    f = {terms}")
            forces = zip("XYN", SHARES[factor[c]][1:], strict=True)
            lines += [f"    {x} += f * {name}" for x, name in forces]
        elif c in BASIN:  # along the basin's axis, turned into the ship's by the heading
            lines.append(f"    F = ({factor[c]}) * ({terms})")
            lines += [f"    {x} += F * {k}" for x, k in zip("XY", BASIN_AXES[c], strict=True)]
        else:
            lines.append(f"    {c} += ({factor[c]}) * ({terms})")
    return lines


def _spline_lines(clamped: str, name: str, n: int) -> list[str]:
    """``s`` = the clamped variable in knot intervals from lo, and its n basis functions
    ``<name>0`` .. ``<name><n-1>``."""
    lines = [f"    s = {clamped}"]
    for j in range(n):
        lines.append(f"    {name}{j} = _b3(s {'+' if j < 1 else '-'} {abs(float(j - 1))!r})")
    return lines


def _basis_lines(g: int, group: Group) -> list[str]:
    """Spline group ``g``'s clamped variable ``s`` and its basis functions ``b0`` .. ``b<n-1>``."""
    return _spline_lines(_clamped(g, group), "b", group.n)


def _side(control: Control) -> str:
    """The hook's line of the side a gap is signed against (:func:`away_sign`): the acting value
    of the step before, or at 0 the gap itself."""
    return f"    side = {control.prev} if {control.prev} != 0.0 else gap"


def _gap_lines(group: Group) -> list[str]:
    """The gap of a memory group's control and the gap's variable z (:data:`CONTROLS`)."""
    k = CONTROLS[group.control]
    code = VARIABLES[group.variable].code
    if VARIABLES[group.variable].away:  # signed away from the control's zero: away_sign
        return [
            f"    gap = {k.log} - {k.prev}",
            _side(k),
            f"    {code} = math.asinh(math.copysign(abs(gap), gap * side) * {1.0 / k.quantum!r})",
        ]
    return [
        f"    gap = {k.log} - {k.prev}",
        f"    {code} = math.asinh(gap * {1.0 / k.quantum!r})",
    ]


def _memory_lines(g: int, group: Group) -> list[str]:
    """The inputs hook's code of memory group ``g``: the control less the share of its gap."""
    c = group.control
    if group.form:  # the step of the closed form; e_max is the group's number k<g>_em
        k = CONTROLS[c]
        coefficient = [f"    c = e.s{g}_{c}0"]
        if VARIABLES[group.variable].away:  # one coefficient moving away, one moving back
            coefficient = [_side(k), f"    c = e.s{g}_{c}0 if gap * side > 0.0 else e.s{g}_{c}1"]
        return [
            f"    # {structure_text(group)}",
            f"    gap = {k.log} - {k.prev}",
            f"    emax = e.k{g}_em",
            *coefficient,
            f"    {k.symbol} -= {MEMORY_FORMS[group.form][2]}",
        ]
    lines = [f"    # {structure_text(group)}", *_gap_lines(group), *_basis_lines(g, group)]
    terms = " + ".join(f"e.s{g}_{c}{j} * b{j}" for j in range(group.n))
    lines.append(f"    {CONTROLS[c].symbol} -= gap * ({terms})")
    return lines


def _probe_memory_lines(groups: Sequence[Group]) -> list[str]:
    """The probe's inputs hook: one basis function (J) of the memory group G at amplitude A."""
    lines: list[str] = []
    for g, group in enumerate(groups):
        if not group.control:
            continue
        lines += [f"    # {group.structure}", f"    w = 1.0 if e.G == {float(g)!r} else 0.0"]
        lines += _gap_lines(group)
        lines.append(
            f"    {CONTROLS[group.control].symbol} -= w * gap * e.A * "
            f"_b3({_lane_clamped(group)} - (e.J - 1.0))"
        )
    return lines


def _probe_lines(groups: Sequence[Group]) -> list[str]:
    """The probe's code: every group's clamped variable and factors weighted by [G == g], then
    one basis function (J) of one component (C) at amplitude A; no branch."""
    pairs = any(g.tensor for g in groups)
    lines = ["    z = 0.0", "    spline = 0.0"]
    if pairs:  # the second variable of a shape of two variables, in the lane's range
        lines += ["    z2 = 0.0", "    pair = 0.0"]
    basin = any(c in BASIN for g in groups for c in g.components)
    sums = ("X", "Y", "N", "SX", "SY", "SN", *(BASIN if basin else ()))
    lines += [f"    f{c} = 0.0" for c in sums]
    for g, group in enumerate(groups):
        if group.control:
            continue
        lines += [f"    # {group.structure}", f"    w = 1.0 if e.G == {float(g)!r} else 0.0"]
        if group.variable != "1":
            lines += [f"    z += w * ({_lane_clamped(group)})", "    spline += w"]
        if group.tensor:
            lines += [f"    z2 += w * ({_lane_clamped(group, True)})", "    pair += w"]
        setup, factor = _factors(group)
        lines += setup
        for c in group.components:
            if c == "S":
                forces = zip("XYN", SHARES[factor[c]][1:], strict=True)
                lines += [f"    fS{x} += w * {name}" for x, name in forces]
            else:
                lines.append(f"    f{c} += w * ({factor[c]})")
    s = float(COMPONENTS.index("S"))
    b = "    b = e.A * (spline * _b3(z - (e.J - 1.0)) + (1.0 - spline))"
    if pairs:  # B_J(z) B_J2(z2) for a lane of a shape of two variables
        lines.append("    b2 = pair * _b3(z2 - (e.J2 - 1.0)) + (1.0 - pair)")
        b += " * b2"
    lines += [b, f"    share = 1.0 if e.C == {s!r} else 0.0"]
    turned = ["", ""]
    if basin:  # a force fixed to the basin, along x0 (ex) or y0 (ey), on the ship's axes
        for c in BASIN:
            k = float(COMPONENTS.index(c))
            lines.append(f"    e{c} = (1.0 if e.C == {k!r} else 0.0) * f{c}")
        turned = ["".join(f" + e{c} * {BASIN_AXES[c][i]}" for c in BASIN) for i in (0, 1)]
    lines += [
        f"    X = ((1.0 if e.C == 0.0 else 0.0) * fX + share * fSX{turned[0]}) * b",
        f"    Y = ((1.0 if e.C == 1.0 else 0.0) * fY + share * fSY{turned[1]}) * b",
        "    N = ((1.0 if e.C == 2.0 else 0.0) * fN + share * fSN) * b",
    ]
    return lines


def _prelude(lines: Sequence[str]) -> list[str]:
    """The prelude blocks that the groups' lines need (and the blocks those need), in order."""
    used = set(re.findall(r"\b\w+\b", "\n".join(lines)))
    wanted = [False] * len(_PRELUDE)
    for k in reversed(range(len(_PRELUDE))):  # later blocks use earlier ones only
        names, code = _PRELUDE[k]
        if used & set(names):
            wanted[k] = True
            used |= set(re.findall(r"\b\w+\b", "\n".join(code)))
    return [f"    {line}" for k, (_, code) in enumerate(_PRELUDE) if wanted[k] for line in code]


def _source(name: str, groups: Sequence[Group], key: str, probe: bool = False) -> str:
    """The generated module: the parameters, a force hook when a group is a force, an inputs
    hook when a group is a memory (:func:`hook_names`)."""
    lines: list[str] = []
    memory: list[str] = []
    fields: list[str] = []
    extra = ""
    if probe:
        lines = _probe_lines(groups)
        memory = _probe_memory_lines(groups)
        fields = [
            "    G: float  # the group (0, 1, ...)",
            "    C: float  # the component (0: X, 1: Y, 2: N, 3: D, 4: P, 5: S, 6: x, 7: y)",
            "    J: float  # the basis function (0 .. n - 1)",
            "    A: float  # its coefficient (0: no force)",
            "    L: float  # the group's knot range [L, U] in the variable's unit",
            "    U: float",
            "    H: float  # its knots per unit of the variable, (n - 3) / (U - L)",
        ]
        if any(g.tensor for g in groups):
            fields += [
                "    J2: float  # the second variable's basis function (0 .. n2 - 1)",
                "    L2: float  # the second variable's knot range [L2, U2]",
                "    U2: float",
                "    H2: float  # its knots per unit, (n2 - 3) / (U2 - L2)",
            ]
        name = "probe of " + "+".join(g.structure for g in groups)  # the same for any range
    else:
        for g, group in enumerate(groups):
            if group.control:
                memory += _memory_lines(g, group)
            else:
                lines += _group_lines(g, group)
            for c in group.components:
                formula = group.formula(c, g)
                fields += [f"    s{g}_{c}{j}: float  # {formula}" for j in range(group.size)]
        # the kernel's rows: the coefficients, then the groups' numbers (the same code for
        # every knot range and closed form's numbers)
        rows = [*fields, *(f"    {f}: float" for f, _ in numbers(groups))]
        extra = f"\n\nclass ShapeRows_{key}(NamedTuple):\n" + "\n".join(rows) + "\n"
        name = "kernel of " + "+".join(structure_text(g) for g in groups)
    force_name, inputs_name = hook_names(groups, key)
    hooks = ""
    if force_name:
        hooks += _FORCE_HOOK.format(
            func=force_name,
            U_0=U_0,
            prelude="".join(f"{line}\n" for line in _prelude(lines)),
            lines="\n".join(lines),
        )
    if inputs_name:
        hooks += _INPUTS_HOOK.format(func=inputs_name, lines="\n".join(memory))
    return _TEMPLATE.format(
        name=name,
        ptype=f"ShapeParams_{key}",
        fields="\n".join(fields) + ("" if probe else extra),
        sixth=1.0 / 6.0,
        hooks=hooks,
    )


def hook_names(groups: Sequence[Group], key: str) -> tuple[str, str]:
    """(force hook, inputs hook) of the generated module of ``groups`` ("" for one it lacks)."""
    force = any(not g.control for g in groups)
    memory = any(g.control for g in groups)
    return (f"shape_force_{key}" if force else "", f"shape_inputs_{key}" if memory else "")


class ShapeEffect(Effect):
    """A generated shape effect: it pickles by its name and parameter table (its module lives in
    the kernel directory, not on the import path), like :class:`mmg.discovered.DiscoveredEffect`.
    Its groups: :func:`groups_of`."""

    def __reduce__(self) -> tuple[Any, ...]:
        """(:func:`rebuild`, (name, parameter table))."""
        return (rebuild, (self.name, tuple(tuple(p) for p in self.params)))

    def kernel_form(self) -> KernelForm:
        """The kernel of the shapes' structure (:func:`shape_kernel`), the groups' numbers
        (:func:`numbers`) after the coefficients; a probe runs itself."""
        if self.name.endswith(PROBE_SUFFIX):
            return self, None, ()
        form = _forms.get(self.name)  # (every simulation asks: parsing the name took 0.2 ms)
        if form is None:
            groups = groups_of(self)
            form = shape_kernel(groups), None, tuple(v for _, v in numbers(groups))
            _forms[self.name] = form
        return form


#: the kernels' effects of shape structures, by the text of the structure
_kernels: dict[str, Effect] = {}
#: the kernel forms of shape effects, by name (the search intervals take no part in them)
_forms: dict[str, tuple[Effect, None, tuple[float, ...]]] = {}


def shape_kernel(groups: Sequence[Group]) -> Effect:
    """The effect whose code the kernel of shapes of ``groups``' structure is compiled from: the
    coefficients and then the groups' numbers (knot ranges, closed forms' numbers:
    :func:`numbers`) are its parameters, so shapes learnt on other data, over other ranges,
    run the same compiled kernel."""
    name = "kernel of " + "+".join(structure_text(g) for g in groups)
    made = _kernels.get(name)
    if made is not None:
        return made
    module, key = _module(name, groups)
    # (the numbers' values come with each shape effect's rows: :meth:`ShapeEffect.kernel_form`)
    params = _coefficients(groups) + [
        EffectParam(f, "-", 0.0, 0.0, 0.0, "a number of the groups' code")
        for f, _ in numbers(groups)
    ]
    made = Effect(
        name=name,
        description="the code of shapes " + "+".join(structure_text(g) for g in groups),
        regime="shapes",
        params=tuple(params),
        param_type=getattr(module, f"ShapeRows_{key}"),
        **_hooks(module, groups, key),
    )
    _kernels[name] = made
    return made


def _coefficients(groups: Sequence[Group]) -> list[EffectParam]:
    """The coefficients of a shape effect of ``groups``: neutral 0, searched in
    [-:data:`DEFAULT_BOUND`, :data:`DEFAULT_BOUND`] (a memory's in [0, DEFAULT_BOUND])."""
    params: list[EffectParam] = []
    for k, g in enumerate(groups):
        lower = 0.0 if g.control else -DEFAULT_BOUND
        for c in g.components:
            formula = g.formula(c, k)
            for j in range(g.size):
                if g.form and g.control:  # the memory's one coefficient, named in the formula
                    role = formula
                elif g.form:
                    role = f"{'ab'[j]} of {formula}"
                else:
                    role = f"coefficient {j} of {formula}"
                params.append(EffectParam(f"s{k}_{c}{j}", "-", 0.0, lower, DEFAULT_BOUND, role))
    return params


#: the shape effects of this process by name, with the default search intervals
_generated: dict[str, ShapeEffect] = {}


def _module(name: str, groups: Sequence[Group], probe: bool = False) -> tuple[Any, str]:
    """The generated module of ``groups`` (written and imported once per process), its key."""
    key = hashlib.sha256(_source(name, groups, "KEY", probe).encode()).hexdigest()[:16]
    module_name = f"mmg_shape_{key}"
    module = generated_module(module_name, _source(name, groups, key, probe))
    return module, key


def _hooks(module: Any, groups: Sequence[Group], key: str) -> dict[str, Any]:
    """The hooks of a generated module: force_at for the forces, inputs for the memories."""
    force, inputs = hook_names(groups, key)
    return {
        "force_at": getattr(module, force) if force else None,
        "inputs": getattr(module, inputs) if inputs else None,
    }


def shape_effect(groups: Sequence[Group] | str, bound: float = DEFAULT_BOUND) -> Effect:
    """The shape effect of ``groups`` (or of a spec) with every coefficient searched in
    [-bound, bound], a memory's in [0, bound] (its share lies between the control's place
    before and the log, f in [0, 1] for bound 1: the B-splines are positive and sum to one);
    the one with the default interval is kept under its name for :func:`by_name`. Raises
    ValueError for a malformed spec, no group or a repeated one."""
    from dataclasses import replace

    gs = parse(groups) if isinstance(groups, str) else tuple(groups)
    name = shape_name(gs)
    if len({g.text for g in gs}) != len(gs):
        raise ValueError(f"repeated shape group in {name!r}")
    effect = _generated.get(name)
    if effect is None:
        kernel = shape_kernel(gs)
        params = tuple(_coefficients(gs))
        # its hooks: the kernel's, with the groups' numbers written in
        hooks = with_numbers(
            "mmg.shapes", name, [q.name for q in params], kernel, [v for _, v in numbers(gs)]
        )
        module = sys.modules[kernel.param_type.__module__]
        effect = ShapeEffect(
            name=name,
            description=(
                "closed form of a missing force: "
                if all(g.form or g.variable == "1" for g in gs)
                else "shapes of a missing force: "
                if not any(g.control for g in gs)
                else "shapes of a missing force or memory of the controls: "
            )
            + "; ".join(g.text for g in gs),
            regime="shapes",
            params=params,
            param_type=getattr(module, kernel.param_type.__name__.replace("Rows", "Params")),
            force_at=hooks.get("force_at"),
            inputs=hooks.get("inputs"),
        )
        _generated[name] = effect
    if bound == DEFAULT_BOUND:
        return effect
    table = tuple(
        q._replace(lower=0.0 if q.lower == 0.0 else -float(bound), upper=float(bound))
        for q in effect.params
    )
    return replace(effect, params=table)


def probe_effect(groups: Sequence[Group] | str) -> Effect:
    """The probe of ``groups``: the force of one coefficient of their shape effect at a time,
    chosen by its parameters (G: group, C: component 0/1/2/5 for X/Y/N/S, J: basis function,
    A: the coefficient's value, A = 0 is neutral; L, U: the group's knot range, H: its knots
    per unit of the variable; with a shape of two variables among ``groups`` also J2, L2, U2,
    H2: the second variable's basis function, range and knots per unit, the lane's force
    B_J(z) B_J2(z2)). Each lane of a batch sets its own, so one simulation batch gives
    the trajectory column of every coefficient at the cost of a single basis function per lane;
    the shape effect itself evaluates all of them in every lane (30 x the base model's time for
    460 coefficients).
    The knots are the lanes' own, not constants of the code: the probes of groups of one
    structure (:attr:`Group.structure`) share one module and one compiled kernel, whatever the
    ranges and numbers of basis functions. Named ``<shape effect's name>#probe``."""
    gs = parse(groups) if isinstance(groups, str) else tuple(groups)
    if any(g.form for g in gs):
        raise ValueError("a closed form is fitted directly; only splines have a probe")
    name = shape_name(gs) + PROBE_SUFFIX
    effect = _generated.get(name)
    if effect is None:
        module, key = _module(name, gs, probe=True)
        table: tuple[tuple[str, float, float, float, str], ...] = (
            ("G", 0.0, 0.0, len(gs) - 1, "group"),
            ("C", 0.0, 0.0, 7.0, "component (0: X, 1: Y, 2: N, 3: D, 4: P, 5: S, 6: x, 7: y)"),
            ("J", 0.0, 0.0, MAX_BASIS - 1, "basis function"),
            ("A", 0.0, 0.0, 1.0, "coefficient"),
            ("L", 0.0, -PROBE_RANGE, PROBE_RANGE, "lower end of the group's knot range"),
            ("U", 1.0, -PROBE_RANGE, PROBE_RANGE, "upper end of the group's knot range"),
            ("H", 1.0, 0.0, PROBE_RANGE, "knots per unit of the variable, (n - 3) / (U - L)"),
        )
        if any(g.tensor for g in gs):
            table += (
                ("J2", 0.0, 0.0, MAX_BASIS - 1, "the second variable's basis function"),
                ("L2", 0.0, -PROBE_RANGE, PROBE_RANGE, "lower end of its knot range"),
                ("U2", 1.0, -PROBE_RANGE, PROBE_RANGE, "upper end of its knot range"),
                ("H2", 1.0, 0.0, PROBE_RANGE, "its knots per unit, (n2 - 3) / (U2 - L2)"),
            )
        effect = ShapeEffect(
            name=name,
            description="one coefficient at a time of " + shape_name(gs),
            regime="shapes",
            params=tuple(
                EffectParam(p, "-", neutral, lo, hi, role) for p, neutral, lo, hi, role in table
            ),
            param_type=getattr(module, f"ShapeParams_{key}"),
            **_hooks(module, gs, key),
        )
        _generated[name] = effect
    return effect


def probe_rows(effect: Effect, step: float, probe: Sequence[Group] | None = None) -> FloatArray:
    """(k, 7) parameter rows of a probe for ``effect`` (a shape effect with k coefficients):
    row i sets the shape effect's coefficient i to ``step`` (G, C, J, A, L, U, H; a probe with a
    shape of two variables has 11 columns, the second variable's J2, L2, U2, H2 after them,
    neutral for a group of one variable). ``probe``: the
    groups the probe was made for (default: the effect's own); each of the effect's groups is
    the probe's first group that serves it (:func:`serves`), at its own range. Raises
    ValueError for a group whose structure the probe lacks."""
    groups = groups_of(effect)
    within = groups if probe is None else probe
    pairs = any(h.tensor for h in within)
    rows: list[tuple[float, ...]] = []
    for group in groups:
        g = next((k for k, h in enumerate(within) if serves(h, group)), None)
        if g is None:
            raise ValueError(f"the probe has no group of the structure {group.structure}")
        knots = (0.0, 1.0, 1.0)  # a constant's lanes: the neutral knots
        if group.variable != "1":  # H as the shape effect's own code computes 1 / h
            knots = (group.lo, group.hi, knots_per_unit(group.lo, group.hi, group.n))
        second = [(0.0, 0.0, 1.0, 1.0)]  # no second variable: its neutral lane values
        if group.tensor:  # coefficient i n2 + j: B_i(z) B_j(z2)
            h2 = knots_per_unit(group.lo2, group.hi2, group.n2)
            second = [(float(j2), group.lo2, group.hi2, h2) for j2 in range(group.n2)]
        for c in group.components:
            rows += [
                (g, COMPONENTS.index(c), j, step, *knots, *(more if pairs else ()))
                for j in range(group.n)
                for more in second
            ]
    return np.asarray(rows, dtype=np.float64)


def serves(probe: Group, group: Group) -> bool:
    """Whether the probe's group ``probe`` gives the columns of ``group``: the same structure,
    or the same but for components, ``probe``'s among them (the probe computes each of its
    components' force and the lane's C picks one: ``XYN~beta`` serves ``N~beta``)."""
    if probe.structure == group.structure:
        return True
    body = probe.structure.partition("~")[2]
    return body == group.structure.partition("~")[2] and set(group.components) <= set(
        probe.components
    )


def groups_of(effect: Effect) -> tuple[Group, ...]:
    """The groups of a shape effect or its probe (from the name)."""
    return parse(effect.name.removesuffix(PROBE_SUFFIX))


def by_name(name: str) -> Effect:
    """The shape effect ``name``: the one made in this process, else made now. Raises
    ValueError for a malformed spec, or one not written canonically (the parameters of a
    parameter file are found by the effect's name, so there is one spelling of it)."""
    made = _generated.get(name)
    if made is not None:
        return made
    probe = name.endswith(PROBE_SUFFIX)
    spec = name[: -len(PROBE_SUFFIX)] if probe else name
    canonical = shape_name(parse(spec)) + (PROBE_SUFFIX if probe else "")
    if canonical != name:
        raise ValueError(f"write the shape effect {name!r} as {canonical!r}")
    return probe_effect(parse(spec)) if probe else shape_effect(parse(spec))


def rebuild(name: str, params: Sequence[Sequence[object]]) -> Effect:
    """The shape effect ``name`` with the parameter table ``params`` (neutral values and search
    intervals as they were): how a pickled shape effect is restored in another process."""
    from dataclasses import replace

    effect = by_name(name)
    table = tuple(EffectParam(*p) for p in params)  # type: ignore[arg-type]
    if table == effect.params:
        return effect
    return replace(effect, params=table)


def generated_names() -> list[str]:
    """The names of the shape effects made so far in this process."""
    return list(_generated)


def is_closed_form(name: str) -> bool:
    """Whether ``name`` is a shape effect of closed forms only (and constants): a learned
    shape named afterwards."""
    if not name.startswith(SHAPE_PREFIX):
        return False
    try:
        groups = parse(name)
    except ValueError:
        return False
    return any(g.form for g in groups) and all(g.form or g.variable == "1" for g in groups)


def penalty_matrix(effect: Effect, order: int = 2) -> FloatArray:
    """(k, k) block-diagonal penalty of all the coefficients of a shape effect, in parameter
    order (:func:`penalty` of each group)."""
    blocks = [penalty(g, order) for g in groups_of(effect)]
    k = sum(b.shape[0] for b in blocks)
    out = np.zeros((k, k))
    i = 0
    for b in blocks:
        out[i : i + b.shape[0], i : i + b.shape[0]] = b
        i += b.shape[0]
    return out


__all__ = [
    "BASIN",
    "BASIN_AXES",
    "COMPONENTS",
    "CONTROLS",
    "DEFAULT_BOUND",
    "FORCES",
    "FORMS",
    "FORM_GRID",
    "HARMONICS",
    "INDICATORS",
    "PROBE_SUFFIX",
    "SCALES",
    "SHAPE_PREFIX",
    "SHARES",
    "VARIABLES",
    "WAVES",
    "Control",
    "Form",
    "Group",
    "ShapeEffect",
    "away_sign",
    "basis",
    "basis2",
    "by_name",
    "cardinal_bspline",
    "curve",
    "difference_penalty",
    "form_scale",
    "groups_of",
    "hook_names",
    "is_closed_form",
    "memory_coefficients",
    "memory_steps",
    "numbers",
    "on_circle",
    "parse",
    "parse_form",
    "penalty",
    "penalty_matrix",
    "probe_effect",
    "probe_rows",
    "rebuild",
    "serves",
    "shape_effect",
    "shape_kernel",
    "shape_name",
    "structure_text",
    "surface",
    "variable_values",
]
