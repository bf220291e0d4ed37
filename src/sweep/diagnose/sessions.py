"""Findings tied to where and when a run was recorded, or to how its controls moved, must carry
over to another session.

A generated candidate whose force depends on the heading, the position or the time (library
terms of those kinds, learned shapes in psi, x0, y0 or t) can stand in for whatever the runs of
one day share: the day's wind, the region of the basin the ship sailed in. Held-out runs of the
same day then confirm it, and another day's recordings do not: on the planted set a moment in
x0 fitted in place of a wind force passed every check on the held-out training runs and made the
test recordings 2.7 x worse; on the real Train-R (one day) a moment in x0 raised the test J2 by
29 %. A bank or a force fixed to the basin acts on every day's runs alike.

A memory of a control (a learned shape of a control's gap, ``D~ed`` or ``P~en``, or its closed
form: a lag, a rate limit, play) acts on how the controls move, and each session's programme
moves them its own way (one day's random runs in many small steps, another day's zigzags in
large reversals, berthing with the propeller reversed). Fitted to one programme's steps it can
stand in for whatever those runs share: on the real Train-R (four random runs of one day) play
of 3.1 deg in the steering gear made every held-out run better and the test recordings (other
days, other manoeuvres) 14 % worse, berthing 2.3 x; on a planted moment of the wind at a medium
magnitude play made the test recordings 35 % worse. A steering gear's play acts on every day's
runs alike.

So each leading candidate of either kind is fitted once more on the runs of some sessions and
judged on the others' (both ways round; the sessions are the dates in the recordings' names,
:func:`sweep.diagnose.windows.session_of`), against the control fitted alike, and must carry
over there by the same rule as on the held-out runs
(:meth:`sweep.diagnose.threshold.AcceptanceNull.carries_over`). When all training runs are of
one session the check cannot be made and such a candidate is not accepted.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from dataclasses import replace

from mmg.effect import DISCOVERED_PREFIX, Effect
from mmg.library import term
from mmg.shapes import SHAPE_PREFIX, parse
from mmg.shapes import VARIABLES as SHAPE_VARIABLES
from sweep.diagnose.candidates import (
    CANDIDATE,
    Candidates,
    FoldFits,
    fold_fits,
    refine_settings,
    run_changes,
    run_losses,
)
from sweep.diagnose.context import Context
from sweep.diagnose.discover import EXOGENOUS_KINDS
from sweep.diagnose.fit import Fit
from sweep.diagnose.scoring import CandidateScore
from sweep.diagnose.shapes import PLACE_AND_TIME_KINDS
from sweep.identification.vector import effect_values, with_effects


def place_or_time(effect: str, kinds: tuple[str, ...] = EXOGENOUS_KINDS) -> bool:
    """Whether a generated effect's force depends on the heading, the position or the time
    (``kinds``: the library's term kinds to look for, a subset of those three; a shape's
    variables are matched to them: psi to heading, x0 and y0 to position, t to time)."""
    if effect.startswith(SHAPE_PREFIX):
        names = {v for k in kinds for v in PLACE_AND_TIME_KINDS[k]}
        return any(g.variable in names or g.multiplier in names for g in parse(effect))
    if effect.startswith(DISCOVERED_PREFIX):
        ids = effect.split(":", 1)[1].split("@", 1)[0].split("+")
        return any(term(i).kind in kinds for i in ids)
    return False


def memory_of_controls(effect: str) -> bool:
    """Whether a learned shape holds a memory of a control (a group of a control's gap)."""
    if not effect.startswith(SHAPE_PREFIX):
        return False
    return any(SHAPE_VARIABLES[g.variable].control for g in parse(effect) if g.variable != "1")


def session_bound(effect: str) -> bool:
    """Whether a generated effect must carry over to another session's runs: its force depends
    on the heading, the position or the time, or it is a memory of a control."""
    return place_or_time(effect) or memory_of_controls(effect)


def tie_text(effect: str) -> str:
    """Why ``effect`` is checked on other sessions, in words."""
    if memory_of_controls(effect):
        return "a memory of the controls, fitted to how one session's runs moved them"
    return "tied to heading, position or time"


def check_sessions(ctx: Context, base: Fit, cands: Candidates) -> None:
    """Fit every leading candidate tied to heading, position or time, and every memory of a
    control, on whole sessions and judge it on the others (stages ``control-sessions-foldJ``
    and ``candidate-c-NAME-sessions-foldJ``), recording the result in its score; logged."""
    tied = [c for c in cands.scores if c.effect in cands.leaders and session_bound(c.effect)]
    if not tied:
        return
    if ctx.session_w is None:
        for c in tied:
            c.sessions = "one session"
        ctx.log(
            "sessions: all training runs are of one session, so "
            + ", ".join(f"{c.effect} ({tie_text(c.effect)})" for c in tied)
            + " cannot be checked on another session's runs"
        )
        return
    by_name = {e.name: e for e in cands.effects}
    for c in tied:
        control, folds = session_fits(ctx, base, cands, by_name[c.effect])
        _record(c, folds, control)
        ctx.log(
            f"sessions: {c.effect} fitted on some sessions' runs and judged on the others': "
            f"gain {c.session_gain:.3g}, "
            f"{sum(v < 0 for v in c.session_run_changes.values())} of "
            f"{len(c.session_run_changes)} runs better, worst run "
            f"{max(c.session_run_changes.values(), default=0.0):+.1%}"
        )


def session_fits(
    ctx: Context, base: Fit, cands: Candidates, eff: Effect
) -> tuple[FoldFits, FoldFits]:
    """(the control, the candidate ``eff``) fitted on the runs of some sessions and judged on
    the others' (stages ``control-sessions-foldJ``, ``candidate-c-NAME-sessions-foldJ``; fold
    J fits half J of ``ctx.session_w``), the candidate from the control's fits with its values
    of its best fold fit. Needs runs of several sessions."""
    assert ctx.session_w is not None
    settings = refine_settings(ctx)
    split = ctx.session_w
    control = fold_fits(ctx, base, "control-sessions", (), settings, split=split)
    values = effect_values(cands.best_fold[eff.name].params, (eff,))
    starts = [
        replace(f, params=with_effects(f.params, (eff,), values), effects=(eff,))
        for f in control.fits
    ]
    name = f"{CANDIDATE}{eff.name}-sessions"
    return control, fold_fits(ctx, base, name, (eff,), settings, starts, split=split)


def _record(c: CandidateScore, folds: FoldFits, control: FoldFits) -> None:
    c.sessions = "checked"
    c.session_gain = float(control.J_heldout.sum() - folds.J_heldout.sum())
    c.session_run_losses = run_losses(folds.J_heldout, control.J_heldout, control.runs)
    c.session_run_changes = run_changes(folds.J_heldout, control.J_heldout, control.runs)
