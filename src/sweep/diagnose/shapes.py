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
``min_gain`` of what the groups before it reached. The smoothing of each group is chosen with
it, on the same held-out gain, from a grid relative to the group's own column scale. The
statistic compared with the null is the in-sample linearised dBIC with the effective degrees of
freedom (the trace of the hat matrix) in place of the number of coefficients;
:meth:`ShapeColumns.null_dbic` gives the same statistic for noise-only residual vectors.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg import Parameters
from mmg.effect import Effect
from mmg.shapes import Group, difference_penalty, shape_effect, variable_values
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.diagnose.linearised import LIBRARY_STEP, MIN_FREE, Linearised
from sweep.identification.polish import residual_vectors

FloatArray = NDArray[np.float64]

#: the variables of the candidate shapes (keys of :data:`mmg.shapes.VARIABLES`)
VARIABLES = (
    "beta",
    "rp",
    "U",
    "u",
    "v",
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
)
#: varying-coefficient candidates: (shape variable, multiplier): Y_v(U) v_m U, Y_r(U) r' U^2,
#: a share of the hull's sway force and of the rudder's normal force
PRODUCTS = (("U", "v"), ("U", "rp"), ("beta", "Y_H"), ("delta", "F_N"))
#: constant groups times a quadrant indicator: astern, propeller reversed
QUADRANTS = ("ast", "rev")
#: basis functions per shape
N_BASIS = 8
#: the knots span these quantiles of a variable over the training windows
RANGE_QUANTILES = (0.005, 0.995)
#: smoothing grid: lambda = kappa x the mean diagonal of the group's projected Gram matrix
KAPPAS = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
#: float64 residuals per simulation batch of the columns [bytes]
BATCH_BYTES = 2**28


def variable_ranges(
    windows: Sequence[Recording],
    params: Parameters,
    names: Sequence[str] = VARIABLES,
    quantiles: tuple[float, float] = RANGE_QUANTILES,
) -> dict[str, tuple[float, float]]:
    """{variable: (lo, hi)}: the ``quantiles`` of each variable over the recorded samples of
    ``windows`` (with the base ``params`` for the rudder inflow and the wake); a variable that
    does not vary there (a constant propeller speed) is left out."""
    cols: dict[str, list[FloatArray]] = {n: [] for n in names}
    for w in windows:
        for n in names:
            cols[n].append(variable_values(n, w.t, w.x, w.u, w.w, params.theta, params.ship))
    out: dict[str, tuple[float, float]] = {}
    for n in names:
        z = np.concatenate(cols[n])
        z = z[np.isfinite(z)]
        if z.size == 0:
            continue
        lo, hi = (float(v) for v in np.quantile(z, quantiles))
        if hi - lo > 1e-6 * max(1.0, abs(lo), abs(hi)):
            out[n] = (lo, hi)
    return out


def candidate_groups(
    windows: Sequence[Recording],
    params: Parameters,
    *,
    variables: Sequence[str] = VARIABLES,
    products: Sequence[tuple[str, str]] = PRODUCTS,
    quadrants: Sequence[str] = QUADRANTS,
    n: int = N_BASIS,
) -> list[Group]:
    """The candidate groups, all three components each (one basis per variable in the hook):
    a shape of each variable that varies over ``windows``, the varying-coefficient
    ``products`` and a constant times each quadrant indicator."""
    ranges = variable_ranges(windows, params, sorted({*variables, *(v for v, _ in products)}))
    groups = [Group("XYN", v, *ranges[v], n) for v in variables if v in ranges]
    groups += [Group("XYN", v, *ranges[v], n, m) for v, m in products if v in ranges]
    groups += [Group("XYN", "1", multiplier=q) for q in quadrants]
    return groups


@dataclass(frozen=True)
class Unit:
    """What the selection picks: one component of one candidate group, its columns."""

    group: Group  # a group of a single component (the shape effect of the chosen ones)
    columns: tuple[int, ...]  # its coefficients' indices among all columns

    @property
    def label(self) -> str:
        return self.group.text


@dataclass
class ShapeSelection:
    """Groups chosen on the trajectory residuals (:meth:`ShapeColumns.select`).

    ``coefficients``: per group its linearised coefficients (fit on all windows, with the
    penalty), ``penalties``: per group the matrix P = lambda D'D (coefficient units, added to
    J: J + c'Pc), ``heldout_gain``: the held-out gain with 1, 2, ... groups as a share of the
    control fits' J, ``edf``: per group its effective degrees of freedom (trace of the hat
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
        k = sum(p.shape[0] for p in self.penalties)
        out = np.zeros((k, k))
        i = 0
        for p in self.penalties:
            out[i : i + p.shape[0], i : i + p.shape[0]] = p
            i += p.shape[0]
        return out


#: what the selection gives for one residual vector: ((unit, kappa) chosen, held-out gain path,
#: J of the control fits, edf per chosen unit, dBIC)
_Row = tuple[list[tuple[int, float]], list[float], float, list[float], float]


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
        QL = _tmul(lib, fold.ix, Q).T  # (rank, T)
        self.LL = self.G - QL.T @ QL
        self.B = np.linalg.solve(fold.Rr, _tmul(lib, fold.ix, Qr).T)  # (57, T)
        self.AL = _tmul(lib, fold.ix, Af).T  # (57, T)
        self.AA = Af.T @ Af


def _tmul(lib: FloatArray, ix: Sequence[int], X: FloatArray) -> FloatArray:
    """lib_f' X for the rows of windows ``ix`` (lib (S, M, T) of any float type; X
    (len(ix) M, D)): (T, D) in float64, one window at a time."""
    M = lib.shape[1]
    out = np.zeros((lib.shape[2], X.shape[1]))
    for i, s in enumerate(ix):
        out += lib[s].astype(np.float64).T @ X[i * M : (i + 1) * M]
    return out


class ShapeColumns:
    """The trajectory columns of candidate shape groups at the base of ``lin``.

    ``groups``: candidate groups (:func:`candidate_groups`); every component of each is a
    selection unit. The columns are (r(step e_j) - r(0)) / step for every coefficient j of the
    groups' shape effect, stored as ``dtype`` (float32 halves the memory: S x M x T values,
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
                one = Group(c, g.variable, g.lo, g.hi, g.n, g.multiplier, g.scale)
                self.units.append(Unit(one, tuple(range(k, k + g.n))))
                k += g.n
        self.lib = self._columns(step, dtype)
        self.simulation_seconds = time.perf_counter() - t0
        # per-window Gram matrices, then each fold's (fit fold 0, fit fold 1, all windows)
        self.grams = np.stack([s.astype(np.float64).T @ s.astype(np.float64) for s in self.lib])
        self.parts = [_Part(f, self.lib, lin.A, self.grams) for f in lin.folds]
        self.all = _Part(lin.all, self.lib, lin.A, self.grams)
        raw = np.array([np.trace(self.all.G[np.ix_(u.columns, u.columns)]) for u in self.units])
        free = np.array([np.trace(self.all.LL[np.ix_(u.columns, u.columns)]) for u in self.units])
        #: share of each unit's columns that the base imitates (1: all of it, or no columns)
        self.absorbed = np.where(raw > 0.0, 1.0 - free / np.maximum(raw, 1e-300), 1.0)
        self.seconds = time.perf_counter() - t0

    def _columns(self, step: float, dtype: Any) -> FloatArray:
        """(S, M, T) columns of every coefficient of the candidate effect, in batches."""
        lin = self.lin
        eff = self.effect
        obj = Objective(
            lin.windows, lin.objective, effects=(*lin.base_effects, eff), ship=lin.params.ship
        )
        th = np.concatenate([lin.theta, np.zeros(len(eff.params))])
        r0 = residual_vectors(obj, th[None])[0][0]  # (S, M)
        S, M = r0.shape
        T = len(eff.params)
        lib = np.empty((S, M, T), dtype=dtype)
        per = max(1, BATCH_BYTES // (8 * S * M))
        for lo in range(0, T, per):
            idx = np.arange(lo, min(T, lo + per))
            rows = np.repeat(th[None, :], idx.size, axis=0)
            rows[np.arange(idx.size), lin.theta.size + idx] = step
            d = (residual_vectors(obj, rows)[0] - r0[None]) / step  # (c, S, M)
            lib[:, :, idx] = np.moveaxis(np.where(np.isfinite(d), d, 0.0), 0, -1)
        return lib

    # -- the residual's side of the fits ------------------------------------------------------

    def _sides(self, R: FloatArray) -> tuple[list[FloatArray], list[FloatArray], FloatArray]:
        """For residual vectors R (S, M, D): per fit fold c = L'Rf (T, D); per (fit j,
        held-out k) pair E'ho0 (T, D); the control fits' J summed over the folds (D,)."""
        lin = self.lin
        cs, ehs = [], []
        J0 = np.zeros(R.shape[-1])
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
            ehs.append(_tmul(self.lib, fk.ix, ho0) - self.parts[j].B.T @ (Ak.T @ ho0))
        return cs, ehs, J0

    def _held(self, j: int, k: int) -> FloatArray:
        """E'E (T, T) of the columns fitted on fold j and held out on fold k."""
        pj, pk = self.parts[j], self.parts[k]
        cross = pk.AL.T @ pj.B
        return np.asarray(pk.G - cross - cross.T + pj.B.T @ pk.AA @ pj.B)

    # -- the fits -----------------------------------------------------------------------------

    def _fit(
        self, part: _Part, c: FloatArray, chosen: Sequence[tuple[int, float]]
    ) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
        """Penalised least squares of the units ``chosen`` ((unit, kappa) pairs) on one fold:
        (coefficients a, the columns' indices, each unit's penalty matrix). The fitted residual
        is Rf + L a; lambda = kappa x the mean diagonal of the unit's projected Gram matrix."""
        idx = np.concatenate([self.units[u].columns for u, _ in chosen]).astype(int)
        H = part.LL[np.ix_(idx, idx)].copy()
        pens = []
        i = 0
        for u, kappa in chosen:
            cols = list(self.units[u].columns)
            scale = float(np.mean(np.diag(part.LL)[cols]))
            P = kappa * max(scale, 0.0) * difference_penalty(len(cols))
            H[i : i + len(cols), i : i + len(cols)] += P
            pens.append(P)
            i += len(cols)
        H[np.diag_indices_from(H)] += 1e-12 * max(float(np.trace(H)), 1e-300) / len(idx)
        return -np.linalg.solve(H, c[idx]), idx, pens

    def _candidates(self) -> list[int]:
        """Units that can be chosen: columns not (nearly) all imitated by the base."""
        return [u for u in range(len(self.units)) if self.absorbed[u] < 1.0 - MIN_FREE]

    def _forward(
        self,
        cs: Sequence[FloatArray],
        ehs: Sequence[FloatArray],
        EEs: Sequence[FloatArray],
        max_groups: int,
        min_gain: float,
        kappas: Sequence[float],
    ) -> tuple[list[tuple[int, float]], list[float]]:
        """Forward selection of (unit, kappa) by the held-out gain summed over both pairs."""
        pairs = ((0, 1), (1, 0))

        def heldout(chosen: list[tuple[int, float]]) -> float:
            total = 0.0
            for (j, _), eh, EE in zip(pairs, ehs, EEs, strict=True):
                a, idx, _ = self._fit(self.parts[j], cs[j], chosen)
                total -= float(2.0 * (a @ eh[idx]) + a @ EE[np.ix_(idx, idx)] @ a)
            return total

        chosen: list[tuple[int, float]] = []
        path: list[float] = []
        best = 0.0
        pool = self._candidates()
        for _ in range(max_groups):
            taken = {u for u, _ in chosen}
            trials = [
                (heldout([*chosen, (u, kap)]), u, kap)
                for u in pool
                if u not in taken
                for kap in (kappas if self.units[u].group.n > 2 else kappas[:1])
            ]
            if not trials:
                break
            g, u, kap = max(trials)
            if not np.isfinite(g) or g <= 0.0 or g <= best * (1.0 + min_gain):
                break
            chosen.append((u, kap))
            path.append(g)
            best = g
        return chosen, path

    def _insample(
        self, cs: Sequence[FloatArray], chosen: list[tuple[int, float]]
    ) -> tuple[float, list[float]]:
        """(in-sample gain summed over the fold fits, per unit edf averaged over the folds)."""
        gain = 0.0
        edf = np.zeros(len(chosen))
        for part, c in zip(self.parts, cs, strict=True):
            a, idx, pens = self._fit(part, c, chosen)
            LL = part.LL[np.ix_(idx, idx)]
            gain -= float(2.0 * (a @ c[idx]) + a @ LL @ a)
            H = LL.copy()
            i = 0
            for P in pens:
                H[i : i + P.shape[0], i : i + P.shape[0]] += P
                i += P.shape[0]
            hat = np.diag(np.linalg.solve(H + 1e-12 * np.trace(H) * np.eye(len(idx)), LL))
            i = 0
            for q, P in enumerate(pens):
                edf[q] += float(hat[i : i + P.shape[0]].sum()) / len(self.parts)
                i += P.shape[0]
        return gain, [float(e) for e in edf]

    def _statistic(
        self,
        R: FloatArray,
        n_eff: float,
        max_groups: int,
        min_gain: float,
        kappas: Sequence[float],
    ) -> list[_Row]:
        """Per residual vector of R (S, M, D): (chosen, held-out path, J0, edf, dBIC)."""
        if len(self.parts) != 2:
            raise ValueError("the shape selection needs two folds")
        cs, ehs, J0 = self._sides(R)
        EEs = [self._held(0, 1), self._held(1, 0)]
        out: list[_Row] = []
        for d in range(R.shape[-1]):
            c_d = [c[:, d] for c in cs]
            chosen, path = self._forward(
                c_d, [e[:, d] for e in ehs], EEs, max_groups, min_gain, kappas
            )
            if not chosen:
                out.append((chosen, path, float(J0[d]), [], 0.0))
                continue
            gain, edf = self._insample(c_d, chosen)
            ratio = max((float(J0[d]) - gain) / float(J0[d]), 1e-12)
            dbic = float(n_eff * np.log(ratio) + sum(edf) * np.log(n_eff))
            out.append((chosen, path, float(J0[d]), edf, dbic))
        return out

    def select(
        self,
        r: FloatArray,
        n_eff: float,
        *,
        max_groups: int = 5,
        min_gain: float = 0.15,
        kappas: Sequence[float] = KAPPAS,
    ) -> ShapeSelection:
        """The groups chosen for the base's residual vector ``r`` (S, M) (see the module
        docstring), with their coefficients fitted (linearised, penalised) on all windows."""
        chosen, path, J0, edf, dbic = self._statistic(
            r[..., None], n_eff, max_groups, min_gain, kappas
        )[0]
        coefficients: list[list[float]] = []
        penalties: list[FloatArray] = []
        if chosen:
            f = self.lin.all
            Rf = f.resid(f.stack(r[..., None]))
            c = _tmul(self.lib, f.ix, Rf[: len(f.ix) * r.shape[1]])[:, 0]
            a, _, penalties = self._fit(self.all, c, chosen)
            i = 0
            for u, _ in chosen:
                n = len(self.units[u].columns)
                coefficients.append([float(v) for v in a[i : i + n]])
                i += n
        return ShapeSelection(
            groups=[self.units[u].group for u, _ in chosen],
            coefficients=coefficients,
            penalties=penalties,
            heldout_gain=[g / J0 for g in path],
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
        min_gain: float = 0.15,
        kappas: Sequence[float] = KAPPAS,
    ) -> FloatArray:
        """(D,) the statistic of :meth:`select` (dBIC, 0 when nothing is chosen) for residual
        vectors R (S, M, D), e.g. of noise-only copies of the windows: its null distribution."""
        rows = self._statistic(R, n_eff, max_groups, min_gain, kappas)
        return np.array([row[-1] for row in rows])
