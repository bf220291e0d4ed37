"""The candidates' fold fits and scores: each effect (catalog and proposed) fitted with the 57
base parameters on one half of the windows and judged on the other, both ways round, against a
control fit of the base alone by the same procedure; then the leading candidates and the control
refined with more Levenberg-Marquardt iterations.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from mmg import Effect
from sweep.data.recordings import Recording
from sweep.diagnose.context import Context
from sweep.diagnose.fit import Fit, FitSettings
from sweep.diagnose.floor import run_of
from sweep.diagnose.scoring import (
    CandidateScore,
    delta_bic,
    generated,
    heldout_per_window,
    typical_change,
)
from sweep.diagnose.store import stage_label
from sweep.identification.polish import PolishSettings
from sweep.identification.vector import effect_values, with_effects

FloatArray = NDArray[np.float64]

#: the candidates' fold stages: ``candidate-c-NAME-foldJ`` continues the control's fit of the
#: fold, ``candidate-NAME-foldJ`` starts from the base (:func:`fit_candidates`)
CANDIDATE = "candidate-c-"
FROM_BASE = "candidate-"


@dataclass(frozen=True)
class FoldFits:
    """The two fold fits of one model and the J of every held-out window (fold 0's, then
    fold 1's), shape (held-out windows,)."""

    fits: list[Fit]
    J_heldout: FloatArray
    #: the run of each held-out window (:func:`sweep.diagnose.floor.run_of`)
    runs: tuple[str, ...] = ()
    #: the held-out windows of each fold (fold 0's come first in ``J_heldout``)
    sizes: tuple[int, ...] = ()
    #: per fold, where a candidate's fit started: ``c`` the control's fit, ``b`` the base
    origins: str = ""


@dataclass
class Candidates:
    """Every candidate's fold fits and score against the control's fold fits.

    ``best_fold`` holds, per candidate, the fold fit that gained more over its control (it
    carries the effect's values); ``leaders`` the candidates that were refined."""

    effects: tuple[Effect, ...]
    control: FoldFits
    folds: dict[str, FoldFits]
    scores: list[CandidateScore]
    best_fold: dict[str, Fit]
    leaders: list[str]
    #: per candidate, where its ``best_fold`` started (``c`` the control's fit, ``b`` the base)
    origin: dict[str, str] = field(default_factory=dict)


def candidate_settings(ctx: Context) -> FitSettings:
    """The fold fits: the effect alone on a grid, then Levenberg-Marquardt on base and effect
    jointly (CMA-ES before it when ``candidate_budget`` > 0)."""
    s = ctx.settings
    return replace(
        ctx.common,
        budget=s.candidate_budget,
        seed=s.seed + 1,
        sigma0=s.refit_sigma,
        effect_only_budget=s.effect_only_budget,
        polish=ctx.lm(s.polish_iterations, PolishSettings.rtol),
    )


def refine_settings(ctx: Context) -> FitSettings:
    """The refinement of fold fits: more Levenberg-Marquardt iterations alone."""
    return replace(
        candidate_settings(ctx),
        budget=0,
        effect_only_budget=0,
        polish=ctx.lm(ctx.settings.refine_iterations, 1e-4),
    )


def fold_fits(
    ctx: Context,
    base: Fit,
    name: str,
    effs: tuple[Effect, ...],
    settings: FitSettings,
    starts: Sequence[Fit] | None = None,
    split: tuple[list[Recording], list[Recording]] | None = None,
    names: Sequence[str] | None = None,
) -> FoldFits:
    """Stages ``NAME-fold0`` and ``NAME-fold1`` (or ``names[j]-foldJ``): ``effs`` fitted on
    each half from the base (or from ``starts``), each judged on the other half (the halves:
    ``split``, by default the context's held-out runs)."""
    fits: list[Fit] = []
    J_ho: list[float] = []
    a, b = (ctx.fit_w, ctx.held_w) if split is None else split
    halves = ((a, b), (b, a))
    runs = tuple(run_of(w) for _, held in halves for w in held)
    for j, (fit_half, held_half) in enumerate(halves):
        p0 = base.params if starts is None else starts[j].params
        label = stage_label(name if names is None else names[j], effs)
        res = ctx.staged(
            f"{label}-fold{j}",
            effs,
            lambda fh=fit_half, p0=p0: ctx.refit(fh, p0, effs, settings, name),  # type: ignore[misc]
        )
        fits.append(res)
        J_ho += heldout_per_window(held_half, res.params, ctx.settings.objective)
    return FoldFits(fits, np.asarray(J_ho), runs, (len(b), len(a)))


def better_ends(continued: FoldFits, fresh: FoldFits, share: float) -> FoldFits:
    """Per fold, the fit that continued the control's (``c``), unless the fit from the base
    (``b``) ends lower by more than ``share`` of its J: the continued fit differs from the
    control by the effect alone, but where the control's fit on a few windows has absorbed the
    effect it can stay in the control's valley."""
    n0 = continued.sizes[0]
    parts = (slice(0, n0), slice(n0, None))
    fits, J_ho, origins = [], [], ""
    for j, part in enumerate(parts):
        use_fresh = fresh.fits[j].f < (1.0 - share) * continued.fits[j].f
        chosen = fresh if use_fresh else continued
        fits.append(chosen.fits[j])
        J_ho.append(chosen.J_heldout[part])
        origins += "b" if use_fresh else "c"
    return FoldFits(fits, np.concatenate(J_ho), continued.runs, continued.sizes, origins)


def origin_of(folds: FoldFits, fit: Fit) -> str:
    """Where the fold fit ``fit`` (one of ``folds.fits``) started: ``c`` or ``b``."""
    j = next(i for i, f in enumerate(folds.fits) if f is fit)
    return folds.origins[j] if folds.origins else "c"


def score(
    eff: Effect, cand: FoldFits, control: FoldFits, n_eff: float, k: float | None = None
) -> tuple[CandidateScore, Fit]:
    """The score of ``eff``'s fold fits against the control's, and the fold fit that carries
    the effect's values (the one that gained more over its control); ``k``: the parameters it
    counts in dBIC (default: its number of parameters)."""
    J_fit = sum(f.f for f in cand.fits)
    best = min(range(2), key=lambda j: cand.fits[j].f / max(control.fits[j].f, 1e-300))
    vals = effect_values(cand.fits[best].params, (eff,))
    J_ho, J_ho_control = cand.J_heldout, control.J_heldout
    run, change, loss = worst_run(J_ho, J_ho_control, control.runs)
    losses = run_losses(J_ho, J_ho_control, control.runs)
    changes = run_changes(J_ho, J_ho_control, control.runs)
    scored = CandidateScore(
        effect=eff.name,
        description=eff.description,
        regime=eff.regime,
        params=dict(zip(eff.param_names, vals, strict=True)),
        J_fit=J_fit,
        J_heldout=float(J_ho.sum()),
        improvement=typical_change(J_ho, J_ho_control),
        improvement_total=float(1.0 - J_ho.sum() / max(J_ho_control.sum(), 1e-300)),
        heldout_gain=float(J_ho_control.sum() - J_ho.sum()),
        worst_run=run,
        worst_run_change=change,
        worst_run_loss=loss,
        run_losses=losses,
        run_changes=changes,
        delta_bic=delta_bic(
            J_fit, sum(f.f for f in control.fits), len(eff.params) if k is None else k, n_eff
        ),
        evaluations=sum(f.evaluations for f in cand.fits),
    )
    return scored, cand.fits[best]


def worst_run(
    J_effect: FloatArray, J_control: FloatArray, runs: Sequence[str]
) -> tuple[str, float, float]:
    """The held-out run whose J the effect raises most relative to the control's J of that run,
    that relative change and the run's loss [J] (J summed over the run's held-out windows; a
    diverged window counts as infinitely worse)."""
    worst, change, loss = "", -np.inf, -np.inf
    for run, c in run_changes(J_effect, J_control, runs).items():
        if c > change or not worst:
            rows = [i for i, r in enumerate(runs) if r == run]
            a, b = float(np.sum(J_effect[rows])), float(np.sum(J_control[rows]))
            worst, change = run, c
            loss = a - b if np.isfinite(a) else np.inf
    return worst, float(change), float(loss)


def run_changes(
    J_effect: FloatArray, J_control: FloatArray, runs: Sequence[str]
) -> dict[str, float]:
    """{held-out run: relative change of its J against the control's} over the run's held-out
    windows (infinite where a window diverged; 0 for a run the control fits exactly and the
    effect does not change)."""
    out = {}
    for run in dict.fromkeys(runs):
        rows = [i for i, r in enumerate(runs) if r == run]
        a, b = float(np.sum(J_effect[rows])), float(np.sum(J_control[rows]))
        if not np.isfinite(a):
            out[run] = float("inf")
        elif b > 0:
            out[run] = a / b - 1.0
        else:
            out[run] = 0.0 if a <= 0 else float("inf")
    return out


def run_losses(
    J_effect: FloatArray, J_control: FloatArray, runs: Sequence[str]
) -> dict[str, float]:
    """{held-out run: J with the effect minus J of the control} over the run's held-out windows
    (infinite where a window diverged)."""
    out = {}
    for run in dict.fromkeys(runs):
        rows = [i for i, r in enumerate(runs) if r == run]
        a = float(np.sum(J_effect[rows]))
        out[run] = a - float(np.sum(J_control[rows])) if np.isfinite(a) else float("inf")
    return out


def candidate_folds(
    ctx: Context, base: Fit, control: FoldFits, eff: Effect, settings: FitSettings
) -> FoldFits:
    """The fold fits of one candidate (stages ``candidate-c-NAME-foldJ`` and
    ``candidate-NAME-foldJ``): two starts in each fold, the control's fit of that fold (the
    base parameters it reached there; the two fits then differ by the effect, not by where the
    base wandered) and the base, the effect at neutral or, for a learned shape, at its
    linearised coefficients; :func:`better_ends` keeps one."""
    values = ctx.starts.get(eff.name)
    on_control = [
        replace(c, params=with_effects(c.params, (eff,), values), effects=(eff,))
        for c in control.fits
    ]
    start = replace(base, params=with_effects(base.params, (eff,), values), effects=(eff,))
    continued = fold_fits(ctx, base, f"{CANDIDATE}{eff.name}", (eff,), settings, on_control)
    fresh = fold_fits(ctx, base, f"{FROM_BASE}{eff.name}", (eff,), settings, [start, start])
    return better_ends(continued, fresh, ctx.settings.base_retry_agreement)


def fit_candidates(ctx: Context, base: Fit, extra: Sequence[Effect]) -> Candidates:
    """The control and every candidate (the catalog's, then ``extra``) fitted and scored."""
    settings = candidate_settings(ctx)
    control = fold_fits(ctx, base, "control", (), settings)
    effects = (*ctx.candidate_effects(), *extra)
    out = Candidates(effects, control, {}, [], {}, [])
    for i, eff in enumerate(effects, 1):
        ctx.log(f"candidate {i}/{len(effects)}: {eff.name}")
        t_c = time.perf_counter()
        out.folds[eff.name] = candidate_folds(ctx, base, control, eff, settings)
        k = ctx.parameter_count(eff)
        c, out.best_fold[eff.name] = score(eff, out.folds[eff.name], control, ctx.n_eff, k)
        out.origin[eff.name] = origin_of(out.folds[eff.name], out.best_fold[eff.name])
        c.seconds = time.perf_counter() - t_c
        out.scores.append(c)
    return out


def leading(scores: Sequence[CandidateScore], threshold: float, top: int) -> list[str]:
    """The candidates to refine: the ``top`` best by dBIC, and every discovered candidate that
    passes ``threshold`` already (a proposal and its alternatives are ranked against each
    other, and only refined candidates can be accepted)."""
    leaders = [c.effect for c in sorted(scores, key=lambda c: c.delta_bic)[:top]]
    leaders += [
        c.effect
        for c in scores
        if generated(c.effect) and c.delta_bic <= threshold and c.effect not in leaders
    ]
    return leaders


def refine(ctx: Context, base: Fit, cands: Candidates, threshold: float) -> Candidates:
    """The leading candidates and the control continued from their fold fits (a joint fit that
    must undo what the base had absorbed can still be descending); the refined scores come
    first, the others follow unchanged."""
    s = ctx.settings
    leaders = leading(cands.scores, threshold, s.refine_top)
    if not s.refines:
        return replace(cands, leaders=leaders)
    settings = refine_settings(ctx)
    control = fold_fits(ctx, base, "control-refined", (), settings, cands.control.fits)
    by_name = {e.name: e for e in cands.effects}
    best_fold = dict(cands.best_fold)
    origin = dict(cands.origin)
    refined = []
    for name in leaders:
        eff = by_name[name]
        t_c = time.perf_counter()
        start = cands.folds[name]
        names = [f"{FROM_BASE}{o}-{name}-refined" for o in start.origins]
        folds = fold_fits(ctx, base, name, (eff,), settings, start.fits, names=names)
        folds = replace(folds, origins=start.origins)
        c, best_fold[name] = score(eff, folds, control, ctx.n_eff, ctx.parameter_count(eff))
        origin[name] = origin_of(folds, best_fold[name])
        c.refined = True
        c.seconds = time.perf_counter() - t_c
        refined.append(c)
    others = [c for c in cands.scores if c.effect not in leaders]
    return replace(
        cands,
        control=control,
        scores=refined + others,
        best_fold=best_fold,
        leaders=leaders,
        origin=origin,
    )
