"""The final models: the base re-identified on all training windows ("before"), the base with
the chosen effect re-identified alike ("after"), and the confirmation that the effect still
passes the threshold there (an effect that refits to nothing only re-balanced the base).

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from mmg import Effect
from sweep.diagnose.candidates import Candidates
from sweep.diagnose.context import Context
from sweep.diagnose.discover import resemblance
from sweep.diagnose.fit import Fit, FitSettings
from sweep.diagnose.scoring import delta_bic
from sweep.diagnose.store import stage_label
from sweep.diagnose.verdict import Verdict, verdict_name
from sweep.identification.vector import effect_values, with_effects


@dataclass(frozen=True)
class Final:
    """The re-identified models, the verdict after the confirmation, the confirmation record
    (None without a chosen effect) and, for a discovered effect, the correlation of its force
    pattern with each catalog effect's."""

    before: Fit
    after: Fit
    verdict: Verdict
    confirmation: dict[str, Any] | None
    resemblance: dict[str, float]


def final_settings(ctx: Context) -> FitSettings:
    """The re-identification: ``final_budget`` CMA-ES evaluations, then the refinement with
    the far weaker prior ``final_prior_weight``."""
    s = ctx.settings
    return replace(
        ctx.common,
        budget=s.final_budget,
        seed=s.seed + 2,
        sigma0=s.refit_sigma,
        polish=ctx.lm(s.final_polish_iterations, 1e-4, s.final_prior_weight),
    )


def finding_settings(ctx: Context) -> FitSettings:
    """The re-identification of the base with a finding: :func:`final_settings` without the
    effect-only search (the finding starts from its fold fit or its values)."""
    return replace(final_settings(ctx), effect_only_share=0.0, effect_only_budget=0)


def final_prefix(ctx: Context) -> str:
    """The final stages' names carry their prior's weight (the settings' fingerprint does not)."""
    return f"final-w{ctx.settings.final_prior_weight:g}"


def reidentify_base(ctx: Context, base: Fit) -> Fit:
    """Stage ``final-wW-base``: the base alone re-identified on all windows from ``base``."""
    settings = final_settings(ctx)
    return ctx.staged(
        f"{final_prefix(ctx)}-base",
        (),
        lambda: ctx.refit(ctx.windows, base.params, (), settings, "final base"),
    )


def reidentify_with(
    ctx: Context,
    base: Fit,
    before: Fit,
    effect: Effect,
    start: Fit,
    verdict: str,
    origin: str = "c",
) -> Fit:
    """Stage ``final-wW-3O-EFFECT`` (``O``: where the fold fit ``start`` began, ``origin``, ``c``
    the control's fit or ``b`` the base): the base with ``effect`` re-identified on all windows from
    three starts, the better end wins: the candidate's joint fold fit ``start`` (base
    re-balanced with the effect, on half the windows), the base fitted on all windows plus the
    effect's values from ``start`` (it had absorbed part of the effect), and ``before`` with the
    effect at neutral (so that the model with the effect never ends above the base)."""
    chosen = (effect,)
    settings = finding_settings(ctx)

    def three_starts() -> Fit:
        starts = (
            start.params,
            with_effects(base.params, chosen, effect_values(start.params, chosen)),
            with_effects(before.params, chosen),
        )
        ends = [ctx.refit(ctx.windows, p0, chosen, settings, f"final {verdict}") for p0 in starts]
        return min(ends, key=lambda e: e.f)

    name = stage_label(f"{final_prefix(ctx)}-3{origin}-{effect.name}", chosen)
    return ctx.staged(name, chosen, three_starts)


def reidentify(
    ctx: Context,
    base: Fit,
    cands: Candidates,
    verdict: Verdict,
    threshold: float,
    significant: bool,
) -> Final:
    """Re-identify before and after; the chosen effect must pass ``threshold`` again on all
    windows against the base re-identified alike, else the verdict falls back as without it."""
    before = reidentify_base(ctx, base)
    if not verdict.effect:
        return Final(before, before, verdict, None, {})
    effect = next(e for e in cands.effects if e.name == verdict.effect)
    start = cands.best_fold[verdict.effect]
    origin = cands.origin.get(verdict.effect, "c")
    after = reidentify_with(ctx, base, before, effect, start, verdict.verdict, origin)
    confirm = delta_bic(after.f, before.f, ctx.parameter_count(effect), ctx.n_eff)
    confirmation = {"effect": verdict.effect, "delta_bic": confirm}
    if confirm > threshold:
        ctx.log(
            f"re-identification on all windows: {verdict.effect} changes the training J from "
            f"{before.f:.4g} to {after.f:.4g} (dBIC {confirm:.1f} > {threshold:.1f}): "
            + ("kept, taken with --take" if verdict.taken else "not confirmed")
        )
        if not verdict.taken:
            fallback = replace(verdict, verdict=verdict_name("", significant), effect="")
            return Final(before, before, fallback, confirmation, {})
    like: dict[str, float] = {}
    if verdict.verdict == "discovered":  # which catalog effect's force pattern it is most like
        like = resemblance(base.params, ctx.windows, effect, verdict.scores, cands.effects)
    return Final(before, after, verdict, confirmation, like)
