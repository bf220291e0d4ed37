"""The backward check of a learned shape of several groups, by output error.

The shape selection (:mod:`sweep.diagnose.shapes`) adds groups one at a time on the linearised
trajectory columns, each raising the linearised held-out gain by :data:`MIN_GAIN` of what the
groups before it reached. A group can pass that test and still not help once the shape is fitted
by output error with the 57 parameters: a memory of the controls, whose columns are secants
that hold a persisting memory only in part, leaves a share of its gain to whatever group
enters beside it. On the planted rate-limited steering gear a share of the rudder's force in
delta entered beside the learned memory of the rudder angle (+15 % linearised) and made the
test recordings' J2 1.63 x the true model's, where the memory alone had reached 1.41 x.

So a shape of two or more groups is checked group by group the way the candidates are judged:
the shape and each shape with one group left out (its coefficients refitted linearised,
:meth:`~sweep.diagnose.shapes.ShapeColumns.restricted`) are fitted with the 57 parameters on
one half of the training runs and judged on the other, both ways round (the candidates' fold
fits, :func:`~sweep.diagnose.candidates.candidate_folds`; stages ``candidate-c-NAME-foldJ``
and ``candidate-NAME-foldJ``, which the candidates stage then resumes). A group stays only
when the shape with it makes the typical held-out window at least :data:`MIN_GAIN` better
(:func:`lead_score`, as for the lead below) than the best shape without it; otherwise that
group is dropped and the check repeats on the rest.

The first group is checked by output error too (:func:`lead_by_output_error`). Far from a good
fit the linearised columns saturate: on a planted thrust deduction growing with the drift angle
(the base's training J 110, 43 x the noise floor) eight single groups each took 93-97 % of the
held-out J off, linearised, and the selection led with a surge force in the apparent wind's
speed, which made the typical held-out window 22 % better by output error. So the single
groups within :data:`SCREEN_SHARE` of the best linearised one (at most :data:`SCREEN_MOST`)
are fitted alone with the 57 parameters, as above, and compared by their typical held-out
window (the geometric mean of the held-out runs' J ratios to the control's,
:func:`lead_score`): when another's is at least :data:`MIN_GAIN` better than the selection's
first group's, the selection is made again with it first. There a share of the thrust ahead
in beta made ten of the twelve held-out runs 19-2,800 times better (+99 % typical) and two
worse, runs that left the drift angles its half of the runs had taught it. The summed held-out
J, which the runs the base fits worst decide, preferred a share of the hull's sway force
(every run 2-30 times better, +79 % typical): led by it, the shape made the test recordings
no better.

A shape the output error has fitted this way, a single group of the lead check or the shape
the backward check keeps, has two splines: the linearised one, fitted on all windows, and that
of its fit by output error on one half of the runs (:func:`fitted_coefficients`), which a base
far from the data does not bend. Each names the shape; where the names differ, both are
candidates and the fit by output error decides (:mod:`sweep.diagnose.shaping`).

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg.precompile import precompile, tasks
from sweep.diagnose.candidates import candidate_folds, candidate_settings, fold_fits, score
from sweep.diagnose.context import Context
from sweep.diagnose.fit import Fit
from sweep.diagnose.scoring import CandidateScore
from sweep.diagnose.shapes import MIN_GAIN, ShapeColumns, ShapeSelection

FloatArray = NDArray[np.float64]


#: single groups whose linearised held-out gain is at least this share of the best one's are
#: checked by output error for the lead (:func:`lead_by_output_error`): the linearised gains
#: of groups within it cannot be told apart
SCREEN_SHARE = 0.9
#: the most single groups checked for the lead
SCREEN_MOST = 12


@dataclass(frozen=True)
class Screened:
    """A single group checked for the lead: its linearised held-out gain (a share of the control
    fits' held-out J), its held-out gain by output error [J] and its typical held-out window's
    change (:attr:`~sweep.diagnose.scoring.CandidateScore.improvement`; positive: better)."""

    group: str
    linearised: float
    heldout_gain: float
    typical: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "group": self.group,
            "linearised_heldout_share": self.linearised,
            "heldout_gain": self.heldout_gain,
            "heldout_typical": self.typical,
        }


@dataclass(frozen=True)
class Dropped:
    """One step of the backward check: the shape before it, the group left out, and the
    held-out gains [J] (the control's held-out J minus the candidate's) and typical held-out
    windows' changes (positive: better) of both shapes."""

    shape: str
    group: str
    gain_with: float
    gain_without: float
    typical_with: float
    typical_without: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "shape": self.shape,
            "group": self.group,
            "heldout_gain_with": self.gain_with,
            "heldout_gain_without": self.gain_without,
            "heldout_typical_with": self.typical_with,
            "heldout_typical_without": self.typical_without,
        }


def register(ctx: Context, selection: ShapeSelection) -> None:
    """The penalty, effective degrees of freedom and linearised start of a shape, by its
    effect's name, for the fits and the dBIC (:class:`~sweep.diagnose.context.Context`)."""
    eff = selection.effect()
    ctx.penalties[eff.name] = tuple(tuple(float(v) for v in row) for row in selection.penalty())
    ctx.dof[eff.name] = float(sum(selection.edf))
    lo, hi = eff.bounds  # a memory's share within [0, 1]
    ctx.starts[eff.name] = [float(v) for v in np.clip(selection.values(), lo, hi)]


def group_to_drop(full: float, without: list[float]) -> int | None:
    """The index of the group to leave out of a shape whose score is ``full`` (:func:`lead_score`
    of its typical held-out window), by the scores ``without`` of the shape without each of its
    groups: the one whose absence costs least, when the shape with it scores less than
    :data:`MIN_GAIN` more than without it (None: every group stays). A score that is not finite
    (a fit that failed) counts as the worst."""
    if not without:
        return None
    w = _failed_as_worst(without)
    i = int(np.argmax(w))
    f = _failed_as_worst([full])[0]
    return None if f > (1.0 + MIN_GAIN) * w[i] else i


def _failed_as_worst(scores: Sequence[float]) -> FloatArray:
    """``scores`` with any that is not finite (a fit that failed) set to -inf."""
    a = np.asarray(scores, dtype=float)
    return np.where(np.isfinite(a), a, -np.inf)


class _Gains:
    """Shapes (selections) scored by output error, each fitted once: the candidates' fold fits
    (:func:`~sweep.diagnose.candidates.candidate_folds`) against the control's; ``scores`` by
    the shapes' names."""

    def __init__(self, ctx: Context, base: Fit) -> None:
        self.ctx, self.base = ctx, base
        self.settings = candidate_settings(ctx)
        self.control = fold_fits(ctx, base, "control", (), self.settings)
        self.scores: dict[str, CandidateScore] = {}

    def scored(self, sels: list[ShapeSelection]) -> list[CandidateScore]:
        """The scores of the shapes ``sels`` by output error, each fitted once."""
        ctx = self.ctx
        todo = [s for s in sels if s.spec not in self.scores]
        for s in todo:
            register(ctx, s)
        effs = [s.effect() for s in todo]
        if effs:
            precompile(tasks(ctx.with_base((e,)) for e in effs), log=ctx.log)
        for s, eff in zip(todo, effs, strict=True):
            folds = candidate_folds(ctx, self.base, self.control, eff, self.settings)
            self.scores[s.spec], _ = score(
                eff, folds, self.control, ctx.n_eff, ctx.parameter_count(eff)
            )
        return [self.scores[s.spec] for s in sels]


def lead_score(improvement: float) -> float:
    """A single group's score for the lead, -log of its typical held-out window's ratio to the
    control's (``improvement`` = 1 - that geometric mean,
    :func:`~sweep.diagnose.scoring.typical_change`): 0 when the typical window is no better,
    log 10 when ten times better; NaN for a fit that failed."""
    return float(-np.log(max(1.0 - improvement, 1e-300))) if np.isfinite(improvement) else np.nan


def lead_to_take(scores: Sequence[float], first: int) -> int | None:
    """The index of the single group to lead a shape, by the lead scores ``scores``
    (:func:`lead_score`) of the single groups checked, ``first`` the selection's own first
    group: the best, when its score is at least 1 + :data:`MIN_GAIN` times ``first``'s (any
    positive score where ``first``'s is not; None: the first stays). A score that is not finite
    (a fit that failed) never leads."""
    finite = _failed_as_worst(scores)
    best = int(np.argmax(finite))
    if not np.isfinite(finite[best]):
        return None
    if best == first or finite[best] <= (1.0 + MIN_GAIN) * max(finite[first], 0.0):
        return None
    return best


def lead_by_output_error(
    ctx: Context,
    base: Fit,
    columns: ShapeColumns,
    r: FloatArray,
    selection: ShapeSelection,
    threshold: float,
) -> tuple[ShapeSelection, list[Screened], dict[str, CandidateScore]]:
    """The check of the lead (module docstring) of ``selection``, chosen on the base's residual
    vector ``r`` (S, M) on ``columns``: the selection, made again when another single group
    leads by output error (and the selection made with it first passes the null's
    ``threshold`` on its linearised dBIC, as the first one did), the single groups checked
    (none when the first group stands out linearised) and their scores by output error by the
    shapes' names (for :func:`fitted_coefficients`); logged."""
    if not selection.groups:
        return selection, [], {}
    singles = columns.singles(r)
    top = [row for row in singles if row[0] >= SCREEN_SHARE * singles[0][0]][:SCREEN_MOST]
    first = selection.groups[0]
    if not any(g == first for _, g, _ in top):
        top.append(next(row for row in singles if row[1] == first))
    if len(top) < 2:
        return selection, [], {}
    gain_of = _Gains(ctx, base)
    sels = [columns.restricted(r, ctx.n_eff, [(g, k)]) for _, g, k in top]
    scores = gain_of.scored(sels)
    screened = [
        Screened(g.text, float(share), float(c.heldout_gain), float(c.improvement))
        for (share, g, _), c in zip(top, scores, strict=True)
    ]
    i_best = lead_to_take(
        [lead_score(x.typical) for x in screened],
        next(i for i, (_, g, _) in enumerate(top) if g == first),
    )
    ctx.log(
        "lead of the shape by output error (typical held-out window, held-out gain [J], "
        "linearised share): "
        + ", ".join(
            f"{x.group} {100 * x.typical:+.1f} % {x.heldout_gain:.4g} ({100 * x.linearised:.0f} %)"
            for x in screened
        )
    )
    if i_best is None:
        return selection, screened, gain_of.scores
    lead = top[i_best][1]
    again = columns.select(r, ctx.n_eff, first=lead)
    kept = not again.groups or again.dbic > threshold
    ctx.log(
        f"lead of the shape: {lead.text} makes the typical held-out window better by output "
        f"error than {first.text} -> selection {again.spec or 'none'}, linearised dBIC "
        f"{again.dbic:.1f}"
        + (f" above the null's threshold {threshold:.1f}: the first kept" if kept else "")
    )
    return (selection if kept else again), screened, gain_of.scores


def fitted_coefficients(
    selection: ShapeSelection, fitted: Mapping[str, CandidateScore]
) -> ShapeSelection:
    """``selection`` with the coefficients of its fit by output error where the lead check or
    the backward check fitted it (``fitted``: their scores by the shapes' names, each with the
    fold fit that carries the effect's values), else as it is: the spline the trajectories
    taught, which a base far from the data does not bend as it bends the linearised one (a
    share of the thrust ahead in beta: the form closest to the linearised spline was
    cos(beta)|cos(beta)|, to the fitted one cos 2 beta, the planted sin^2 beta)."""
    c = fitted.get(selection.spec) if selection.groups else None
    values = list(c.params.values()) if c is not None else []
    if len(values) != len(selection.values()):
        return selection
    per_group, k = [], 0
    for cs in selection.coefficients:
        per_group.append(values[k : k + len(cs)])
        k += len(cs)
    return replace(selection, coefficients=per_group)


def prune(
    ctx: Context, base: Fit, columns: ShapeColumns, r: FloatArray, selection: ShapeSelection
) -> tuple[ShapeSelection, list[Dropped], dict[str, CandidateScore]]:
    """The backward check (module docstring) of the groups ``selection`` chose on the base's
    residual vector ``r`` (S, M) on ``columns``: the selection without the groups dropped, the
    steps that dropped them, and the shapes' scores by output error by their names (for
    :func:`fitted_coefficients`); logged."""
    dropped: list[Dropped] = []
    if len(selection.groups) < 2:
        return selection, dropped, {}
    gain_of = _Gains(ctx, base)

    while len(selection.groups) >= 2:
        pairs = list(zip(selection.groups, selection.kappas, strict=True))
        subs = [
            columns.restricted(r, ctx.n_eff, pairs[:i] + pairs[i + 1 :]) for i in range(len(pairs))
        ]
        full, *without = gain_of.scored([selection, *subs])
        ctx.log(
            f"backward check of {selection.spec} by output error (typical held-out window, "
            f"held-out gain [J]): {100 * full.improvement:+.1f} %, {full.heldout_gain:.4g}; "
            + ", ".join(
                f"without {g.text} {100 * w.improvement:+.1f} %, {w.heldout_gain:.4g}"
                for g, w in zip(selection.groups, without, strict=True)
            )
        )
        i = group_to_drop(
            lead_score(full.improvement), [lead_score(w.improvement) for w in without]
        )
        if i is None:
            break
        w = without[i]
        dropped.append(
            Dropped(
                selection.spec,
                selection.groups[i].text,
                full.heldout_gain,
                w.heldout_gain,
                full.improvement,
                w.improvement,
            )
        )
        ctx.log(
            f"backward check: {selection.groups[i].text} adds less than {MIN_GAIN:.0%} to the "
            f"typical held-out window of the rest by output error -> dropped"
        )
        selection = subs[i]
    return selection, dropped, gain_of.scores


__all__ = [
    "SCREEN_MOST",
    "SCREEN_SHARE",
    "Dropped",
    "Screened",
    "group_to_drop",
    "lead_by_output_error",
    "lead_score",
    "lead_to_take",
    "prune",
    "register",
]
