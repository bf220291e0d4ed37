"""The learned shape of the missing force as a candidate: the groups of penalised splines chosen
on the base's trajectory residuals (:mod:`sweep.diagnose.shapes`), proposed only beyond the null
of the same selection on noise-only copies of the training windows; its smoothness penalty and
effective degrees of freedom go with it into the fold fits and the verdict. With it goes its
name: each group's closest closed form (:mod:`sweep.diagnose.naming`), one effect of two
coefficients per group, fitted as an ordinary candidate.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg import Effect, Parameters
from mmg.shapes import (
    DEFAULT_BOUND,
    MAX_BASIS,
    Form,
    Group,
    form_scale,
    groups_of,
    parse_form,
    shape_effect,
)
from mmg.shapes import VARIABLES as SHAPE_VARIABLES
from sweep.data.recordings import Recording
from sweep.diagnose.calibration import Calibration
from sweep.diagnose.candidates import candidate_settings
from sweep.diagnose.context import Context
from sweep.diagnose.corners import ITERATIONS as CORNER_ITERATIONS
from sweep.diagnose.corners import fit_numbers
from sweep.diagnose.discover import null_sets
from sweep.diagnose.fit import Fit
from sweep.diagnose.linearised import RefitDrift
from sweep.diagnose.naming import (
    FAMILY,
    GRID,
    ClosedForm,
    Product,
    closest_forms,
    closest_products,
    complexity,
    fit_points,
    fitted_form,
    form_group,
    form_transform,
    group_families,
    memory_forms,
    memory_named,
    product_r2,
    product_transform,
    products,
)
from sweep.diagnose.pruning import (
    Dropped,
    Screened,
    fitted_coefficients,
    lead_by_output_error,
    prune,
    register,
)
from sweep.diagnose.shapes import (
    SHIP_VARIABLES,
    VARIABLES,
    ShapeColumns,
    ShapeSelection,
    candidate_groups,
    jointly_sampled,
    pair_groups,
    sampled,
)
from sweep.diagnose.threshold import CEILING
from sweep.identification.polish import PolishSettings
from sweep.identification.vector import with_effects

FloatArray = NDArray[np.float64]

#: basis functions over a chosen group's range on which its closed forms are compared
FINE_BASIS = MAX_BASIS
#: a simpler closed form (fewer numbers taken from the data,
#: :func:`~sweep.diagnose.naming.complexity`) within this share of the spline's held-out gain
#: of the best is chosen
FORM_TIE = 0.01


@dataclass(frozen=True)
class ShapeProposal:
    """The shape selection on the base's residuals, the null of its dBIC, the threshold (the
    ``alpha`` quantile, capped at :data:`CEILING`) and whether it is proposed."""

    selection: ShapeSelection
    null: list[float]
    threshold: float
    proposed: bool
    seconds: float
    #: the shape named: per group of the selection its closest closed form (None: a constant
    #: or flat group), and the effect of those forms with its starting coefficients
    named: list[ClosedForm | None] | None = None
    form: Effect | None = None
    form_start: list[float] | None = None
    #: the effect of each group's closed form closest to its spline (:func:`closest_form`),
    #: when it is another than ``form``, and its starting coefficients
    closest: Effect | None = None
    closest_start: list[float] | None = None
    #: the variables the candidate groups were made of (:func:`default_variables`)
    variables: tuple[str, ...] = ()
    #: {variable: its values at evenly spaced quantiles of the training samples} of the chosen
    #: groups (:func:`sample_values`): where closed forms are fitted to their shapes
    samples: dict[str, list[float]] = field(default_factory=dict)
    #: the selection before the backward check by output error (:mod:`sweep.diagnose.pruning`)
    #: when that dropped groups (None: nothing dropped), and its steps
    chosen: ShapeSelection | None = None
    dropped: list[Dropped] = field(default_factory=list)
    #: the single groups checked for the lead by output error (:mod:`sweep.diagnose.pruning`)
    screened: list[Screened] = field(default_factory=list)
    #: the closed-form candidates whose corners or widths were fitted by output error
    #: (:func:`fitted_numbers`): the named effect, the fitted one, their training J, the trials
    numbers: list[dict[str, Any]] = field(default_factory=list)
    #: the shapes of two variables tried (:func:`paired`): the pairs, the selection with them,
    #: its dBIC and its null's threshold, whether it was taken (None: not tried)
    pairs: dict[str, Any] | None = None
    #: what the control's fold fits, against which the held-out gains are measured, make of
    #: the held-out windows (:meth:`~sweep.diagnose.linearised.Linearised.refit_drift`)
    drift: RefitDrift | None = None

    @property
    def flexible(self) -> ShapeSelection:
        """The selection before the backward check: how much a flexible smooth correction
        explains (linearised)."""
        return self.chosen if self.chosen is not None else self.selection

    @property
    def effect(self) -> Effect:
        """The shape effect of the chosen groups."""
        return self.selection.effect()

    def as_dict(self) -> dict[str, Any]:
        """As ``report.json`` shows it (``shapes``)."""
        sel = self.selection
        null = np.asarray(self.null) if self.null else np.zeros(1)
        return {
            "effect": sel.spec,
            "groups": [g.text for g in sel.groups],
            "coefficients": sel.coefficients,
            "edf": sel.edf,
            "kappas": sel.kappas,
            "heldout_gain": sel.heldout_gain,
            "absorbed": sel.absorbed,
            "dbic": sel.dbic,
            "threshold": self.threshold,
            "null": {"draws": len(self.null), "median": float(np.median(null))},
            "proposed": self.proposed,
            "seconds": self.seconds,
            "form": self.form.name if self.form is not None else None,
            "closest": self.closest.name if self.closest is not None else None,
            "named": [None if c is None else asdict(c) for c in (self.named or [])],
            "variables": list(self.variables),
            "before_backward_check": self.chosen.spec if self.chosen is not None else None,
            "numbers": self.numbers,
            "dropped": [d.as_dict() for d in self.dropped],
            "screened": [x.as_dict() for x in self.screened],
            "pairs": self.pairs,
            "refit_drift": self.drift.as_dict() if self.drift is not None else None,
        }


def _fine_structures(
    groups: Sequence[Group], candidates: Sequence[Group]
) -> tuple[list[Group], dict[int, list[tuple[Group, int]]]]:
    """Per chosen group (not a constant or a memory) the fine groups (:data:`FINE_BASIS`) of its
    variable, in its own structure and in every other structure of that variable among the
    ``candidates`` (the plain shape, its products), each with its unit: units after the chosen
    groups', one per fine group, so that two chosen groups of one variable in the same
    components (a shape and a product of it) share them. Returns (the fine groups in unit
    order, {chosen group: [(fine group, unit)]})."""
    # a chosen group already of FINE_BASIS functions (a shape of time) is its own fine group
    units: dict[str, int] = {g.text: i for i, g in enumerate(groups)}
    extra: list[Group] = []
    fine: dict[int, list[tuple[Group, int]]] = {}
    for i, g in enumerate(groups):
        if g.variable == "1" or g.control or g.tensor:  # (a surface has no closed form yet)
            continue
        fs = [replace(g, n=FINE_BASIS)] + [
            Group(g.components, h.variable, g.lo, g.hi, FINE_BASIS, h.multiplier, h.scale)
            for h in candidates
            if h.variable == g.variable
            and (h.multiplier, h.scale) != (g.multiplier, g.scale)
            and (h.components == "S") == (g.components == "S")  # a share is of a force
        ]
        for f in fs:
            if f.text not in units:
                units[f.text] = len(groups) + len(extra)
                extra.append(f)
        fine[i] = [(f, units[f.text]) for f in fs]
    return extra, fine


def named_form(
    columns: ShapeColumns,
    selection: ShapeSelection,
    r: FloatArray,
    samples: Mapping[str, Sequence[float]] | None = None,
    joint: Mapping[tuple[str, str], tuple[FloatArray, FloatArray]] | None = None,
) -> tuple[list[ClosedForm | None], Effect | None, list[float]]:
    """Each chosen group's closed form, compared on the trajectories, and the effect of those
    forms (constant groups kept as they are) with its coefficients fitted on them (None if
    nothing is left).

    For each chosen group in turn, every closed form of
    :func:`~sweep.diagnose.naming.families` (corners at the training samples' quantiles
    ``samples`` too, :func:`sample_values`) takes the group's place beside the other chosen
    groups, and its held-out gain on the base's residual vector ``r`` (S, M) is measured the
    way the selection measured the spline's, on the trajectory columns of
    :data:`FINE_BASIS` basis functions over the group's range (``columns``: the
    :class:`~sweep.diagnose.shapes.ShapeColumns` the selection was made on, for its base):
    a kink or a step the selection's spline rounds off is compared as it is. The forms are
    tried in the group's own structure and in the other candidate structures of its variable
    (the plain shape with the variable's scaling, its products: a share of the hull's sway
    force in beta competes with a force in beta times U^2). The form of the largest gain is
    the group's name; a simpler one within :data:`FORM_TIE` of the spline's gain of it wins
    (fewer numbers taken from the data: a power before a hinge before a step), and among the
    equally simple the one of the largest gain (u^2 and u|u| are alike where u is rarely
    negative: the trajectories choose, not the order of the list). A group no form gains on
    is left out. The coefficients: all named forms fitted together on all windows
    (linearised).

    A surface (a shape of two variables) is named the same way by a product of closed forms
    g1(z) g2(z2) (:func:`~sweep.diagnose.naming.products`, drawn in the surface's own basis
    at the training samples' pairs ``joint`` {(variable, variable2): (z, z2)},
    :func:`~sweep.diagnose.naming.product_transform`): on the trajectories, where the base's
    parameters move with it, not by its likeness to the fitted surface, which holds only
    what the base could not absorb (on a planted yaw moment in u|u| times the wind's angle the
    surface fell with u, the trajectories' part the base left)."""
    groups = selection.groups
    extra, fine_units = _fine_structures(groups, columns.groups)
    surfaces = {
        i: at2
        for i, g in enumerate(groups)
        if g.tensor and joint is not None and (at2 := joint.get((g.variable, g.variable2)))
    }
    if not fine_units and not surfaces:
        return _named_forms(selection, {}, {})
    cols = ShapeColumns(columns.lin, [*groups, *extra])
    chosen = list(enumerate(selection.kappas))
    # every trial at once (one pass over the columns for r): the splines as chosen, then per
    # chosen group and fine structure each form in the group's place
    trials: list[tuple[list[tuple[int, float]], dict[int, FloatArray]]] = [(chosen, {})]
    # per (chosen group, fine unit): its forms, their transforms and their trials' places
    tried: dict[tuple[int, int], list[tuple[Form | Product, FloatArray, int]]] = {}
    for i, fus in fine_units.items():
        g = groups[i]
        at = None if samples is None else samples.get(g.variable)
        forms = group_families(g, at)
        for fg, fu in fus:
            trial = [(fu, 0.0) if k == i else (u, kap) for k, (u, kap) in enumerate(chosen)]
            for form in forms:
                W = form_transform(fg, form, at)
                if W is not None:
                    tried.setdefault((i, fu), []).append((form, W, len(trials)))
                    trials.append((trial, {fu: W}))
    for i, (z, z2) in surfaces.items():  # a surface's unit is its own: i
        trial = [(i, 0.0) if k == i else (u, kap) for k, (u, kap) in enumerate(chosen)]
        for product in products(groups[i]):
            W = product_transform(groups[i], product, z, z2)
            if W is not None:
                tried.setdefault((i, i), []).append((product, W, len(trials)))
                trials.append((trial, {i: W}))
    gains = cols.form_gains(r, trials)
    spline = float(gains[0])
    # per chosen group and fine structure the form of the largest gain (a simpler one within
    # FORM_TIE of the spline's gain of it, the largest gain among the equally simple); then,
    # largest gain first, each group takes its structure whose form gains most among the
    # units no other group has taken
    options: list[tuple[float, int, Form | Product, int, FloatArray]] = []
    for (i, fu), mine in tried.items():
        values = [float(gains[k]) for _, _, k in mine]
        top = max(values)
        near = [m for m, v in enumerate(values) if v >= top - FORM_TIE * abs(spline)]
        least = min(complexity(mine[m][0]) for m in near)
        m = max((m for m in near if complexity(mine[m][0]) == least), key=lambda m: values[m])
        if top > 0.0:
            options.append((values[m], i, mine[m][0], fu, mine[m][1]))
    fine = {fu: fg for fus in fine_units.values() for fg, fu in fus}  # unit -> its fine group
    fine.update({i: groups[i] for i in surfaces})
    picks: dict[int, tuple[Group, Form | Product, int, FloatArray, float]] = {}
    taken: set[int] = set()
    for v, i, name, fu, W in sorted(options, key=lambda o: -o[0]):
        if i not in picks and fu not in taken:
            picks[i] = (fine[fu], name, fu, W, v)
            taken.add(fu)
    if not picks:
        return _named_forms(selection, {}, {})
    together = [(picks[k][2], 0.0) if k in picks else (u, kap) for k, (u, kap) in enumerate(chosen)]
    transforms = {fu: W for _, _, fu, W, _ in picks.values()}
    coefficients = cols.form_fit(r, together, transforms)
    named = {i: (fg, form, gain, coefficients[i]) for i, (fg, form, _, _, gain) in picks.items()}
    levels = {i: coefficients[i] for i, g in enumerate(groups) if g.variable == "1"}
    return _named_forms(selection, named, levels, spline, samples, joint)


def _named_forms(
    selection: ShapeSelection,
    forms: Mapping[int, tuple[Group, Form | Product, float, list[float]]],
    coefficients: Mapping[int, list[float]],
    spline: float = 0.0,
    samples: Mapping[str, Sequence[float]] | None = None,
    joint: Mapping[tuple[str, str], tuple[FloatArray, FloatArray]] | None = None,
) -> tuple[list[ClosedForm | None], Effect | None, list[float]]:
    """:func:`named_form`'s result from its picks: per chosen force group its form ``forms``
    {group: (fine group, form, held-out gain, coefficients (a, b))}, constant groups with their
    ``coefficients`` (else the selection's), and each memory of a control as its closest closed form
    (:func:`~sweep.diagnose.naming.memory_forms`: a lag, a rate limit, play), started at the
    coefficient fitted to its spline. ``spline``: the shape's own linearised held-out gain;
    ``samples`` and ``joint``: where a form's likeness to its shape (R^2) is taken."""
    groups = selection.groups
    named: list[ClosedForm | None] = []
    out: list[Group] = []
    start: list[float] = []
    for i, g in enumerate(groups):
        if g.variable == "1":
            named.append(None)
            out.append(g)
            start += coefficients.get(i, selection.coefficients[i])
            continue
        if g.control:
            best = memory_forms(g, selection.coefficients[i])[:1]
            named.append(best[0] if best else None)
            if best:
                memory_group, values = memory_named(g, best[0])
                out.append(memory_group)
                start += values
            continue
        if i not in forms:
            named.append(None)
            continue
        fg, form, gain, (a, b) = forms[i]
        if isinstance(form, Product):  # a surface's product of closed forms
            named_group = replace(fg, n=2, n2=1, form=form.text)
            pairs = None if joint is None else joint.get((g.variable, g.variable2))
            closed = ClosedForm(
                form.family,
                form.formula(
                    SHAPE_VARIABLES[g.variable].symbol, SHAPE_VARIABLES[g.variable2].symbol
                ),
                a,
                b / form_scale(named_group),
                0.0 if pairs is None else product_r2(g, selection.coefficients[i], form, *pairs),
                form.text,
                gain / spline if spline > 0.0 else None,
            )
        else:
            at = None if samples is None else samples.get(g.variable)
            close = fitted_form(g, selection.coefficients[i], form, fit_points(g, at))
            named_group = replace(fg, n=2, form=form.text)
            closed = ClosedForm(
                FAMILY[form.key],
                form.formula(SHAPE_VARIABLES[g.variable].symbol),
                a,
                b / form_scale(named_group),
                close.r2 if close is not None and fg.structure == g.structure else 0.0,
                form.text,
                gain / spline if spline > 0.0 else None,
            )
        named.append(closed)
        if named_group.text not in {h.text for h in out}:
            out.append(named_group)
            start += [a, b]
    return (named, *form_effect(out, start))


def closest_form(
    selection: ShapeSelection,
    samples: Mapping[str, Sequence[float]] | None = None,
    joint: Mapping[tuple[str, str], tuple[FloatArray, FloatArray]] | None = None,
) -> tuple[Effect | None, list[float]]:
    """The effect of each chosen group's closed form closest to its spline (R^2 at the training
    samples ``samples``, :func:`sweep.diagnose.naming.closest_forms`, of the coarse families:
    corners at shares of the range), constant groups kept as they are, with its coefficients
    fitted to the splines (None if nothing is left). A second name beside
    :func:`named_form`'s: fitted to the penalised spline, it sees no kink the spline rounds
    off, but no fold's noise either, which a form chosen among hundreds by its held-out gain on
    the linearised columns can follow (a drift hinge, weak: the trajectories chose a hinge
    where 5 % of the samples lie, dBIC -79, the spline's closest form a harmonic, -192). A
    surface (a shape of two variables) is named by the product of closed forms closest to it
    where the training runs went (``joint``: {(variable, variable2): (z, z2)} of the training
    samples, :func:`~sweep.diagnose.shapes.jointly_sampled`;
    :func:`~sweep.diagnose.naming.closest_products`); without its samples it is left out."""
    groups: list[Group] = []
    start: list[float] = []
    for group, coef in zip(selection.groups, selection.coefficients, strict=True):
        if group.variable == "1":
            groups.append(group)
            start += coef
            continue
        if group.control:  # a memory: its closed form closest to the spline
            memory = memory_forms(group, coef)[:1]
            if memory:
                memory_group, values = memory_named(group, memory[0])
                groups.append(memory_group)
                start += values
            continue
        if group.tensor:  # a surface: the product of closed forms closest to it
            at2 = None if joint is None else joint.get((group.variable, group.variable2))
            product = closest_products(group, coef, *at2, top=1) if at2 is not None else []
            if product:
                g, ab = form_group(group, group.components, product[0])
                if g.text not in {h.text for h in groups}:
                    groups.append(g)
                    start += ab
            continue
        at = None if samples is None else samples.get(group.variable)
        best = closest_forms(group, coef, top=1, at=at, fine=False)
        if best:
            g, ab = form_group(group, group.components, best[0])
            if g.text not in {h.text for h in groups}:
                groups.append(g)
                start += ab
    return form_effect(groups, start)


def form_effect(
    groups: Sequence[Group], start: Sequence[float]
) -> tuple[Effect | None, list[float]]:
    """The effect of the closed-form ``groups`` (constant groups beside them) with each lone
    sway force or yaw moment completed (:func:`with_sibling`), and its starting coefficients
    ``start`` held within the search interval; (None, []) when no group has a closed form."""
    if not any(g.form for g in groups):
        return None, []
    out, values = with_sibling(groups, start)
    return shape_effect(out), [float(np.clip(v, -DEFAULT_BOUND, DEFAULT_BOUND)) for v in values]


#: a side force and its yaw moment: a force acting at a point of the hull gives both
SIBLING = {"Y": "N", "N": "Y"}


def with_sibling(
    groups: Sequence[Group], start: Sequence[float]
) -> tuple[list[Group], list[float]]:
    """The closed-form ``groups`` (coefficients ``start``, in order) with each single sway
    force or yaw moment completed by the other in the same closed form, started at neutral,
    unless a group of the other in the same variable, multiplier and scaling is among them: a
    force that acts at a point of the hull drives both, at a lever the fit finds, and the
    selection on the linearised columns may pass over the weaker of the two."""
    out: list[Group] = []
    values: list[float] = []
    i = 0
    for g in groups:
        k = len(g.components) * g.n
        c = list(start[i : i + k])
        i += k
        other = SIBLING.get(g.components)
        if (
            g.form
            and other
            and not any(
                h.components == other
                and (h.variable, h.multiplier, h.scale) == (g.variable, g.multiplier, g.scale)
                for h in groups
            )
        ):
            zero = [0.0] * g.n
            c = c + zero if g.components == "Y" else zero + c
            g = replace(g, components="YN")
        out.append(g)
        values += c
    return out, values


def sample_values(
    windows: Sequence[Recording], params: Parameters, groups: Sequence[Group]
) -> dict[str, list[float]]:
    """{variable: its values at :data:`~sweep.diagnose.naming.GRID` evenly spaced quantiles of
    the recorded samples of ``windows``} for the variables of the spline ``groups``
    (:func:`~sweep.diagnose.shapes.sampled`): the training data's distribution of each
    variable, where a shape's closed form is fitted."""
    names = sorted({g.variable for g in groups if g.variable != "1" and not g.control})
    q = np.linspace(0.0, 1.0, GRID)
    return {
        n: [float(v) for v in np.quantile(z, q)]
        for n, z in sampled(windows, params, names).items()
        if z.size
    }


def pair_samples(
    windows: Sequence[Recording], params: Parameters, groups: Sequence[Group]
) -> dict[tuple[str, str], tuple[FloatArray, FloatArray]]:
    """{(variable, variable2): (z, z2)} of the surfaces among ``groups``: both variables on the
    same recorded samples of ``windows`` (:func:`~sweep.diagnose.shapes.jointly_sampled`),
    where a surface's products of closed forms are drawn and compared."""
    return {
        (g.variable, g.variable2): jointly_sampled(windows, params, g.variable, g.variable2)
        for g in groups
        if g.tensor
    }


def fitted_numbers(
    ctx: Context,
    base: Fit,
    effect: Effect,
    start: Sequence[float],
    named: Sequence[ClosedForm | None] = (),
    variables: Sequence[str] = (),
) -> tuple[Effect, list[float], list[ClosedForm | None], dict[str, Any] | None]:
    """The closed-form ``effect`` (coefficients ``start``) with its corners and widths fitted
    by output error on the training windows (:func:`~sweep.diagnose.corners.fit_numbers`, each
    trial a short joint fit with the base from ``base``), its coefficients there, and the
    closed forms ``named`` (of the shapes of ``variables``, in order) with the fitted numbers;
    unchanged, coefficients included, when no group has a corner or no fitted number lowers
    the BIC; and what was fitted (None when nothing could be: the effects' names, training J,
    trials and seconds, as ``report.json`` shows it). Each number fitted counts as a parameter
    in the effect's dBIC."""
    settings = replace(
        candidate_settings(ctx),
        budget=0,
        effect_only_budget=0,
        polish=ctx.lm(CORNER_ITERATIONS, PolishSettings.rtol),
    )

    def refit(e: Effect, p0: Parameters) -> tuple[float, Parameters]:
        f = ctx.refit(ctx.windows, p0, (e,), settings, f"numbers of {e.name}")
        return f.f, f.params

    p0 = with_effects(base.params, (effect,), start)
    fitted = fit_numbers(effect, p0, refit, FINE_BASIS, ctx.n_eff, ctx.log)
    if fitted is None:
        return effect, list(start), list(named), None
    record = {
        "named": effect.name,
        "fitted": fitted.effect.name,
        "J_named": fitted.J_named,
        "J_fitted": fitted.J_fitted,
        "numbers": fitted.count,
        "trials": [{"effect": name, "J": J} for name, J in fitted.trials],
        "seconds": fitted.seconds,
    }
    if fitted.count == 0:  # no number paid for itself: the candidate as it was named
        return effect, list(start), list(named), record
    ctx.dof[fitted.effect.name] = float(len(fitted.effect.params) + fitted.count)
    renamed = {
        (g.variable, g.form): h.form
        for g, h in zip(groups_of(effect), groups_of(fitted.effect), strict=True)
        if g.form != h.form
    }
    out: list[ClosedForm | None] = []
    for c, variable in zip(named, variables, strict=True):
        text = renamed.get((variable, c.form)) if c is not None else None
        if c is None or text is None:
            out.append(c)
            continue
        formula = parse_form(text).formula(SHAPE_VARIABLES[variable].symbol)
        out.append(replace(c, form=text, formula=formula))
    return fitted.effect, fitted.start, out, record


@dataclass
class Paired:
    """The selection made again with shapes of two variables among the candidates
    (:func:`paired`): its columns, the selection, its null and threshold, whether it is taken
    in place of the first, and the record ``report.json`` shows (``shapes.pairs``)."""

    columns: ShapeColumns
    selection: ShapeSelection
    null: list[float]
    threshold: float
    taken: bool
    record: dict[str, Any]


def paired(
    ctx: Context,
    cal: Calibration,
    columns: ShapeColumns,
    selection: ShapeSelection,
    r: FloatArray,
    R: FloatArray,
    variables: Sequence[str],
) -> Paired | None:
    """The selection with the interactions of its first group's variable among the candidates
    (:func:`~sweep.diagnose.shapes.pair_groups`: a surface of that variable and each other
    one, in the group's components and multiplier), on the columns of both kinds; its null the
    same selection on the noise-only residual vectors ``R`` (S, M, D) (more candidates, a
    higher null). Taken in place of ``selection`` when it chose a surface, passes its own
    null's threshold and has a lower in-sample dBIC; logged. None when the first group has no
    pairs (a constant, a memory)."""
    s = ctx.settings
    first = selection.groups[0]
    # each variable's knot range as its candidate groups have it (the training windows' range)
    ranges = {g.variable: (g.lo, g.hi) for g in columns.groups if g.variable != "1"}
    groups = pair_groups(ranges, first, variables)
    if not groups:
        return None
    t0 = time.perf_counter()
    both = ShapeColumns(cal.lin, [*columns.groups, *groups])
    again = both.select(r, ctx.n_eff)
    record: dict[str, Any] = {
        "pairs": [g.text for g in groups],
        "selection": again.spec,
        "dbic": again.dbic,
        "threshold": None,
        "taken": False,
    }
    null: list[float] = []
    threshold = CEILING
    if any(g.tensor for g in again.groups):
        null = [float(v) for v in both.null_dbic(R, ctx.n_eff)]
        threshold = min(float(np.quantile(null, s.alpha)), CEILING)
        record["threshold"] = threshold
        record["taken"] = again.dbic <= threshold and again.dbic < selection.dbic
    record["seconds"] = time.perf_counter() - t0
    ctx.log(
        f"shapes of two variables: {len(groups)} interactions of {first.variable} -> "
        f"{again.spec or 'no group'} (linearised dBIC {again.dbic:.1f}"
        + (
            f" against its null's {s.alpha:.0%} quantile {threshold:.1f} and the first "
            f"selection's {selection.dbic:.1f}"
            if record["threshold"] is not None
            else ", no surface among its groups"
        )
        + f") -> {'taken' if record['taken'] else 'not taken'} ({record['seconds']:.0f} s)"
    )
    return Paired(both, again, null, threshold, bool(record["taken"]), record)


def default_variables(ctx: Context) -> tuple[str, ...]:
    """The variables the shapes may depend on: ``--shape-variables`` when given; else every
    variable when the training runs come from several sessions (a shape in heading, position
    or time must then carry over to another session's runs, :mod:`sweep.diagnose.sessions`),
    and the ship's state and controls alone when they come from one (no other session could
    show that such a shape does not carry over)."""
    if ctx.settings.shape_variables:
        return ctx.settings.shape_variables
    return VARIABLES if ctx.session_w is not None else SHIP_VARIABLES


def _with_numbers(
    ctx: Context,
    base: Fit,
    selection: ShapeSelection,
    named_on_trajectories: tuple[Effect | None, list[float], list[ClosedForm | None]],
    closest_to_spline: tuple[Effect | None, list[float]],
) -> tuple[
    Effect | None,
    list[float],
    list[ClosedForm | None],
    Effect | None,
    list[float],
    list[dict[str, Any]],
]:
    """The two named candidates of ``selection`` with their closed forms' numbers fitted by
    output error (:func:`fitted_numbers`): the form named on the trajectories (effect, start,
    per group its closed form) and the one closest to the spline (effect, start; None when it
    is the same effect), and the records of the numbers fitted; logged."""
    form, start, named = named_on_trajectories
    closest, closest_start = closest_to_spline
    numbers: list[dict[str, Any]] = []
    if closest is not None and form is not None and closest.name == form.name:
        closest = None  # (before the numbers are fitted: one search for the two)
    if form is not None:
        variables_named = [g.variable for g in selection.groups]
        form, start, named, record = fitted_numbers(ctx, base, form, start, named, variables_named)
        numbers += [record] if record is not None else []
    if closest is not None:
        closest, closest_start, _, record = fitted_numbers(ctx, base, closest, closest_start)
        numbers += [record] if record is not None else []
    if closest is not None and form is not None and closest.name == form.name:
        closest = None
    if closest is not None:
        ctx.log(f"shapes' closest closed forms: candidate {closest.name}")
    return form, start, named, closest, closest_start, numbers


def propose_shape(ctx: Context, base: Fit, cal: Calibration) -> ShapeProposal | None:
    """The shape candidate at the ``base`` model (None with shapes off), checked group by group
    by output error (:mod:`sweep.diagnose.pruning`) when it has several, logged."""
    s = ctx.settings
    if not s.shapes:
        return None
    t0 = time.perf_counter()
    params = base.params
    variables = default_variables(ctx)
    columns = ShapeColumns(cal.lin, candidate_groups(ctx.windows, params, variables=variables))
    r = cal.lin.residuals(ctx.windows)
    selection = columns.select(r, ctx.n_eff)
    drift = cal.lin.refit_drift(r)
    null: list[float] = []
    threshold = CEILING
    R: FloatArray | None = None
    if selection.groups:
        rng = np.random.default_rng(s.seed + 19)
        copies = null_sets(params, ctx.windows, cal.noise, rng, s.shape_null_draws)
        R = np.stack([cal.lin.residuals(c) for c in copies], axis=-1)
        null = [float(v) for v in columns.null_dbic(R, ctx.n_eff)]
        threshold = min(float(np.quantile(null, s.alpha)), CEILING)
    proposed = bool(selection.groups) and selection.dbic <= threshold
    gain = selection.heldout_gain[-1] if selection.heldout_gain else 0.0
    ctx.log(
        f"shapes: {selection.spec or 'no group'} ({sum(selection.edf):.1f} effective degrees "
        f"of freedom, held-out gain {100 * gain:.0f} % of the control's held-out J), linearised "
        f"dBIC {selection.dbic:.1f} against the null's {s.alpha:.0%} quantile {threshold:.1f} "
        f"-> {'proposed' if proposed else 'not proposed'}; the control's fold fits make the "
        f"held-out windows' J {drift.ratio:.2f} x the base's ({drift.window}: "
        f"{100 * drift.share:.0f} % of it)"
    )
    samples: dict[str, list[float]] = {}
    named: list[ClosedForm | None] = []
    form: Effect | None = None
    start: list[float] = []
    closest: Effect | None = None
    closest_start: list[float] = []
    chosen: ShapeSelection | None = None
    dropped: list[Dropped] = []
    screened: list[Screened] = []
    numbers: list[dict[str, Any]] = []
    pairs: dict[str, Any] | None = None
    if proposed:
        selection, screened, fits = lead_by_output_error(
            ctx, base, columns, r, selection, threshold
        )
        if s.shape_pairs and R is not None:
            pair = paired(ctx, cal, columns, selection, r, R, variables)
            if pair is not None:
                pairs = pair.record
                if pair.taken:
                    columns, selection, null, threshold = (
                        pair.columns,
                        pair.selection,
                        pair.null,
                        pair.threshold,
                    )
        full = selection
        selection, dropped, more = prune(ctx, base, columns, r, selection)
        chosen = full if dropped else None
        samples = sample_values(ctx.windows, params, selection.groups)
        joint = pair_samples(ctx.windows, params, selection.groups)
        # named on the trajectories from the linearised spline (a memory's closed form is read
        # off its spline), the closest forms from the spline of its fit by output error where
        # the checks fitted it: two views, and the fit by output error decides between them
        named, form, start = named_form(columns, selection, r, samples, joint)
        selection = fitted_coefficients(selection, {**fits, **more})
        closest, closest_start = closest_form(selection, samples, joint)
        form, start, named, closest, closest_start, numbers = _with_numbers(
            ctx, base, selection, (form, start, named), (closest, closest_start)
        )
    if form is not None:
        ctx.log(
            "shapes named on the trajectories: "
            + "; ".join(
                (
                    f"{c.formula} ({100 * c.share:.0f} % of the spline's held-out gain, "
                    f"R^2 {c.r2:.2f})"
                    if c.share is not None
                    else f"{c.family} ({c.form}, coefficient {c.a:.3g}; {100 * c.r2:.0f} % of "
                    "the memory's share kept)"
                )
                for c in named
                if c is not None
            )
            + f" -> candidate {form.name}"
        )
    seconds = time.perf_counter() - t0
    out = ShapeProposal(
        selection,
        null,
        threshold,
        proposed,
        seconds,
        named,
        form,
        start,
        closest,
        closest_start,
        tuple(variables),
        samples,
        chosen,
        dropped,
        screened,
        numbers,
        pairs,
        drift,
    )
    if proposed:
        register(ctx, selection)
    if form is not None:
        ctx.starts[form.name] = start
    if closest is not None:
        ctx.starts[closest.name] = closest_start
    return out


__all__ = [
    "ShapeProposal",
    "closest_form",
    "default_variables",
    "fitted_numbers",
    "form_effect",
    "named_form",
    "pair_samples",
    "propose_shape",
    "sample_values",
    "with_sibling",
]
