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
run, or by a held-out gain one run's loss keeps below the null's) is checked a second way: its
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

A finding tied to position or time gets no transfer check: both halves share how the ship's
position grows with time along a day's runs, so a shape in x0 stands in for a force that builds
up in time on both alike (planted build-up, without the library's time terms: the x0 shape
passed the transfer check and the other sessions' check, and left one test run 43 % worse). It
must still pass the held-out check itself. A finding tied to the heading gets the check, and
still must carry over to another session's runs (:mod:`sweep.diagnose.sessions`).

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sweep.diagnose.candidates import Candidates, candidate_settings, run_changes
from sweep.diagnose.context import Context
from sweep.diagnose.fit import Fit
from sweep.diagnose.floor import run_of
from sweep.diagnose.scoring import CandidateScore, generated, heldout_per_window
from sweep.diagnose.sessions import place_or_time
from sweep.diagnose.store import stage_label
from sweep.diagnose.threshold import AcceptanceNull, more_better
from sweep.diagnose.verdict import carries_to_other_sessions

#: the stages of the reference: the control's fit of each half continued
REFERENCE = "control-transfer"
#: the stages of a candidate: ``transfer-NAME-foldJ``, its effect from the other fold held
TRANSFER = "transfer-"


def needs_transfer(ctx: Context, null: AcceptanceNull, threshold: float, c: CandidateScore) -> bool:
    """Whether a generated candidate not tied to position or time, which makes more held-out
    runs better than worse and passes every other condition of acceptance (refined, when the
    refinement runs), is refused by its held-out runs: by its worst one, or by a held-out gain
    that a single run's loss can keep below the null's. Only then can the transfer check
    accept it."""
    s = ctx.settings
    return (
        generated(c.effect)
        and not place_or_time(c.effect, ("position", "time"))
        and c.refined == s.refines
        and c.delta_bic <= threshold
        and c.improvement >= s.min_improvement
        and more_better(c.run_changes)
        and carries_to_other_sessions(null, c)
        and not null.carries_over(c.heldout_gain, c.run_losses, c.run_changes, generated=True)
    )


def check_transfer(ctx: Context, cands: Candidates, null: AcceptanceNull, threshold: float) -> None:
    """The transfer check of every leading candidate that needs it (:func:`needs_transfer`),
    recorded in its score; logged."""
    leaders = set(cands.leaders)
    todo = [
        c for c in cands.scores if c.effect in leaders and needs_transfer(ctx, null, threshold, c)
    ]
    if not todo:
        return
    # Levenberg-Marquardt alone, as the candidates' first fits
    settings = replace(candidate_settings(ctx), budget=0, effect_only_budget=0)
    halves = (ctx.fit_w, ctx.held_w)
    reference: list[float] = []
    for j, half in enumerate(halves):
        # the control's fit of this half, continued (fold j of the control fits this half)
        start = cands.control.fits[j].params
        ref = ctx.staged(
            f"{REFERENCE}-fold{j}",
            (),
            lambda h=half, p=start: ctx.refit(h, p, (), settings, REFERENCE),  # type: ignore[misc]
        )
        reference += heldout_per_window(half, ref.params, ctx.settings.objective)
    J_ref = np.asarray(reference)
    runs = tuple(run_of(w) for half in halves for w in half)
    held = replace(settings, fixed_effects=True)
    by_name = {e.name: e for e in cands.effects}
    for c in todo:
        eff = by_name[c.effect]
        folds = cands.folds[c.effect]
        J: list[float] = []
        for j, half in enumerate(halves):
            # the effect as fitted on the other half (its first fold fit: the refinement keeps
            # only the scores), on the control's (refined) fit of this half
            start = replace(cands.control.fits[j].params, effects=folds.fits[1 - j].params.effects)
            fit: Fit = ctx.staged(
                f"{TRANSFER}{stage_label(c.effect, (eff,))}-fold{j}",
                (eff,),
                lambda h=half, p=start, e=eff: ctx.refit(h, p, (e,), held, e.name),  # type: ignore[misc]
            )
            J += heldout_per_window(half, fit.params, ctx.settings.objective)
        J_t = np.asarray(J)
        c.transfer_gain = float(J_ref.sum() - J_t.sum())
        c.transfer_change = float(J_t.sum() / max(J_ref.sum(), 1e-300) - 1.0)
        c.transfer_run_changes = run_changes(J_t, J_ref, runs)
        c.transfer_checked = True
        worst = max(c.transfer_run_changes.values(), default=0.0)
        better = sum(v < 0 for v in c.transfer_run_changes.values())
        ctx.log(
            f"transfer: {c.effect} held as fitted on one half of the runs, the base refitted on "
            f"the other: their J {100 * c.transfer_change:+.1f} % against the control refitted "
            f"alike ({better} of {len(c.transfer_run_changes)} runs better, worst run "
            f"{100 * worst:+.1f} %)"
        )
