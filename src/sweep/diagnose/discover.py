"""Discovery: propose a term nobody wrote down, from the equation-level residuals.

Equation error proposes, output error decides: this module proposes; the proposed terms become a
generated effect (:mod:`mmg.discovered`) that the diagnosis fits on trajectories and ranks with
the catalog's effects by the same rules. The steps (other docstrings refer to their numbers):

1. **Residuals** of Eq. (1): recorded accelerations (u_dot, v_m_dot, r_dot) by a cubic
   Savitzky-Golay filter (``sg_window_s``) minus the model's at the smoothed states and controls,
   every ``stride``-th sample of every training window.
2. **Regressors**: per library term (:mod:`mmg.library`) the accelerations its force with a unit
   coefficient causes through the model's mass matrix
   (:func:`mmg.integrate.effect_accelerations_rows`), one column per grid point of its shape;
   the base's regressors are the derivatives of its accelerations by the 57 parameters.
3. **Cancellation** (Frisch-Waugh-Lovell): residual and columns are projected off the base
   regressors; a term whose column the base imitates beyond ``max_absorbed`` is dropped.
4. **Selection**: forward stepwise on held-out R^2 (cross-validation over whole windows), up to
   ``max_terms``, each step adding at least ``min_gain`` of the R^2 so far.
4b. **Alternatives**: heading, position and time drift together over a run, so for each such kind
   in the selection it is repeated without that kind; sets reaching ``alternative_ratio`` of the
   R^2 are proposed beside it and the trajectory fits decide.
5. **Calibration**: the same procedure on base-model simulations with noise of the estimated
   level and colour (:mod:`sweep.diagnose.floor`); terms are proposed only if the held-out R^2
   exceeds the null's ``1 - alpha`` quantile.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import savgol_filter

from mmg import Effect, Parameters, bounds, derivatives, get_effect
from mmg.discovered import discovered_effect, unit_rows, with_bounds
from mmg.integrate import derivatives_rows, effect_accelerations_rows
from mmg.library import SEARCHED, Column, chosen_shapes, library_columns, term
from mmg.params import N_THETA
from mmg.precompile import precompile, tasks
from sweep.data.recordings import Recording
from sweep.diagnose.floor import NoiseModel, simulate_windows
from sweep.diagnose.threads import map_threads
from sweep.identification.vector import effect_values

FloatArray = NDArray[np.float64]

ACC = (1, 3, 5)  # u_dot, v_m_dot, r_dot in the state derivative


@dataclass(frozen=True)
class DiscoverySettings:
    """Rules of the proposal."""

    max_terms: int = 3
    min_gain: float = 0.15  # share of the held-out R^2 reached so far a further term must add
    max_absorbed: float = 0.97
    sg_window_s: float = 2.1
    stride: int = 3  # every stride-th sample of the smoothed series
    folds: int = 4
    null_draws: int = 19
    alpha: float = 0.05
    terms: tuple[str, ...] = ()  # library terms searched (empty: all)
    alternatives: int = 2  # further term sets proposed without one kind of variable (step 4b)
    alternative_ratio: float = 0.8  # ... when they reach this share of the held-out R^2


#: kinds of library terms that describe where and when, not how the ship moves: they drift
#: together over a run and are the ones step 4b swaps
EXOGENOUS_KINDS = ("heading", "position", "time")


@dataclass
class EquationData:
    """Stacked, weighted equation residuals and regressors of a set of windows."""

    y: FloatArray  # (3M,) residual
    C: FloatArray  # (3M, T) term columns
    B: FloatArray  # (3M, 57) base regressors
    groups: NDArray[np.int64]  # (3M,) window of each row
    term_ids: list[str]  # (T,) the term of each column (a term with a shape has several)
    scale: FloatArray  # (3,) channel weights applied (1 / RMS of the residual)
    columns: list[Column] = field(default_factory=list)  # (T,) term and shape grid point
    t: FloatArray = field(default_factory=lambda: np.zeros(0))  # (M,) time of each sample [s]
    psi: FloatArray = field(default_factory=lambda: np.zeros(0))  # (M,) its heading [rad]

    @property
    def labels(self) -> list[str]:
        """(T,) a unique label per column (the term id, with its shape if it has one)."""
        return [c.label for c in self.columns] if self.columns else list(self.term_ids)


def _smooth(a: FloatArray, m: int) -> FloatArray:
    return np.asarray(savgol_filter(a, m, 3, axis=0))


def spans(windows: Sequence[Recording]) -> dict[str, FloatArray]:
    """The positions x0, y0 [m] over the windows: where the grid of a step's centre and width
    lies (:func:`mmg.library.shape_grid`)."""
    return {
        "x0": np.concatenate([np.asarray(w.x)[:, 0] for w in windows]),
        "y0": np.concatenate([np.asarray(w.x)[:, 2] for w in windows]),
    }


def equation_data(
    params: Parameters,
    windows: Sequence[Recording],
    settings: DiscoverySettings,
    where: dict[str, FloatArray] | None = None,
) -> EquationData:
    """Residuals and regressors (see the module docstring, steps 1-2). ``where``: the positions
    the shapes' grid is laid over (default: these windows')."""
    ids = list(settings.terms or SEARCHED)
    columns = library_columns(ids, where if where is not None else spans(windows))
    lib = discovered_effect(ids)
    base_effects = tuple(get_effect(n) for n, _ in params.effects)
    effects = (*base_effects, lib)
    ys, Cs, Bs, gs, ts, psis = [], [], [], [], [], []
    lo, hi = bounds()
    steps = 1e-3 * (hi - lo)
    theta0 = params.vector()
    # parameter rows: the base and each base parameter stepped (through the base model's
    # kernel: the library's search effect, which carries all its terms, adds exactly nothing at
    # neutral values), and each column (a term at one point of its shape's grid) at coefficient 1
    extra_b = effect_values(params, base_effects)
    p0 = np.concatenate([theta0, extra_b])
    Pb = np.repeat(p0[None, :], 1 + N_THETA, axis=0)  # (1 + 57, n_params of the base)
    Pb[1 + np.arange(N_THETA), np.arange(N_THETA)] += steps
    T = len(columns)
    Pl = np.repeat(np.concatenate([p0, lib.neutral()])[None, :], T, axis=0)  # (T, n_params)
    Pl[:, p0.size :] = unit_rows(lib, columns, 1.0)
    for g, w in enumerate(windows):
        dt = w.dt
        m = max(7, round(settings.sg_window_s / dt) | 1)
        if w.n_samples < 2 * m:
            continue
        x = np.asarray(w.x, dtype=np.float64).copy()
        x[:, 4] = np.unwrap(x[:, 4])
        xs = _smooth(x, m)
        acc = np.asarray(savgol_filter(x[:, list(ACC)], m, 3, deriv=1, delta=dt, axis=0))
        us = _smooth(np.asarray(w.u, dtype=np.float64), m)  # the controls averaged alike
        wind = np.asarray(w.w)
        tt = np.asarray(w.t, dtype=np.float64)
        sl = slice(m // 2, x.shape[0] - m // 2, settings.stride)  # away from the filter's edges
        xs, acc, us, wind, tt = xs[sl], acc[sl], us[sl], wind[sl], tt[sl]
        db = derivatives_rows(xs, us, wind, Pb, base_effects, params.ship, tt)[..., ACC]
        db = np.moveaxis(db, 1, 0)  # (n, 1 + 57, 3)
        # a column's regressor: what its term's force adds to the accelerations (Eq. (1) is
        # linear in the forces: the library's forces alone, not the whole right-hand side)
        dl = effect_accelerations_rows(xs, us, wind, Pl, effects, params.ship, tt)
        base = db[:, 0]
        ys.append(acc - base)
        Bs.append((db[:, 1:] - base[:, None]) / steps[None, :, None])
        Cs.append(np.moveaxis(dl, 1, 0))  # (n, T, 3)
        gs.append(np.full(ys[-1].shape[0], g))
        ts.append(tt)
        psis.append(xs[:, 4])
    if not ys:
        raise ValueError("no window is long enough for the equation-level residuals")
    y = np.concatenate(ys)  # (M, 3)
    Bm = np.concatenate(Bs)  # (M, 57, 3)
    Cm = np.concatenate(Cs)  # (M, T, 3)
    grp = np.concatenate(gs)
    scale = 1.0 / np.maximum(np.sqrt(np.mean(y * y, axis=0)), 1e-12)
    y = y * scale
    Bm = Bm * scale[None, None, :]
    Cm = Cm * scale[None, None, :]
    M = y.shape[0]
    return EquationData(
        y=y.T.reshape(3 * M),
        C=np.moveaxis(Cm, 2, 0).reshape(3 * M, T),
        B=np.moveaxis(Bm, 2, 0).reshape(3 * M, N_THETA),
        groups=np.tile(grp, 3),
        term_ids=[c.term for c in columns],
        scale=scale,
        columns=columns,
        t=np.concatenate(ts),
        psi=np.concatenate(psis),
    )


@dataclass
class Selection:
    """The outcome of steps 3-4 on one data set."""

    terms: list[str]
    coefficients: list[float]  # joint (projected) least-squares estimates
    cv_r2: float
    path: list[dict[str, float | str]]
    absorbed: dict[str, float]
    single: list[dict[str, float | str]]  # every term alone: held-out R^2, absorbed fraction
    #: step 4b: term sets without one kind of variable that explain nearly as much
    alternatives: list[Alternative] = field(default_factory=list)
    #: the chosen shape of each selected term that has one: {term: {placeholder: value}}
    shapes: dict[str, dict[str, float]] = field(default_factory=dict)
    labels: list[str] = field(default_factory=list)  # the selected columns, with their shapes


@dataclass
class Alternative:
    """A term set selected without the terms of one kind (``without``), step 4b."""

    terms: list[str]
    coefficients: list[float]
    cv_r2: float
    without: str
    shapes: dict[str, dict[str, float]] = field(default_factory=dict)
    labels: list[str] = field(default_factory=list)  # the terms with their shapes


def _shapes(data: EquationData, chosen: Sequence[int]) -> dict[str, dict[str, float]]:
    """{term: {placeholder: value}} of the chosen columns whose term has a shape."""
    return chosen_shapes([data.columns[k] for k in chosen]) if data.columns else {}


class _HeldOut:
    """Held-out R^2 of least squares of ``y`` on subsets of the columns of ``C``, the folds
    ``folds`` (boolean row masks that partition the rows) each held out in turn.

    From per-fold Gram matrices, formed once: a subset's fit on the other folds solves the
    k x k normal equations (k <= a few terms), and its squared error on the held-out fold is
    ``y_f'y_f - 2 beta'C_f'y_f + beta'C_f'C_f beta``, so the thousands of subsets that forward
    selection tries cost microseconds each instead of a least-squares solve over all rows (and
    the subsets of one step are solved as one batch, :meth:`r2_many`).
    """

    def __init__(self, y: FloatArray, C: FloatArray, folds: list[NDArray[np.bool_]]) -> None:
        parts = [C[f] for f in folds]  # one copy per fold: Cf.T @ Cf is then a syrk
        self.G = [Cf.T @ Cf for Cf in parts]
        self.b = [Cf.T @ y[f] for Cf, f in zip(parts, folds, strict=True)]
        self.yy = [float(y[f] @ y[f]) for f in folds]
        G_all = np.sum(self.G, axis=0)
        b_all = np.sum(self.b, axis=0)
        # the normal equations of the fit without each fold
        self.G_out = [G_all - G for G in self.G]
        self.b_out = [b_all - b for b in self.b]
        self.total = max(float(y @ y), 1e-300)

    def r2_many(self, chosen: Sequence[int], candidates: Sequence[int]) -> FloatArray:
        """(n,) held-out R^2 of ``chosen`` plus each of the n ``candidates`` in turn: the n
        small systems of a forward step solved as one batch (numpy's least squares one at a
        time cost more in Python than in arithmetic)."""
        cand = np.asarray(candidates, dtype=np.intp)
        idx = np.empty((cand.size, len(chosen) + 1), dtype=np.intp)
        idx[:, :-1] = np.asarray(chosen, dtype=np.intp)
        idx[:, -1] = cand
        rows, cols = idx[:, :, None], idx[:, None, :]
        sse = np.zeros(cand.size)
        for G, b, yy, G_out, b_out in zip(
            self.G, self.b, self.yy, self.G_out, self.b_out, strict=True
        ):
            beta = _lstsq_many(G_out[rows, cols], b_out[idx])
            fitted = np.einsum("nj,njk,nk->n", beta, G[rows, cols], beta)
            sse += yy - 2.0 * np.einsum("nj,nj->n", beta, b[idx]) + fitted
        return np.asarray(1.0 - sse / self.total)


def _lstsq_many(A: FloatArray, b: FloatArray) -> FloatArray:
    """(n, m) minimum-norm least-squares solutions of the n systems A (n, m, m) x = b (n, m),
    as :func:`numpy.linalg.lstsq` with ``rcond=None`` solves each (singular values at most
    eps m times the largest count as zero)."""
    U, s, Vt = np.linalg.svd(A)
    cutoff = np.finfo(np.float64).eps * A.shape[-1] * s[:, :1]
    inv = np.divide(1.0, s, out=np.zeros_like(s), where=s > cutoff)
    return np.asarray(np.einsum("nkj,nk->nj", Vt, inv * np.einsum("njk,nj->nk", U, b)))


def _projected(data: EquationData) -> tuple[FloatArray, FloatArray]:
    """(y, C) with the base regressors projected out (step 3)."""
    U, s, _ = np.linalg.svd(data.B, full_matrices=False)
    Q = U[:, s > 1e-8 * s[0]] if s.size and s[0] > 0 else U[:, :0]
    return data.y - Q @ (Q.T @ data.y), data.C - Q @ (Q.T @ data.C)


#: labels of the three equations of Eq. (1), in the order of the residual's channels
CHANNEL_NAMES = ("surge (X)", "sway (Y)", "yaw (N)")


def regression_view(data: EquationData, terms: Sequence[str], bins: int = 10) -> dict[str, Any]:
    """The equation residual regressed on ``terms``, per channel (surge, sway, yaw), after the
    base model's own regressors are projected out: the share of each channel's residual the
    terms explain jointly (R^2), each term's coefficient, and per channel and term the binned
    partial-regression points (the term's fitted contribution against the residual left by the
    other terms, both in units of the channel's residual RMS), for the report's figure."""
    y, C = _projected(data)
    labels = data.labels
    ks = [labels.index(t) for t in terms if t in labels]
    M = y.size // 3
    beta = np.linalg.lstsq(C[:, ks], y, rcond=None)[0] if ks else np.zeros(0)
    fit = C[:, ks] @ beta if ks else np.zeros_like(y)
    out: dict[str, Any] = {"terms": [labels[k] for k in ks], "channels": []}
    for c, name in enumerate(CHANNEL_NAMES):
        rows = slice(c * M, (c + 1) * M)
        yc, fc = y[rows], fit[rows]
        ss = float(yc @ yc)
        channel: dict[str, Any] = {
            "channel": name,
            "rms": float(np.sqrt(np.mean(yc * yc))) if yc.size else 0.0,
            "r2": 1.0 - float((yc - fc) @ (yc - fc)) / ss if ss > 0 else 0.0,
            "partial": [],
        }
        for j, k in enumerate(ks):
            x = C[rows, k] * beta[j]
            raw = [float(np.linalg.norm(data.C[c2 * M : (c2 + 1) * M, k])) for c2 in range(3)]
            if not np.any(x) or raw[c] < 0.01 * max(raw):
                continue  # the term does not act in this channel (only through the projection)
            partial = yc - (fc - x)  # the residual left by the other terms
            edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, bins + 1)))
            idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
            pts = [
                (float(x[idx == b].mean()), float(partial[idx == b].mean()), int((idx == b).sum()))
                for b in range(edges.size - 1)
                if np.any(idx == b)
            ]
            channel["partial"].append({"term": labels[k], "points": pts})
        out["channels"].append(channel)
    return out


def select(
    data: EquationData, settings: DiscoverySettings, with_alternatives: bool = True
) -> Selection:
    """Project out the base regressors, then forward stepwise selection by held-out R^2 (and,
    with ``with_alternatives``, the alternatives of step 4b)."""
    y, C = _projected(data)
    norm0 = np.sum(data.C * data.C, axis=0)
    norm = np.sum(C * C, axis=0)
    absorbed = np.where(norm0 > 0, 1.0 - norm / np.maximum(norm0, 1e-300), 1.0)
    usable = [k for k in range(C.shape[1]) if norm0[k] > 0 and absorbed[k] <= settings.max_absorbed]
    windows = np.unique(data.groups)
    F = max(2, min(settings.folds, windows.size))
    folds = [np.isin(data.groups, windows[f::F]) for f in range(F)]
    labels = data.labels
    held = _HeldOut(y, C, folds)
    alone = held.r2_many([], usable) if usable else np.zeros(0)
    single: list[dict[str, float | str]] = [
        {
            "term": labels[k],
            "id": data.term_ids[k],
            "cv_r2": float(r2),
            "absorbed": float(absorbed[k]),
        }
        for k, r2 in zip(usable, alone, strict=True)
    ]
    single.sort(key=lambda r: r["cv_r2"], reverse=True)
    chosen, best, steps = _forward(held, usable, settings, data.term_ids)
    names = [data.term_ids[k] for k in chosen]
    path: list[dict[str, float | str]] = [{"term": labels[k], "cv_r2": r2} for k, r2 in steps]
    alternatives: list[Alternative] = []
    if with_alternatives and chosen:
        seen = {frozenset(names)}
        for kind in EXOGENOUS_KINDS:
            if len(alternatives) >= settings.alternatives:
                break
            if all(term(n).kind != kind for n in names):
                continue
            rest = [k for k in usable if term(data.term_ids[k]).kind != kind]
            alt, r2, _steps = _forward(held, rest, settings, data.term_ids)
            alt_names = [data.term_ids[k] for k in alt]
            if not alt or r2 < settings.alternative_ratio * best or frozenset(alt_names) in seen:
                continue
            seen.add(frozenset(alt_names))
            alternatives.append(
                Alternative(
                    alt_names,
                    _coefficients(y, C, alt),
                    r2,
                    kind,
                    _shapes(data, alt),
                    [labels[k] for k in alt],
                )
            )
    return Selection(
        terms=names,
        coefficients=_coefficients(y, C, chosen),
        cv_r2=best,
        path=path,
        absorbed={data.term_ids[k]: float(absorbed[k]) for k in chosen},
        single=single[:12],
        alternatives=alternatives,
        shapes=_shapes(data, chosen),
        labels=[labels[k] for k in chosen],
    )


def _forward(
    held: _HeldOut,
    usable: Sequence[int],
    settings: DiscoverySettings,
    term_ids: Sequence[str],
) -> tuple[list[int], float, list[tuple[int, float]]]:
    """Forward stepwise selection among the columns ``usable`` (step 4): (chosen columns, their
    held-out R^2, the path as (column, held-out R^2) per step). A term enters once (at one point
    of its shape's grid)."""
    chosen: list[int] = []
    path: list[tuple[int, float]] = []
    best = 0.0
    for _ in range(settings.max_terms):
        taken = {term_ids[k] for k in chosen}
        open_ = [k for k in usable if term_ids[k] not in taken]
        if not open_:
            break
        r2s = held.r2_many(chosen, open_)
        r2s = np.where(np.isfinite(r2s), r2s, -np.inf)  # (a column that is not finite: never)
        # the best held-out R^2; of equal ones the last column, as max() over (r2, k) had it
        j = len(open_) - 1 - int(np.argmax(r2s[::-1]))
        r2, k = float(r2s[j]), open_[j]
        if r2 <= 0.0 or (chosen and r2 - best < settings.min_gain * best):
            break
        chosen.append(k)
        best = r2
        path.append((k, r2))
    return chosen, best, path


def _coefficients(y: FloatArray, C: FloatArray, chosen: Sequence[int]) -> list[float]:
    """Joint least-squares coefficients of the columns ``chosen``."""
    if not chosen:
        return []
    beta, *_ = np.linalg.lstsq(C[:, list(chosen)], y, rcond=None)
    return [float(b) for b in beta]


@dataclass
class Proposal:
    """What discovery proposes for the trajectory fits (or why nothing)."""

    selection: Selection
    threshold: float
    null: list[float]
    alpha: float
    proposed: bool
    seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def terms(self) -> list[str]:
        """Library ids of the proposed terms (empty when nothing is proposed)."""
        return self.selection.terms if self.proposed else []

    def effect(self, widen: float = 4.0) -> Effect:
        """The generated effect of the proposed terms, its box +-``widen`` x the estimate."""
        sel = self.selection
        return _boxed(sel.terms, sel.coefficients, widen, sel.shapes)

    def effects(self, widen: float = 4.0) -> list[Effect]:
        """The proposed effect and its alternatives (step 4b), each boxed like :meth:`effect`;
        none when nothing is proposed."""
        if not self.proposed:
            return []
        alts = [
            _boxed(a.terms, a.coefficients, widen, a.shapes) for a in self.selection.alternatives
        ]
        return [self.effect(widen), *alts]


def _boxed(
    terms: Sequence[str],
    coefficients: Sequence[float],
    widen: float,
    shapes: dict[str, dict[str, float]] | None = None,
) -> Effect:
    """The generated effect of ``terms``, its box +-``widen`` x the equation-level estimates,
    the shapes starting at the grid points chosen (:func:`mmg.discovered.with_bounds`)."""
    half = [max(widen * abs(c), 1e-6) for c in coefficients]
    return with_bounds(discovered_effect(terms), half, shapes)


def null_sets(
    params: Parameters,
    windows: Sequence[Recording],
    noise: NoiseModel,
    rng: np.random.Generator,
    draws: int,
) -> list[list[Recording]]:
    """``draws`` synthetic copies of the windows: the model's simulation plus noise."""
    sims = simulate_windows(params, windows)
    out = []
    for _ in range(draws):
        series = noise.draw_many(rng, [x.shape[0] for x in sims])
        out.append(
            [
                Recording(w.name, None, w.t, x + e, w.u, w.w)
                for w, x, e in zip(windows, sims, series, strict=True)
            ]
        )
    return out


def discover(
    params: Parameters,
    windows: Sequence[Recording],
    noise: NoiseModel,
    rng: np.random.Generator,
    settings: DiscoverySettings | None = None,
    log: Any = None,
) -> Proposal:
    """Steps 1-5 of the module docstring on the training windows."""
    import time

    s = settings or DiscoverySettings()
    for t in s.terms:
        term(t)  # unknown ids fail here, naming the library
    t0 = time.perf_counter()
    where = spans(windows)  # the shapes' grid, the same for the null's copies
    data = equation_data(params, windows, s, where)
    sel = select(data, s)
    # the regression view: the selected terms, or (none selected) the three best alone
    shown = sel.labels or [str(r["term"]) for r in sel.single[:3]]
    view = regression_view(data, shown)

    def statistic(recs: list[Recording]) -> float:
        return select(equation_data(params, recs, s, where), s, with_alternatives=False).cv_r2

    # the noise-only copies side by side (each drawn before, in order: the same null)
    null = map_threads(statistic, null_sets(params, windows, noise, rng, s.null_draws))
    threshold = float(np.quantile(null, 1.0 - s.alpha)) if null else 0.0
    proposed = bool(sel.terms) and sel.cv_r2 > threshold
    if log is not None:
        log(
            f"discovery: {' + '.join(sel.labels) or 'no term'} explains {100 * sel.cv_r2:.1f} % of "
            f"the held-out equation residual (null {1 - s.alpha:.0%} quantile "
            f"{100 * threshold:.1f} %) -> {'proposed' if proposed else 'not proposed'}"
        )
        for a in sel.alternatives if proposed else []:
            log(
                f"discovery, alternative without {a.without} terms: {' + '.join(a.terms)} "
                f"explains {100 * a.cv_r2:.1f} % -> proposed beside it"
            )
    return Proposal(
        sel, threshold, null, s.alpha, proposed, time.perf_counter() - t0, {"regression": view}
    )


def force_patterns(
    params: Parameters,
    windows: Sequence[Recording],
    effects: Sequence[Effect],
    values: Sequence[Sequence[float]],
    stride: int = 5,
) -> list[FloatArray]:
    """For each of ``effects`` at its ``values``: (3M,) the accelerations (u_dot, v_m_dot,
    r_dot) it adds to the model at the recorded states, every ``stride``-th sample, each channel
    divided by the model's own acceleration RMS (an effect acting only on controls or the
    measurement adds none here).

    One right-hand side holds the model's effects and all of ``effects``; each pattern is taken
    with the others at their neutral values, which add exactly nothing: one kernel to compile,
    not one per effect."""
    if len(values) != len(effects):
        raise ValueError(f"{len(effects)} effects, {len(values)} sets of values")
    base_effects = tuple(get_effect(n) for n, _ in params.effects)
    extra0 = effect_values(params, base_effects)
    neutral = [np.asarray(e.neutral(), dtype=np.float64) for e in effects]
    head = np.concatenate([params.vector(), extra0])
    rows = [np.concatenate([head, *neutral])]
    for i, v in enumerate(values):
        parts = [np.asarray(v, dtype=np.float64) if j == i else z for j, z in enumerate(neutral)]
        rows.append(np.concatenate([head, *parts]))
    P = np.stack(rows)
    x = np.concatenate([np.asarray(w.x)[::stride] for w in windows])
    u = np.concatenate([np.asarray(w.u)[::stride] for w in windows])
    wind = np.concatenate([np.asarray(w.w)[::stride] for w in windows])
    tt = np.concatenate([np.asarray(w.t)[::stride] for w in windows])
    n, b = x.shape[0], P.shape[0]
    d = derivatives(
        np.broadcast_to(x, (b, n, 6)),
        np.broadcast_to(u, (b, n, 2)),
        np.broadcast_to(wind, (b, n, 2)),
        np.broadcast_to(P[:, None, :], (b, n, P.shape[1])),
        (*base_effects, *effects),
        t=np.broadcast_to(tt, (b, n)),
    )
    acc = d[..., list(ACC)]  # (b, n, 3)
    a0 = acc[0]
    scale = 1.0 / np.maximum(np.sqrt(np.mean(a0 * a0, axis=0)), 1e-12)
    return [np.asarray(((acc[k] - a0) * scale).T.reshape(-1)) for k in range(1, b)]


def resemblance(
    params: Parameters,
    windows: Sequence[Recording],
    chosen: Effect,
    scores: Sequence[Any],
    effects: Sequence[Effect],
) -> dict[str, float]:
    """Correlation of the chosen (discovered) effect's force pattern with each catalog
    candidate's, both at their fitted values; catalog effects that add no force are left out."""
    by_name = {e.name: e for e in effects}
    fitted = {c.effect: c.params for c in scores}
    compared = [
        by_name[n]
        for n in fitted
        if n in by_name and n != chosen.name and not n.startswith("discovered:")
    ]
    base_effects = tuple(get_effect(n) for n, _ in params.effects)
    every = (chosen, *compared)
    precompile(tasks([(*base_effects, *every)], ("derivatives",)))
    ref, *pats = force_patterns(
        params, windows, every, [list(fitted[e.name].values()) for e in every]
    )
    out: dict[str, float] = {}
    for eff, pat in zip(compared, pats, strict=True):
        den = float(np.linalg.norm(pat) * np.linalg.norm(ref))
        if den > 0:
            out[eff.name] = float(pat @ ref / den)
    return dict(sorted(out.items(), key=lambda kv: -abs(kv[1])))
