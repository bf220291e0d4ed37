"""The base model: identified on all training windows from two competing routes, and a second
CMA-ES start when its misfit is above the floor (a stop in another basin is not missing physics).

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

from sweep.diagnose.calibration import Calibration, calibrate
from sweep.diagnose.context import Context
from sweep.diagnose.fit import Fit


def routes_agree(ends: Sequence[float], tolerance: float) -> bool:
    """Whether the competing routes of a fit (at least two) ended within ``tolerance`` times
    the lowest J of each other (never with ``tolerance`` 0)."""
    if tolerance <= 0.0 or len(ends) < 2 or not all(math.isfinite(f) for f in ends):
        return False
    return max(ends) - min(ends) <= tolerance * abs(min(ends))


def base_fit(ctx: Context) -> Fit:
    """The better end of CMA-ES then Levenberg-Marquardt and of Levenberg-Marquardt alone, both
    from the start on all windows; its ``ends`` are the routes' J, its cost their sum."""
    s, common = ctx.settings, ctx.common
    first = replace(common, budget=s.base_budget, seed=s.seed)
    ends = [ctx.refit(ctx.windows, ctx.start, (), first, "base")]
    if s.base_lm_iterations > 0:
        descent = replace(common, budget=0, polish=ctx.lm(s.base_lm_iterations, 1e-4))
        ends.append(ctx.refit(ctx.windows, ctx.start, (), descent, "base, descent alone"))
        ctx.log(f"base: CMA-ES then descent J = {ends[0].f:.2f}, descent alone J = {ends[1].f:.2f}")
    best = min(ends, key=lambda e: e.f)
    return replace(
        best,
        evaluations=sum(e.evaluations for e in ends),
        seconds=sum(e.seconds for e in ends),
        ends=tuple(e.f for e in ends),
    )


def identify_base(ctx: Context) -> Fit:
    """Stage ``base``: :func:`base_fit`, stored."""
    return ctx.staged("base", (), lambda: base_fit(ctx))


def second_start(
    ctx: Context, base: Fit, cal: Calibration
) -> tuple[Fit, Calibration, dict[str, float] | None]:
    """Stage ``base-retry``: a second CMA-ES start (another seed) unless the base's routes
    already agree; a lower end replaces the base and the calibration is redone there. Also
    when the misfit is within the floor: routes that end apart show more than one basin, and
    a base in the worse one can fit the training windows within the floor and still miss the
    test recordings (on a planted no-effect case J2 0.720 on the training windows, the true
    model's 0.670, and 5.1 x the true model's test J2). Returns (base, calibration, the
    ``base_retry`` record)."""
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
    if retry.f < base.f:
        spent = base.evaluations + retry.evaluations
        base = replace(retry, evaluations=spent, seconds=base.seconds + retry.seconds)
        cal = calibrate(ctx, base.params)
    return base, cal, record
