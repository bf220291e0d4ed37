"""The fold fits of the diagnosis linearised at the base model (Gauss-Newton).

:class:`Linearised` holds the Jacobian of the base model's residual vectors with respect to the
57 base parameters (normalised box, the coordinates of the fits' prior), each candidate's
directions and, with discovery on, the library's columns; from them it gives the J and the gains
of the control and candidate fits for any residual vectors (the acceptance null of
:mod:`sweep.diagnose.threshold`, the refit factor of the misfit test, the generalisation test)
and the selection of library terms on the trajectory residuals (:meth:`Linearised.select`).
The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mmg import Effect, Parameters, bounds, get_effect
from mmg.discovered import discovered_effect, unit_rows
from mmg.library import SEARCHED, Column, chosen_shapes, library_columns
from mmg.params import N_THETA
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.diagnose.discover import spans
from sweep.diagnose.floor import run_of
from sweep.identification.polish import residual_vectors
from sweep.identification.vector import effect_values

FloatArray = NDArray[np.float64]
#: forward-difference step of the base Jacobian, in the normalised box
FD_STEP = 1e-3
#: grid points per effect parameter for the directions of a nonlinear effect
GRID = 5
#: a library term whose trajectory column the base imitates beyond 1 - MIN_FREE of its squared
#: norm counts nothing (as ``DiscoverySettings.max_absorbed`` in the equation-level proposal)
MIN_FREE = 0.01
#: the library's span keeps the directions whose squared singular value exceeds this share of
#: the largest (singular values down to 1e-5 of it: the Gram matrix's rounding is ~1e-16)
GRAM_RCOND = 1e-10
#: coefficient step of the library columns (the terms are linear in their coefficient)
LIBRARY_STEP = 1e-4


def _residuals(obj: Objective, thetas: FloatArray) -> FloatArray:
    r, _ = residual_vectors(obj, thetas)
    return r  # (C, S, M)


def _effect_directions(
    obj: Objective, theta0: FloatArray, eff: Effect, r0: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(derivative columns (S, M, k), grid directions (S, M, g)) of ``eff`` at the base."""
    k = len(eff.params)
    lo = np.array([q.lower for q in eff.params])
    hi = np.array([q.upper for q in eff.params])
    neutral = np.array(eff.neutral())
    rows = np.repeat(theta0[None, :], k, axis=0)
    h = 1e-3 * (hi - lo)
    rows[np.arange(k), N_THETA + np.arange(k)] += h
    d = (_residuals(obj, rows) - r0[None]) / h[:, None, None]
    axes = [np.linspace(lo[j], hi[j], GRID) for j in range(k)] if k <= 2 else []
    if axes:
        grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
        grid = grid[np.any(np.abs(grid - neutral) > 1e-12, axis=1)]
        gr = np.repeat(theta0[None, :], len(grid), axis=0)
        gr[:, N_THETA:] = grid
        g = _residuals(obj, gr) - r0[None]
        good = np.isfinite(g).all(axis=(1, 2))
        g = g[good]
    else:
        g = np.zeros((0, *r0.shape))
    return np.moveaxis(d, 0, -1), np.moveaxis(g, 0, -1)


def _orth(X: FloatArray, rcond: float = 1e-10) -> FloatArray:
    """Orthonormal basis of the column span of X (rank-revealing by the SVD)."""
    if X.shape[1] == 0:
        return X
    U, s, _ = np.linalg.svd(X, full_matrices=False)
    keep = s > rcond * max(float(s[0]), 1e-300)
    return U[:, keep]


def _span_gain(X: FloatArray, R: FloatArray) -> FloatArray:
    """Squared norm of the projection of each column of R onto the span of X: (D,)."""
    Q = _orth(X)
    if Q.shape[1] == 0:
        return np.zeros(R.shape[1])
    return np.asarray(((Q.T @ R) ** 2).sum(axis=0))


def _direction_gain(G: FloatArray, R: FloatArray) -> FloatArray:
    """Best single direction of G for each column of R: max_i (g_i.r)^2 / |g_i|^2, (D,)."""
    if G.shape[1] == 0:
        return np.zeros(R.shape[1])
    n2 = (G * G).sum(axis=0)
    ok = n2 > 1e-300
    if not ok.any():
        return np.zeros(R.shape[1])
    G = G[:, ok] / np.sqrt(n2[ok])
    return np.asarray(((G.T @ R) ** 2).max(axis=0))


def _greedy(
    parts: Sequence[tuple[FloatArray, FloatArray, FloatArray]],
    max_terms: int,
    groups: Sequence[str] | None = None,
) -> tuple[FloatArray, list[list[int]]]:
    """Greedy forward selection of library columns, the same terms in every fold.

    ``parts`` holds per fold (columns (m, T), residuals (m, D)) in an orthonormal basis of that
    fold, the columns scaled by their norm *before* the base was projected out, so that a
    column's squared norm is the share of the term the base cannot imitate; a term the base
    imitates beyond ``1 - MIN_FREE`` in a fold counts nothing there; columns of one group (one
    term at several points of its shape's grid) enter once. Returns the summed gains
    (max_terms, D) (row t: with t + 1 terms) and the chosen columns of each residual.
    """
    D = parts[0][1].shape[1]
    out = np.zeros((max_terms, D))
    paths: list[list[int]] = []
    for d in range(D):
        rs = [R[:, d].copy() for _, R, _ in parts]
        Cs = [C.copy() for C, _, _ in parts]
        gain = 0.0
        chosen: list[int] = []
        for t in range(max_terms):
            score = np.zeros(Cs[0].shape[1])
            for C, r in zip(Cs, rs, strict=True):
                cn = (C * C).sum(axis=0)
                score += np.where(cn > MIN_FREE, (C.T @ r) ** 2 / np.maximum(cn, 1e-300), 0.0)
            score[chosen] = -1.0
            if groups is not None:
                taken = {groups[c] for c in chosen}
                score[[i for i, g in enumerate(groups) if g in taken]] = -1.0
            j = int(np.argmax(score))
            if score[j] <= 0:
                out[t:, d] = gain
                break
            for i, (C, r) in enumerate(zip(Cs, rs, strict=True)):
                cn = float(C[:, j] @ C[:, j])
                if cn <= MIN_FREE:
                    continue
                q = C[:, j] / np.sqrt(cn)
                gain += float(q @ r) ** 2
                rs[i] = r - q * (q @ r)
                Cs[i] = C - np.outer(q, q @ C)
            chosen.append(j)
            out[t, d] = gain
        paths.append(chosen)
    return out, paths


def _library_part(
    fold: _Fold, lib: FloatArray, Rf: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(columns, residuals, column scales) of a fold in an orthonormal basis of the library's
    projected span; columns divided by their norm before the base was projected out (the
    scales)."""
    raw = fold.stack(lib)
    n0 = np.sqrt((raw * raw).sum(axis=0))
    n0 = np.where(n0 > 1e-300, n0, np.inf)
    L = fold.resid(raw) / n0
    # the basis U = L V s^-1 from the eigenvectors of the Gram matrix L'L (T x T), never formed:
    # the coordinates are U'L = s V' and U'Rf = s^-1 V'(L'Rf). The SVD of the tall L gave the
    # same span and took most of the null's time on long recordings
    lam, V = np.linalg.eigh(L.T @ L)
    keep = lam > GRAM_RCOND * max(float(lam[-1]), 1e-300)
    s, V = np.sqrt(lam[keep]), V[:, keep]
    return s[:, None] * V.T, (V.T @ (L.T @ Rf)) / s[:, None], n0


class _Fold:
    """The rows of one fold fit, with the base Jacobian and the prior projected out."""

    def __init__(self, ix: list[int], A: FloatArray, mu: float) -> None:
        self.ix = ix
        Aa = np.vstack([self.rows(A), np.sqrt(mu) * np.eye(N_THETA)])
        self.Qr, self.Rr = np.linalg.qr(Aa)
        # with the prior's rows the stacked Jacobian has full column rank: Q of the QR spans it
        self.Q = self.Qr if mu > 0 else _orth(Aa)

    def base_coef(self, X: FloatArray) -> FloatArray:
        """(57, c) least-squares base coefficients of stacked columns X (with the prior)."""
        return np.asarray(np.linalg.solve(self.Rr, self.Qr.T @ X))

    def rows(self, X: FloatArray) -> FloatArray:
        Y = X[self.ix]
        return Y.reshape(Y.shape[0] * Y.shape[1], -1)

    def stack(self, X: FloatArray) -> FloatArray:
        """(S, M, c) columns as fold rows with the prior's rows (zero for these columns)."""
        Y = self.rows(X)
        return np.vstack([Y, np.zeros((N_THETA, Y.shape[1]))])

    def resid(self, X: FloatArray) -> FloatArray:
        return X - self.Q @ (self.Q.T @ X)


@dataclass(frozen=True)
class HeldOut:
    """The linearised fits on residual vectors (S, M, D): every candidate's dBIC (D,), the held-out
    gain (D,) of each column's best candidate, and the largest loss of the held-out J of one run
    (D,; positive: that run fits worse) by the best catalog candidate, each relative to the
    control's held-out J (of all held-out windows; of that run)."""

    dbic: dict[str, FloatArray]
    gain: FloatArray
    worst_run: FloatArray


@dataclass(frozen=True)
class RefitDrift:
    """What the control's fold fits (the base's 57 parameters refitted, linearised with the
    prior, on one fold's windows) make of the other fold's windows, both ways round: their
    held-out J against the base's own J on the same windows, and the held-out window of the
    largest J with its share. Every held-out gain of the diagnosis is measured against these
    fits: where they drift far above the base, a gain can be the drift undone rather than the
    base's misfit explained."""

    heldout: float  # the control fits' J on the held-out windows, summed over both pairs
    base: float  # the base's J on the same windows
    window: str  # the held-out window of the largest control J
    share: float  # its share of ``heldout``

    @property
    def ratio(self) -> float:
        """The control fits' held-out J over the base's own J there."""
        return self.heldout / max(self.base, 1e-300)

    def as_dict(self) -> dict[str, float | str]:
        return {
            "heldout": self.heldout,
            "base": self.base,
            "ratio": self.ratio,
            "window": self.window,
            "share": self.share,
        }


@dataclass
class TrajectorySelection:
    """Library terms chosen on the trajectory residuals (:meth:`Linearised.select`)."""

    terms: list[str]
    coefficients: list[float]  # linearised estimates, in the terms' coefficient units
    heldout_gain: list[float]  # held-out gain with 1, 2, ... of the terms, share of the fit J
    dbic: float  # in-sample linearised dBIC of the terms
    #: the grid point of each chosen term that has a shape: {term: {placeholder: value}}
    shapes: dict[str, dict[str, float]] = field(default_factory=dict)
    #: the chosen terms' held-out gain as a share of the control fits' held-out J (both ways
    #: round, linearised): the learned shapes' measure, so the two can be compared
    heldout_share: float = 0.0


class Linearised:
    """The fold fits of the diagnosis linearised at the base model ``params``.

    ``folds``: the indices into ``windows`` each fold fit sees. In each fold the control fit is
    the least squares of a residual vector on the base Jacobian ``A`` with the fits' prior (rows
    ``sqrt(prior_weight) I``); a candidate adds its directions (the span of its derivatives at
    neutral, or the best single direction from neutral to a point of a grid over its box,
    whichever gains more): what a converged joint fit gains to first order.
    ``library_terms`` > 0 adds the discovered candidate (greedy forward selection of up to that
    many library terms, the same in every fold).
    """

    def __init__(
        self,
        params: Parameters,
        windows: Sequence[Recording],
        folds: Sequence[Sequence[int]],
        candidates: Sequence[Effect],
        *,
        objective: str = "J2",
        prior_weight: float = 1.0,
        library_terms: int = 0,
    ) -> None:
        self.params = params
        self.windows = list(windows)
        self.objective = objective
        self.library_terms = library_terms
        self.base_effects = tuple(get_effect(n) for n, _ in params.effects)
        ship = params.ship
        theta_b = np.concatenate(
            [params.vector(), np.asarray(effect_values(params, self.base_effects), dtype=float)]
        )
        self.theta = theta_b
        lo, hi = bounds()
        obj = Objective(windows, objective, effects=self.base_effects, ship=ship)
        r0 = _residuals(obj, theta_b[None])[0]  # (S, M)
        # base Jacobian in normalised coordinates (the prior's units)
        rows = np.repeat(theta_b[None, :], N_THETA, axis=0)
        rows[np.arange(N_THETA), np.arange(N_THETA)] += FD_STEP * (hi - lo)
        A = np.moveaxis((_residuals(obj, rows) - r0[None]) / FD_STEP, 0, -1)  # (S, M, 57)
        # candidate directions (derivatives, grid directions) on the same windows
        self.cand: dict[str, tuple[FloatArray, FloatArray, int]] = {}
        for eff in candidates:
            o = Objective(windows, objective, effects=(*self.base_effects, eff), ship=ship)
            th = np.concatenate([theta_b, np.asarray(eff.neutral(), dtype=np.float64)])
            re = _residuals(o, th[None])[0]
            d, g = _effect_directions(o, th, eff, re)
            self.cand[eff.name] = (d, g, len(eff.params))
        self.lib: FloatArray | None = None
        #: the library's columns: each term at every point of its shape's grid
        self.columns: list[Column] = []
        if library_terms > 0:
            ids = list(SEARCHED)
            leff = discovered_effect(ids)
            self.columns = library_columns(ids, spans(windows))
            o = Objective(windows, objective, effects=(*self.base_effects, leff), ship=ship)
            th = np.concatenate([theta_b, np.asarray(leff.neutral(), dtype=np.float64)])
            rl = np.repeat(th[None, :], len(self.columns), axis=0)
            rl[:, theta_b.size :] = unit_rows(leff, self.columns, LIBRARY_STEP)
            lib = np.moveaxis((_residuals(o, rl) - r0[None]) / LIBRARY_STEP, 0, -1)  # (S, M, T)
            self.lib = np.where(np.isfinite(lib), lib, 0.0)
        self.A = A
        self.folds = [_Fold(list(idx), A, float(prior_weight)) for idx in folds]
        self.all = _Fold(list(range(len(self.windows))), A, float(prior_weight))
        self.term_ids = [c.term for c in self.columns]  # (T,) the term of each column

    def with_prior(self, prior_weight: float) -> Linearised:
        """The same linearisation (Jacobian, candidates, library) with the fold fits' prior
        weight ``prior_weight``: a new object, this one unchanged."""
        out = copy.copy(self)
        out.folds = [_Fold(f.ix, self.A, float(prior_weight)) for f in self.folds]
        out.all = _Fold(self.all.ix, self.A, float(prior_weight))
        return out

    def select(self, r: FloatArray, n_eff: float, min_gain: float = 0.15) -> TrajectorySelection:
        """Discovery in trajectory space for the base's residual ``r`` (S, M).

        Forward selection of library terms by their *held-out* gain: base and terms fitted
        (linearised) on one fold's windows, the gain over the control measured on the other
        fold's windows without refitting, both ways round; a further term must add at least
        ``min_gain`` times the held-out gain reached so far. A term that only fits the windows
        it was fitted on (a position term standing in for a drift) gains nothing held out. The
        chosen terms' in-sample linearised dBIC is the statistic compared with the null, and
        their coefficients come from the linearised fit on all windows.
        """
        if self.lib is None:
            raise ValueError("no library: build Linearised with library_terms > 0")
        R = r[..., None]
        J0 = 0.0
        parts = []
        for fold in self.folds:
            Rf = fold.resid(fold.stack(R))
            J0 += float((Rf * Rf).sum())
            parts.append(_library_part(fold, self.lib, Rf))
        # held-out images: control residual and term columns of fold k fitted on fold j
        pairs = []
        J_ho0 = 0.0
        for j, k in ((0, 1), (1, 0)):
            fj, fk = self.folds[j], self.folds[k]
            Ak = fk.rows(self.A)
            ho0 = fk.rows(R)[:, 0] - Ak @ fj.base_coef(fj.stack(R))[:, 0]
            E = fk.rows(self.lib) - Ak @ fj.base_coef(fj.stack(self.lib))
            # the held-out residual with terms S at coefficients a is e = ho0 + E_S a, and its
            # gain |ho0|^2 - |e|^2 = -(2 a'E_S'ho0 + a'E_S'E_S a): from E'ho0 and E'E, formed
            # once (gathering E_S from the tall E for every trial took most of the selection)
            pairs.append((parts[j], E.T @ ho0, E.T @ E))
            J_ho0 += float(ho0 @ ho0)

        def heldout(S: list[int]) -> float:
            total = 0.0
            for (C, Rp, n0), Eh, EE in pairs:
                cols = C[:, S]
                if np.any((cols * cols).sum(axis=0) <= MIN_FREE):
                    return -np.inf
                a = -np.linalg.lstsq(cols, Rp[:, 0], rcond=None)[0] / n0[S]
                total -= float(2.0 * (a @ Eh[S]) + a @ EE[np.ix_(S, S)] @ a)
            return total

        chosen: list[int] = []
        path_gain: list[float] = []
        best = 0.0
        for _ in range(self.library_terms):
            taken = {self.term_ids[c] for c in chosen}
            scores = [
                (heldout([*chosen, t]), t)
                for t in range(len(self.term_ids))
                if self.term_ids[t] not in taken
            ]
            g, t = max(scores)
            if not np.isfinite(g) or g <= best * (1.0 + min_gain) or g <= 0.0:
                break
            chosen.append(t)
            path_gain.append(g)
            best = g
        gain = 0.0
        for C, Rp, _ in parts:
            gain += float(_span_gain(C[:, chosen], Rp)[0]) if chosen else 0.0
        k = len(chosen)
        dbic = float(n_eff * np.log(max((J0 - gain) / J0, 1e-12)) + k * np.log(n_eff))
        G = self.all.resid(self.all.stack(self.lib[:, :, chosen]))
        y = self.all.resid(self.all.stack(R))[:, 0]
        coef = -np.linalg.lstsq(G, y, rcond=None)[0] if k else np.zeros(0)
        return TrajectorySelection(
            terms=[self.term_ids[j] for j in chosen],
            coefficients=[float(c) for c in coef],
            heldout_gain=[g / J0 for g in path_gain],
            dbic=dbic if k else 0.0,
            shapes=chosen_shapes([self.columns[j] for j in chosen]),
            heldout_share=path_gain[-1] / J_ho0 if path_gain and J_ho0 > 0 else 0.0,
        )

    def residuals(self, recordings: Sequence[Recording]) -> FloatArray:
        """(S, M) residual vector of the base model on recordings of the same windows."""
        obj = Objective(
            recordings, self.objective, effects=self.base_effects, ship=self.params.ship
        )
        return _residuals(obj, self.theta[None])[0]

    def gains(self, R: FloatArray) -> tuple[FloatArray, dict[str, tuple[FloatArray, int]]]:
        """(J of the control fits (D,), {candidate: (gain of its fits (D,), parameters)}) for
        residual vectors R (S, M, D), summed over the folds; the discovered candidate's gain
        is per number of terms (rows)."""
        J0, out, _ = self._gains(R)
        return J0, out

    def _gains(
        self, R: FloatArray
    ) -> tuple[
        FloatArray,
        dict[str, tuple[FloatArray, int]],
        tuple[list[tuple[FloatArray, FloatArray, FloatArray]], list[list[int]]],
    ]:
        """:meth:`gains`, and the library's fold parts and greedy paths (for the held-out
        gains of the same terms)."""
        D = R.shape[-1]
        J0 = np.zeros(D)
        gains = {name: np.zeros(D) for name in self.cand}
        lib_parts: list[tuple[FloatArray, FloatArray, FloatArray]] = []
        for fold in self.folds:
            resid, stack = fold.resid, fold.stack
            Rf = resid(stack(R))
            J0 += (Rf * Rf).sum(axis=0)
            for name, (dcols, gcols, _) in self.cand.items():
                gd = _span_gain(resid(stack(dcols)), Rf)
                gg = _direction_gain(resid(stack(gcols)), Rf) if gcols.shape[-1] else 0.0 * gd
                gains[name] += np.maximum(gd, gg)
            if self.lib is not None:
                lib_parts.append(_library_part(fold, self.lib, Rf))
        out = {name: (gains[name], k) for name, (_, _, k) in self.cand.items()}
        paths: list[list[int]] = []
        if self.lib is not None:
            lib_gain, paths = _greedy(lib_parts, self.library_terms, self.term_ids)
            for t in range(self.library_terms):
                out[f"discovered/{t + 1}"] = (lib_gain[t], t + 1)
        return J0, out, (lib_parts, paths)

    def heldout(self, R: FloatArray, n_eff: float) -> HeldOut:
        """The dBIC of every candidate and, for each column's best candidate (the lowest dBIC,
        as the verdict would pick it; ``discovered``: the number of library terms with the
        lowest dBIC), what its fits do on the held-out runs, for residual vectors R (S, M, D);
        the worst held-out run is that of the best catalog candidate.

        A candidate's linearised fit on one fold is judged on the other fold's windows, both
        ways round, against the control fitted alike: its held-out gain [J] and the relative
        change of the held-out J of each run (:func:`sweep.diagnose.floor.run_of`)."""
        J0, gains, (parts, paths) = self._gains(R)
        pairs = [self._pair(j, k, R) for j, k in ((0, 1), (1, 0))]
        library = self._heldout_library(pairs, parts, paths) if self.lib is not None else {}
        dbic: dict[str, FloatArray] = {}
        held: dict[str, FloatArray] = {}  # per held-out window (W, D)
        for name, (gain, k) in gains.items():
            ratio = np.clip((J0 - gain) / J0, 1e-12, None)
            v = np.asarray(n_eff * np.log(ratio) + k * np.log(n_eff))
            key = name.split("/")[0]
            h = (
                library[int(name.split("/")[1])]
                if key == "discovered"
                else self._heldout_candidate(pairs, name)
            )
            if key in dbic:
                better = v < dbic[key]
                dbic[key] = np.where(better, v, dbic[key])
                held[key] = np.where(better[None, :], h, held[key])
            else:
                dbic[key], held[key] = v, h
        names = list(dbic)
        J0_w = np.concatenate([np.asarray(p["J0_w"]) for p in pairs])  # (W, D)
        runs = [run_of(self.windows[i]) for k in (1, 0) for i in self.folds[k].ix]
        worst = {n: self._worst_run(held[n], J0_w, runs) for n in names}
        best = np.argmin(np.stack([dbic[n] for n in names]), axis=0)
        cols = np.arange(best.size)
        # relative to the control's held-out J: the linearised refit of the base on one fold can
        # move directions the other fold is sensitive to far beyond what the nonlinear fits do
        # (on Train-TZR held-out J of 1e5 where the fits reach 1e3), and the gains with it
        gain = np.stack([held[n].sum(axis=0) for n in names])[best, cols]
        gain = gain / np.maximum(J0_w.sum(axis=0), 1e-300)
        # the worst held-out run of the best catalog candidate: the library's greedy path on
        # noise is not what a proposal fits (its held-out losses reach 100 x the run's J)
        named = [n for n in names if n != "discovered"] or names
        best_named = np.argmin(np.stack([dbic[n] for n in named]), axis=0)
        worst_best = np.stack([worst[n] for n in named])[best_named, cols]
        return HeldOut(dbic, gain, worst_best)

    @staticmethod
    def _worst_run(gain_w: FloatArray, J0_w: FloatArray, runs: Sequence[str]) -> FloatArray:
        """(D,) the largest loss of one run's held-out J relative to the control's held-out J of
        that run, from the gains and the control's J (W, D) per held-out window."""
        worst = np.full(gain_w.shape[1], -np.inf)
        for run in dict.fromkeys(runs):
            rows = [i for i, r in enumerate(runs) if r == run]
            j0 = np.maximum(J0_w[rows].sum(axis=0), 1e-300)
            worst = np.maximum(worst, -gain_w[rows].sum(axis=0) / j0)
        return worst

    def _pair(self, j: int, k: int, R: FloatArray) -> dict[str, object]:
        """What every candidate's held-out gain from fold j to fold k needs: the folds, the
        fold-k base Jacobian rows, the fold-j residuals with the base projected out, the
        control's held-out residuals H0 (fold-k rows, D) and its J per fold-k window (W_k, D)."""
        fj, fk = self.folds[j], self.folds[k]
        Ak = fk.rows(self.A)
        Rj = fj.resid(fj.stack(R))
        H0 = fk.rows(R) - Ak @ fj.base_coef(fj.stack(R))
        J0_w = (H0 * H0).reshape(len(fk.ix), -1, H0.shape[1]).sum(axis=1)
        return {"fj": fj, "fk": fk, "Ak": Ak, "Rj": Rj, "H0": H0, "J0_w": J0_w}

    @staticmethod
    def _images(pair: dict[str, object], X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(fold-j columns with the base projected out, their held-out images on fold k: the
        columns minus what the base fitted on fold j makes of them) of columns X (S, M, c)."""
        fj, fk, Ak = pair["fj"], pair["fk"], pair["Ak"]
        assert isinstance(fj, _Fold) and isinstance(fk, _Fold) and isinstance(Ak, np.ndarray)
        C = fj.resid(fj.stack(X))
        E = fk.rows(X) - Ak @ fj.base_coef(fj.stack(X))
        return C, E

    @staticmethod
    def _per_window(pair: dict[str, object], X: FloatArray) -> FloatArray:
        """Rows of fold k (W_k * M, D) summed per window: (W_k, D)."""
        fk = pair["fk"]
        assert isinstance(fk, _Fold)
        return X.reshape(len(fk.ix), -1, X.shape[1]).sum(axis=1)

    @staticmethod
    def _free(pair: dict[str, object], X: FloatArray, C: FloatArray) -> FloatArray:
        """(c,) whether each column of X keeps at least :data:`MIN_FREE` of its squared norm on
        fold j once the base is projected out (``C``): a column the base imitates has no
        stable coefficient, and its held-out image would be noise amplified."""
        fj = pair["fj"]
        assert isinstance(fj, _Fold)
        raw = (fj.stack(X) ** 2).sum(axis=0)
        return np.asarray((C * C).sum(axis=0) > MIN_FREE * np.maximum(raw, 1e-300))

    def _heldout_candidate(self, pairs: Sequence[dict[str, object]], name: str) -> FloatArray:
        """(W, D) held-out gain per held-out window (fold 1's, then fold 0's) of a candidate's
        fits: the span of its derivatives, or its best single grid direction where that fits
        the fold better (as :meth:`gains` scores it); columns the base imitates beyond
        1 - :data:`MIN_FREE` are left out."""
        dcols, gcols, _ = self.cand[name]
        out = []
        for pair in pairs:
            Rj, H0 = pair["Rj"], pair["H0"]
            assert isinstance(Rj, np.ndarray) and isinstance(H0, np.ndarray)
            C, E = self._images(pair, dcols)
            keep = self._free(pair, dcols, C)
            C, E = C[:, keep], E[:, keep]
            Q = _orth(C)
            D = Rj.shape[1]
            a = np.linalg.lstsq(C, Rj, rcond=1e-8)[0] if C.shape[1] else np.zeros((0, D))
            EA = E @ a
            h = self._per_window(pair, 2.0 * H0 * EA - EA * EA)
            fit = ((Q.T @ Rj) ** 2).sum(axis=0) if Q.shape[1] else np.zeros(D)
            if gcols.shape[-1]:
                G, Eg = self._images(pair, gcols)
                free = self._free(pair, gcols, G)
                n2 = np.where(free, np.maximum((G * G).sum(axis=0), 1e-300), np.inf)[:, None]
                P = G.T @ Rj  # (g, D)
                i = np.argmax(P * P / n2, axis=0)
                cols = np.arange(D)
                use = (P * P / n2)[i, cols] > fit
                if use.any():
                    EG = Eg[:, i] * (P[i, cols] / n2[i, 0])[None, :]  # the chosen direction's
                    hg = self._per_window(pair, 2.0 * H0 * EG - EG * EG)
                    h = np.where(use[None, :], hg, h)
            out.append(h)
        return np.concatenate(out)

    def _heldout_library(
        self,
        pairs: Sequence[dict[str, object]],
        parts: Sequence[tuple[FloatArray, FloatArray, FloatArray]],
        paths: Sequence[Sequence[int]],
    ) -> dict[int, FloatArray]:
        """{t: (W, D) held-out gain per held-out window of the first t library terms of each
        column's greedy path} (the terms :meth:`gains` chose in-sample), fitted on one fold,
        judged on the other."""
        assert self.lib is not None
        D = len(paths)
        out: dict[int, list[FloatArray]] = {t: [] for t in range(1, self.library_terms + 1)}
        for (j, _), pair in zip(((0, 1), (1, 0)), pairs, strict=True):
            H0, fk = pair["H0"], pair["fk"]
            assert isinstance(H0, np.ndarray) and isinstance(fk, _Fold)
            _, E = self._images(pair, self.lib)
            W = len(fk.ix)
            Ew = E.reshape(W, -1, E.shape[1])
            Et = Ew.transpose(0, 2, 1)
            EH = Et @ H0.reshape(W, -1, D)  # per window E'H0 (W, T, D)
            EE = Et @ Ew  # per window E'E (W, T, T)
            C, Rp, n0 = parts[j]
            for t in out:
                h = np.zeros((W, D))
                for d in range(D):
                    S = list(paths[d][:t])  # (a path that stopped early keeps its last terms)
                    if not S:
                        continue
                    a = -np.linalg.lstsq(C[:, S], Rp[:, d], rcond=None)[0] / n0[S]
                    h[:, d] = -(
                        2.0 * EH[:, S, d] @ a + np.einsum("s,wst,t->w", a, EE[:, S][:, :, S], a)
                    )
                out[t].append(h)
        return {t: np.concatenate(v) for t, v in out.items()}

    def refit_drift(self, r: FloatArray) -> RefitDrift:
        """:class:`RefitDrift` of the control's fold fits for the base's residual vector ``r``
        (S, M)."""
        R = r[..., None]
        J_ho: list[float] = []
        J_base: list[float] = []
        names: list[str] = []
        for j, k in ((0, 1), (1, 0)):
            pair = self._pair(j, k, R)
            J0_w = np.asarray(pair["J0_w"])[:, 0]
            ix = self.folds[k].ix
            J_ho += [float(v) for v in J0_w]
            J_base += [float(np.sum(r[i] * r[i])) for i in ix]
            names += [self.windows[i].name for i in ix]
        total = float(sum(J_ho))
        worst = int(np.argmax(J_ho)) if J_ho else 0
        return RefitDrift(
            heldout=total,
            base=float(sum(J_base)),
            window=names[worst] if names else "",
            share=J_ho[worst] / total if total > 0.0 else 0.0,
        )

    def refit_factor(self, R: FloatArray) -> float:
        """Mean J of the base refitted (linearised, with the prior) on all windows over the mean
        J before refitting, for residual vectors R (S, M, D): below 1 by what the refit fits of
        the noise itself (the floor of a *fitted* model's J is this times the plain floor)."""
        raw = float(np.sum(R * R))
        if raw <= 0.0:
            return 1.0
        Rf = self.all.resid(self.all.stack(R))
        return float(np.sum(Rf * Rf)) / raw

    def dbic(self, R: FloatArray, n_eff: float) -> dict[str, FloatArray]:
        """dBIC (D,) of every candidate's linearised fits for residual vectors R (S, M, D);
        ``discovered``: the best over the number of library terms."""
        J0, gains = self.gains(R)
        out: dict[str, FloatArray] = {}
        for name, (gain, k) in gains.items():
            ratio = np.clip((J0 - gain) / J0, 1e-12, None)
            v = np.asarray(n_eff * np.log(ratio) + k * np.log(n_eff))
            key = name.split("/")[0]
            out[key] = np.minimum(out[key], v) if key in out else v
        return out
