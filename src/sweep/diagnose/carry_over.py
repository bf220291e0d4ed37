"""The final models on the test recordings: J1, J2, J3 before and after, and whether the model
carries over (:mod:`sweep.diagnose.generalise`): an effect the training manoeuvres do not excite
leaves the training windows at the floor but the test recordings beyond it.

A finding is known only over the states the training recordings reached: its ranges
(:mod:`sweep.data.ranges`) are stated, the finding acts only in their box (:mod:`mmg.domain`,
held at the boundary or switched off outside, as ``outside`` says), and the test recordings that
leave the ranges are named.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from mmg import Parameters, get_effect
from mmg.domain import within
from mmg.precompile import precompile, tasks
from sweep.data.ranges import Departure, Ranges, departures, ranges_of
from sweep.data.recordings import Recording
from sweep.diagnose.context import Context
from sweep.diagnose.final import Final
from sweep.diagnose.floor import NoiseModel
from sweep.diagnose.generalise import GeneralisationTest, generalisation_test
from sweep.diagnose.scoring import diverged_text, test_table, test_table_diverged
from sweep.diagnose.windows import cut_windows


@dataclass(frozen=True)
class CarryOver:
    """{J: {label: value, "Total": value}} before and after (empty without test recordings),
    the generalisation test of the model before and after (None when not run), and the final
    model after the test (its verdict ``unexplained`` when nothing was chosen on the training
    windows but the base does not carry over)."""

    test_before: dict[str, dict[str, float]]
    test_after: dict[str, dict[str, float]]
    generalisation: GeneralisationTest | None
    generalisation_after: GeneralisationTest | None
    final: Final
    #: the ranges of the training recordings (where the finding was fitted; None without one)
    ranges: Ranges | None = None
    #: the test recordings' departures from them
    departures: list[Departure] = field(default_factory=list)
    #: {J: {label: value}} of the finding without its box (extrapolated; empty when the
    #: finding has no force or there is no test)
    test_unbounded: dict[str, dict[str, float]] = field(default_factory=dict)
    #: {"before"/"after": {label: [diverged, all] subsequences}} of the test recordings whose
    #: simulation diverged (their J is the divergence penalty; empty: none diverged)
    test_diverged: dict[str, dict[str, list[int]]] = field(default_factory=dict)


def bounded(ctx: Context, final: Final) -> tuple[Final, Ranges | None]:
    """The final model with its finding restricted to the box of the training recordings'
    states (``settings.outside``: held at its boundary or switched off outside; a finding
    without a force or moment is unchanged), and the ranges of those recordings (also without
    a finding: where the model was fitted)."""
    name = final.verdict.effect
    ranges = ranges_of(ctx.windows, final.after.params.ship)
    if not name:
        return final, ranges
    effect = get_effect(name)
    if effect.force is None and effect.force_at is None:
        return final, ranges
    wrapped = within(effect, ranges.domain(ctx.settings.outside))
    p = final.after.params
    effects = tuple((wrapped.name if n == name else n, v) for n, v in p.effects)
    params = Parameters(p.theta, p.ship, effects)
    fit_effects = tuple(wrapped if e.name == name else e for e in final.after.effects)
    after = replace(final.after, params=params, effects=fit_effects)
    ctx.log(f"the finding acts in the box of the training states: {wrapped.name}")
    # the bounded model's kernels (the test tables, the generalisation test, the trust), side
    # by side rather than one after another at first use
    bounded_effects = tuple(get_effect(n) for n, _ in effects)
    precompile(tasks([bounded_effects], ("simulate", "moments", "derivatives")), log=ctx.log)
    return replace(final, after=after), ranges


def _test_departures(ctx: Context, ranges: Ranges | None) -> list[Departure]:
    if ranges is None or not ctx.test:
        return []
    labels = [
        r.name if lab == r.name else f"{lab}/{r.name}"
        for lab, r in zip(ctx.test_labels, ctx.test, strict=True)
    ]
    found = departures(ranges, ctx.test, labels)
    for d in found:
        ctx.log(f"beyond the fitted ranges: {d.text()}")
    return found


def test_tables(
    ctx: Context, final: Final
) -> tuple[
    dict[str, dict[str, float]], dict[str, dict[str, float]], dict[str, dict[str, list[int]]]
]:
    """J1, J2, J3 of the models before and after on every test recording (logged), and the
    test recordings on which either model's simulation diverged (:attr:`CarryOver.test_diverged`,
    logged)."""
    if not ctx.test:
        return {}, {}, {}
    before, div_before = test_table_diverged(final.before.params, ctx.test, ctx.test_labels)
    after, div_after = test_table_diverged(final.after.params, ctx.test, ctx.test_labels)
    J = ctx.settings.objective
    ctx.log(f"test {J}: before {before[J]['Total']:.1f}, after {after[J]['Total']:.1f}")
    diverged = {k: v for k, v in (("before", div_before), ("after", div_after)) if v}
    for which, runs in diverged.items():
        ctx.log(f"test recordings where the model {which} diverges: {diverged_text(runs)}")
    return before, after, diverged


def generalisation(
    ctx: Context, params: Parameters, test_w: Sequence[Recording], noise: NoiseModel
) -> GeneralisationTest:
    """The J of ``params`` on the test windows ``test_w`` against models exact in form
    identified on the training windows with noise of the estimated level."""
    s = ctx.settings
    return generalisation_test(
        params,
        ctx.windows,
        test_w,
        noise,
        np.random.default_rng(s.seed + 17),
        objective=s.objective,
        prior_weight=s.final_prior_weight,
        draws=s.generalisation_draws,
        alpha=s.generalisation_alpha,
        margin=s.generalisation_margin,
    )


def _log_generalisation(ctx: Context, label: str, g: GeneralisationTest) -> None:
    ctx.log(
        f"test recordings ({label}): {ctx.settings.objective} {g.J:.3g}, {g.ratio:.2f} x the "
        f"median of a model exact in form identified on these windows "
        f"({g.median:.3g}; {100 * (1 - g.alpha):.0f} % quantile {g.quantile:.3g}): "
        + ("significant" if g.significant else "within")
    )


def carry_over(ctx: Context, final: Final, noise: NoiseModel) -> CarryOver:
    """The finding bounded to its ranges, the test tables and the generalisation tests of the
    final models."""
    unbounded = final.after.params
    final, ranges = bounded(ctx, final)
    found = _test_departures(ctx, ranges)
    test_before, test_after, diverged = test_tables(ctx, final)
    test_unbounded: dict[str, dict[str, float]] = {}
    if ctx.test and unbounded is not final.after.params:
        test_unbounded = test_table(unbounded, ctx.test, ctx.test_labels)
    extra: dict[str, Any] = {
        "ranges": ranges,
        "departures": found,
        "test_unbounded": test_unbounded,
        "test_diverged": diverged,
    }
    # (every window the test J sums over, the short last one of each recording too)
    draws = ctx.settings.generalisation_draws
    test_w = cut_windows(ctx.test, min_window=0.0) if ctx.test and draws > 0 else []
    if not test_w:
        return CarryOver(test_before, test_after, None, None, final, **extra)
    gen = generalisation(ctx, final.before.params, test_w, noise)
    after = final.after.params
    gen_after = generalisation(ctx, after, test_w, noise) if final.verdict.effect else None
    _log_generalisation(ctx, "before", gen)
    if gen_after is not None:
        _log_generalisation(ctx, "after", gen_after)
    v = final.verdict
    if not v.effect and gen.significant and v.verdict == "none":
        final = replace(final, verdict=replace(v, verdict="unexplained"))
        ctx.log("verdict: unexplained (the model does not carry over to the test recordings)")
    return CarryOver(test_before, test_after, gen, gen_after, final, **extra)
