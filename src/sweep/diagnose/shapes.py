"""Shapes of the missing force chosen on the linearised trajectory columns.

The candidates are penalised splines of physical variables (:mod:`mmg.shapes`): for each
variable a group of basis functions per force component X, Y, N, knots over the range the
training windows cover. :class:`ShapeColumns` simulates one trajectory column per basis function
(the residual vectors' derivative with respect to its coefficient, at the base model of a
:class:`sweep.diagnose.linearised.Linearised`, in one batch) and keeps, per fold, the small
matrices that every fit below needs: the columns' Gram matrix with the base Jacobian (and the
prior's rows) projected out, and the images of the columns held out.

:meth:`ShapeColumns.select` picks whole groups (a variable's shape in one component) by their
*held-out* gain: base and shapes fitted (linearised, each shape with its second-difference
penalty lambda c' D'D c) on one fold's windows, the gain measured on the other fold's windows
without refitting, both ways round; each added group must raise the held-out gain by
``min_gain`` of what the groups before it reached, and lower the in-sample dBIC. The smoothing
of each group is chosen with it, on the same held-out gain, from a grid relative to the group's
own column scale. The
statistic compared with the null is the in-sample linearised dBIC with the effective degrees of
freedom (the trace of the hat matrix) in place of the number of coefficients;
:meth:`ShapeColumns.null_dbic` gives the same statistic for noise-only residual vectors.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg import Parameters
from mmg.effect import Effect
from mmg.shapes import (
    COMPONENTS,
    MAX_BASIS,
    Group,
    basis2,
    penalty,
    probe_effect,
    probe_rows,
    serves,
    shape_effect,
    variable_values,
)
from mmg.shapes import VARIABLES as SHAPE_VARIABLES
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.diagnose.linearised import LIBRARY_STEP, MIN_FREE, Linearised
from sweep.diagnose.threads import column_parts, map_threads
from sweep.identification.polish import residual_vectors

FloatArray = NDArray[np.float64]

#: the variables of the candidate shapes (keys of :data:`mmg.shapes.VARIABLES`)
VARIABLES = (
    "beta",
    "rp",
    "U",
    "u",
    "v",
    "vp",
    "delta",
    "alphaR",
    "JP",
    "n",
    "gammaA",
    "UA",
    "psi",
    "x0",
    "y0",
    "t",
    "ed",
    "en",
    "eda",
    "ena",
)
#: heading, position and time: where and when a run was recorded
PLACE_AND_TIME_KINDS = {"heading": ("psi",), "position": ("x0", "y0"), "time": ("t",)}
PLACE_AND_TIME = tuple(v for vs in PLACE_AND_TIME_KINDS.values() for v in vs)
#: the variables of the ship's state and controls (the default candidates): without heading,
#: position and time, which describe where and when a run was recorded. A force in them fitted
#: on one session's runs carries over to its other runs but not to another day's: on the real
#: Train-R (one day) a yaw moment in x0 passed every check on the held-out training runs and
#: raised the test recordings' J2 by 29 %
SHIP_VARIABLES = tuple(v for v in VARIABLES if v not in PLACE_AND_TIME)
#: the variables of a force fixed to the basin (components x, y: along x0 and y0), beside the
#: force on the ship's axes (X, Y, N): a force of the water or the air in the basin (a current,
#: a seiche, a wind set-up) keeps its direction there while the ship turns under it, which no
#: shape on the ship's axes of position or time alone can follow
BASIN_VARIABLES = ("x0", "y0", "t")
#: position also with the ship's speed's scaling, U^2 (beside the default U_ref^2 of a force
#: that exists at rest, fixed to the basin): a hull force that changes with where the ship is
#: (the water's depth over an uneven floor, a bank, weeds), which vanishes at rest as the
#: hull's forces do; the term library holds both kinds (E_x0, E_y0; X_Ux, Y_Usy). On a planted
#: patch of shallow water (a drag growing with u|u| and v_m|v_m| where the ship passes), a
#: surge force in x0 took 71 % of the held-out J off with U^2, 1 % with U_ref^2, where a shape
#: in time (the runs sail along the basin as time goes) had led with 55 %. With both, also the
#: surface of x0 and y0 in U^2 (:data:`PAIR_BASIS` basis functions each way): a patch of the
#: floor or a bank's stretch is local in both, where a shape of one of them spreads the force
#: over the whole width or length of the basin
SPEED_SCALED_PLACE = ("x0", "y0")
#: varying-coefficient candidates: (shape variable, multiplier). The hull's derivatives
#: varying with speed, Y_v(U) v_m U and Y_r(U) r' U^2, and with the propeller's loading,
#: Y_v(n_p) (n_p D_p)^2 v_m / U_e and Y_r(n_p) (n_p D_p)^2 r' (a propeller in oblique inflow or
#: yawing); a share of each sub-model's force varying with the drift angle (the oblique inflow
#: every sub-model sees) and with the sub-model's own variable: the hull's sway force in beta,
#: the propeller's thrust in beta and in the advance ratio J_P, the rudder's normal force in the
#: rudder angle and in its effective inflow angle alpha_R. The thrust is that of Eq. (5), where
#: n_p >= 0 (``X_P*pos``): the thrust deduction and the wake fraction act in that branch of the
#: propeller model alone, the reversed propeller's thrust is another formula (Eq. (11)); on the
#: planted thrust deduction growing with drift, its named form a + b cos 2 beta refitted by output
#: error as a share of both branches to a training J of 3.56, as a share of Eq. (5)'s to 0.858,
#: the planted form's own (benchmarks/refit_forms.py). Last, the wind's heel: the wind's side
#: force Y_A (Eq. (27)) heels the ship, and a heeled hull sailing at speed turns and drifts, a
#: force f(u) Y_A [N] (times L_pp in N) that changes with the ship's speed as the hull's forces
#: do, where the wind's own forces (a shape in gamma_A or U_A at the wind's pressure) depend on
#: the wind alone
PRODUCTS = (
    ("U", "v"),
    ("U", "rp"),
    ("n", "v"),
    ("n", "rp"),
    ("beta", "Y_H"),
    ("beta", "X_P*pos"),
    ("JP", "X_P*pos"),
    ("delta", "F_N"),
    ("alphaR", "F_N"),
    ("u", "Y_A"),
)
#: share candidates (component S): one shape scaling a sub-model's whole force (its surge force,
#: sway force and yaw moment alike), a change of that force component of the model: the hull's
#: forces in the drift angle, the rudder's in the rudder angle and in its effective inflow angle
SHARE_PRODUCTS = (
    ("beta", "F_H"),
    ("delta", "F_R"),
    ("alphaR", "F_R"),
)
#: constant groups times a quadrant indicator: astern, propeller reversed
QUADRANTS = ("ast", "rev")
#: a further group must raise the held-out gain by this share of what the groups before it
#: reached (:meth:`ShapeColumns.select`; by output error, :mod:`sweep.diagnose.pruning`)
MIN_GAIN = 0.15
#: basis functions per shape (at least)
N_BASIS = 8
#: basis functions of each variable of a shape of two variables (:func:`pair_groups`)
PAIR_BASIS = 6
#: an angle's knots are at most this far apart [rad] (up to :data:`MAX_ANGLE_BASIS` basis
#: functions): a flow angle recorded going ahead and astern spans most of a turn (alpha_R over
#: [-3.3, 2.6] rad, beta over [-3.0, 2.8]), where eight basis functions put a knot every 0.8-1.2
#: rad and round off whatever sets in within a few degrees (a stall, a separation); more knots
#: and the penalty (chosen per group on held-out runs) leave the smoothness to the data, as
#: P-splines do
ANGLE_KNOT_SPACING = 0.25
#: basis functions of an angle's shape at most
MAX_ANGLE_BASIS = 24
#: a shape of time has its knots at most this far apart [s] (up to
#: :data:`mmg.shapes.MAX_BASIS` basis functions): about the time the ship takes to sail its own
#: length at the recordings' speeds (L_pp / U = 3 m / 0.3 m/s), the shortest change of a force
#: its motion resolves; eight basis functions over a 400-s recording put a knot every 80 s, and
#: a force that changes sign within that (a sloshing basin, gusts) would be averaged away
TIME_KNOT_SPACING = 10.0
#: basis functions per memory shape (the share of a control's gap left open, over the gap's
#: asinh scale: a knot every ~0.6, from a degree's play to a reversal)
N_MEMORY_BASIS = 16
#: the knots span these quantiles of a variable over the training windows
RANGE_QUANTILES = (0.005, 0.995)
#: values at least this large are a sub-model's guard, not a state (J_s = 1e4 at n_p = 0)
GUARD = 1e3
#: variables on a clock [s], never a sub-model's guard: a session's split logs go on counting
#: (the real random runs' last logs start at 1176-3224 s), and a guard on them held every
#: window after 1000 s at the shape's value there
CLOCKS = ("t",)
#: smoothing grid: lambda = kappa x the mean diagonal of the group's projected Gram matrix
KAPPAS = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)
#: weight of the centring of a shape whose level another chosen group carries: the penalty
#: CENTRE_WEIGHT x the group's column scale x (sum of its coefficients)^2 / n, for the joint fit
CENTRE_WEIGHT = 1e3
#: a surface's coefficient whose basis function holds less than this share of the training
#: samples (:func:`support`) is held at 0 by a ridge of SUPPORT_WEIGHT x the unit's column
#: scale: the range of a pair of variables is a rectangle, and the runs visit only part of
#: it; where none went, a surface fitted elsewhere predicts nothing (on the strong planted
#: weather helm a 6 x 6 surface of u and the apparent-wind angle made 12 of 12 held-out
#: training runs better and the test recordings' J2 300 x worse; held at 0 there, 28 x)
SUPPORT_MIN = 5e-3
SUPPORT_WEIGHT = 1e3
#: the coefficient at which a memory's columns are taken (a secant, not a derivative): at a
#: share of 0 the acting control closes every gap at once, so a small share left open at one
#: step is closed at the next and a derivative there sees only the log's own steps, never a
#: memory that persists (a play, a rate limit over several steps); at a share of about one the
#: perturbation persists as the memory does
MEMORY_STEP = 1.0
#: float64 residuals per simulation batch of the columns [bytes]
BATCH_BYTES = 2**28


def variable_ranges(
    windows: Sequence[Recording],
    params: Parameters,
    names: Sequence[str] = VARIABLES,
    quantiles: tuple[float, float] = RANGE_QUANTILES,
) -> dict[str, tuple[float, float]]:
    """{variable: (lo, hi)}: the ``quantiles`` of each variable over the recorded samples of
    ``windows`` (with the base ``params`` for the rudder inflow and the wake), leaving out
    a sub-model's guard (:func:`usable`: the advance ratio where the propeller stands still); a
    variable that does not vary there (a constant propeller speed; a range narrower than 1e-4
    of the variable's size) is left out. A control's gap spans [-m, m], m its largest size:
    the log's steps are few, and the largest matter."""
    out: dict[str, tuple[float, float]] = {}
    for n, z in sampled(windows, params, names).items():
        if SHAPE_VARIABLES[n].control and z.size:
            m = float(np.max(np.abs(z)))
            r = (-m, m) if _varies(-m, m) else None
        else:
            r = range_of(z, quantiles)
        if r is not None:
            out[n] = r
    return out


def range_of(
    z: FloatArray, quantiles: tuple[float, float] = RANGE_QUANTILES
) -> tuple[float, float] | None:
    """The knot range of the values ``z``: their ``quantiles``; None where there are none or
    they do not vary (a range narrower than 1e-4 of their size)."""
    if z.size == 0:
        return None
    lo, hi = (float(v) for v in np.quantile(z, quantiles))
    return (lo, hi) if _varies(lo, hi) else None


def _varies(lo: float, hi: float) -> bool:
    # (wider than the 6 significant digits a group's range is written with)
    return hi - lo > 1e-4 * max(1.0, abs(lo), abs(hi))


def sampled(
    windows: Sequence[Recording], params: Parameters, names: Sequence[str]
) -> dict[str, FloatArray]:
    """{variable: its values on the recorded samples of ``windows``} (with the base ``params``
    for the rudder inflow and the wake), leaving out values that are not a state
    (:func:`usable`)."""
    out: dict[str, FloatArray] = {}
    for n in names:
        z = np.concatenate(
            [variable_values(n, w.t, w.x, w.u, w.w, params.theta, params.ship) for w in windows]
        )
        out[n] = z[usable(n, z)]
    return out


def usable(variable: str, z: FloatArray) -> NDArray[np.bool_]:
    """Where the values ``z`` of ``variable`` are a state: finite, and below :data:`GUARD`
    unless the variable is a clock (:data:`CLOCKS`)."""
    ok = np.isfinite(z)
    return ok if variable in CLOCKS else ok & (np.abs(z) < GUARD)


#: at most this many samples, evenly spaced, of a pair of variables (:func:`jointly_sampled`)
JOINT_MOST = 4000


def jointly_sampled(
    windows: Sequence[Recording], params: Parameters, first: str, second: str
) -> tuple[FloatArray, FloatArray]:
    """(z, z2) of the variables ``first`` and ``second`` on the same recorded samples of
    ``windows`` (as :func:`sampled`, a sample left out where either is not a state,
    :func:`usable`), at most :data:`JOINT_MOST` of them evenly spaced: where the training runs
    went in the plane of the two, where a surface is compared with closed forms."""
    th, sh = params.theta, params.ship
    pairs = [
        np.stack([variable_values(v, w.t, w.x, w.u, w.w, th, sh) for v in (first, second)])
        for w in windows
    ]
    zz = np.concatenate(pairs, axis=1) if pairs else np.zeros((2, 0))
    keep = usable(first, zz[0]) & usable(second, zz[1])
    zz = zz[:, keep]
    if zz.shape[1] > JOINT_MOST:
        zz = zz[:, np.linspace(0, zz.shape[1] - 1, JOINT_MOST).astype(int)]
    return zz[0], zz[1]


def candidate_groups(
    windows: Sequence[Recording],
    params: Parameters,
    *,
    variables: Sequence[str] = VARIABLES,
    products: Sequence[tuple[str, str]] = PRODUCTS,
    shares: Sequence[tuple[str, str]] = SHARE_PRODUCTS,
    quadrants: Sequence[str] = QUADRANTS,
    n: int = N_BASIS,
) -> list[Group]:
    """The candidate groups, all three components each (one basis per variable in the hook):
    a shape of each variable that varies over ``windows`` (of position and time also a force
    fixed to the basin, :data:`BASIN_VARIABLES`; of position also one with the speed's scaling,
    :data:`SPEED_SCALED_PLACE`, and the surface of both in U^2), the varying-coefficient
    ``products``, the ``shares`` of sub-models' forces (one component, S) and a constant times
    each quadrant indicator; a control's gap gives the memory of that control (one component,
    :data:`N_MEMORY_BASIS` functions)."""
    used = {*variables, *(v for v, _ in products), *(v for v, _ in shares)}
    ranges = variable_ranges(windows, params, sorted(used))
    return groups_over(ranges, variables, products, shares, quadrants, n)


def groups_over(
    ranges: Mapping[str, tuple[float, float]],
    variables: Sequence[str],
    products: Sequence[tuple[str, str]],
    shares: Sequence[tuple[str, str]],
    quadrants: Sequence[str],
    n: int,
) -> list[Group]:
    """The candidate groups of the variables that have a knot range in ``ranges``."""

    def spline(components: str, v: str, multiplier: str = "") -> Group:
        return Group(components, v, *ranges[v], basis_count(v, *ranges[v], n), multiplier)

    groups = [
        Group(c, v, *ranges[v], N_MEMORY_BASIS)
        if (c := SHAPE_VARIABLES[v].control)
        else spline("XYN", v)
        for v in variables
        if v in ranges
    ]
    groups += [spline("xy", v) for v in variables if v in ranges and v in BASIN_VARIABLES]
    speed = {
        v: replace(spline("XYN", v), scale="U2")
        for v in variables
        if v in ranges and v in SPEED_SCALED_PLACE
    }
    groups += speed.values()
    if len(speed) == len(SPEED_SCALED_PLACE):  # the surface, as pair_groups draws one
        z, z2 = SPEED_SCALED_PLACE
        lo2, hi2 = ranges[z2]
        groups.append(
            replace(speed[z], n=PAIR_BASIS, variable2=z2, lo2=lo2, hi2=hi2, n2=PAIR_BASIS)
        )
    groups += [spline("XYN", v, m) for v, m in products if v in ranges]
    groups += [spline("S", v, m) for v, m in shares if v in ranges]
    groups += [Group("XYN", "1", multiplier=q) for q in quadrants]
    return groups


def pair_groups(
    ranges: Mapping[str, tuple[float, float]], first: Group, variables: Sequence[str]
) -> list[Group]:
    """Shapes of two variables, interactions of the chosen ``first`` group's variable z with
    each other variable z2 of ``variables`` that has a knot range in ``ranges`` (no gap of a
    control): in ``first``'s components, times its multiplier, :data:`PAIR_BASIS` basis
    functions each way. With z's scaling (z & z2) and, where z2's own scaling differs and the
    group is not a share of a force, with z2's (z2 & z, the same surface scaled otherwise: a yaw
    moment in the ship's speed and the apparent-wind angle scales with the wind). No pairs for
    a constant, a memory, a closed form or a shape of two variables."""
    if first.variable == "1" or first.control or first.tensor or first.form:
        return []
    out: list[Group] = []
    lo, hi = first.lo, first.hi
    for z2 in variables:
        if z2 == first.variable or z2 not in ranges or SHAPE_VARIABLES[z2].control:
            continue
        lo2, hi2 = ranges[z2]
        out.append(replace(first, n=PAIR_BASIS, variable2=z2, lo2=lo2, hi2=hi2, n2=PAIR_BASIS))
        scaled = first.scale_name
        if scaled and SHAPE_VARIABLES[z2].scale != scaled:
            out.append(
                Group(
                    first.components,
                    z2,
                    lo2,
                    hi2,
                    PAIR_BASIS,
                    first.multiplier,
                    variable2=first.variable,
                    lo2=lo,
                    hi2=hi,
                    n2=PAIR_BASIS,
                )
            )
    return out


def support(group: Group, windows: Sequence[Recording], params: Parameters) -> FloatArray:
    """(n n2,) 1.0 where a surface's basis function B_i(z) B_j(z2) holds at least
    :data:`SUPPORT_MIN` of the recorded samples of ``windows`` (its mean over them), else 0.0
    (with the base ``params`` for the rudder inflow and the wake)."""
    zs = [
        np.concatenate(
            [variable_values(v, w.t, w.x, w.u, w.w, params.theta, params.ship) for w in windows]
        )
        for v in (group.variable, group.variable2)
    ]
    ok = usable(group.variable, zs[0]) & usable(group.variable2, zs[1])
    if not ok.any():
        return np.zeros(group.size)
    mass = basis2(group, zs[0][ok], zs[1][ok]).mean(axis=0)
    return np.asarray(mass >= SUPPORT_MIN, dtype=np.float64)


def basis_count(variable: str, lo: float, hi: float, n: int = N_BASIS) -> int:
    """The basis functions of a shape of ``variable`` over [lo, hi]: ``n``, or for an angle
    as many as put its knots at most :data:`ANGLE_KNOT_SPACING` apart (up to
    :data:`MAX_ANGLE_BASIS`), for time at most :data:`TIME_KNOT_SPACING` apart (up to
    :data:`mmg.shapes.MAX_BASIS`); knots are n - 3 intervals apart."""
    if variable == "t":
        spacing, most = TIME_KNOT_SPACING, MAX_BASIS
    elif SHAPE_VARIABLES[variable].unit == "rad":
        spacing, most = ANGLE_KNOT_SPACING, MAX_ANGLE_BASIS
    else:
        return n
    need = int(np.ceil((hi - lo) / spacing - 1e-9)) + 3
    return int(min(max(n, need), max(n, most)))


def probe_groups(groups: Sequence[Group]) -> list[Group]:
    """The groups a probe of ``groups`` is made for: every candidate of the default settings
    (their structure; knot ranges and spacings come with the probe's lanes,
    :func:`mmg.shapes.probe_rows`), then those of ``groups`` that none of them serves
    (:func:`mmg.shapes.serves`: ``XYN~beta`` gives ``N~beta``'s columns too). Diagnoses of
    other data, with other variables, and a selection's groups of one component then share
    one probe kernel, compiled once (a new probe took 1.5-2.5 minutes to compile)."""
    unit = {v: (0.0, 1.0) for v in {*VARIABLES, *(v for v, _ in (*PRODUCTS, *SHARE_PRODUCTS))}}
    out = groups_over(unit, VARIABLES, PRODUCTS, SHARE_PRODUCTS, QUADRANTS, N_BASIS)
    for g in groups:
        if not any(serves(h, g) for h in out):
            if g.tensor:
                out.append(replace(g, lo=0.0, hi=1.0, lo2=0.0, hi2=1.0))
            else:
                out.append(replace(g, lo=0.0, hi=1.0) if g.variable != "1" else g)
    return out


@dataclass(frozen=True)
class Unit:
    """What the selection picks: one component of one candidate group, its columns."""

    group: Group  # a group of a single component (the shape effect of the chosen ones)
    columns: tuple[int, ...]  # its coefficients' indices among all columns

    @property
    def label(self) -> str:
        return self.group.text

    @property
    def kind(self) -> tuple[str, str, str]:
        """(component, scaling, multiplier): units of one kind share the constant function."""
        g = self.group
        return g.components, g.scale_name, g.multiplier


def _centred(n: int) -> FloatArray:
    """(n, n - 1) orthonormal basis of the coefficient vectors that sum to 0 (for n = 1: no
    column; a constant group of a kind already chosen adds nothing)."""
    U = np.linalg.svd(np.ones((n, 1)))[0]
    return np.asarray(U[:, 1:])


def _block_diag(blocks: Sequence[FloatArray]) -> FloatArray:
    rows = sum(b.shape[0] for b in blocks)
    cols = sum(b.shape[1] for b in blocks)
    out = np.zeros((rows, cols))
    i = j = 0
    for b in blocks:
        out[i : i + b.shape[0], j : j + b.shape[1]] = b
        i += b.shape[0]
        j += b.shape[1]
    return out


@dataclass
class ShapeSelection:
    """Groups chosen on the trajectory residuals (:meth:`ShapeColumns.select`).

    ``coefficients``: per group its linearised coefficients (fit on all windows, with the
    penalty), ``penalties``: per group the matrix P = lambda D'D (coefficient units, added to
    J: J + c'Pc), ``heldout_gain``: the held-out gain with 1, 2, ... groups as a share of the
    control fits' held-out J, ``edf``: per group its effective degrees of freedom (trace of the hat
    matrix, mean of the two folds' fits), ``dbic``: in-sample linearised dBIC with sum(edf) in
    the penalty, ``absorbed``: per group the share of its columns the base imitates."""

    groups: list[Group]
    coefficients: list[list[float]]
    penalties: list[FloatArray]
    heldout_gain: list[float]
    edf: list[float]
    dbic: float
    absorbed: list[float] = field(default_factory=list)
    #: per group the smoothing chosen: lambda = kappa x the mean diagonal of its Gram matrix
    kappas: list[float] = field(default_factory=list)

    @property
    def spec(self) -> str:
        """The name of the shape effect of the chosen groups ("" if none)."""
        from mmg.shapes import shape_name

        return shape_name(self.groups) if self.groups else ""

    def effect(self) -> Effect:
        """The shape effect of the chosen groups (for the joint fit by output error)."""
        return shape_effect(self.groups)

    def values(self) -> list[float]:
        """The chosen groups' coefficients in the effect's parameter order."""
        return [c for cs in self.coefficients for c in cs]

    def penalty(self) -> FloatArray:
        """(k, k) block-diagonal penalty of all chosen coefficients, parameter order."""
        return _block_diag(self.penalties)


def _dbic(J0: float, gain: float, edf: Sequence[float], n_eff: float) -> float:
    """The linearised dBIC of units taking ``gain`` off the control's J ``J0``, with their
    effective degrees of freedom ``edf`` in place of a parameter count."""
    ratio = max((J0 - gain) / J0, 1e-12) if J0 > 0 else 1.0
    return float(n_eff * np.log(ratio) + sum(edf) * np.log(n_eff))


def insample_share(dbic: float, edf: Sequence[float], n_eff: float) -> float:
    """The share of the control's J that units take off in-sample, read back from their
    linearised dBIC and effective degrees of freedom (the inverse of :func:`_dbic`)."""
    return float(1.0 - np.exp((dbic - sum(edf) * np.log(n_eff)) / n_eff))


#: what the selection gives for one residual vector: ((unit, kappa) chosen, held-out gain path
#: as a share of the control fits' held-out J, edf per chosen unit, dBIC)
_Row = tuple[list[tuple[int, float]], list[float], list[float], float]


@dataclass(frozen=True)
class _Options:
    max_groups: int
    min_gain: float
    kappas: tuple[float, ...]


@dataclass(frozen=True)
class _Sides:
    """The residual's side of the fits for D residual vectors: per fit fold L'Rf (T, D), per
    (fit, held-out) pair E'ho0 (T, D), the control fits' J summed over the folds (D,) and
    their held-out J summed over the pairs (D,)."""

    c: list[FloatArray]
    eh: list[FloatArray]
    J0: FloatArray
    Jho: FloatArray


class _Part:
    """One fold's matrices for the shape columns: Gram with the base projected out (LL),
    raw Gram (G), the columns' base coefficients (B), A'lib (AL) and A'A."""

    def __init__(self, fold: Any, lib: FloatArray, A: FloatArray, grams: FloatArray) -> None:
        self.fold = fold
        m_rows = len(fold.ix) * lib.shape[1]
        self.G = grams[fold.ix].sum(axis=0)
        Q = fold.Q[:m_rows]
        Qr = fold.Qr[:m_rows]
        Af = fold.rows(A)
        k, n = Q.shape[1], Qr.shape[1]
        prod = _tmul(lib, fold.ix, np.hstack([Q, Qr, Af])).T  # one pass over the columns
        QL = prod[:k]  # (rank, T)
        self.LL = self.G - QL.T @ QL
        self.B = np.linalg.solve(fold.Rr, prod[k : k + n])  # (57, T)
        self.AL = prod[k + n :]  # (57, T): A'lib
        self.AA = Af.T @ Af


def _gram(X: FloatArray) -> FloatArray:
    """X'X in float64."""
    Y = X.astype(np.float64)
    return np.asarray(Y.T @ Y)


def _tmul(lib: FloatArray, ix: Sequence[int], X: FloatArray) -> FloatArray:
    """lib_f' X for the rows of windows ``ix`` (lib (S, M, T) of any float type; X
    (len(ix) M, D)): (T, D) in float64, one window at a time."""
    M = lib.shape[1]
    out = np.zeros((lib.shape[2], X.shape[1]))
    products = map_threads(
        lambda i: lib[ix[i]].astype(np.float64).T @ X[i * M : (i + 1) * M], range(len(ix))
    )
    for p in products:  # summed in the windows' order, as one after another
        out += p
    return out


class ShapeColumns:
    """The trajectory columns of candidate shape groups at the base of ``lin``.

    ``groups``: candidate groups (:func:`candidate_groups`); every component of each is a
    selection unit. The columns are (r(step e_j) - r(0)) / step for every coefficient j of the
    groups' shape effect (simulated through its probe, :func:`mmg.shapes.probe_effect`; for a
    memory of a control the secant at :data:`MEMORY_STEP`), stored
    as ``dtype`` (float32 halves the memory: S x M x T values,
    0.35 GB for Train-R's 190k residuals and 460 columns); the matrices of the fits are formed
    from them in float64."""

    def __init__(
        self,
        lin: Linearised,
        groups: Sequence[Group],
        *,
        step: float = LIBRARY_STEP,
        dtype: Any = np.float32,
    ) -> None:
        import time

        t0 = time.perf_counter()
        self.lin = lin
        self.groups = list(groups)
        self.effect = shape_effect(self.groups)
        self.units: list[Unit] = []
        k = 0
        for g in self.groups:
            for c in g.components:
                one = replace(g, components=c)
                self.units.append(Unit(one, tuple(range(k, k + g.size))))
                k += g.size
        self.lib = self._columns(step, dtype)
        self.simulation_seconds = time.perf_counter() - t0
        # per-window Gram matrices, then each fold's (fit fold 0, fit fold 1, all windows)
        self.grams = np.stack(map_threads(_gram, list(self.lib)))
        self.parts = [_Part(f, self.lib, lin.A, self.grams) for f in lin.folds]
        self.all = _Part(lin.all, self.lib, lin.A, self.grams)
        raw = np.array([np.trace(self.all.G[np.ix_(u.columns, u.columns)]) for u in self.units])
        free = np.array([np.trace(self.all.LL[np.ix_(u.columns, u.columns)]) for u in self.units])
        #: share of each unit's columns that the base imitates (1: all of it, or no columns)
        self.absorbed = np.where(raw > 0.0, 1.0 - free / np.maximum(raw, 1e-300), 1.0)
        #: per unit of a surface its coefficients' basis functions with training samples
        self.supported = {
            u: support(unit.group, lin.windows, lin.params)
            for u, unit in enumerate(self.units)
            if unit.group.tensor
        }
        self.seconds = time.perf_counter() - t0

    def _columns(self, step: float, dtype: Any) -> FloatArray:
        """(S, M, T) columns of every coefficient of the candidate effect, simulated through its
        probe (one basis function per lane), in batches."""
        lin = self.lin
        within = probe_groups(self.groups)
        probe = probe_effect(within)
        obj = Objective(
            lin.windows, lin.objective, effects=(*lin.base_effects, probe), ship=lin.params.ship
        )
        th = np.concatenate([lin.theta, probe.neutral()])
        r0 = residual_vectors(obj, th[None])[0][0]  # (S, M)
        S, M = r0.shape
        units = probe_rows(self.effect, step, within)  # (T, 7)
        memory = np.isin(units[:, 1], [COMPONENTS.index(c) for c in "DP"])
        units[memory, 3] = MEMORY_STEP
        T = units.shape[0]
        lib = np.empty((S, M, T), dtype=dtype)
        per = max(1, BATCH_BYTES // (8 * S * M))
        for lo in range(0, T, per):
            idx = np.arange(lo, min(T, lo + per))
            rows = np.repeat(th[None, :], idx.size, axis=0)
            rows[:, lin.theta.size :] = units[idx]
            res = residual_vectors(obj, rows)[0]

            def store(w: int, res: FloatArray = res, idx: NDArray[np.int64] = idx) -> None:
                d = (res[:, w] - r0[None, w]) / units[idx, 3, None]
                lib[w][:, idx] = np.where(np.isfinite(d), d, 0.0).T

            map_threads(store, range(S))  # window by window, side by side
        return lib

    # -- the residual's side of the fits ------------------------------------------------------

    def _sides(self, R: FloatArray) -> _Sides:
        """The residual's side of the fits for residual vectors R (S, M, D)."""
        lin = self.lin
        cs, ehs = [], []
        J0 = np.zeros(R.shape[-1])
        Jho = np.zeros(R.shape[-1])
        for p in self.parts:
            f = p.fold
            Rf = f.resid(f.stack(R))
            J0 += (Rf * Rf).sum(axis=0)
            cs.append(_tmul(self.lib, f.ix, Rf[: len(f.ix) * R.shape[1]]))
        for j, k in ((0, 1), (1, 0)):
            fj, pk = lin.folds[j], self.parts[k]
            fk = pk.fold
            Ak = fk.rows(lin.A)
            ho0 = fk.rows(R) - Ak @ fj.base_coef(fj.stack(R))
            Jho += (ho0 * ho0).sum(axis=0)
            ehs.append(_tmul(self.lib, fk.ix, ho0) - self.parts[j].B.T @ (Ak.T @ ho0))
        return _Sides(cs, ehs, J0, Jho)

    def _held(self, j: int, k: int) -> FloatArray:
        """E'E (T, T) of the columns fitted on fold j and held out on fold k."""
        pj, pk = self.parts[j], self.parts[k]
        cross = pk.AL.T @ pj.B
        return np.asarray(pk.G - cross - cross.T + pj.B.T @ pk.AA @ pj.B)

    # -- the fits -----------------------------------------------------------------------------

    def _fit(
        self,
        part: _Part,
        c: FloatArray,
        chosen: Sequence[tuple[int, float]],
        edf: bool = False,
        forms: Mapping[int, FloatArray] | None = None,
    ) -> tuple[FloatArray, FloatArray, list[FloatArray], list[float]]:
        """Penalised least squares of the units ``chosen`` ((unit, kappa) pairs, in the order
        chosen) on one fold: (coefficients a, the columns' indices, each unit's penalty matrix
        in coefficient units, each unit's effective degrees of freedom if ``edf``). The fitted
        residual is Rf + L a; lambda = kappa x the mean diagonal of the unit's projected Gram
        matrix. A unit whose level another chosen unit of its kind already carries (same
        component, scaling and multiplier: the constant is in every spline's span) is fitted
        centred (its coefficients sum to 0), and its penalty holds it there
        (:data:`CENTRE_WEIGHT`). ``forms``: {unit: W (n, 2)} units fitted as a closed form,
        their coefficients a = W (a0, b), unpenalised: W's columns are the constant and the
        form in the unit's basis (:func:`sweep.diagnose.naming.form_transform`); without the
        constant where another unit of its kind carries the level."""
        idx = np.concatenate([self.units[u].columns for u, _ in chosen]).astype(int)
        Zs, pens, reduced = [], [], []
        seen: set[tuple[str, str, str]] = set()
        diag = np.diag(part.LL)
        for u, kappa in chosen:
            unit = self.units[u]
            n = len(unit.columns)
            if forms is not None and u in forms:
                Z = forms[u][:, 1:] if unit.kind in seen else forms[u]
                seen.add(unit.kind)
                Zs.append(Z)
                pens.append(np.zeros((n, n)))
                reduced.append(np.zeros((Z.shape[1], Z.shape[1])))
                continue
            scale = max(float(np.mean(diag[list(unit.columns)])), 0.0)
            P = kappa * scale * penalty(unit.group)  # a surface's along both variables
            if u in self.supported:  # a surface held at 0 where no training run went
                P = P + SUPPORT_WEIGHT * scale * np.diag(1.0 - self.supported[u])
            Z = _centred(n) if unit.kind in seen else np.eye(n)
            seen.add(unit.kind)
            reduced.append(Z.T @ P @ Z)
            if Z.shape[1] < n:
                P = P + CENTRE_WEIGHT * scale * np.ones((n, n)) / n
            Zs.append(Z)
            pens.append(P)
        Z = _block_diag(Zs)
        LLz = Z.T @ part.LL[np.ix_(idx, idx)] @ Z
        H = LLz + _block_diag(reduced)
        H[np.diag_indices_from(H)] += 1e-12 * max(float(np.trace(H)), 1e-300) / max(len(H), 1)
        a = -Z @ np.linalg.solve(H, Z.T @ c[idx])
        dof: list[float] = []
        if edf:
            hat = np.diag(np.linalg.solve(H, LLz))
            i = 0
            for Zu in Zs:
                dof.append(float(hat[i : i + Zu.shape[1]].sum()))
                i += Zu.shape[1]
        return a, idx, pens, dof

    def _kappas(self, u: int, kappas: Sequence[float]) -> Sequence[float]:
        """The smoothings tried for unit ``u``: all of ``kappas``, the first alone for a unit of
        one or two coefficients (a constant, a closed form: nothing to smooth)."""
        return kappas if self.units[u].group.n > 2 else kappas[:1]

    def _candidates(self) -> list[int]:
        """Units that can be chosen: columns not (nearly) all imitated by the base."""
        return [u for u in range(len(self.units)) if self.absorbed[u] < 1.0 - MIN_FREE]

    def _forward(
        self,
        sides: _Sides,
        d: int,
        EEs: Sequence[FloatArray],
        n_eff: float,
        opts: _Options,
        first: int | None = None,
    ) -> _Row:
        """:meth:`_entered` over the forces alone, and with a memory of the controls entering
        first and any unit after it: the path of the lower in-sample dBIC (ties: the forces);
        each step of either raised the held-out gain. The two kinds are not mixed in one
        greedy path: a memory's columns are secants that hold a persisting memory only in
        part, so a memory and a force that stands in for it each lead where the other is
        right and end the selection there (a steering gear's play: a yaw moment in delta led,
        56 % against 49 % of the held-out J, with an in-sample dBIC of -4 against -170; a
        drift-angle hinge: a memory led and nothing was chosen). The controls act upstream
        of every force, so a memory goes first on its path. ``first``: the unit that enters
        first, on its kind's path (a force: forces after it; a memory: any unit)."""
        memory = {u for u, unit in enumerate(self.units) if unit.group.control}
        forces = set(range(len(self.units))) - memory
        if first is not None:
            after = None if first in memory else forces
            return self._entered(sides, d, EEs, n_eff, opts, {first}, after)
        rows = [self._entered(sides, d, EEs, n_eff, opts, forces, forces)]
        if memory & set(self._candidates()):
            rows.append(self._entered(sides, d, EEs, n_eff, opts, memory, None))
        return min(rows, key=lambda row: row[-1])

    def _entered(
        self,
        sides: _Sides,
        d: int,
        EEs: Sequence[FloatArray],
        n_eff: float,
        opts: _Options,
        lead: set[int] | None,
        only: set[int] | None,
    ) -> _Row:
        """Forward selection of (unit, kappa) for residual vector d: the best held-out gain
        summed over both pairs, kept while it raises the held-out gain by ``min_gain`` of the
        gain so far and lowers the in-sample dBIC. ``lead``: the units that may enter first,
        ``only``: the units that may enter at all (None: any)."""
        cs = [c[:, d] for c in sides.c]
        ehs = [e[:, d] for e in sides.eh]
        J0 = float(sides.J0[d])

        def heldout(chosen: list[tuple[int, float]]) -> float:
            return self._heldout(cs, ehs, EEs, chosen)

        chosen: list[tuple[int, float]] = []
        path: list[float] = []
        best, dbic, edf = 0.0, 0.0, []
        pool = [u for u in self._candidates() if only is None or u in only]
        for _ in range(opts.max_groups):
            allowed = pool if chosen or lead is None else [u for u in pool if u in lead]
            taken = {u for u, _ in chosen}
            kinds = {self.units[u].kind for u in taken}
            trials = [
                (heldout([*chosen, (u, kap)]), u, kap)
                for u in allowed
                if u not in taken and (self.units[u].group.n > 1 or self.units[u].kind not in kinds)
                for kap in self._kappas(u, opts.kappas)
            ]
            if not trials:
                break
            g, u, kap = max(trials)
            if not np.isfinite(g) or g <= 0.0 or g <= best * (1.0 + opts.min_gain):
                break
            gain, dof = self._insample(cs, [*chosen, (u, kap)])
            new = _dbic(J0, gain, dof, n_eff)
            if new >= dbic:
                break
            chosen.append((u, kap))
            path.append(g / max(float(sides.Jho[d]), 1e-300))
            best, dbic, edf = g, new, dof
        return chosen, path, edf, dbic

    def _heldout(
        self,
        cs: Sequence[FloatArray],
        ehs: Sequence[FloatArray],
        EEs: Sequence[FloatArray],
        chosen: Sequence[tuple[int, float]],
        forms: Mapping[int, FloatArray] | None = None,
    ) -> float:
        """The held-out gain of the units ``chosen``: fitted on one fold, the fall of J on the
        other, summed over both pairs (the residual's sides ``cs``, ``ehs`` of one vector)."""
        total = 0.0
        for j, eh, EE in zip((0, 1), ehs, EEs, strict=True):
            a, idx, _, _ = self._fit(self.parts[j], cs[j], chosen, forms=forms)
            total -= float(2.0 * (a @ eh[idx]) + a @ EE[np.ix_(idx, idx)] @ a)
        return total

    def form_gains(
        self,
        r: FloatArray,
        trials: Sequence[tuple[Sequence[tuple[int, float]], Mapping[int, FloatArray]]],
    ) -> FloatArray:
        """(len(trials),) the held-out gain for the base's residual vector ``r`` (S, M) of each
        trial (units chosen, {unit: W} of those fitted as closed forms, :meth:`_fit`); the
        same sums as the selection's."""
        _, cs, ehs, EEs = self._one(r)
        return np.array([self._heldout(cs, ehs, EEs, chosen, f) for chosen, f in trials])

    def _one(
        self, r: FloatArray
    ) -> tuple[_Sides, list[FloatArray], list[FloatArray], list[FloatArray]]:
        """The sides of the fits for the one residual vector ``r`` (S, M): (the sides, per fit
        fold L'Rf, per pair E'ho0, per pair the held-out columns' E'E)."""
        sides = self._sides(r[..., None])
        cs = [c[:, 0] for c in sides.c]
        ehs = [e[:, 0] for e in sides.eh]
        return sides, cs, ehs, [self._held(0, 1), self._held(1, 0)]

    def form_fit(
        self,
        r: FloatArray,
        chosen: Sequence[tuple[int, float]],
        forms: Mapping[int, FloatArray],
    ) -> list[list[float]]:
        """Per chosen unit its coefficients fitted on all windows for the residual vector ``r``
        (S, M): a spline's n, a closed form's (a0, b) (a0 = 0 where another unit of its kind
        carries the level)."""
        f = self.lin.all
        Rf = f.resid(f.stack(r[..., None]))
        c = _tmul(self.lib, f.ix, Rf[: len(f.ix) * r.shape[1]])[:, 0]
        a, _, _, _ = self._fit(self.all, c, chosen, forms=forms)
        out: list[list[float]] = []
        i = 0
        for u, _ in chosen:
            n = len(self.units[u].columns)
            part = a[i : i + n]
            i += n
            if u in forms:
                W = forms[u]
                ab, *_ = np.linalg.lstsq(W, part, rcond=None)
                out.append([float(v) for v in ab])
            else:
                out.append([float(v) for v in part])
        return out

    def _insample(
        self, cs: Sequence[FloatArray], chosen: list[tuple[int, float]]
    ) -> tuple[float, list[float]]:
        """(in-sample gain summed over the fold fits, per unit edf averaged over the folds)."""
        gain = 0.0
        edf = np.zeros(len(chosen))
        for part, c in zip(self.parts, cs, strict=True):
            a, idx, _, dof = self._fit(part, c, chosen, edf=True)
            gain -= float(2.0 * (a @ c[idx]) + a @ part.LL[np.ix_(idx, idx)] @ a)
            edf += np.asarray(dof) / len(self.parts)
        return gain, [float(e) for e in edf]

    def _statistic(self, R: FloatArray, n_eff: float, opts: _Options) -> list[_Row]:
        """:meth:`_forward` for every residual vector of R (S, M, D)."""
        if len(self.parts) != 2:
            raise ValueError("the shape selection needs two folds")
        sides = self._sides(R)
        EEs = [self._held(0, 1), self._held(1, 0)]
        return [self._forward(sides, d, EEs, n_eff, opts) for d in range(R.shape[-1])]

    def select(
        self,
        r: FloatArray,
        n_eff: float,
        *,
        max_groups: int = 5,
        min_gain: float = MIN_GAIN,
        kappas: Sequence[float] = KAPPAS,
        first: Group | None = None,
    ) -> ShapeSelection:
        """The groups chosen for the base's residual vector ``r`` (S, M) (see the module
        docstring), with their coefficients fitted (linearised, penalised) on all windows.
        ``first``: a group of one component (a unit's, :meth:`singles`) that enters first."""
        opts = _Options(max_groups, min_gain, tuple(kappas))
        if first is None:
            chosen, path, edf, dbic = self._statistic(r[..., None], n_eff, opts)[0]
        else:
            u = next(u for u, unit in enumerate(self.units) if unit.group == first)
            sides, _, _, EEs = self._one(r)
            chosen, path, edf, dbic = self._forward(sides, 0, EEs, n_eff, opts, u)
        return self._selection(r, chosen, path, edf, dbic)

    def singles(
        self, r: FloatArray, kappas: Sequence[float] = KAPPAS
    ) -> list[tuple[float, Group, float]]:
        """Every candidate unit alone for the base's residual vector ``r`` (S, M): (held-out
        gain as a share of the control fits' held-out J, the unit's group, kappa), the
        smoothing the best of ``kappas``; the largest gain first."""
        sides, cs, ehs, EEs = self._one(r)
        Jho = max(float(sides.Jho[0]), 1e-300)
        out = []
        for u in self._candidates():
            g, k = max((self._heldout(cs, ehs, EEs, [(u, k)]), k) for k in self._kappas(u, kappas))
            out.append((g / Jho, self.units[u].group, float(k)))
        return sorted(out, key=lambda row: -row[0])

    def restricted(
        self, r: FloatArray, n_eff: float, groups: Sequence[tuple[Group, float]]
    ) -> ShapeSelection:
        """The selection of the given (group, kappa) pairs (groups of :meth:`select`'s, in its
        order) for the base's residual vector ``r`` (S, M), fitted (linearised, penalised) as
        :meth:`select` fits its choice: the held-out gain of each prefix, the in-sample dBIC
        and effective degrees of freedom. A choice with one of its groups left out."""
        unit = {self.units[u].group.text: u for u in range(len(self.units))}
        chosen = [(unit[g.text], float(kappa)) for g, kappa in groups]
        sides, cs, ehs, EEs = self._one(r)
        Jho = max(float(sides.Jho[0]), 1e-300)
        path = [self._heldout(cs, ehs, EEs, chosen[: i + 1]) / Jho for i in range(len(chosen))]
        edf: list[float] = []
        dbic = 0.0
        if chosen:
            gain, edf = self._insample(cs, chosen)
            dbic = _dbic(float(sides.J0[0]), gain, edf, n_eff)
        return self._selection(r, chosen, path, edf, dbic)

    def _selection(
        self,
        r: FloatArray,
        chosen: Sequence[tuple[int, float]],
        path: list[float],
        edf: list[float],
        dbic: float,
    ) -> ShapeSelection:
        """The :class:`ShapeSelection` of the units ``chosen``, their coefficients fitted on all
        windows for the residual vector ``r`` (S, M)."""
        coefficients: list[list[float]] = []
        penalties: list[FloatArray] = []
        if chosen:
            f = self.lin.all
            Rf = f.resid(f.stack(r[..., None]))
            c = _tmul(self.lib, f.ix, Rf[: len(f.ix) * r.shape[1]])[:, 0]
            a, _, penalties, _ = self._fit(self.all, c, chosen)
            i = 0
            for u, _ in chosen:
                n = len(self.units[u].columns)
                coefficients.append([float(v) for v in a[i : i + n]])
                i += n
        return ShapeSelection(
            groups=[self.units[u].group for u, _ in chosen],
            coefficients=coefficients,
            penalties=penalties,
            heldout_gain=path,
            edf=edf,
            dbic=dbic,
            absorbed=[float(self.absorbed[u]) for u, _ in chosen],
            kappas=[float(k) for _, k in chosen],
        )

    def null_dbic(
        self,
        R: FloatArray,
        n_eff: float,
        *,
        max_groups: int = 5,
        min_gain: float = MIN_GAIN,
        kappas: Sequence[float] = KAPPAS,
    ) -> FloatArray:
        """(D,) the statistic of :meth:`select` (dBIC, 0 when nothing is chosen) for residual
        vectors R (S, M, D), e.g. of noise-only copies of the windows: its null distribution."""
        opts = _Options(max_groups, min_gain, tuple(kappas))
        # the copies in PARTS parts side by side: the same figures on any machine
        done = map_threads(
            lambda ix: self._statistic(R[..., ix], n_eff, opts), column_parts(R.shape[-1])
        )
        return np.array([row[-1] for rows in done for row in rows])
