"""Identify the MMG parameters jointly with the parameters of extra-physics effects.

The search space is the paper's 57-parameter box (:func:`mmg.bounds`) followed by each effect's
own search interval (:class:`mmg.EffectParam`), normalised to [0, 1] like the base job. A joint fit
starts from given base parameters (usually the base model identified without the effect) with the
effect at its neutral values, then: (1) the effect alone on top of the base (a grid for one or two
parameters); (2) optionally CMA-ES on all coordinates (``budget`` > 0; the effect's coordinates
step ``effect_sigma`` of their interval, the base ones ``sigma0``); (3) optionally
Levenberg-Marquardt on all coordinates (``polish``, :mod:`sweep.identification.polish`). In (2)
and (3) the base can re-balance what it had absorbed of the effect (the cancellation effect) while
the effect's parameters move freely. With ``budget`` 0 the fit is deterministic.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg import Effect, Parameters
from mmg.params import N_THETA
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.identification.cmaes import Box, Result, Settings, optimise
from sweep.identification.polish import PolishSettings, polish
from sweep.identification.vector import from_full_vector, full_vector, joint_box
from sweep.identification.workers import make_evaluator

FloatArray = NDArray[np.float64]


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
    #: evaluations of the effect-only grid when ``budget`` is 0 (local refinement only)
    effect_only_budget: int = 300
    #: Levenberg-Marquardt refinement after CMA-ES (None: none); with ``budget`` 0 the fit is
    #: the effect-only grid followed by this refinement alone (deterministic)
    polish: PolishSettings | None = None
    #: (k, k) quadratic penalty c' P c on the effects' k parameters c (their units), added in
    #: the refinement: a shape's smoothness (:func:`sweep.diagnose.shapes`); None: none
    penalty: tuple[tuple[float, ...], ...] | None = None
    #: hold the effects at their values in the start and refit the base alone (the transfer
    #: check, :mod:`sweep.diagnose.transfer`): no effect-only search, no CMA-ES
    fixed_effects: bool = False


#: half-width of the interval an effect's coordinate is held in by ``fixed_effects``, as a
#: share of its search interval: Levenberg-Marquardt works in the box, so a held coordinate
#: gets a box of (almost) no width rather than leaving the vector
HELD = 1e-9


def held_box(box: Box, x0: FloatArray) -> Box:
    """``box`` with the coordinates after the 57 base parameters pinned at ``x0``'s values."""
    lower, upper = box.lower.copy(), box.upper.copy()
    eps = HELD * (upper[N_THETA:] - lower[N_THETA:])
    lower[N_THETA:] = x0[N_THETA:] - eps
    upper[N_THETA:] = x0[N_THETA:] + eps
    return Box(lower, upper)


@dataclass(frozen=True)
class Fit:
    """Outcome of a joint fit."""

    params: Parameters
    effects: tuple[Effect, ...]
    f: float
    evaluations: int
    seconds: float
    history: list[dict[str, float]]
    #: J at the end of each competing route of a fit made of several (the base's two starts)
    ends: tuple[float, ...] = ()


def fit(
    recordings: Sequence[Recording],
    start: Parameters,
    effects: Sequence[Effect],
    settings: FitSettings,
    workers: int | None = 0,
    progress: Any = None,
    objective: Objective | None = None,
    prior_center: Parameters | None = None,
) -> Fit:
    """Minimise the objective over base + effect parameters, starting from ``start``.

    ``objective`` may be given to reuse a prepared :class:`Objective` (it must carry ``effects``).
    With a prior in ``settings.polish`` (``prior_weight`` > 0 on the first ``prior_dims``
    coordinates), the Levenberg-Marquardt refinement minimises J + prior, the prior pulling the
    base parameters toward ``prior_center`` (default: the point the refinement starts from, the
    CMA-ES end if there is one); its end is then kept even when its J alone is a little above
    that of its start (it traded J for plausibility). ``Fit.f`` is always J alone.
    """
    effects = tuple(effects)
    obj = objective or Objective(recordings, settings.objective, effects=effects, ship=start.ship)
    if obj.effects != effects:
        raise ValueError("the objective was built for other effects")
    box = joint_box(effects)
    x0 = full_vector(start, effects)
    k = box.n - N_THETA
    budget = settings.budget
    if settings.fixed_effects and k:
        box = held_box(box, x0)
        k, budget = 0, 0
    spent = 0
    t0 = time.perf_counter()
    if k and (
        (budget > 0 and settings.effect_only_share > 0)
        or (budget == 0 and settings.effect_only_budget > 0)
    ):
        # phase 1: the effect alone on top of the given base (a k-dimensional search)
        first = (
            settings.effect_only_budget
            if budget == 0
            else max(settings.popsize, int(budget * settings.effect_only_share))
        )
        x0, spent = _fit_effect_only(obj, box, x0, first, settings, workers)
        budget = max(settings.popsize, budget - spent) if budget else 0
    theta = x0
    f = float(obj.evaluate(x0[None, :])[0])
    spent += 1
    history: list[dict[str, float]] = []
    if budget > 0:
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
        spent += result.evaluations
        history = list(result.history)
        # the start itself competes: a fit never reports worse parameters than it was given
        if result.f < f:
            theta, f = result.theta, result.f
    if settings.polish is not None:
        done = spent
        center = None if prior_center is None else full_vector(prior_center, effects)
        P = None
        if settings.penalty is not None:
            P = np.zeros((box.n, box.n))
            P[N_THETA:, N_THETA:] = np.asarray(settings.penalty, dtype=np.float64)
        res = polish(obj, box, theta, settings.polish, prior_center=center, penalty=P)
        spent += res.evaluations
        history += [{**row, "evaluations": row["evaluations"] + done} for row in res.history]
        with_prior = (
            settings.polish.prior_weight > 0 and settings.polish.prior_dims > 0
        ) or settings.penalty is not None
        if with_prior or res.f < f:
            theta, f = res.theta, res.f
    return Fit(
        params=from_full_vector(theta, start, effects),
        effects=effects,
        f=f,
        evaluations=spent,
        seconds=time.perf_counter() - t0,
        history=history,
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


__all__ = ["Fit", "FitSettings", "fit"]
