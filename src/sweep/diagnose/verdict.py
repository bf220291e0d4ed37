"""The verdict: which candidates pass the acceptance threshold and the held-out veto, how they
rank, and what the verdict is called.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from mmg.effect import DISCOVERED_PREFIX
from mmg.shapes import SHAPE_PREFIX, is_closed_form
from sweep.diagnose.context import Context
from sweep.diagnose.scoring import (
    KEEP,
    CandidateScore,
    form_share,
    judged_as_generated,
    rank,
    shape_and_form,
)
from sweep.diagnose.sessions import tie_text
from sweep.diagnose.settings import DiagnoseSettings
from sweep.diagnose.threshold import CEILING, NEGLIGIBLE, AcceptanceNull, more_better


@dataclass(frozen=True)
class Verdict:
    """The ranked candidates, the verdict and the chosen candidate's effect name (empty when
    none was chosen; the verdict is ``discovered`` for a generated effect)."""

    scores: list[CandidateScore]
    verdict: str
    effect: str
    #: the effect was taken with ``--take``, accepted or not (a what-if: no confirmation)
    taken: bool = False


def verdict_name(effect: str, significant: bool) -> str:
    """The verdict for the chosen ``effect`` ("" for none), given whether the misfit test found
    the base significantly above the noise floor: ``discovered`` for library terms, ``shape``
    for a learned shape."""
    if effect:
        if effect.startswith(SHAPE_PREFIX):
            return "shape"
        return "discovered" if effect.startswith(DISCOVERED_PREFIX) else effect
    return "unexplained" if significant else "none"


def acceptance_threshold(settings: DiagnoseSettings, null: AcceptanceNull) -> float:
    """The dBIC a candidate must reach: ``--max-delta-bic`` or the calibrated null's."""
    return null.threshold if settings.max_delta_bic is None else settings.max_delta_bic


def _log_threshold(ctx: Context, null: AcceptanceNull, threshold: float, significant: bool) -> None:
    s = ctx.settings
    catalog = (
        "of the control's J of that run for a catalog effect, of its noise J for library terms "
        "and learned shapes"
        if significant
        else "of its noise J for every candidate, the misfit being within the noise floor"
    )
    ctx.log(
        f"acceptance: dBIC <= {threshold:.1f} ("
        + (
            f"the {s.alpha:.0%} quantile of the best candidate's dBIC over {null.draws} "
            f"noise-only copies, {null.quantile:.1f}, capped at {CEILING:.0f}"
            if s.max_delta_bic is None
            else "set by --max-delta-bic"
        )
        + ")"
    )
    ctx.log(
        f"carrying over: a held-out gain above {null.heldout_threshold:.4g} (the "
        f"{1 - s.alpha:.0%} quantile of the best candidate's held-out gain over {null.draws} "
        f"noise-only copies, {100 * null.heldout_quantile:.1f} % of the noise's J "
        f"{null.noise_J:.3g}, at least 0), more held-out runs better than worse, and no held-out "
        f"run worse by more than {100 * null.worst_run_limit:.0f} % (the same quantile of the best "
        f"catalog candidate's worst held-out run) {catalog} (a run worse by at most "
        f"{100 * NEGLIGIBLE:.0f} % of its J is not counted)"
    )


def decide(
    ctx: Context,
    scores: Sequence[CandidateScore],
    leaders: Sequence[str],
    null: AcceptanceNull,
    significant: bool,
) -> Verdict:
    """Mark the accepted candidates (refined when the refinement ran, dBIC at most the
    threshold, a held-out gain above the null's, typical held-out window at least
    ``min_improvement``), rank the leaders (:func:`rank`) before the others (by dBIC), and name
    the verdict after the first accepted candidate in that order; logged.

    A catalog effect's worst held-out run is judged relative to the control's J of that run
    only when the misfit test finds the base beyond the noise floor (``significant``): that
    scale stands in for a missing force inflating every run's J far beyond its noise. Within the
    floor there is no such force, and every candidate's worst run is judged in units of its
    noise J, as a generated candidate's always is."""
    s = ctx.settings
    threshold = acceptance_threshold(s, null)
    _log_threshold(ctx, null, threshold, significant)
    refined = s.refines
    for c in scores:
        c.worst_run_excess = null.run_excess(c.run_losses, c.run_changes)
        c.sessions_carry = carries_to_other_sessions(null, c)
        c.carries_over = (
            null.carries_over(
                c.heldout_gain,
                c.run_losses,
                c.run_changes,
                judged_as_generated(c.effect, significant),
            )
            or transferred(null, c)
        ) and c.sessions_carry
        c.accepted = (
            c.refined == refined
            and c.improvement >= s.min_improvement
            and c.delta_bic <= threshold
            and c.carries_over
        )
    top = rank([c for c in scores if c.effect in leaders], s.tie_margin)
    ranked = top + sorted([c for c in scores if c.effect not in leaders], key=lambda c: c.delta_bic)
    # the first accepted in that order: a better fit that does not carry over to the held-out
    # runs does not hide one that does
    effect = next((c.effect for c in ranked if c.accepted), "")
    effect = _named(ctx, ranked, effect)
    verdict = verdict_name(effect, significant)
    ctx.log(
        "ranking: "
        + ", ".join(
            f"{c.effect} dBIC {c.delta_bic:.0f} ({100 * c.improvement:+.1f}% held out, gain "
            f"{c.heldout_gain:.3g}, {c.runs_better} of {len(c.run_changes)} runs better, "
            f"worst run {100 * c.worst_run_change:+.1f} %, largest loss of a run "
            f"{100 * c.worst_run_excess:+.0f} % of its noise J"
            f"{_carry_text(c)})"
            for c in ranked
        )
        + f" -> verdict: {verdict}"
    )
    if s.take:
        effect = _taken(ctx, ranked, s.take)
        return Verdict(ranked, verdict_name(effect, significant), effect, taken=True)
    return Verdict(ranked, verdict, effect)


def _taken(ctx: Context, ranked: Sequence[CandidateScore], take: str) -> str:
    """The candidate ``--take`` names among the ``ranked`` ones (``best``: the first, ``shape``:
    the first learned shape that is not a closed form); logged. Raises ValueError naming the
    candidates when there is none such."""
    if take == "best":
        found = ranked[:1]
    elif take == "shape":
        found = [
            c for c in ranked if c.effect.startswith(SHAPE_PREFIX) and not is_closed_form(c.effect)
        ][:1]
    else:
        found = [c for c in ranked if c.effect == take]
    if not found:
        names = ", ".join(c.effect for c in ranked) or "none"
        raise ValueError(
            f"--take {take!r}: no such candidate in this diagnosis; its candidates: {names} "
            "(or 'best', 'shape')"
        )
    c = found[0]
    state = "accepted" if c.accepted else "not accepted"
    ctx.log(f"--take: {c.effect} taken whatever the verdict ({state})")
    return c.effect


def transferred(null: AcceptanceNull, c: CandidateScore) -> bool:
    """Whether a candidate passes the transfer check (:mod:`sweep.diagnose.transfer`), and,
    when it was checked across sessions too, carries over there: the other sessions' summed J
    falls, more of their runs get better than worse and none worse than the limit of a catalog
    effect's held-out run. The size of the gain is judged within the sessions only: the null's
    held-out quantile is calibrated on the held-out split, not on the sessions'."""
    if not c.transfer_checked:
        return False
    if not null.transfers(c.transfer_gain, c.transfer_run_changes, c.heldout_gain):
        return False
    if not c.session_transfer_checked:
        return True
    changes = c.session_transfer_run_changes
    return (
        c.session_transfer_gain > 0.0
        and more_better(changes)
        and max(changes.values(), default=0.0) <= null.run_change_limit
    )


def carries_to_other_sessions(null: AcceptanceNull, c: CandidateScore) -> bool:
    """Whether a candidate tied to heading, position or time, or a memory of a control, carries
    over to another session's runs (:mod:`sweep.diagnose.sessions`; True for any other
    candidate)."""
    if c.sessions == "one session":
        return False
    if c.sessions == "checked":
        return null.carries_over(
            c.session_gain, c.session_run_losses, c.session_run_changes, generated=True
        )
    return True


def _carry_text(c: CandidateScore) -> str:
    if c.carries_over and c.transfer_checked:
        return ": carries over by the transfer check"
    if c.carries_over:
        return ""
    if c.session_transfer_checked and c.sessions_carry:
        return ": does not carry over (the transfer check across sessions)"
    if not c.sessions_carry:
        if c.sessions == "one session":
            return f": {tie_text(c.effect)}, and all training runs are of one session"
        return f": {tie_text(c.effect)}, does not carry over to another session's runs"
    return ": does not carry over"


def shape_name(
    scores: Sequence[CandidateScore], effect: str
) -> tuple[CandidateScore, float] | None:
    """The name of the learned shape ``effect`` (a spline, or the closed form it was named
    after): among the accepted closed forms, the one the shape was named after
    (:mod:`sweep.diagnose.naming`), a library term's (``discovered:``) or a catalog effect,
    the one of the largest held-out gain when it keeps at least :data:`KEEP` of the shape's
    (the spline's when it is accepted, else the chosen effect's own); with that share. None
    when none keeps enough, or when the chosen effect is already the best name."""
    chosen = next(c for c in scores if c.effect == effect)
    spline, form = shape_and_form(scores)
    gain = chosen.heldout_gain
    if spline is not None and spline.accepted:
        gain = max(gain, spline.heldout_gain)
    if gain <= 0.0:
        return None
    names = [
        c for c in scores if c.accepted and (c is form or not c.effect.startswith(SHAPE_PREFIX))
    ]
    best = max(names, key=lambda c: c.heldout_gain, default=None)
    if best is None or best.effect == effect or best.heldout_gain < KEEP * gain:
        return None
    return best, best.heldout_gain / gain


def _named(ctx: Context, scores: Sequence[CandidateScore], effect: str) -> str:
    """The chosen effect, or the name of a chosen learned shape (:func:`shape_name`): the
    closed form it was named after, a library term or a catalog effect, accepted and keeping
    :data:`KEEP` of the shape's held-out gain; logged."""
    if not effect.startswith(SHAPE_PREFIX):
        return effect
    form = shape_and_form(scores)[1]
    if form is not None and not is_closed_form(effect):
        kept = form_share(scores) or 0.0
        ctx.log(
            f"the closed form {form.effect} keeps {100 * kept:.0f} % of the learned shape's "
            f"held-out gain{'' if form.accepted else ' and is not accepted'}"
        )
    named = shape_name(scores, effect)
    if named is None:
        ctx.log(f"the finding is {'the closed form' if is_closed_form(effect) else 'the shape'}")
        return effect
    name, kept = named
    what = (
        "closed form"
        if name.effect.startswith(SHAPE_PREFIX)
        else ("library term" if name.effect.startswith(DISCOVERED_PREFIX) else "catalog effect")
    )
    ctx.log(
        f"the {what} {name.effect} keeps {100 * kept:.0f} % of the learned shape's held-out "
        f"gain, the most of the accepted closed forms: the finding is the {what}"
    )
    return name.effect
