"""A closed form's corner, and a step's width, fitted by output error.

The naming (:func:`sweep.diagnose.shaping.named_form`) places a hinge's or a step's corner on a
grid: shares of the range and quantiles of the training samples, compared on trajectory columns
of a spline with knots a fortieth of the range apart. A force that sets in within a degree
(a rudder whose normal force collapses beyond an angle of attack) is then named with a corner
a few degrees off and a width as wide as the grid's, and the fit by output error, which moves
the coefficients only, cannot mend it: on a strong collapse planted at |alpha_R| = 23 deg, the
form named at 20 deg reached a training J of 0.711, the same form at 23 deg 0.646.

:func:`fit_numbers` fits them by output error on the training windows, one group at a time:
at each trial corner a short joint fit of the form's coefficients and the base
(:data:`ITERATIONS` Levenberg-Marquardt iterations from the best trial so far; with the base
held, the profile's minimum on that collapse was the named corner itself: the base had
absorbed part of the force); the corner moves over the naming's grid spacing, two of them
either way, and the search halves its step around the best corner :data:`ROUNDS` times; a
step's width is then tried at shares of the named one (:data:`WIDTHS`), and the corner once
more at the best width. A wave's period is searched the same way in its frequency (the naming's
spacing: half a cycle over the range) and its phase (the naming's spacing of phases) together,
to each of the eight neighbours, from half the spacing, halved each round: named on a grid, a
wave of ten cycles over a recording is a quarter of a cycle out at the far end, and the best
phase moves with the period. Fitted numbers replace the named ones only when they lower the BIC
(each a parameter), and a candidate with fitted numbers counts each of them as a parameter in
its dBIC.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from mmg import Effect, Parameters
from mmg.shapes import (
    SHAPE_PREFIX,
    SYMMETRIC,
    WAVES,
    Form,
    Group,
    groups_of,
    parse_form,
    shape_effect,
)
from sweep.diagnose.naming import WAVE_PHASES
from sweep.diagnose.scoring import delta_bic
from sweep.identification.vector import effect_values, with_effects

#: closed forms whose first number is a corner (:data:`mmg.shapes.FORMS`)
CORNERED = ("up", "down", "absup", "oddup", "step", "absstep")
#: closed forms whose second number is a width
WIDTHED = ("step", "absstep")
#: halvings of the corner's step around the best corner
ROUNDS = 3
#: a step's widths tried, as shares of the named one
WIDTHS = (0.25, 0.5, 2.0)
#: Levenberg-Marquardt iterations of each trial's fit (coefficients and base)
ITERATIONS = 6
#: a wave's moves at one step size while they lower J, at most this many times
PASSES = 3
#: a wave's rounds, each halving its steps from half the naming's spacing: a frequency to 1/128
#: of half a cycle over the range (on a planted sloshing of 40 s over 400 s of recordings, a
#: period 0.05 s off at the best phase left a training J of 1.79 against 0.99, and the test
#: recordings' J2 4.6 x the true model's against 1.04 x)
WAVE_ROUNDS = 7


@dataclass(frozen=True)
class Fitted:
    """A closed-form effect with its numbers fitted: ``effect`` (named with them), its
    coefficients ``start`` at the best trial, the training J before (the named numbers) and
    after, the numbers fitted (``count``) and the trials' (form text, J)."""

    effect: Effect
    start: list[float]
    J_named: float
    J_fitted: float
    count: int
    trials: list[tuple[str, float]]
    seconds: float


def corner_range(group: Group, form: Form) -> tuple[float, float]:
    """The open interval a corner of ``form`` lies in over ``group``'s range: a symmetric
    form's in [0, the range's larger side), another's in (lo, hi)."""
    if form.key in (*SYMMETRIC, "absstep"):
        return 0.0, max(abs(group.lo), abs(group.hi))
    return group.lo, group.hi


def grid_step(group: Group, fine: int) -> float:
    """The naming's corner resolution over ``group``'s range: the knot spacing of ``fine``
    basis functions."""
    return (group.hi - group.lo) / (fine - 3)


#: J and the fitted parameters of shapes whose coefficients, and the base, are refitted from
#: given parameters (the coefficients in them under any shape's name: by position)
Evaluate = Callable[[Sequence[Group], Parameters], tuple[float, Parameters]]


def _fit_group(
    evaluate: Evaluate, groups: Sequence[Group], i: int, at: Parameters, fine: int, n_eff: float
) -> tuple[Group, Parameters, int]:
    """Group ``i``'s corner (and a step's width) fitted, the other ``groups`` as they are,
    each trial started from the best one's fit (``at`` at first): (the group, the best trial's
    fit, the numbers fitted). The named numbers stay unless the fitted ones pay for
    themselves in BIC over ``n_eff`` residuals (each number a parameter)."""
    g = groups[i]
    form = parse_form(g.form)
    lo, hi = corner_range(g, form)
    best = list(form.args)
    best_J, at = evaluate(groups, at)
    named_J, named_at = best_J, at

    def with_group(args: Sequence[float]) -> list[Group]:
        return [*groups[:i], _with_args(g, args), *groups[i + 1 :]]

    step = grid_step(g, fine)
    widths = [[best[1] * share] for share in WIDTHS] if form.key in WIDTHED else []
    # the corner moved by one and two steps either way, the step halved around the best corner
    # each round; a step's widths at the best corner, then one more round of the corner
    plan: list[tuple[str, float]] = [("corner", step / 2**r) for r in range(ROUNDS)]
    if widths:
        plan += [("width", 0.0), ("corner", step / 2**ROUNDS)]
    if form.key in WAVES:  # frequency and phase together, the steps halved each round
        plan = [("wave", float(r)) for r in range(WAVE_ROUNDS)]
    for what, h in plan:
        for _ in range(PASSES if what == "wave" else 1):
            if what == "corner":
                tries = [[best[0] + m * h, *best[1:]] for m in (-2, -1, 1, 2)]
                tries = [t for t in tries if lo < t[0] < hi]
            elif what == "wave":
                tries = _wave_tries(g, best, int(h))
            else:
                tries = [[best[0], *w] for w in widths]
            start, moved = at, False
            for args in tries:
                J, p = evaluate(with_group(args), start)
                if best_J > J:
                    best, best_J, at, moved = list(args), J, p, True
            if not moved:
                break
    count = len(form.args) if form.key in WAVES else 1 + (1 if widths else 0)
    if delta_bic(best_J, named_J, count, n_eff) >= 0.0:
        return g, named_at, 0
    return _with_args(g, best), at, count


def _wave_tries(group: Group, args: Sequence[float], r: int) -> list[list[float]]:
    """A wave's (period, phase) moved one step of round ``r`` in its frequency, its phase or
    both (8 neighbours): steps of the naming's spacing (half a cycle over the range,
    pi / :data:`WAVE_PHASES`) halved ``r + 1`` times, from half of it: the named wave is the
    grid's nearest, and a whole step lands on a neighbour the naming judged (where a wave of
    ten cycles fits another side lobe). The phase moves as the phase at the middle of the range,
    which a change of the frequency leaves in place (at z = 0, a period 1 % longer over ten
    cycles turns the phase at the far end by a tenth of a cycle), and is written back at z = 0,
    within (-pi, pi]."""
    zc = 0.5 * (group.lo + group.hi)
    df = 0.5 / (group.hi - group.lo) / 2 ** (r + 1)
    dphi = math.pi / WAVE_PHASES / 2 ** (r + 1)
    f0 = 1.0 / args[0]
    mid = args[1] + 2.0 * math.pi * f0 * zc
    out = []
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            f = f0 + a * df
            if (a, b) != (0, 0) and f > 0.0:
                phase = math.remainder(mid + b * dphi - 2.0 * math.pi * f * zc, 2.0 * math.pi)
                out.append([1.0 / f, phase])
    return out


def _cornered(group: Group) -> bool:
    """Whether ``group`` is a closed form of one variable with a corner or a period (a product
    of two closed forms keeps the numbers it was named with)."""
    return (
        bool(group.form)
        and not group.control
        and not group.tensor
        and parse_form(group.form).key in (*CORNERED, *WAVES)
    )


def _with_args(group: Group, args: Sequence[float]) -> Group:
    """``group`` with its closed form's numbers ``args`` (rounded as a spec writes them)."""
    return replace(group, form=Form(parse_form(group.form).key, tuple(args)).text)


def fit_numbers(
    effect: Effect,
    start: Parameters,
    refit: Callable[[Effect, Parameters], tuple[float, Parameters]],
    fine: int,
    n_eff: float,
    log: Callable[[str], None] | None = None,
) -> Fitted | None:
    """The closed-form shape ``effect`` with the corner of each of its hinges and steps, each
    step's width, and each wave's period and phase, fitted by output error:
    ``refit(effect, p0)`` fits an effect's coefficients and the base from ``p0`` and returns
    (J, its parameters); ``start``: the base with ``effect``'s coefficients; ``fine``: the basis
    functions of the naming's grid (its corner resolution); ``n_eff``: the effective number of
    residuals of the refit's J. A group's fitted numbers replace the named ones only when they
    lower the BIC, each counted as a parameter: on a strong planted propeller in oblique inflow,
    a step at n_p = 0 moved to -1.9 rev/s and half as wide lowered the training J by 0.2 % and
    raised the test J2 from 1.36 x to 1.95 x the true model's. None when no group has a corner
    or a period."""
    groups = list(groups_of(effect))
    if not any(_cornered(g) for g in groups):
        return None
    t0 = time.perf_counter()
    done: dict[str, tuple[float, Parameters]] = {}

    def evaluate(gs: Sequence[Group], p0: Parameters) -> tuple[float, Parameters]:
        """(J, parameters) of the shapes ``gs`` fitted from ``p0``, whose last shape effect
        (the trial it came from; the base's own effects come first) gives the coefficients."""
        trial = shape_effect(gs)
        if trial.name not in done:
            shapes = [vals for name, vals in p0.effects if name.startswith(SHAPE_PREFIX)]
            values = [v for _, v in shapes[-1]] if shapes else []
            if len(values) != len(trial.params):
                raise ValueError(f"{trial.name}: {len(values)} coefficients to start from")
            done[trial.name] = refit(trial, with_effects(p0, (trial,), values))
        return done[trial.name]

    J_named, at = evaluate(groups, start)
    count = 0
    for i, g in enumerate(groups):
        if _cornered(g):
            groups[i], at, k = _fit_group(evaluate, groups, i, at, fine, n_eff)
            count += k
    best = shape_effect(groups)
    J_fitted, at = evaluate(groups, at)
    seconds = time.perf_counter() - t0
    if log is not None and count:
        log(
            f"closed form's numbers fitted by output error: {effect.name} -> {best.name}, "
            f"training J {J_named:.4g} -> {J_fitted:.4g} ({len(done)} trials, {seconds:.0f} s)"
        )
    elif log is not None:
        lowest = min(J for J, _ in done.values())
        log(
            f"closed form's numbers kept as named: {effect.name} (training J {J_named:.4g}; the "
            f"best of {len(done)} trials, {lowest:.4g}, does not pay for its numbers in BIC; "
            f"{seconds:.0f} s)"
        )
    trials = [(name, J) for name, (J, _) in done.items()]
    return Fitted(best, effect_values(at, (best,)), J_named, J_fitted, count, trials, seconds)


__all__ = ["CORNERED", "Fitted", "corner_range", "fit_numbers", "grid_step"]
