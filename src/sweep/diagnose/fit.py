"""Identify the MMG parameters jointly with the parameters of extra-physics effects.

The search space is the paper's 57-parameter box (:func:`mmg.bounds`) followed by each effect's
own search interval (:class:`mmg.EffectParam`), normalised to [0, 1] like the base job. A joint fit
starts from given base parameters (usually the base model identified without the effect) with the
effect at its neutral values; the step size of the effect's coordinates is ``effect_sigma`` of
their interval, that of the base coordinates ``sigma0``: the base can re-balance what it had
absorbed of the effect (the cancellation effect) while the effect's parameters move freely.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg import Effect, Parameters, bounds
from mmg.params import N_THETA
from sweep.cmaes import Box, Result, Settings, optimise
from sweep.objective import Objective
from sweep.recordings import Recording
from sweep.workers import make_evaluator

FloatArray = NDArray[np.float64]


def with_effects(
    base: Parameters, effects: Sequence[Effect], values: Sequence[float] | None = None
) -> Parameters:
    """``base`` carrying ``effects`` with the given values in kernel order (neutral if None)."""
    out: list[tuple[str, tuple[tuple[str, float], ...]]] = []
    i = 0
    for eff in effects:
        k = len(eff.params)
        vals = eff.neutral() if values is None else tuple(float(v) for v in values[i : i + k])
        i += k
        out.append((eff.name, tuple(zip(eff.param_names, vals, strict=True))))
    return Parameters(base.theta, base.ship, tuple(out))


def effect_values(p: Parameters, effects: Sequence[Effect]) -> list[float]:
    """The effects' values of ``p`` in kernel order (neutral where absent)."""
    values: list[float] = []
    for eff in effects:
        given = p.effect_values(eff.name)
        values += [given.get(q.name, q.neutral) for q in eff.params]
    return values


def full_vector(p: Parameters, effects: Sequence[Effect]) -> FloatArray:
    """(57 + k,) base values then effect values."""
    return np.concatenate([p.vector(), np.asarray(effect_values(p, effects), dtype=np.float64)])


def from_full_vector(v: Any, ship_of: Parameters, effects: Sequence[Effect]) -> Parameters:
    """Inverse of :func:`full_vector`."""
    v = np.asarray(v, dtype=np.float64)
    base = Parameters.from_vector(v[:N_THETA], ship=ship_of.ship)
    return with_effects(base, effects, v[N_THETA:])


def joint_box(effects: Sequence[Effect]) -> Box:
    """The search box of the 57 base parameters and the effects' parameters."""
    lo, hi = bounds()
    e_lo = [q.lower for e in effects for q in e.params]
    e_hi = [q.upper for e in effects for q in e.params]
    return Box(np.concatenate([lo, e_lo]), np.concatenate([hi, e_hi]))


@dataclass(frozen=True)
class FitSettings:
    """Budget and step sizes of one joint fit."""

    objective: str = "J2"
    budget: int = 1500
    seed: int = 0
    sigma0: float = 0.03  # base coordinates, normalised box
    effect_sigma: float = 0.15  # effect coordinates, normalised box
    popsize: int = 20
    #: share of the budget spent first on the effect's parameters alone (base held fixed)
    effect_only_share: float = 0.25


@dataclass(frozen=True)
class Fit:
    """Outcome of a joint fit."""

    params: Parameters
    effects: tuple[Effect, ...]
    f: float
    evaluations: int
    seconds: float
    history: list[dict[str, float]]


def fit(
    recordings: Sequence[Recording],
    start: Parameters,
    effects: Sequence[Effect],
    settings: FitSettings,
    workers: int | None = 0,
    progress: Any = None,
    objective: Objective | None = None,
) -> Fit:
    """Minimise the objective over base + effect parameters, starting from ``start``.

    ``objective`` may be given to reuse a prepared :class:`Objective` (it must carry ``effects``).
    """
    effects = tuple(effects)
    obj = objective or Objective(recordings, settings.objective, effects=effects, ship=start.ship)
    if obj.effects != effects:
        raise ValueError("the objective was built for other effects")
    box = joint_box(effects)
    x0 = full_vector(start, effects)
    k = box.n - N_THETA
    budget = settings.budget
    spent = 0
    if k and settings.effect_only_share > 0:
        # phase 1: the effect alone on top of the given base (a k-dimensional search)
        first = max(settings.popsize, int(settings.budget * settings.effect_only_share))
        x0, spent = _fit_effect_only(obj, box, x0, first, settings, workers)
        budget = max(settings.popsize, settings.budget - spent)
    stds = (1.0,) * N_THETA + (settings.effect_sigma / settings.sigma0,) * k
    cma_settings = Settings(
        seed=settings.seed,
        max_evaluations=budget,
        sigma0=settings.sigma0,
        popsize_start=settings.popsize,
        popsize_max=settings.popsize,
        stds=stds if k else None,
    )
    with make_evaluator(obj, workers) as evaluate:
        result: Result = optimise(evaluate, box, x0, cma_settings, progress=progress)
    # the start itself competes: a fit never reports worse parameters than it was given
    f_start = float(obj.evaluate(x0[None, :])[0])
    theta = result.theta if result.f <= f_start else x0
    return Fit(
        params=from_full_vector(theta, start, effects),
        effects=effects,
        f=min(result.f, f_start),
        evaluations=spent + result.evaluations + 1,
        seconds=result.seconds,
        history=result.history,
    )


def _fit_effect_only(
    obj: Objective, box: Box, x0: FloatArray, budget: int, settings: FitSettings, workers: Any
) -> tuple[FloatArray, int]:
    """Optimise the effect coordinates of x0 with the base ones fixed; returns (x, evaluations).

    Up to two effect parameters: a grid over the whole interval, then a finer grid around the
    best point, each evaluated as one batch (global, deterministic, and what pycma cannot do in
    one dimension); more parameters: CMA-ES in the effect's box.
    """
    base = x0[:N_THETA]
    lo, hi = box.lower[N_THETA:], box.upper[N_THETA:]
    k = lo.size
    with make_evaluator(obj, workers) as evaluate_full:

        def evaluate(effect_thetas: FloatArray) -> FloatArray:
            full = np.concatenate(
                [np.broadcast_to(base, (effect_thetas.shape[0], N_THETA)), effect_thetas], axis=1
            )
            return np.asarray(evaluate_full(full), dtype=np.float64)

        best_x = x0[N_THETA:].copy()
        best_f = float(evaluate(best_x[None, :])[0])
        used = 1
        if k <= 2:
            per_axis = max(3, round((budget / 2) ** (1.0 / k)))
            a, b = lo.copy(), hi.copy()
            for _ in range(2):
                axes = [np.linspace(a[j], b[j], per_axis) for j in range(k)]
                grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
                f = evaluate(grid)
                used += len(f)
                i = int(np.argmin(f))
                if f[i] < best_f:
                    best_f, best_x = float(f[i]), grid[i].copy()
                half = (b - a) / (per_axis - 1)
                a = np.maximum(lo, best_x - half)
                b = np.minimum(hi, best_x + half)
        else:
            sub = Box(lo, hi)
            cma_settings = Settings(
                seed=settings.seed + 1000,
                max_evaluations=max(budget, settings.popsize),
                sigma0=min(1.0, settings.effect_sigma * 2),
            )
            result = optimise(evaluate, sub, best_x, cma_settings)
            used += result.evaluations
            if result.f < best_f:
                best_f, best_x = result.f, result.theta
    return np.concatenate([base, best_x]), used


def refit(previous: Fit, recordings: Sequence[Recording], settings: FitSettings, **kw: Any) -> Fit:
    """Continue a fit with a new budget and seed (same effects)."""
    return fit(recordings, previous.params, previous.effects, settings, **kw)


__all__ = [
    "Fit",
    "FitSettings",
    "effect_values",
    "fit",
    "from_full_vector",
    "full_vector",
    "joint_box",
    "refit",
    "with_effects",
]
