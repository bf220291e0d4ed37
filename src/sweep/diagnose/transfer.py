"""Does a generated finding carry over once the base is refitted? The transfer check.

The held-out check (:mod:`sweep.diagnose.candidates`) refits the 57 base parameters on half the
training runs, with and without the candidate, and compares the other half's J. Where the model
misses a force, the base fitted on half the runs wanders, and the held-out J of one run can grow
several-fold with or without a right finding: on the planted forms no library term expresses, a
learned rudder-angle shape for a dead band took 27.5 off the held-out J (9 of 12 runs better) but
one run rose 4.6-fold (101 x its noise J), and the shape was refused. Transferred, it made 11 of
12 runs better (J -34 %) and was accepted; the test recordings' J2 fell from 3.99 to 0.455, 1.47 x
the true model's.

So each leading generated candidate (library terms, learned shapes and their closed forms) that
makes more held-out runs better than worse but is refused by its held-out runs (by its worst
run, or by a held-out gain one run's loss keeps below the null's) is checked a second way (and
so is a catalog effect where the base's misfit is within the noise floor, since its worst run
is then judged as a generated candidate's): its
effect as fitted on one half of the runs is held fixed, and the base alone is refitted on the
*other* half, from the control's fit of that half (stage ``transfer-NAME-foldJ``); the reference
is the control's fit of that half continued by the same Levenberg-Marquardt without an effect
(stage ``control-transfer-foldJ``). Both sides then refit the same 57 parameters on the same
runs, and the effect's form is the only thing carried from the runs it was fitted on: a stand-in
fitted to what the runs of one half happen to have (a moment in the speed for a moment that
needs the wind, which differs from run to run) makes the other half worse. It carries over when
the summed J falls, more runs get better than worse, no run gets relatively worse than the null
allows a catalog effect's held-out run, and the gain on runs the effect was not fitted on beats
the held-out null in this check or the held-out one
(:meth:`sweep.diagnose.threshold.AcceptanceNull.transfers`).

When the runs are of several sessions, a candidate that passes is checked once more the same
way across sessions: held as fitted on some sessions' runs, the base refitted on the others'
(stages ``control-transfer-sessions-foldJ``, ``transfer-sessions-NAME-foldJ``), and must carry
over there too: the summed J falls, more runs get better than worse, none worse than the limit
(:func:`sweep.diagnose.verdict.transferred`; the size of the gain is judged within the
sessions, where the held-out null is calibrated). The two halves of the held-out split share
each day's wind and water; another day's runs do not. On the planted weather helm (a yaw
moment that needs the wind) a learned memory of the rudder with a moment in U times v_m passed
the transfer check within the sessions (9 of 12 runs better) and made the test recordings' J2
1.9 x worse; across sessions it made 1 of 12 runs better and was refused, while the dead
band's shape made 12 of 12 better there too.

A finding tied to position or time gets no transfer check: both halves share how the ship's
position grows with time along a day's runs, so a shape in x0 stands in for a force that builds
up in time on both alike (planted build-up, without the library's time terms: the x0 shape
passed the transfer check and the other sessions' check, and left one test run 43 % worse). It
must still pass the held-out check itself. A finding tied to the heading gets the check, and
still must carry over to another session's runs (:mod:`sweep.diagnose.sessions`).

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from mmg import Effect
from sweep.data.recordings import Recording
from sweep.diagnose.candidates import Candidates, candidate_settings, run_changes
from sweep.diagnose.context import Context
from sweep.diagnose.fit import Fit, FitSettings
from sweep.diagnose.floor import run_of
from sweep.diagnose.scoring import CandidateScore, heldout_per_window, judged_as_generated
from sweep.diagnose.sessions import place_or_time, session_fits
from sweep.diagnose.store import stage_label
from sweep.diagnose.threshold import AcceptanceNull, more_better
from sweep.diagnose.verdict import carries_to_other_sessions

#: the stages of the reference: the control's fit of each half continued
REFERENCE = "control-transfer"
#: the stages of a candidate: ``transfer-NAME-foldJ``, its effect from the other fold held
TRANSFER = "transfer-"
#: ... of the check across sessions: ``transfer-sessions-NAME-foldJ``
SESSIONS = "sessions-"


def needs_transfer(
    ctx: Context,
    null: AcceptanceNull,
    threshold: float,
    c: CandidateScore,
    significant: bool,
) -> bool:
    """Whether a generated candidate not tied to position or time, which makes more held-out
    runs better than worse and passes every other condition of acceptance (refined, when the
    refinement runs), is refused by its held-out runs: by its worst one, or by a held-out gain
    that a single run's loss can keep below the null's. Only then can the transfer check
    accept it. Where the misfit is within the noise floor (not ``significant``) a catalog
    effect's worst run is judged as a generated candidate's (:func:`sweep.diagnose.verdict.decide`),
    and it gets the same second look."""
    s = ctx.settings
    return (
        judged_as_generated(c.effect, significant)
        and not place_or_time(c.effect, ("position", "time"))
        and c.refined == s.refines
        and c.delta_bic <= threshold
        and c.improvement >= s.min_improvement
        and more_better(c.run_changes)
        and carries_to_other_sessions(null, c)
        and not null.carries_over(c.heldout_gain, c.run_losses, c.run_changes, generated=True)
    )


def check_transfer(
    ctx: Context,
    base: Fit,
    cands: Candidates,
    null: AcceptanceNull,
    threshold: float,
    significant: bool,
) -> None:
    """The transfer check of every leading candidate that needs it (:func:`needs_transfer`;
    ``significant``: whether the base's misfit is beyond the noise floor), recorded in its
    score; when it passes and the runs are of several sessions, the same check across
    sessions; logged."""
    leaders = set(cands.leaders)
    todo = [
        c
        for c in cands.scores
        if c.effect in leaders and needs_transfer(ctx, null, threshold, c, significant)
    ]
    if not todo:
        return
    # Levenberg-Marquardt alone, as the candidates' first fits
    settings = replace(candidate_settings(ctx), budget=0, effect_only_budget=0)
    by_name = {e.name: e for e in cands.effects}
    for c in todo:
        eff = by_name[c.effect]
        halves = (ctx.fit_w, ctx.held_w)
        fits = cands.folds[c.effect].fits
        gain, change, changes = _transfer(ctx, halves, cands.control.fits, fits, eff, "", settings)
        c.transfer_gain, c.transfer_change, c.transfer_run_changes = gain, change, changes
        c.transfer_checked = True
        ctx.log(
            f"transfer: {c.effect} held as fitted on one half of the runs, the base refitted on "
            f"the other: {_summary(change, changes)}"
        )
        if ctx.session_w is None or not null.transfers(gain, changes, c.heldout_gain):
            continue
        control, folds = session_fits(ctx, base, cands, eff)
        gain, change, changes = _transfer(
            ctx, ctx.session_w, control.fits, folds.fits, eff, SESSIONS, settings
        )
        c.session_transfer_gain, c.session_transfer_change = gain, change
        c.session_transfer_run_changes = changes
        c.session_transfer_checked = True
        ctx.log(
            f"transfer across sessions: {c.effect} held as fitted on some sessions' runs, the "
            f"base refitted on the others': {_summary(change, changes)}"
        )


def _summary(change: float, changes: dict[str, float]) -> str:
    worst = max(changes.values(), default=0.0)
    better = sum(v < 0 for v in changes.values())
    return (
        f"their J {100 * change:+.1f} % against the control refitted alike ({better} of "
        f"{len(changes)} runs better, worst run {100 * worst:+.1f} %)"
    )


def _transfer(
    ctx: Context,
    halves: tuple[list[Recording], list[Recording]],
    control: Sequence[Fit],
    fits: Sequence[Fit],
    eff: Effect,
    prefix: str,
    settings: FitSettings,
) -> tuple[float, float, dict[str, float]]:
    """(gain [J], relative change, per run its relative change): on each half J the control's
    fit of it (``control[J]``) continued (stage ``control-transfer-PREFIXfoldJ``), against the
    base refitted alike with ``eff`` held as fitted on the other half (``fits[1 - J]``; stage
    ``transfer-PREFIXNAME-foldJ``)."""
    held = replace(settings, fixed_effects=True)
    reference: list[float] = []
    J: list[float] = []
    for j, half in enumerate(halves):
        start = control[j].params
        ref = ctx.staged(
            f"{REFERENCE}-{prefix}fold{j}",
            (),
            lambda h=half, p=start: ctx.refit(h, p, (), settings, REFERENCE),  # type: ignore[misc]
        )
        reference += heldout_per_window(half, ref.params, ctx.settings.objective)
        # the effect as fitted on the other half (its first fold fit: the refinement keeps only
        # the scores), on the control's fit of this half
        start = replace(control[j].params, effects=fits[1 - j].params.effects)
        fit: Fit = ctx.staged(
            f"{TRANSFER}{prefix}{stage_label(eff.name, (eff,))}-fold{j}",
            (eff,),
            lambda h=half, p=start, e=eff: ctx.refit(h, p, (e,), held, e.name),  # type: ignore[misc]
        )
        J += heldout_per_window(half, fit.params, ctx.settings.objective)
    J_ref, J_t = np.asarray(reference), np.asarray(J)
    runs = tuple(run_of(w) for half in halves for w in half)
    gain = float(J_ref.sum() - J_t.sum())
    change = float(J_t.sum() / max(J_ref.sum(), 1e-300) - 1.0)
    return gain, change, run_changes(J_t, J_ref, runs)
