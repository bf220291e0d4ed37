"""The final models on the test recordings: J1, J2, J3 before and after, and whether the model
carries over (:mod:`sweep.diagnose.generalise`): an effect the training manoeuvres do not excite
leaves the training windows at the floor but the test recordings beyond it.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from mmg import Parameters
from sweep.data.recordings import Recording
from sweep.diagnose.context import Context
from sweep.diagnose.final import Final
from sweep.diagnose.floor import NoiseModel
from sweep.diagnose.generalise import GeneralisationTest, generalisation_test
from sweep.diagnose.scoring import test_table
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


def test_tables(
    ctx: Context, final: Final
) -> tuple[dict[str, dict[str, float]], dict[str, dict[str, float]]]:
    """J1, J2, J3 of the models before and after on every test recording (logged)."""
    if not ctx.test:
        return {}, {}
    before = test_table(final.before.params, ctx.test, ctx.test_labels)
    after = test_table(final.after.params, ctx.test, ctx.test_labels)
    J = ctx.settings.objective
    ctx.log(f"test {J}: before {before[J]['Total']:.1f}, after {after[J]['Total']:.1f}")
    return before, after


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
    """The test tables and the generalisation tests of the final models."""
    test_before, test_after = test_tables(ctx, final)
    # (every window the test J sums over, the short last one of each recording too)
    draws = ctx.settings.generalisation_draws
    test_w = cut_windows(ctx.test, min_window=0.0) if ctx.test and draws > 0 else []
    if not test_w:
        return CarryOver(test_before, test_after, None, None, final)
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
    return CarryOver(test_before, test_after, gen, gen_after, final)
