"""Memories of the controls probed by their closed forms, beside the learned shapes.

A memory shape (``D~ed``, ``P~en``: :mod:`mmg.shapes`) is chosen, like every shape, on trajectory
columns linearised at the base model, where the control has no memory: the gap between the log
and the acting control is then one time step's change of the log, and each column moves the
acting control for one step. A lag shows there. Play and a rate limit do not, or barely: their
effect is that the gap *accumulates* over many steps (play holds the rudder until the log has
moved b beyond it; a rate limit lets a large step take several), a change of order zero in the
share f that no first-order column holds. On the planted steering gear with a play of 0.72 deg
(3.5-5 x the true model's test J2) the shapes' selection found no group of the ship's state and
controls, and the closed form ``D~ed:play`` fitted by output error took the training J from 1.25
to 0.562, the planted form's own.

So each closed form of a memory the catalog does not hold (:data:`FORMS`: a rate limit and play;
the catalog's ``actuator_lag`` is a first-order lag of both controls), of each control's gap and
of its gap signed away from its zero (there with the moves back as logged: a steering gear
slower away from midships than back; the candidate's fit then frees the moves back's
coefficient, :func:`mmg.shapes.memory_coefficients`), is probed at finite sizes,
as the catalog's candidates are by their grid directions (:mod:`sweep.diagnose.linearised`): the
base model simulated with the form at each size of a geometric grid (:data:`GRID_EXPONENTS`,
quanta of the control: play b = q 2^k, a rate limit's largest step per time step m = q 2^k), the
change of the residual vector taken as one direction, the base's 57 parameters refitted beside
it (linearised, with the prior), its scale free but positive (the form between none and more of
it). The best direction's in-sample dBIC (one coefficient) is compared with the same statistic
on noise-only copies of the training windows (the ``alpha`` quantile, capped at
:data:`sweep.diagnose.threshold.CEILING`); the best form then goes to the candidates, where it
is fitted by output error and judged on held-out runs like every other.

The probe looks for the cause of a misfit, and runs only where the misfit test finds one (the
base beyond the noise floor). Within the floor, a memory sized to the training's small misfit
stands in for whatever else is missing: on a planted yaw moment of the wind (misfit 1.27 x the
floor, z = 2.6) play made 8 of 12 held-out runs better (+2.6 % the typical window), passed the
transfer check (J -0.5 %, across sessions -0.9 %), and made the test recordings 35 % worse.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg import Effect, Parameters
from mmg.precompile import tasks
from mmg.shapes import CONTROLS, Group, memory_coefficients, memory_range, shape_effect
from mmg.shapes import VARIABLES as SHAPE_VARIABLES
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.diagnose.calibration import Calibration
from sweep.diagnose.context import Context
from sweep.diagnose.discover import null_sets
from sweep.diagnose.fit import Fit
from sweep.diagnose.proposals import ProbeProposal
from sweep.diagnose.shapes import variable_ranges
from sweep.diagnose.threshold import CEILING
from sweep.identification.polish import residual_vectors

FloatArray = NDArray[np.float64]

#: the closed forms probed (keys of :data:`mmg.shapes.MEMORY_FORMS`): a rate limit and play; a
#: first-order lag of both controls is the catalog's ``actuator_lag``
FORMS = ("rate", "play")
#: the sizes probed, as powers of two of the control's quantum (1 deg of rudder, 0.5 rev/s of
#: propeller: :data:`mmg.shapes.CONTROLS`): play of 1/16 to 16 quanta, a rate limit of 1/16 to
#: 16 quanta per time step
GRID_EXPONENTS = tuple(range(-4, 5))
#: the gap variables of the controls (keys of :data:`mmg.shapes.VARIABLES`)
GAPS = tuple(v for v, var in SHAPE_VARIABLES.items() if var.control)


def memory_groups(windows: Sequence[Recording], params: Parameters) -> list[Group]:
    """A group of every probed closed form (:data:`FORMS`) of every control that moves on
    ``windows``, over the range of its gap there (the range the learned memory shapes take)."""
    ranges = variable_ranges(windows, params, GAPS)
    return [
        Group(SHAPE_VARIABLES[v].control, v, lo, hi, memory_coefficients(v), form=form)
        for v, (lo, hi) in ranges.items()
        for form in FORMS
    ]


def by_form(groups: Sequence[Group]) -> list[tuple[Effect, list[Group]]]:
    """The effects that probe ``groups``, each with its groups in the order of its parameters:
    one effect per form and kind of gap (the plain gap, the gap signed away from the control's
    zero), with that form's group of each control. One group per control: a form at 0 leaves
    its control as logged only for gaps within its range, and a memory probed beside it lets
    the gap grow beyond (a rate limit's accumulated lag), where the form at 0 would act too."""
    forms: dict[tuple[str, bool], list[Group]] = {}
    for g in groups:
        forms.setdefault((g.form, SHAPE_VARIABLES[g.variable].away), []).append(g)
    return [(shape_effect(gs), gs) for gs in forms.values()]


def grid_values(group: Group) -> list[float]:
    """The coefficients c in (0, 1) of ``group``'s closed form at the probed sizes: play
    b = c e_max, a rate limit's step m = (1 - c) e_max (e_max: :func:`mmg.shapes.memory_range`)."""
    q = CONTROLS[group.control].quantum
    emax = memory_range(group)
    sizes = [q * 2.0**k / emax for k in GRID_EXPONENTS]
    cs = sizes if group.form == "play" else [1.0 - s for s in sizes]
    return [c for c in cs if 0.0 < c < 1.0]


def probe_kernels(ctx: Context) -> list[tuple[tuple[Effect, ...], str]]:
    """The kernels the probe simulates (on the base model), for the diagnosis' first
    compilation: a kernel is of the groups' structure, not of their ranges, so the ranges at
    the starting parameters name the same kernels as the base model's."""
    groups = memory_groups(ctx.windows, ctx.start)
    return tasks([ctx.with_base((eff,)) for eff, _ in by_form(groups)], ("simulate",))


@dataclass
class Trial:
    """One probed size: the group's spec, its coefficient, the direction's scale (1: the size
    as probed) and in-sample dBIC."""

    group: str
    c: float
    scale: float
    dbic: float


@dataclass
class MemoryProposal(ProbeProposal):
    """The probe's result: the best form (its single-group effect and start), its dBIC, the
    null's quantile it is compared with, whether it is proposed; every probed size's dBIC."""

    trials: list[Trial] = field(default_factory=list)

    what = "closed form of a memory"

    def as_dict(self) -> dict[str, Any]:
        return {**super().as_dict(), "trials": [asdict(t) for t in self.trials]}


def _directions(
    ctx: Context, params: Parameters, cal: Calibration, groups: Sequence[Group]
) -> tuple[FloatArray, list[tuple[Group, float]]]:
    """(changes of the base's residual vector (S, M, n), (group, c) of each): the base model
    simulated with each group's closed form at each of its :func:`grid_values`."""
    lin = cal.lin
    r0 = lin.residuals(ctx.windows)
    cols: list[FloatArray] = []
    where: list[tuple[Group, float]] = []
    for eff, members in by_form(groups):
        obj = Objective(
            ctx.windows, lin.objective, effects=(*lin.base_effects, eff), ship=params.ship
        )
        rows: list[FloatArray] = []
        # each group's first coefficient (of a gap signed away from the control's zero, the
        # moves away: the moves back as logged)
        first = np.cumsum([0] + [g.size for g in members])
        for j, g in enumerate(members):
            for c in grid_values(g):
                th = np.concatenate([lin.theta, np.zeros(len(eff.params))])
                th[lin.theta.size + first[j]] = c
                rows.append(th)
                where.append((g, c))
        if rows:
            r, _ = residual_vectors(obj, np.stack(rows))
            cols.extend(r - r0[None])
    if not cols:
        return np.zeros((*r0.shape, 0)), []
    G = np.moveaxis(np.stack(cols), 0, -1)
    ok = np.asarray(np.isfinite(G).all(axis=(0, 1)))
    return G[..., ok], [w for w, k in zip(where, ok.tolist(), strict=True) if k]


def best_direction(
    cal: Calibration, G: FloatArray, R: FloatArray, n_eff: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(dBIC (n, D) of each direction of G (S, M, n) for each residual vector of R (S, M, D),
    its scale (n, D), the control's J (D,)): the base refitted (linearised, with the prior, on
    all windows) beside each direction, its scale free but positive; one coefficient."""
    fold = cal.lin.all
    Rf = fold.resid(fold.stack(R))
    Gf = fold.resid(fold.stack(G))
    J0 = (Rf * Rf).sum(axis=0)
    n2 = np.maximum((Gf * Gf).sum(axis=0), 1e-300)
    scale = -(Gf.T @ Rf) / n2[:, None]  # r0 + a g: the change that takes the residual away
    gain = np.where(scale > 0.0, scale * scale * n2[:, None], 0.0)
    ratio = np.clip((J0[None] - gain) / np.maximum(J0[None], 1e-300), 1e-12, None)
    return n_eff * np.log(ratio) + math.log(n_eff), scale, J0


def propose_memory(ctx: Context, base: Fit, cal: Calibration) -> MemoryProposal | None:
    """The best closed form of a control's memory at the ``base`` model, proposed when its
    dBIC passes the null's quantile (None with shapes off, no control that moves, or the base
    within the noise floor); logged."""
    s = ctx.settings
    if not s.shapes:
        return None
    if not cal.misfit.significant:
        ctx.log("memories of the controls: not probed (the base is within the noise floor)")
        return None
    t0 = time.perf_counter()
    params = base.params
    groups = memory_groups(ctx.windows, params)
    G, where = _directions(ctx, params, cal, groups)
    if not where:
        return None
    r = cal.lin.residuals(ctx.windows)
    dbic, scale, _ = best_direction(cal, G, r[..., None], ctx.n_eff)
    i = int(np.argmin(dbic[:, 0]))
    trials = [
        Trial(g.text, c, float(scale[k, 0]), float(dbic[k, 0])) for k, (g, c) in enumerate(where)
    ]
    rng = np.random.default_rng(s.seed + 29)
    copies = null_sets(params, ctx.windows, cal.noise, rng, s.shape_null_draws)
    R = np.stack([cal.lin.residuals(c) for c in copies], axis=-1)
    null = best_direction(cal, G, R, ctx.n_eff)[0].min(axis=0)
    threshold = min(float(np.quantile(null, s.alpha)), CEILING)
    group, c = where[i]
    proposed = float(dbic[i, 0]) <= threshold
    effect = shape_effect([group])
    start = [c] + [0.0] * (group.size - 1)
    out = MemoryProposal(
        effect,
        start,
        float(dbic[i, 0]),
        threshold,
        proposed,
        time.perf_counter() - t0,
        [float(v) for v in null],
        trials,
    )
    ctx.log(
        f"memories of the controls: {effect.name} at c = {c:.4g} (of {len(where)} sizes of "
        f"{len(groups)} closed forms), linearised dBIC {out.dbic:.1f} against the null's "
        f"{s.alpha:.0%} quantile {threshold:.1f} -> {'proposed' if proposed else 'not proposed'} "
        f"({out.seconds:.0f} s)"
    )
    if proposed:
        # (a rate limit the learned shapes named already starts where its fit put it)
        ctx.starts.setdefault(effect.name, start)
    return out


__all__ = [
    "FORMS",
    "GRID_EXPONENTS",
    "MemoryProposal",
    "best_direction",
    "by_form",
    "grid_values",
    "memory_groups",
    "probe_kernels",
    "propose_memory",
]
