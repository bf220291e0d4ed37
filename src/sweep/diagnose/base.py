"""The base model: identified on all training windows from two competing routes; when they end
apart, a second CMA-ES start and a descent over growing horizons (a stop in another basin is not
missing physics).

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

from sweep.diagnose.calibration import Calibration, calibrate
from sweep.diagnose.context import Context
from sweep.diagnose.fit import Fit, FitSettings
from sweep.diagnose.windows import cut_windows


def routes_agree(ends: Sequence[float], tolerance: float) -> bool:
    """Whether the competing routes of a fit (at least two) ended within ``tolerance`` times
    the lowest J of each other (never with ``tolerance`` 0)."""
    if tolerance <= 0.0 or len(ends) < 2 or not all(math.isfinite(f) for f in ends):
        return False
    return max(ends) - min(ends) <= tolerance * abs(min(ends))


def descent_alone(ctx: Context, iterations: int) -> FitSettings:
    """The settings of Levenberg-Marquardt alone (no CMA-ES) for up to ``iterations``."""
    return replace(ctx.common, budget=0, polish=ctx.lm(iterations, 1e-4))


def base_fit(ctx: Context) -> Fit:
    """The better end of CMA-ES then Levenberg-Marquardt and of Levenberg-Marquardt alone, both
    from the start on all windows; its ``ends`` are the routes' J, its cost their sum."""
    s, common = ctx.settings, ctx.common
    first = replace(common, budget=s.base_budget, seed=s.seed)
    ends = [ctx.refit(ctx.windows, ctx.start, (), first, "base")]
    if s.base_lm_iterations > 0:
        alone = descent_alone(ctx, s.base_lm_iterations)
        ends.append(ctx.refit(ctx.windows, ctx.start, (), alone, "base, descent alone"))
        ctx.log(f"base: CMA-ES then descent J = {ends[0].f:.2f}, descent alone J = {ends[1].f:.2f}")
    best = min(ends, key=lambda e: e.f)
    return replace(
        best,
        evaluations=sum(e.evaluations for e in ends),
        seconds=sum(e.seconds for e in ends),
        ends=tuple(e.f for e in ends),
    )


def horizon_descent(ctx: Context, horizons: Sequence[float], iterations: int) -> Fit:
    """Levenberg-Marquardt from the start on the training windows cut into pieces of each of
    ``horizons`` [s] in turn (each piece starting from its recorded state, pieces shorter than
    half the horizon dropped), each from the end of the one before, then on the windows
    themselves; its cost is the sum.

    Over a short horizon the simulated states stay near the recorded ones, so J is nearly
    quadratic in the parameters over a wide region; over 100 s a parameter set whose trajectory
    has drifted onto another track has basins of its own. Each horizon's end starts the next
    in the basin the short ones chose (continuation in the horizon, as in multiple-shooting
    identification). On the planted no-effect cases whose routes stopped in a worse basin it
    ended nearest the true model: training J2 0.838 and 0.740 from the other routes, 0.799 and
    0.683 over horizons of 10, 25 and 50 s, the true model's 0.791 and 0.664 (test J2 0.425 ->
    0.294 and 0.426 -> 0.346; the true model's 0.240 and 0.199)."""
    descent = descent_alone(ctx, iterations)
    p = ctx.start
    evaluations, seconds = 0, 0.0
    for tf in horizons:
        pieces = cut_windows(ctx.windows, t_f=tf, min_window=0.5 * tf)
        if not pieces:
            continue
        label = f"base, descent over {tf:g}-s horizons"
        step = ctx.refit(pieces, p, (), descent, label)
        ctx.log(f"{label}: J = {step.f:.4g} on {len(pieces)} pieces")
        p = step.params
        evaluations += step.evaluations
        seconds += step.seconds
    last = ctx.refit(ctx.windows, p, (), descent, "base, descent over growing horizons")
    return replace(last, evaluations=evaluations + last.evaluations, seconds=seconds + last.seconds)


def identify_base(ctx: Context) -> Fit:
    """Stage ``base``: :func:`base_fit`, stored."""
    return ctx.staged("base", (), lambda: base_fit(ctx))


def second_start(
    ctx: Context, base: Fit, cal: Calibration
) -> tuple[Fit, Calibration, dict[str, float] | None]:
    """Stages ``base-retry`` and ``base-horizons``: unless the base's two routes already agree
    (:func:`routes_agree`), a second CMA-ES start (another seed) and the descent over growing
    horizons (:func:`horizon_descent`, when ``base_horizons`` are set). The second start
    replaces the base when it ends lower; the descent over horizons when it ends lower than
    both by more than the routes' agreement tolerance (ends that close are one point reached
    two ways). The calibration is then redone at the new base. Also when the misfit is within
    the floor: routes that end apart show more than one basin, and a base in the worse one can
    fit the training windows within the floor and still miss the test recordings (on a planted
    no-effect case J2 0.720 on the training windows, the true model's 0.670, and 5.1 x the true
    model's test J2). Returns (base, calibration, the ``base_retry`` record)."""
    s = ctx.settings
    if not s.base_retry:
        return base, cal, None
    routes = {f"J_route{i + 1}": f for i, f in enumerate(base.ends)}
    if routes_agree(base.ends, s.base_retry_agreement):
        ctx.log(
            "base, second start not needed: the two routes ended at J = "
            + " and ".join(f"{f:.6g}" for f in base.ends)
            + f" (within {100 * s.base_retry_agreement:g} %)"
        )
        return base, cal, {"J_first": base.f, "skipped": 1.0, **routes}
    settings = replace(ctx.common, budget=s.base_budget, seed=s.seed + 100)
    retry = ctx.staged(
        "base-retry",
        (),
        lambda: ctx.refit(ctx.windows, ctx.start, (), settings, "base, second start"),
    )
    record = {"J_first": base.f, "J_second": retry.f, **routes}
    ctx.log(f"base, second start: J = {retry.f:.4g} against {base.f:.4g}")
    tried = [base, retry]
    best = retry if retry.f < base.f else base
    if s.horizons_on:
        grown = ctx.staged(
            "base-horizons",
            (),
            lambda: horizon_descent(ctx, s.base_horizons, s.base_lm_iterations),
        )
        tried.append(grown)
        record["J_horizons"] = grown.f
        ctx.log(f"base, descent over growing horizons: J = {grown.f:.4g} against {best.f:.4g}")
        if grown.f < (1.0 - s.base_retry_agreement) * best.f:
            best = grown
    if best is not base:
        spent = sum(f.evaluations for f in tried)
        base = replace(best, evaluations=spent, seconds=sum(f.seconds for f in tried))
        cal = calibrate(ctx, base.params)
    return base, cal, record
