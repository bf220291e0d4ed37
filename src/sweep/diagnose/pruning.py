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
when the shape with it takes at least :data:`MIN_GAIN` more off the held-out runs' J than the
best shape without it; otherwise that group is dropped and the check repeats on the rest.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg.precompile import precompile, tasks
from sweep.diagnose.candidates import candidate_folds, candidate_settings, fold_fits, score
from sweep.diagnose.context import Context
from sweep.diagnose.fit import Fit
from sweep.diagnose.shapes import MIN_GAIN, ShapeColumns, ShapeSelection

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Dropped:
    """One step of the backward check: the shape before it, the group left out, and the
    held-out gains [J] (the control's held-out J minus the candidate's) of both shapes."""

    shape: str
    group: str
    gain_with: float
    gain_without: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "shape": self.shape,
            "group": self.group,
            "heldout_gain_with": self.gain_with,
            "heldout_gain_without": self.gain_without,
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
    """The index of the group to leave out of a shape whose held-out gain [J] is ``full``, by
    the held-out gains ``without`` of the shape without each of its groups: the one whose
    absence costs least, when the shape with it takes less than :data:`MIN_GAIN` more off the
    held-out runs' J than without it (None: every group stays)."""
    if not without:
        return None
    i = int(np.argmax(without))
    return None if full > (1.0 + MIN_GAIN) * without[i] else i


def prune(
    ctx: Context, base: Fit, columns: ShapeColumns, r: FloatArray, selection: ShapeSelection
) -> tuple[ShapeSelection, list[Dropped]]:
    """The backward check (module docstring) of the groups ``selection`` chose on the base's
    residual vector ``r`` (S, M) on ``columns``: the selection without the groups dropped, and
    the steps that dropped them; logged."""
    dropped: list[Dropped] = []
    if len(selection.groups) < 2:
        return selection, dropped
    settings = candidate_settings(ctx)
    control = fold_fits(ctx, base, "control", (), settings)
    gains: dict[str, float] = {}

    def gain_of(sels: list[ShapeSelection]) -> list[float]:
        todo = [s for s in sels if s.spec not in gains]
        for s in todo:
            register(ctx, s)
        effs = [s.effect() for s in todo]
        if effs:
            precompile(tasks(ctx.with_base((e,)) for e in effs), log=ctx.log)
        for s, eff in zip(todo, effs, strict=True):
            folds = candidate_folds(ctx, base, control, eff, settings)
            c, _ = score(eff, folds, control, ctx.n_eff, ctx.parameter_count(eff))
            gains[s.spec] = c.heldout_gain
        return [gains[s.spec] for s in sels]

    while len(selection.groups) >= 2:
        pairs = list(zip(selection.groups, selection.kappas, strict=True))
        subs = [
            columns.restricted(r, ctx.n_eff, pairs[:i] + pairs[i + 1 :]) for i in range(len(pairs))
        ]
        full, *without = gain_of([selection, *subs])
        ctx.log(
            f"backward check of {selection.spec} by output error: held-out gain {full:.4g}; "
            + ", ".join(
                f"without {g.text} {w:.4g}" for g, w in zip(selection.groups, without, strict=True)
            )
        )
        i = group_to_drop(full, without)
        if i is None:
            break
        dropped.append(Dropped(selection.spec, selection.groups[i].text, full, without[i]))
        ctx.log(
            f"backward check: {selection.groups[i].text} adds less than {MIN_GAIN:.0%} to the "
            f"held-out gain of the rest by output error -> dropped"
        )
        selection = subs[i]
    return selection, dropped


__all__ = ["Dropped", "group_to_drop", "prune", "register"]
