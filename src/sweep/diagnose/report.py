"""The diagnosis report: ``report.json`` (machine-readable), ``report.md`` and its plots."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from mmg import Parameters, get_effect, simulate_batch
from mmg.shapes import BASIN, SHAPE_PREFIX, is_closed_form
from sweep.data.recordings import Recording
from sweep.diagnose.generalise import GeneralisationTest
from sweep.diagnose.locate import GROUPS, bin_edges, residual_frame
from sweep.diagnose.pruning import SCREEN_SHARE
from sweep.diagnose.run import Diagnosis, round_dir
from sweep.diagnose.scoring import CandidateScore, diverged_text, form_share, shape_and_form
from sweep.diagnose.shapes import MIN_GAIN, PLACE_AND_TIME
from sweep.diagnose.threshold import NEGLIGIBLE
from sweep.diagnose.verdict import shape_name

#: the regime variable in which each catalog effect acts
EFFECT_REGIME_VARIABLE = {
    "current": "U",
    "propeller_walk": "n_p",
    "rudder_stall": "delta_deg",
    "a_h_drift": "beta_deg",
    "actuator_lag": "delta_deg",
    "rudder_offset": "delta_deg",
    "heading_bias": "gamma_A_deg",
}


def _effects(p: Parameters) -> tuple[Any, ...]:
    return tuple(get_effect(n) for n, _ in p.effects)


def misfit_text(d: Diagnosis) -> str:
    """The base model's misfit against the noise floor, in words."""
    m = d.misfit
    if m is None:
        return ""
    refit = (
        f" The floor is that of a model fitted to these windows: refitting the 57 parameters "
        f"to noise alone keeps {100 * m.refit_factor:.0f} % of the noise's J."
        if m.refit_factor != 1.0
        else ""
    )
    first = d.extra.get("noise_first_sample") or {}
    exact = (
        " The windows begin at exact states, not recorded ones (the start of a simulation: "
        f"log-odds {first['log_odds_exact']:.0f} over {first['items']} windows x channels), and "
        + (
            "so do the noise-only copies behind this floor and every null."
            # (a report without the field was written when the copies always began as the
            # windows did)
            if first.get("copies_exact", True)
            else "the noise-only copies behind this floor and the acceptance nulls begin noisy "
            "all the same (`--exact-starts`: exactly; the test recordings' null begins as the "
            "windows do)."
        )
        if first and not first["noisy"]
        else ""
    )
    return (
        f"The base model's {m.objective} on the training windows is {m.J:.3g}, {m.ratio:.2f} x "
        f"the floor that measurement noise alone gives ({m.floor:.3g}, z = {m.z:.1f}; "
        f"significant above {1 + m.margin:.2f} x and z > {m.z_crit:.0f}).{refit}{exact}"
    )


def remainder(d: Diagnosis) -> dict[str, Any] | None:
    """The model after (with the finding) on the training windows against the same noise floor
    as the base model's misfit: its J, ratio to the floor, z and whether it is still
    significant (more is missing than the finding); None without a finding or a misfit test."""
    m = d.misfit
    if m is None or not d.verdict_effect:
        return None
    J = float(d.after.f)
    z = (J - m.floor) / m.floor_sd
    return {
        "J": J,
        "ratio": J / m.floor,
        "z": z,
        "significant": d.more_missing,
        # the share of the base's excess over the floor the finding takes away (None: no excess)
        "share_of_excess": (m.J - J) / (m.J - m.floor) if m.floor < m.J else None,
    }


def remainder_text(d: Diagnosis) -> str:
    """The misfit left with the finding on the training windows, in words ("" without one)."""
    r = remainder(d)
    if r is None:
        return ""
    m = d.misfit
    assert m is not None
    share = r["share_of_excess"]
    took = (
        f" it takes {100 * share:.0f} % of the base model's excess over the floor away"
        if share is not None
        else ""
    )
    if r["significant"]:
        return (
            f" With it the training windows are still {r['ratio']:.1f} x the noise floor "
            f"({m.objective} {r['J']:.3g}, z = {r['z']:.0f}):{took}, but more is missing than "
            "this finding."
        )
    return (
        f" With it the training windows are at the noise floor ({r['ratio']:.2f} x, "
        f"z = {r['z']:.1f})."
    )


def generalisation_text(d: Diagnosis) -> str:
    """The test recordings' misfit against a model exact in form, in words."""
    g = d.generalisation
    if g is None:
        return ""
    text = (
        f"On the test recordings (not fitted to) the re-identified base model's {g.objective} is "
        f"{g.J:.3g}, {g.ratio:.2f} x the median of what a model exact in form, identified on "
        f"these training windows with noise of the estimated level, reaches there ({g.median:.3g}"
        f"; {100 * (1 - g.alpha):.0f} % quantile {g.quantile:.3g}, significant above "
        f"{1 + g.margin:.2f} x it"
        + ("; its noise-only copies begin exactly, as these windows do" if g.copies_exact else "")
        + "): "
        + ("it does not carry over." if g.significant else "within what noise explains.")
    )
    ga = d.generalisation_after
    if ga is not None:
        text += f" With the chosen effect: {ga.J:.3g}, {ga.ratio:.2f} x " + (
            "(still significant)." if ga.significant else "(within)."
        )
    return text


def discovered_entry(d: Diagnosis) -> dict[str, Any]:
    """The discovered terms: formulas, coefficients, and how to reuse them."""
    if d.verdict != "discovered":
        return {}
    from mmg.library import term

    values = d.finding_values()
    terms = d.verdict_effect.split(":", 1)[1].split("+")
    c = d.chosen
    return {
        "effect": d.verdict_effect,
        "terms": [
            {
                "term": t,
                "kind": term(t).kind,
                "formula": term(t).force_formula(),
                "coefficient": term(t).coefficient,
                "value": values[term(t).coefficient],
            }
            for t in terms
        ],
        "formula": "; ".join(
            term(t)
            .force_formula()
            .replace(term(t).coefficient, f"({values[term(t).coefficient]:.4g})")
            for t in terms
        ),
        "heldout_improvement": c.improvement if c else None,
        "heldout_improvement_total": c.improvement_total if c else None,
        "delta_bic": c.delta_bic if c else None,
        "resembles": d.extra.get("resemblance", {}),
        "reuse": "python -m sweep.evaluate --params params_after.json (the effect is rebuilt "
        "from its name in any process)",
    }


def shape_entry(d: Diagnosis) -> dict[str, Any]:
    """The learned shape when the verdict is ``shape``: per group its formula, the range it was
    learnt on, its values on a grid, and the closed forms closest to it; else {}."""
    if d.verdict != "shape":
        return {}
    from mmg.shapes import VARIABLES, curve, groups_of
    from sweep.diagnose.naming import CLOSE, closest_forms, memory_forms

    eff = get_effect(d.verdict_effect)
    values = d.finding_values()
    # a report.json written before the time step was kept: the recordings' 0.1 s
    dt = d.extra.get("time_step", 0.1)
    groups = []
    for g, group in enumerate(groups_of(eff)):
        for comp in group.components:
            names = [f"s{g}_{comp}{j}" for j in range(group.size)]
            coef = [values.get(n, 0.0) for n in names]
            if group.tensor:
                groups.append(_surface_entry(group, comp, g, coef))
                continue
            if group.form and group.control:
                said = group.memory_closed(coef[0], dt, *coef[1:2])
                formula = f"{said}: {group.formula(comp, g)}"
            elif group.form:
                formula = group.closed(comp, coef[0], coef[1], g)
            else:
                formula = group.formula(comp, g)
            entry: dict[str, Any] = {
                "group": group.text,
                "component": comp,
                "formula": formula,
                "variable": group.variable,
                "coefficients": coef,
                "closed_form": bool(group.form),
            }
            if group.variable != "1":
                var = VARIABLES[group.variable]
                z = np.linspace(group.lo, group.hi, 9)
                entry.update(
                    {
                        "range": [group.lo, group.hi],
                        "unit": var.unit,
                        "meaning": var.meaning,
                        "z": [float(v) for v in z],
                        "f": [float(v) for v in curve(group, coef, z)],
                        "band": _band(d, group, names, z),
                    }
                )
                if group.control:
                    entry["memory"] = _memory_entry(group, coef, dt)
                at = d.shape.samples.get(group.variable) if d.shape is not None else None
                if group.form:
                    forms = []
                elif group.control:
                    forms = memory_forms(group, coef)
                else:
                    forms = closest_forms(group, coef, at=at)
                entry["closest"] = [asdict(c) for c in forms]
                entry["named"] = bool(group.form) or (bool(forms) and forms[0].r2 >= CLOSE)
            groups.append(entry)
    return {
        "effect": d.verdict_effect,
        "closed_form": is_closed_form(d.verdict_effect),
        "kept": form_share(d.candidates),
        "groups": groups,
    }


def _surface_entry(group: Any, comp: str, g: int, coef: list[float]) -> dict[str, Any]:
    """A shape of two variables (or the product of closed forms it was named by): f on a grid
    of 9 values of the first variable over its range and 5 of the second (``surface``, rows
    the first)."""
    from mmg.shapes import VARIABLES, surface

    var, var2 = VARIABLES[group.variable], VARIABLES[group.variable2]
    z = np.linspace(group.lo, group.hi, 9)
    z2 = np.linspace(group.lo2, group.hi2, 5)
    Z, Z2 = np.meshgrid(z, z2, indexing="ij")
    f = surface(group, coef, Z.ravel(), Z2.ravel()).reshape(Z.shape)
    named = bool(group.form)  # a product of closed forms
    return {
        "group": group.text,
        "component": comp,
        "formula": group.closed(comp, coef[0], coef[1], g) if named else group.formula(comp, g),
        "variable": group.variable,
        "variable2": group.variable2,
        "coefficients": coef,
        "closed_form": named,
        "range": [group.lo, group.hi],
        "range2": [group.lo2, group.hi2],
        "unit": var.unit,
        "unit2": var2.unit,
        "meaning": var.meaning,
        "meaning2": var2.meaning,
        "z": [float(v) for v in z],
        "z2": [float(v) for v in z2],
        "surface": [[float(v) for v in row] for row in f],
        "closest": [],
        "named": named,
    }


def _memory_entry(group: Any, coef: list[float], dt: float) -> dict[str, Any]:
    """A memory of a control in the control's terms: at gaps over the range it was learnt on
    (both signs), the share f left open in one time step of ``dt`` [s], the step the control
    takes and that step as a rate; a rudder's in degrees. ``away``: the gaps are signed away
    from the control's zero (+ moving away, - moving back)."""
    from mmg.shapes import CONTROLS, VARIABLES, memory_steps

    k = CONTROLS[group.control]
    z = np.linspace(0.0, max(abs(group.lo), abs(group.hi)), 7)[1:]
    gaps = np.sinh(np.concatenate([-z[::-1], z])) * k.quantum
    share, step = memory_steps(group, coef, gaps)
    to = np.degrees if k.unit == "rad" else np.asarray
    return {
        "control": k.symbol,
        "unit": "deg" if k.unit == "rad" else k.unit,
        "time_step": dt,
        "away": VARIABLES[group.variable].away,
        "gap": [float(v) for v in to(gaps)],
        "share": [float(v) for v in share],
        "step": [float(v) for v in to(step)],
        "rate": [float(v) for v in to(step / dt)],
    }


def _band(d: Diagnosis, group: Any, names: list[str], z: Any) -> list[float] | None:
    """The half-width of the shape's confidence band at z (the intervals' level, from the
    covariance of the model after: :func:`sweep.diagnose.trust.trust_of`), None where it was
    not computed."""
    from mmg.shapes import basis

    cov = (d.extra.get("trust") or {}).get("after", {}).get("effect_covariance")
    if not cov or any(n not in cov["names"] for n in names) or (group.control and group.form):
        return None
    ix = [cov["names"].index(n) for n in names]
    C = np.array([[cov["matrix"][i][j] for j in ix] for i in ix], dtype=float)
    if not np.all(np.isfinite(C)):
        return None
    B = basis(group, z)
    var = np.einsum("zi,ij,zj->z", B, C, B)
    return [float(v) for v in float(cov["quantile"]) * np.sqrt(np.clip(var, 0.0, None))]


def names_shape(d: Diagnosis) -> dict[str, Any] | None:
    """The accepted learned shape that the finding, a library term or a catalog effect, names
    (the finding is the shape's name by :func:`sweep.diagnose.verdict.shape_name`): {"shape",
    "kept"}, the share of the shape's held-out gain the finding keeps; else None."""
    spline = shape_and_form(d.candidates)[0]
    c = d.chosen
    if c is None or c.effect.startswith(SHAPE_PREFIX) or spline is None or not spline.accepted:
        return None  # a shape finding is stated by the shape section (its closed form's share)
    named = shape_name(d.candidates, spline.effect)
    if named is None or named[0].effect != c.effect:
        return None
    return {"shape": spline.effect, "kept": named[1]}


def names_shape_text(d: Diagnosis) -> str:
    """:func:`names_shape` in words ("" without)."""
    n = names_shape(d)
    if n is None:
        return ""
    return (
        f"It names the learned shape {n['shape']} (accepted too): it keeps "
        f"{100 * n['kept']:.0f} % of the shape's held-out gain. "
    )


def _shape_text(d: Diagnosis) -> str:
    entry = shape_entry(d)
    parts = []
    for g in entry["groups"]:
        if g["variable"] == "1":
            parts.append(f"{g['formula']} = {g['coefficients'][0]:.3g}")
            continue
        lo, hi = g["range"]
        if "surface" in g:
            lo2, hi2 = g["range2"]
            parts.append(
                f"{g['formula']}, a smooth function of the {g['meaning']} and the "
                f"{g['meaning2']} learnt over [{lo:.3g}, {hi:.3g}] {g['unit']} x "
                f"[{lo2:.3g}, {hi2:.3g}] {g['unit2']} (held at its edges beyond)"
            )
            continue
        if g["closed_form"]:
            parts.append(
                f"{g['formula']}, with the {g['meaning']} held within [{lo:.3g}, {hi:.3g}] "
                f"{g['unit']}"
            )
            continue
        text = (
            f"{g['formula']}, a smooth function of the {g['meaning']} learnt over "
            f"[{lo:.3g}, {hi:.3g}] {g['unit']} (held at its end values beyond)"
        )
        if g.get("named"):
            c = g["closest"][0]
            text += f"; close to {c['a']:.3g} + {c['b']:.3g} {c['formula']} (R^2 {c['r2']:.2f})"
        parts.append(text)
    if entry["closed_form"]:
        kept = entry["kept"]
        share = (
            f"; it keeps {100 * kept:.0f} % of the learned shape's held-out gain"
            if kept is not None
            else ""
        )
        return (
            "Missing physics, named after its learned shape (no library term or catalog "
            "effect): " + "; ".join(parts) + share + ". See shapes.png. "
        )
    return (
        "Missing physics, learned as a shape (no library term or catalog effect): "
        + "; ".join(parts)
        + ". See shapes.png and the table in report.md. "
    )


#: the control's fold fits drift far from the base when they make the held-out windows' J more
#: than this many times the base's own there: the report then says what the held-out gains are
#: measured against (:func:`drift_text`)
DRIFT_RATIO = 2.0


def explainable(d: Diagnosis) -> dict[str, Any] | None:
    """How much of the misfit a smooth correction explains on held-out runs: the held-out gain
    (share of the control's held-out J, linearised) of the learned shapes and of the library
    terms chosen on the trajectories, and the share of the first that the named terms keep;
    with what the control's fold fits make of the held-out windows (``refit_drift``,
    :class:`~sweep.diagnose.linearised.RefitDrift`); None without the shape selection."""
    if d.shape is None:
        return None
    sel = d.shape.flexible
    flexible = sel.heldout_gain[-1] if sel.heldout_gain else 0.0
    tr = d.extra.get("trajectory_discovery") or {}
    named = float(tr.get("heldout_share") or 0.0)
    drift = d.shape.drift
    return {
        "flexible_heldout_gain": flexible,
        "named_heldout_gain": named,
        "named_share": named / flexible if flexible > 0 else None,
        "shape": sel.spec,
        "refit_drift": drift.as_dict() if drift is not None else None,
    }


def drift_text(drift: dict[str, Any] | None, gain: float) -> str:
    """What the held-out ``gain`` (share of the control fits' held-out J) is measured against,
    in words, when the control's fold fits ``drift`` (:meth:`RefitDrift.as_dict`) make the
    held-out windows' J more than :data:`DRIFT_RATIO` x the base's own ("" otherwise): the
    part of the gain beyond the base's whole J there cannot be the base's misfit explained."""
    if drift is None or drift["ratio"] <= DRIFT_RATIO:
        return ""
    text = (
        " The held-out gains are measured against the 57 parameters refitted on the other half "
        f"of the runs, which make the held-out windows' J {_times(drift['ratio'])} x the base's "
        f"own ({drift['window']}: {100 * drift['share']:.0f} % of it)"
    )
    if gain <= 0.0:
        return text + "."
    text += f"; with the correction it is still {_times(drift['ratio'] * (1.0 - gain))} x."
    absolute = gain * drift["heldout"]
    if absolute > drift["base"]:
        beyond = math.floor(100.0 * (absolute - drift["base"]) / absolute)  # a lower bound
        text += (
            f" The gain, {absolute:.3g}, is {_times(absolute / drift['base'])} x the base's "
            f"whole J there ({drift['base']:.3g}), so at least {beyond} % of it undoes the "
            "refit's drift rather than explaining the base's misfit."
        )
    return text


def _times(ratio: float) -> str:
    """A ratio to a tenth below 100, whole above."""
    return f"{ratio:.1f}" if ratio < 99.95 else f"{ratio:.0f}"


def explainable_text(d: Diagnosis) -> str:
    """The explainable share in words ("" without the shape selection)."""
    e = explainable(d)
    if e is None:
        return ""
    if e["flexible_heldout_gain"] <= 0:
        return (
            " No smooth function of the ship's state and controls (learned shapes) helps on "
            "held-out runs."
        )
    share = e["named_share"]
    kept = f"; the library's terms keep {100 * share:.0f} % of it" if share is not None else ""
    text = (
        f" A flexible smooth correction (learned shapes, {e['shape']}) takes "
        f"{100 * e['flexible_heldout_gain']:.0f} % off the held-out runs' J when linearised"
        f"{kept}." + drift_text(e["refit_drift"], e["flexible_heldout_gain"])
    )
    sp = d.shape
    final = e["shape"]
    if sp is not None and sp.dropped:
        final = sp.selection.spec
        text += (
            " The backward check by output error left out "
            + ", ".join(x.group for x in sp.dropped)
            + f" (each made the typical held-out window less than {MIN_GAIN:.0%} better than the "
            f"rest alone): {final}."
        )
    fitted = next((c for c in d.candidates if c.effect == final), None)
    if fitted is not None:
        change = 100 * -fitted.improvement_total
        text += (
            f" Fitted by output error with the 57 parameters it changed the held-out runs' "
            f"summed J by {change:+.{0 if abs(change) >= 9.5 else 1}f} %"
            + ("." if fitted.carries_over else ": the linearised gain does not carry over.")
        )
    return text


def _best_text(d: Diagnosis) -> str:
    best = d.candidates[0] if d.candidates else None
    if best is None:
        return ""
    return (
        f" The best candidate was {best.effect} (dBIC {best.delta_bic:.1f}, held-out "
        f"change {100 * best.improvement:+.1f} %)."
    )


def _unexplained_statement(d: Diagnosis) -> str:
    m = d.misfit
    assert m is not None
    g = d.generalisation
    if m.significant or g is None:
        text = (
            f"Unexplained misfit: the base model misses by {m.ratio:.1f} x what measurement "
            f"noise alone gives ({d.settings.objective} {m.J:.3g} against a floor of "
            f"{m.floor:.3g}, z = {m.z:.0f}), and no candidate (catalog, discovered or learned "
            "shape) was accepted." + explainable_text(d)
        )
    else:
        beyond = ", ".join(
            f"{r['run']} ({r['ratio']:.1f} x)" for r in g.per_run if r["significant"]
        )
        text = (
            f"Unexplained misfit on recordings the model was not fitted to: on the training "
            f"windows the base model is at the noise floor ({m.ratio:.2f} x), but on the "
            f"test recordings its {g.objective} is {g.J:.3g}, {g.ratio:.1f} x the median of "
            f"what a model exact in form, identified on the same training windows, reaches "
            f"there ({g.median:.3g}; significant above {g.limit:.3g}). "
            + (
                "No candidate"
                if d.departures
                else "Something the training manoeuvres do not excite is missing: no candidate"
            )
            + " (catalog or discovered) could be fitted to it. Runs beyond their own "
            f"limit: {beyond or 'none alone'}; add training recordings of their regime."
            + _departures_text(d)
        )
    conf = d.extra.get("confirmation")
    if conf:
        text += (
            f" ({conf['effect']} passed on the two halves, but re-identified on all windows "
            f"it does not lower J beyond the threshold: dBIC {conf['delta_bic']:.1f}; it "
            "only re-balanced the base parameters.)"
        )
    if m.per_run and m.significant:
        worst = m.per_run[0]
        ch = max(worst["channels"], key=worst["channels"].get)
        text += f" Worst run: {worst['run']} ({worst['ratio']:.1f} x its floor, most in {ch})."
    return text + _best_text(d)


def _departures_text(d: Diagnosis) -> str:
    """Where the test recordings leave the training's ranges, and what that means for a gap on
    them ("" when they stay inside)."""
    if not d.departures:
        return ""
    longest = max(d.departures, key=lambda x: x.time_share)
    return (
        f" The test recordings leave the training's ranges ({len(d.departures)} excursion(s); "
        f"the longest: {longest.text()}): there a force the training manoeuvres do not excite and "
        "base parameters they leave undetermined look alike, so the gap may be either; training "
        "recordings of that regime tell them apart."
    )


def _none_statement(d: Diagnosis) -> str:
    text = (
        "Nothing significant was found: the model fits to the noise floor and no candidate "
        "effect, fitted jointly with the base "
        f"parameters, reached dBIC <= {d.threshold:.1f} against the base model refitted "
        "by the same procedure with a held-out change of J of at least "
        f"{100 * d.settings.min_improvement:+.0f} %."
    ) + _best_text(d)
    return text + " " + misfit_text(d) + (" " + generalisation_text(d)).rstrip()


def _taken(d: Diagnosis) -> bool:
    """Whether the finding was taken with ``--take`` (not necessarily accepted)."""
    return bool(d.extra.get("taken"))


def _how_chosen(d: Diagnosis) -> str:
    c = d.chosen
    if not _taken(d):
        return "accepted on the training runs"
    state = "accepted" if c is not None and c.accepted else "not accepted"
    return f"taken with --take, {state} on the training runs"


def _acceptance_text(d: Diagnosis, c: CandidateScore) -> str:
    if not _taken(d):
        return f"accepted at <= {d.threshold:.1f}"
    if c.accepted:
        return f"accepted at <= {d.threshold:.1f}; taken with --take"
    return (
        f"NOT accepted: the threshold is {d.threshold:.1f} and it must carry over to held-out "
        "runs; taken with --take to see what it does"
    )


def _found_statement(d: Diagnosis) -> str:
    c = d.chosen
    assert c is not None
    after = d.finding_values()
    eff = get_effect(d.verdict_effect)
    units = {q.name: q.unit for q in eff.params}
    values = ", ".join(f"{k} = {v:.4g} {units[k]}" for k, v in after.items())
    if d.verdict == "shape":
        text = _shape_text(d)
        if is_closed_form(d.verdict_effect):
            values = f"{len(after)} coefficients (a level a and an amplitude b per group)"
        else:
            dof = sum(d.shape.selection.edf) if d.shape is not None else float("nan")
            values = f"{len(after)} spline coefficients ({dof:.1f} effective degrees of freedom)"
    elif d.verdict == "discovered":
        entry = discovered_entry(d)
        like = entry["resembles"]
        text = (
            f"Missing physics, discovered (no catalog entry): {entry['formula']} "
            f"(regime: {eff.regime}). "
        )
        if like:
            name, r = next(iter(like.items()))
            text += f"Its force pattern resembles {name} most (correlation {r:+.2f}). "
        text += names_shape_text(d)
    else:
        text = f"Missing physics: {eff.description} (`{d.verdict}`; regime: {eff.regime}). "
        text += names_shape_text(d)
    text += (
        f"Fitted jointly with the 57 base parameters: {values}. "
        f"Against the base model refitted by the same procedure: dBIC = {c.delta_bic:.1f} "
        f"({_acceptance_text(d, c)}); J on a held-out training window improves "
        f"typically by {100 * c.improvement:+.1f} % (geometric mean over windows; their sum "
        f"by {100 * c.improvement_total:+.1f} %)."
    )
    text += remainder_text(d)
    J = d.settings.objective
    if d.test_before:
        b, a = d.test_before[J]["Total"], d.test_after[J]["Total"]
        change = 100 * (a - b) / b
        text += f" On the test recordings {J} goes from {b:.1f} to {a:.1f} ({change:+.1f} %)."
    ga = d.generalisation_after
    if ga is not None and ga.significant:
        text += (
            f" With it the test recordings are still {ga.ratio:.1f} x what a model exact in form "
            f"would reach there ({ga.median:.3g}): more is missing than this effect."
        )
    return text


#: what each subset of the paper's test set holds (the harm statement names the manoeuvre)
SUBSET_KIND = {
    "Test-B-S": "berthing (starboard)",
    "Test-B-P": "berthing (port)",
    "Test-R": "random manoeuvres",
    "Test-T": "turning",
    "Test-Z": "zigzags",
}
#: a test subset this much worse with the finding is harmed (and the total at any worsening)
HARM_SUBSET = 0.10


def harm(d: Diagnosis) -> dict[str, Any] | None:
    """How the finding changes J on the test recordings: the total's and each subset's ratio
    after / before, the harmed subsets (worse by more than :data:`HARM_SUBSET`) and whether
    the finding does harm (total worse, or a subset harmed); None without a finding or
    without test recordings."""
    if not d.verdict_effect or not d.test_before:
        return None
    J = d.settings.objective
    before, after = d.test_before[J], d.test_after[J]
    ratio = {k: after[k] / before[k] if before[k] > 0 else float("inf") for k in before}
    harmed = [k for k, r in ratio.items() if k != "Total" and r > 1.0 + HARM_SUBSET]
    return {
        "objective": J,
        "ratio": ratio,
        "total_change": ratio["Total"] - 1.0,
        "harmed_subsets": sorted(harmed, key=lambda k: -ratio[k]),
        "harmful": bool(ratio["Total"] > 1.0 or harmed),
    }


def harm_text(d: Diagnosis) -> str:
    """The harm the finding does on the test recordings, said first in the verdict
    ("" when it does none)."""
    h = harm(d)
    if h is None or not h["harmful"]:
        return ""
    r = h["ratio"]
    change = h["total_change"]
    parts = [
        f"the test recordings are {100 * change:.0f} % worse with it"
        if change > 0
        else f"the test recordings are {100 * -change:.0f} % better in total with it"
    ]
    parts += [f"{k} x {r[k]:.2f}" for k in h["harmed_subsets"]]
    kinds = [SUBSET_KIND.get(k, k) for k in h["harmed_subsets"]]
    tail = f": it does not carry over to {', '.join(kinds)}" if kinds else ""
    return (
        f"HARM: {d.verdict_effect} ({_how_chosen(d)}; {', '.join(parts)}{tail}). "
        "Use the model before, or add training recordings of those manoeuvres."
    )


def statement(d: Diagnosis) -> str:
    """The verdict in plain words (the harm a finding does on the test recordings first)."""
    diverged = diverged_sentence(d)
    tail = " " + diverged if diverged else ""
    if d.verdict == "unexplained":
        return _unexplained_statement(d) + tail
    if d.verdict == "none":
        return _none_statement(d) + tail
    warning = harm_text(d)
    return (warning + " " if warning else "") + _found_statement(d) + tail


def diverged_sentence(d: Diagnosis) -> str:
    """The test recordings on which the model before or after diverges ("" for none): their J
    is the divergence penalty (10 x the duration per channel), so a test total with them says
    that the model leaves the recorded motion, not by how much."""
    before, after = d.test_diverged.get("before"), d.test_diverged.get("after")
    if not before and not after:
        return ""
    if before == after:  # (the same model when nothing was found)
        parts = [f"the model before and after on {diverged_text(before or {})}"]
    else:
        parts = [
            f"{label} on {diverged_text(runs)}"
            for label, runs in (("the base model", before), ("the model after", after))
            if runs
        ]
    return (
        "The simulation diverges (the limiter of Algorithm 1) on test recordings: "
        + "; ".join(parts)
        + "; there J is the divergence penalty, not a misfit."
    )


def _generalisation_dict(g: GeneralisationTest | None) -> dict[str, Any] | None:
    if g is None:
        return None
    return {
        **asdict(g),
        "ratio": g.ratio,
        "limit": g.limit,
        "method": "parametric bootstrap, identification linearised (sweep.diagnose.generalise)",
    }


def report_dict(d: Diagnosis) -> dict[str, Any]:
    """Everything of ``report.json``."""
    chosen = d.chosen
    fitted = d.finding_values()
    prop = d.proposal
    return {
        "verdict": d.verdict,
        "statement": statement(d),
        "discovered": discovered_entry(d),
        "shape": shape_entry(d),
        "names_shape": names_shape(d),
        "shapes": d.shape.as_dict() if d.shape is not None else None,
        "explainable": explainable(d),
        "memory": d.extra.get("memory"),
        "waves": d.extra.get("waves"),
        "misfit": asdict(d.misfit) if d.misfit is not None else None,
        "generalisation": _generalisation_dict(d.generalisation),
        "generalisation_after": _generalisation_dict(d.generalisation_after),
        "remainder": remainder(d),
        "noise_model": d.extra.get("noise", {}),
        "noise_first_sample": d.extra.get("noise_first_sample"),
        "discovery": (
            {
                "proposed": prop.proposed,
                "terms": prop.selection.terms,
                "shapes": prop.selection.shapes,
                "equation_coefficients": prop.selection.coefficients,
                "heldout_r2": prop.selection.cv_r2,
                "threshold": prop.threshold,
                "alpha": prop.alpha,
                "null": prop.null,
                "absorbed": prop.selection.absorbed,
                "path": prop.selection.path,
                "single_terms": prop.selection.single,
                "alternatives": [asdict(a) for a in prop.selection.alternatives],
                "regression": {
                    "terms": prop.extra.get("regression", {}).get("terms", []),
                    "channels": [
                        {"channel": c["channel"], "rms": c["rms"], "r2": c["r2"]}
                        for c in prop.extra.get("regression", {}).get("channels", [])
                    ],
                },
                "seconds": prop.seconds,
            }
            if prop is not None
            else None
        ),
        "acceptance": d.extra.get("acceptance"),
        "trajectory_discovery": d.extra.get("trajectory_discovery"),
        "confirmation": d.extra.get("confirmation"),
        "base_retry": d.extra.get("base_retry"),
        "candidates": [asdict(c) for c in d.candidates],
        "fitted_effect_params": fitted,
        "finding": d.finding_name,
        "taken": _taken(d),
        "harm": harm(d),
        "ranges": d.ranges.as_dict() if d.ranges is not None else None,
        "outside": d.settings.outside,
        "departures": [x.as_dict() for x in d.departures],
        "J_after_unbounded": d.test_unbounded,
        "test_diverged": d.test_diverged,
        "candidate_fit_params": chosen.params if chosen else {},
        "J_before": d.test_before,
        "J_after": d.test_after,
        "located_regimes": d.regimes,
        "equation_bias": d.biases,
        "worst_windows": d.windows,
        "training": {
            "windows": d.train_windows,
            "fit_windows": d.fit_windows,
            "heldout_windows": d.heldout_windows,
            "n_eff": d.n_eff,
            "J_base_fit": d.base.f,
            "J_control_fit": d.control.f,
            "J_heldout_control": d.extra.get("J_heldout_control"),
            "J_final_base": d.before.f,
            "J_final_after": d.after.f,
        },
        "settings": asdict(d.settings),
        "seconds": d.seconds,
        "stage_seconds": d.extra.get("stage_seconds", {}),
        "trust": d.extra.get("trust"),
        "params_before": d.before.params.to_dict(),
        "params_after": d.after.params.to_dict(),
    }


def _binned_energy(frame: pd.DataFrame, var: str, group: str = "velocity") -> pd.Series:
    cols = [f"res_{c}" for c in GROUPS[group]]
    clean = frame.dropna(subset=cols)
    e = (clean[cols] ** 2).sum(axis=1)
    labels = pd.cut(clean[var], bin_edges(clean)[var], right=False)
    return e.groupby(labels, observed=True).mean()


def _threshold_origin(d: Diagnosis) -> str:
    acc = d.extra.get("acceptance")
    if d.settings.max_delta_bic is not None or not acc:
        return "set by --max-delta-bic"
    return (
        f"the {100 * acc['alpha']:.0f} % quantile of the best candidate's dBIC over "
        f"{acc['draws']} noise-only copies, {acc['quantile']:.1f}, capped at {acc['ceiling']:.0f}"
    )


def plot_candidates(d: Diagnosis, path: Path) -> None:
    """dBIC (the ranking) and held-out change (the veto) of every candidate."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.2), sharey=True)
    names = [c.effect for c in d.candidates][::-1]
    colors = ["tab:green" if c.accepted else "tab:gray" for c in d.candidates][::-1]
    bic = [c.delta_bic for c in d.candidates][::-1]
    ax1.barh(names, bic, color=colors)
    ax1.axvline(d.threshold, color="k", ls="--", lw=1, label="threshold")
    ax1.set_xscale("symlog", linthresh=10.0)
    ax1.set_xlabel("dBIC vs refitted base (lower: better)")
    ax1.legend(loc="lower left", fontsize=8)
    ax2.barh(names, [100 * c.improvement for c in d.candidates][::-1], color=colors)
    ax2.axvline(100 * d.settings.min_improvement, color="k", ls="--", lw=1)
    ax2.set_xlabel("held-out change of J [%] (higher: better)")
    fig.suptitle(f"candidate effects (verdict: {d.verdict})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_regimes(
    before: pd.DataFrame, after: pd.DataFrame, variables: Sequence[str], path: Path
) -> None:
    """The mean squared standardised residual of (u, v_m, r) of the model before and after (the
    residual tables ``before``/``after``) by bin of each regime variable in ``variables``, one
    panel each, saved as PNG at ``path``."""
    fig, axes = plt.subplots(1, len(variables), figsize=(5.5 * len(variables), 3.4), squeeze=False)
    for ax, var in zip(axes[0], variables, strict=True):
        b = _binned_energy(before, var)
        a = _binned_energy(after, var)
        idx = [str(i) for i in b.index]
        x = np.arange(len(idx))
        ax.bar(x - 0.2, b.values, 0.4, label="before")
        ax.bar(x + 0.2, a.reindex(b.index).values, 0.4, label="after")
        ax.set_xticks(x, idx, rotation=30, fontsize=7)
        ax.set_xlabel(var)
        ax.set_ylabel("mean sq. std. residual\n(u, v_m, r)")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _simulate(p: Parameters, rec: Recording) -> np.ndarray:
    x = np.asarray(rec.x)
    sim = simulate_batch(
        x[None, 0],
        np.asarray(rec.u)[None, :-1],
        np.asarray(rec.w)[None, :-1],
        p,
        effects=_effects(p),
        t0=float(rec.t[0]),
    )
    return sim.states[0]


def plot_trajectories(d: Diagnosis, test: Sequence[Recording], path: Path, limit: int = 6) -> None:
    """The tracks (x0, y0 [m]) of up to ``limit`` test recordings beside the model's simulations
    before and after the diagnosis, saved as PNG at ``path``."""
    recs = list(test)[:limit]
    if not recs:
        return
    cols = min(3, len(recs))
    rows = (len(recs) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.2 * rows), squeeze=False)
    for ax, rec in zip(axes.ravel(), recs, strict=False):
        xb = _simulate(d.before.params, rec)
        xa = _simulate(d.after.params, rec)
        ax.plot(rec.x[:, 2], rec.x[:, 0], "k-", lw=1.6, label="recorded")
        ax.plot(xb[:, 2], xb[:, 0], "--", color="tab:red", label="before")
        ax.plot(xa[:, 2], xa[:, 0], "-", color="tab:blue", label="after")
        ax.set_title(rec.name[:40], fontsize=8)
        ax.set_xlabel("y0 [m]")
        ax.set_ylabel("x0 [m]")
        ax.set_aspect("equal", adjustable="datalim")
    for ax in axes.ravel()[len(recs) :]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _table_md(before: dict[str, dict[str, float]], after: dict[str, dict[str, float]]) -> str:
    if not before:
        return "(no test recordings)\n"
    labels = list(next(iter(before.values())))
    lines = ["| subset | " + " | ".join(f"{J} before | {J} after" for J in before) + " |"]
    lines.append("|---|" + "---:|---:|" * len(before))
    for lab in labels:
        cells = " | ".join(f"{before[J][lab]:.1f} | {after[J][lab]:.1f}" for J in before)
        lines.append(f"| {lab} | {cells} |")
    return "\n".join(lines) + "\n"


def _acceptance_md(d: Diagnosis) -> list[str]:
    acc = d.extra.get("acceptance")
    if not acc:
        return []
    b = acc["best_dbic"]
    lines = [
        f"A candidate is accepted at dBIC <= {d.threshold:.1f}: {_threshold_origin(d)}. "
        f"Null of the best candidate's dBIC (linearised fits of every candidate on "
        f"{acc['draws']} copies of the training windows simulated by the base model with the "
        f"estimated noise): min {b['min']:.1f}, 5 % {b['q05']:.1f}, median {b['median']:.1f}, "
        f"95 % {b['q95']:.1f}, max {b['max']:.1f}.",
        "",
        f"| candidate | null median dBIC | null {100 * acc['alpha']:.0f} % quantile | this data |",
        "|---|---:|---:|---:|",
    ]
    seen = {c.effect: c.delta_bic for c in d.candidates}
    for name, v in acc["per_candidate"].items():
        here = seen.get(name)
        if name == "discovered":
            here = next(
                (c.delta_bic for c in d.candidates if c.effect.startswith("discovered:")), None
            )
        shown = f"{here:.1f}" if here is not None else "(not proposed)"
        lines.append(f"| {name} | {v['median']:.1f} | {v['quantile']:.1f} | {shown} |")
    return lines


def _trajectory_md(d: Diagnosis) -> list[str]:
    tr = d.extra.get("trajectory_discovery")
    acc = d.extra.get("acceptance") or {}
    if not tr:
        return []
    q = acc.get("per_candidate", {}).get("discovered", {}).get("quantile")
    limit = min(q, acc.get("ceiling", -10.0)) if q is not None else float("nan")
    path = ", ".join(
        f"{t} ({100 * v:+.1f} %)" for t, v in zip(tr["terms"], tr["heldout_gain"], strict=False)
    )
    chosen = " + ".join(tr["terms"]) or "no term"
    verdict = "proposed" if tr["terms"] and tr["dbic"] <= limit else "not proposed"
    return [
        f"Trajectory residuals (linearised output error, the base's 57 parameters refitted): "
        f"forward selection by held-out gain {path or '(none)'}; chosen {chosen} at "
        f"linearised dBIC {tr['dbic']:.1f} "
        f"against the null's {100 * acc.get('alpha', 0.05):.0f} % quantile {limit:.1f} -> "
        f"{verdict}.",
        "",
    ]


def _generalisation_md(d: Diagnosis) -> list[str]:
    g = d.generalisation
    if g is None:
        return []
    return [
        "### On the test recordings: does the model carry over?",
        "",
        generalisation_text(d),
        "",
        "| test run | J | null median | null quantile | J / median | beyond the limit |",
        "|---|---:|---:|---:|---:|---|",
        *(
            f"| {r['run']} | {r['J']:.3g} | {r['median']:.3g} | {r['quantile']:.3g} | "
            f"{r['ratio']:.2f} | {'yes' if r['significant'] else 'no'} |"
            for r in g.per_run
        ),
        "",
    ]


def _discovery_md(d: Diagnosis) -> list[str]:
    p = d.proposal
    if p is None:
        return ["(discovery switched off)"]
    sel = p.selection
    lines = [
        *_trajectory_md(d),
        f"Selected: {' + '.join(sel.labels or sel.terms) or 'no term'}; held-out R^2 of the "
        "equation residual "
        f"{100 * sel.cv_r2:.2f} % against the null's {100 * (1 - p.alpha):.0f} % quantile "
        f"{100 * p.threshold:.2f} % ({len(p.null)} noise-only copies of the windows: "
        f"{', '.join(f'{100 * v:.2f}' for v in sorted(p.null))} %) -> "
        + ("proposed as a candidate." if p.proposed else "not proposed."),
        "",
        *(
            f"Alternative without the {a.without} terms: {' + '.join(a.labels or a.terms)}, "
            f"held-out R^2 {100 * a.cv_r2:.2f} %"
            + (" (proposed beside it; the trajectories decide)." if p.proposed else ".")
            for a in sel.alternatives
        ),
        *([""] if sel.alternatives else []),
        "| term (alone) | force | held-out R^2 | absorbed by the base |",
        "|---|---|---:|---:|",
    ]
    from mmg.library import term

    for r in sel.single[:8]:
        label = str(r["term"])  # the term with its shape grid point, if it has one
        t = term(str(r.get("id", label)))
        lines.append(
            f"| {label} | {t.force_formula()} | {100 * float(r['cv_r2']):.2f} % | "
            f"{100 * float(r['absorbed']):.0f} % |"
        )
    return lines


def plot_regression(view: dict[str, Any], path: Path) -> None:
    """Partial-regression plots of the equation residual: one row per channel, one column per
    term (binned means, the fitted line through the origin)."""
    channels = view["channels"]
    terms = view["terms"]
    if not terms:
        return
    fig, axes = plt.subplots(
        len(channels), len(terms), figsize=(3.6 * len(terms), 2.6 * len(channels)), squeeze=False
    )
    for i, ch in enumerate(channels):
        by_term = {p["term"]: p["points"] for p in ch["partial"]}
        for j, t in enumerate(terms):
            ax = axes[i][j]
            pts = by_term.get(t, [])
            if pts:
                x = np.array([q[0] for q in pts])
                y = np.array([q[1] for q in pts])
                ax.plot(x, y, "o", ms=4, color="C0")
                lim = np.array([x.min(), x.max()])
                ax.plot(lim, lim, "-", color="C3", lw=1)
            else:
                ax.text(0.5, 0.5, "term absent here", ha="center", transform=ax.transAxes)
            ax.axhline(0.0, color="0.7", lw=0.6)
            if i == 0:
                ax.set_title(t, fontsize=9)
            if j == 0:
                ax.set_ylabel(f"{ch['channel']}\nresidual (R^2 {100 * ch['r2']:.0f} %)", fontsize=8)
            if i == len(channels) - 1:
                ax.set_xlabel("term's fitted contribution", fontsize=8)
    fig.suptitle(
        "equation residual (base regressors projected out, units of its RMS) against each term",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _regression_md(view: dict[str, Any]) -> list[str]:
    terms = view.get("terms", [])
    if not terms:
        return []
    lines = [
        "",
        f"Regression view of the equation residual on {' + '.join(terms)} (the base model's "
        "own regressors projected out): the share of each channel's residual these terms "
        "explain, and the partial-regression plots in `equation_residuals.png`.",
        "",
        "| channel | residual explained (R^2) |",
        "|---|---:|",
    ]
    lines += [f"| {c['channel']} | {100 * c['r2']:.1f} % |" for c in view["channels"]]
    return [*lines, "", "![equation residuals](equation_residuals.png)"]


def write_figures(
    d: Diagnosis, test: Sequence[Recording], out: Path, view: dict[str, Any]
) -> list[str]:
    """The report's plots in ``out``: candidates, the regression ``view`` of the equation
    residual (when it has terms) and, with test recordings, residual by regime and
    trajectories; returns their file names."""
    plot_candidates(d, out / "candidates.png")
    figures = ["candidates.png"]
    if d.verdict == "shape":
        plot_shapes(d, out / "shapes.png")
        figures.append("shapes.png")
    if view.get("terms"):
        plot_regression(view, out / "equation_residuals.png")
        figures.append("equation_residuals.png")
    if test:
        fb = residual_frame(d.before.params, test, _effects(d.before.params))
        fa = residual_frame(d.after.params, test, _effects(d.after.params))
        variables = []
        if d.regimes:
            variables.append(str(d.regimes[0]["variable"]))
        if d.verdict in EFFECT_REGIME_VARIABLE:
            variables.append(EFFECT_REGIME_VARIABLE[d.verdict])
        known = bin_edges(fb)
        variables = list(dict.fromkeys(v for v in variables if v in known)) or ["delta_deg"]
        plot_regimes(fb, fa, variables, out / "residual_vs_regime.png")
        plot_trajectories(d, test, out / "trajectories.png")
        figures += ["residual_vs_regime.png", "trajectories.png"]
    return figures


def plot_shapes(d: Diagnosis, path: Path) -> None:
    """Each learned shape f(z) over its range and a little beyond (held there)."""
    entry = shape_entry(d)
    curves = [g for g in entry["groups"] if g["variable"] != "1"]
    if not curves:
        return
    from mmg.shapes import curve, parse

    groups = {g.text: g for g in parse(entry["effect"])}
    fig, axes = plt.subplots(1, len(curves), figsize=(4.5 * len(curves), 3.4), squeeze=False)
    for ax, g in zip(axes[0], curves, strict=True):
        lo, hi = g["range"]
        pad = 0.15 * (hi - lo)
        z = np.linspace(lo - pad, hi + pad, 300)
        group = groups[g["group"]]
        if group.tensor:
            _plot_surface(ax, group, g, z)
            continue
        f = curve(group, g["coefficients"], z)
        ax.plot(z, f, "C0")
        names = [f"s{list(groups).index(g['group'])}_{g['component']}{j}" for j in range(group.n)]
        band = _band(d, group, names, z)
        if band is not None:
            level = (d.extra.get("trust") or {}).get("after", {}).get("level", 0.9)
            half = np.asarray(band)
            ax.fill_between(
                z, f - half, f + half, color="C0", alpha=0.25, lw=0, label=f"{level:.0%} band"
            )
        ax.axvspan(lo, hi, color="C0", alpha=0.08, label="learnt over")
        learned = _learned_curve(d, group, g["component"], z) if group.form else None
        if learned is not None:
            ax.plot(z, learned, "C1--", lw=1, label="learned shape")
        if g.get("closed_form"):
            ax.set_title(g["formula"], fontsize=7)
        elif g.get("closest"):
            c = g["closest"][0]
            ax.set_title(f"closest: {c['formula']} (R^2 {c['r2']:.2f})", fontsize=8)
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel(f"{g['variable']} [{g['unit']}]")
        along = BASIN.get(g["component"])  # a force fixed to the basin: along its axis
        ax.set_ylabel(f"f_{g['component']} [-]" + (f", along {along}" if along else ""))
        ax.legend(fontsize=7)
    title = "named after its learned shape" if entry["closed_form"] else "learned shape(s)"
    fig.suptitle(f"{title}: {entry['effect']}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_surface(ax: Any, group: Any, g: dict[str, Any], z: Any) -> None:
    """A shape of two variables as curves f(z) at five values of the second variable."""
    from mmg.shapes import surface

    for k, z2 in enumerate(g["z2"]):
        f = surface(group, g["coefficients"], z, np.full_like(z, z2))
        ax.plot(z, f, f"C{k}", label=f"{g['variable2']} = {z2:.3g} {g['unit2']}")
    ax.axvspan(*g["range"], color="C0", alpha=0.08)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel(f"{g['variable']} [{g['unit']}]")
    ax.set_ylabel(f"f_{g['component']} [-]")
    if g.get("closed_form"):  # a product of closed forms: its formula
        ax.set_title(g["formula"], fontsize=7)
    else:
        ax.set_title(f"a shape of {g['variable']} and {g['variable2']}", fontsize=8)
    ax.legend(fontsize=6)


def _learned_curve(d: Diagnosis, form: Any, component: str, z: Any) -> Any:
    """The learned spline shape a closed-form group was named after (the same component,
    variable, multiplier and scaling), as the candidate's fit gave it, at z; None if absent."""
    from mmg.shapes import curve, parse

    c = shape_and_form(d.candidates)[0]
    if c is not None:
        for k, g in enumerate(parse(c.effect)):
            same = (g.variable, g.multiplier, g.scale_name) == (
                form.variable,
                form.multiplier,
                form.scale_name,
            )
            if same and not g.form and component in g.components:
                coef = [c.params.get(f"s{k}_{component}{j}", 0.0) for j in range(g.n)]
                return curve(g, coef, z)
    return None


def _variables_md(variables: Sequence[str], chosen: bool) -> str:
    """The variables the shapes were made of, in words: ``chosen`` by the user
    (``--shape-variables``), else the default, which holds heading, position and time only
    when the training runs come from several sessions."""
    if chosen:
        why = "chosen with --shape-variables"
    elif any(v in PLACE_AND_TIME for v in variables):
        why = (
            "heading, position and time among them: the training runs come from several "
            "sessions, and a shape in them must carry over to another session's runs too"
        )
    else:
        why = "without heading, position and time, which one session's runs cannot check"
    return f"Candidate groups in {', '.join(variables)} ({why})."


def _memory_probe_md(memory: dict[str, Any] | None) -> list[str]:
    """The probe of the controls' memories by their closed forms
    (:mod:`sweep.diagnose.memory`), a paragraph; none where no control moves."""
    if not memory or not memory.get("effect"):
        return []
    return [
        "Memories of the controls, probed by their closed forms at finite sizes (a rate limit "
        "and play; the catalog's actuator_lag is the lag), which the shapes' columns, linearised "
        f"where the controls act as logged, do not show: {len(memory['trials'])} sizes, the "
        f"best `{memory['effect']}` at c = {memory['start'][0]:.4g}, linearised dBIC "
        f"{memory['dbic']:.1f} against the null's quantile {memory['threshold']:.1f} "
        f"({len(memory['null'])} noise-only copies): "
        + ("proposed." if memory["proposed"] else "not proposed."),
        "",
    ]


def _waves_probe_md(waves: dict[str, Any] | None) -> list[str]:
    """The probe of forces periodic in the recording's time (:mod:`sweep.diagnose.waves`), a
    paragraph; none where it did not run."""
    if not waves or not waves.get("effect"):
        return []
    text = (
        "Forces periodic in the recording's time, probed by their closed forms (a spline of time "
        "learnt on some runs says nothing of the times only other runs cover; a period does): "
        f"{waves['periods']} periods, the best linearised dBIC {waves['dbic']:.1f} against the "
        f"null's quantile {waves['threshold']:.1f} ({len(waves['null'])} noise-only copies): "
    )
    if not waves["proposed"]:
        return [text + "not proposed.", ""]
    scan = waves.get("scan") or []
    best = min(scan, key=lambda row: row["J"]) if scan else None
    text += (
        f"proposed; the basin's components fitted by output error at {len(scan)} periods, "
        f"the lowest training J {best['J']:.4g} at {best['period']:.1f} s: candidate "
        f"`{waves['effect']}`."
        if best is not None
        else "proposed."
    )
    return [text, ""]


def _shape_md(d: Diagnosis) -> list[str]:
    """The learned shape: formula, table and plot (verdict ``shape``), or the selection's
    result otherwise."""
    sp = d.shape
    if sp is None:
        return []
    sel = sp.selection
    md = [
        "## Learned shape of the missing force",
        "",
        _variables_md(sp.variables, bool(d.settings.shape_variables)),
        "",
        f"{'Groups chosen on the trajectory residuals' if sp.chosen is None else 'Groups kept'}: "
        f"`{sel.spec or 'none'}`; effective degrees "
        f"of freedom {sum(sel.edf):.1f}; held-out gain "
        + ", ".join(f"{100 * g:.0f} %" for g in sel.heldout_gain)
        + f" of the control's held-out J; linearised dBIC {sel.dbic:.1f} against the null's "
        f"quantile {sp.threshold:.1f} ({len(sp.null)} noise-only copies): "
        + ("proposed." if sp.proposed else "not proposed.")
        + drift_text(
            sp.drift.as_dict() if sp.drift is not None else None,
            sel.heldout_gain[-1] if sel.heldout_gain else 0.0,
        ),
        "",
    ]
    md += _memory_probe_md(d.extra.get("memory"))
    md += _waves_probe_md(d.extra.get("waves"))
    if sp.pairs is not None:
        pr = sp.pairs
        verdict = "taken" if pr["taken"] else "not taken"
        against = (
            f" against its null's quantile {pr['threshold']:.1f}"
            if pr.get("threshold") is not None
            else " (no surface among its groups)"
        )
        md += [
            f"Shapes of two variables: {len(pr['pairs'])} interactions of the first group's "
            f"variable among the candidates; chosen `{pr['selection'] or 'none'}`, linearised "
            f"dBIC {pr['dbic']:.1f}{against}: {verdict}.",
            "",
        ]
    if sp.screened:
        md += [
            "First group checked by output error among the single groups within "
            f"{SCREEN_SHARE:.0%} of the best linearised one (each fitted alone with the 57 "
            "parameters on one half of the runs and judged on the other, led by the best "
            "typical held-out window; its change, the held-out gain [J] and the linearised "
            "share): "
            + "; ".join(
                f"`{x.group}` {100 * x.typical:+.1f} %, {x.heldout_gain:.4g} "
                f"({100 * x.linearised:.0f} %)"
                for x in sp.screened
            )
            + ".",
            "",
        ]
    if sp.chosen is not None:
        md += [
            f"Chosen on the trajectory residuals: `{sp.chosen.spec}`. Backward check by output "
            "error, each shape fitted with the 57 parameters on one half of the runs and judged "
            f"on the other (a group stays when it makes the typical held-out window "
            f"{MIN_GAIN:.0%} better, on a log scale, than the rest alone): "
            + "; ".join(
                f"`{x.group}` left out (typical held-out window {100 * x.typical_with:+.1f} % "
                f"with it, {100 * x.typical_without:+.1f} % without; held-out gain "
                f"{x.gain_with:.4g} and {x.gain_without:.4g})"
                for x in sp.dropped
            )
            + ".",
            "",
        ]
    entry = shape_entry(d)
    for g in entry.get("groups", []):
        md += [f"`{g['formula']}`", ""]
        if g["variable"] == "1":
            md += [f"value {g['coefficients'][0]:.4g}", ""]
            continue
        if "memory" in g:
            md += _memory_md(g["memory"])
        if "surface" in g:
            md += _surface_md(g)
            continue
        band = g.get("band") or [float("nan")] * len(g["z"])
        md += [f"| {g['variable']} [{g['unit']}] | f | +- (band) |", "|---:|---:|---:|"]
        md += [
            f"| {z:.4g} | {f:.4g} | {'-' if not np.isfinite(b) else f'{b:.2g}'} |"
            for z, f, b in zip(g["z"], g["f"], band, strict=True)
        ]
        if "memory" in g:
            md += ["", "Closest closed forms of a memory (share of the memory kept):", ""]
            md += [
                f"- {c['family']} ({c['formula']}), coefficient {c['a']:.3g}: {c['r2']:.2f}"
                for c in g["closest"]
            ]
        else:
            md += ["", "Closest closed forms (a + b g, share of the shape's variance kept):", ""]
            md += [
                f"- {c['a']:.3g} + {c['b']:.3g} {c['formula']}: R^2 {c['r2']:.2f}"
                for c in g["closest"]
            ]
        md.append("")
    if entry:
        md += ["![learned shape](shapes.png)", ""]
    return md


def _surface_md(g: dict[str, Any]) -> list[str]:
    """A shape of two variables as a table: f at the first variable's values (rows) and the
    second's (columns)."""
    head = f"| {g['variable']} [{g['unit']}] \\ {g['variable2']} [{g['unit2']}] | " + " | ".join(
        f"{v:.3g}" for v in g["z2"]
    )
    md = [head + " |", "|---:|" + "---:|" * len(g["z2"])]
    md += [
        f"| {z:.3g} | " + " | ".join(f"{v:.4g}" for v in row) + " |"
        for z, row in zip(g["z"], g["surface"], strict=True)
    ]
    return [*md, ""]


def _memory_md(m: dict[str, Any]) -> list[str]:
    """A memory of a control as a table of the steps it lets the control take."""
    c, u, dt = m["control"], m["unit"], m["time_step"]
    md = [
        f"A memory of the {c}: in each time step of {dt:.3g} s the acting {c} closes the gap "
        f"to the logged one except for the share f. A constant share is a first-order lag; a "
        f"step that stops growing with the gap is a rate limit; no step below a gap is play."
        + (
            f" The gap is signed away from zero: + where the {c} moves away from 0 (midships, "
            "rest), - where it moves back."
            if m.get("away")
            else ""
        ),
        "",
        f"| gap [{u}] | share left open f | step in {dt:.3g} s [{u}] | as a rate [{u}/s] |",
        "|---:|---:|---:|---:|",
    ]
    md += [
        f"| {e:.3g} | {f:.3f} | {s:.3g} | {r:.3g} |"
        for e, f, s, r in zip(m["gap"], m["share"], m["step"], m["rate"], strict=True)
    ]
    return [*md, ""]


def _misfit_md(d: Diagnosis) -> list[str]:
    return [
        "## Is anything missing? The misfit against the noise floor",
        "",
        misfit_text(d),
        "",
        "| run | J / floor | z | worst channel |",
        "|---|---:|---:|---|",
        *(
            f"| {r['run']} | {r['ratio']:.2f} | {r['z']:.1f} | "
            f"{max(r['channels'], key=r['channels'].get)} |"
            for r in (d.misfit.per_run[:8] if d.misfit else [])
        ),
        "",
    ]


def _location_md(d: Diagnosis) -> list[str]:
    md = [
        "## Where the base model misses (training windows)",
        "",
        "| regime variable | channels | eta^2 | worst bin | worst / mean |",
        "|---|---|---:|---|---:|",
    ]
    for r in d.regimes[:6]:
        md.append(
            f"| {r['variable']} | {r['group']} | {r['eta2']:.2f} | {r['worst_bin']} | "
            f"{r['worst_ratio']:.1f} |"
        )
    md += ["", "Equation residuals with the strongest bias (recorded - model acceleration):", ""]
    md += ["| regime bin | acceleration | mean | t |", "|---|---|---:|---:|"]
    for b in d.biases[:6]:
        md.append(
            f"| {b['variable']} {b['bin']} | {b['channel']} | {b['mean']:.3g} | {b['t']:.1f} |"
        )
    return md


def _candidates_md(d: Diagnosis) -> list[str]:
    md = [
        "## Candidates (fitted jointly with the 57 base parameters)",
        "",
        "| effect | dBIC | held-out improvement (typical) | (summed J) | held-out gain "
        "| runs better | worst run | largest run loss / its noise J | carries over | accepted "
        "| fitted parameters |",
        "|---|---:|---:|---:|---:|---:|---:|---:|:-:|:-:|---|",
    ]
    for c in d.candidates:
        vals = ", ".join(f"{k} = {v:.4g}" for k, v in c.params.items())
        md.append(
            f"| {c.effect}{' *' if c.refined else ''} | {c.delta_bic:.1f} | "
            f"{100 * c.improvement:+.1f} % | {100 * c.improvement_total:+.1f} % | "
            f"{c.heldout_gain:.4g} | {c.runs_better} of {len(c.run_changes)} | "
            f"{100 * c.worst_run_change:+.0f} % | {c.worst_run_excess:.2f} | "
            f"{_carries_md(c)} | "
            f"{'yes' if c.accepted else 'no'} | {vals} |"
        )
    held = (d.extra.get("acceptance") or {}).get("heldout")
    if held:
        within = d.misfit is not None and not d.misfit.significant
        scale = (
            "of that run's noise J for every candidate (the base's misfit is within the noise "
            "floor, so a catalog effect's too; else it is judged relative to the control's J of "
            "the run)"
            if within
            else "of the control's J of that run for a catalog effect, of that run's noise J for "
            "library terms and learned shapes (chosen on all training windows, so their "
            "held-out gains are biased in their favour)"
        )
        md += [
            "",
            f"Carrying over: a candidate's fits on one half must take more than "
            f"{held['threshold']:.4g} off the control's {d.settings.objective} on the other "
            f"half's whole runs (held-out gain, both ways round): the {100 * held['q']:.0f} % "
            f"quantile of the best candidate's held-out gain on noise-only copies of the "
            f"training windows, {100 * held['quantile']:.1f} % of the noise's J "
            f"({held.get('noise_J', float('nan')):.3g}), and at least 0; make more held-out runs "
            f"better than worse; and make no held-out run worse by more than "
            f"{100 * held.get('worst_run_limit', 0.0):.0f} % (the same quantile of the best "
            f"catalog candidate's worst held-out run) {scale}; a run "
            f"worse by at most {100 * NEGLIGIBLE:.0f} % of its J is not counted. A library "
            "term or shape of the heading, the position or the time, and a memory of a control, "
            "must carry over alike to another session's runs (fitted on some days' runs, judged "
            "on the others'): "
            '"no (one session)" when all training runs are of one day, "no (other '
            'sessions)" when it does not.',
        ]
    md += _transfer_md(d)
    return [*md, "", "![candidates](candidates.png)", ""]


def _transfer_md(d: Diagnosis) -> list[str]:
    """The transfer check of the generated candidates refused by their held-out runs
    (:mod:`sweep.diagnose.transfer`)."""
    checked = [c for c in d.candidates if c.transfer_checked]
    if not checked:
        return []
    md = [
        "",
        "Transfer check (a library term or shape, or within the noise floor a catalog effect, "
        "that makes more held-out runs better than worse but is refused by its worst held-out "
        "run, or by a held-out gain below the null's): its "
        "effect as fitted on one half of the runs held fixed, the 57 base parameters refitted on "
        "the other half from the control's fit of it, against that fit continued without the "
        "effect. It carries over when the summed J falls, more runs get better than worse, no "
        "run gets worse by more than the limit of a catalog effect's held-out run, and the gain "
        "on runs the effect was not fitted on beats the held-out null here or on the held-out "
        "runs. When it passes and the runs are of several sessions, it must carry over "
        "across sessions too (held as fitted on some sessions' runs, the base refitted on the "
        "others': their summed J falls, more runs get better than worse, none worse than the "
        "limit).",
        "",
        "| effect | J against the control refitted alike | runs better | worst run "
        "| carries over |",
        "|---|---:|---:|---:|:-:|",
    ]
    for c in checked:
        rows = [("", c.transfer_change, c.transfer_run_changes)]
        if c.session_transfer_checked:
            rows.append(
                (" (across sessions)", c.session_transfer_change, c.session_transfer_run_changes)
            )
        for where, change, ch in rows:
            md.append(
                f"| {c.effect}{where} | {100 * change:+.1f} % | "
                f"{sum(v < 0 for v in ch.values())} of {len(ch)} | "
                f"{100 * max(ch.values(), default=0.0):+.0f} % | "
                f"{'yes' if c.carries_over else 'no'} |"
            )
    return md


def _carries_md(c: CandidateScore) -> str:
    """The table's "carries over" cell: yes, no, or why a candidate tied to heading, position or
    time does not (:mod:`sweep.diagnose.sessions`)."""
    if c.carries_over:
        return "yes (transfer check)" if c.transfer_checked else "yes"
    if c.session_transfer_checked and c.sessions_carry:
        return "no (transfer check across sessions)"
    if not c.sessions_carry:
        return "no (one session)" if c.sessions == "one session" else "no (other sessions)"
    return "no"


def _test_md(d: Diagnosis, test: Sequence[Recording]) -> list[str]:
    md = [
        f"## Test recordings: J before and after (the base model refitted vs with `{d.verdict}`)",
        "",
        _table_md(d.test_before, d.test_after),
    ]
    if d.test_diverged:
        md += [diverged_sentence(d), ""]
    if test:
        md += [
            "![residual vs regime](residual_vs_regime.png)",
            "",
            "![trajectories](trajectories.png)",
            "",
        ]
    return md


def _ranges_md(d: Diagnosis) -> list[str]:
    """Where the finding holds: the training ranges, its box, the test recordings beyond them
    and the test subsets with the finding held and extrapolated."""
    if d.ranges is None:
        return []
    from sweep.data.ranges import QUADRANTS, VARIABLES

    how = {
        "held": "held at its value on the boundary of that box (above the top speed: its "
        "non-dimensional force, so it still grows with U^2)",
        "off": "switched off",
    }[d.settings.outside]
    if d.verdict_effect:
        head = [
            "## Where the finding holds",
            "",
            f"`{d.verdict_effect}` was fitted on training recordings that cover the ranges "
            f"below. Beyond the box of their states it is {how} (`--outside "
            f"{d.settings.outside}`): `{d.finding_name}`.",
        ]
    else:
        head = [
            "## Where the model was fitted",
            "",
            "No finding was accepted. The training recordings cover the ranges below; a model "
            "identified on them is known only there, and a finding would act only in their box.",
        ]
    md = [
        *head,
        "",
        "| variable | lowest | highest | unit |",
        "|---|---:|---:|---|",
        *(
            f"| {k} | {lo:.4g} | {hi:.4g} | {VARIABLES[k]} |"
            for k, (lo, hi) in d.ranges.intervals.items()
        ),
        "",
        "Quadrants: "
        + ", ".join(f"{q} ({QUADRANTS[q]}) {100 * v:.0f} %" for q, v in d.ranges.quadrants.items())
        + ".",
        "",
    ]
    if d.departures:
        md += ["Test recordings beyond the fitted ranges:", ""]
        md += [f"- {x.text()}" for x in d.departures]
        md.append("")
    elif d.test_before:
        md += ["No test recording leaves the fitted ranges.", ""]
    J = d.settings.objective
    if d.test_before and d.verdict_effect:
        md += [
            f"{J} per test subset: the model before, with the finding as used (bounded), and "
            "with it extrapolated beyond the ranges:",
            "",
            "| subset | before | with the finding | change | extrapolated |",
            "|---|---:|---:|---:|---:|",
        ]
        unb = d.test_unbounded.get(J, {})
        for k, b in d.test_before[J].items():
            a = d.test_after[J][k]
            e = unb.get(k, a)
            md.append(f"| {k} | {b:.4g} | {a:.4g} | {100 * (a / b - 1):+.1f} % | {e:.4g} |")
        md.append("")
    return md


def _trust_md(d: Diagnosis) -> list[str]:
    """How well the training windows determine the models before and after, and their standard
    manoeuvres with intervals (:mod:`sweep.diagnose.trust`)."""
    trust = d.extra.get("trust")
    if not trust:
        return []
    from sweep.diagnose.trust import trust_markdown

    return [
        "## How sure: the models before and after",
        "",
        "Parameter intervals from the training windows (guide: uncertainty) and the standard "
        "manoeuvres they leave (guide: manoeuvres), full scale:",
        "",
        trust_markdown(trust),
        "",
    ]


def base_routes_text(retry: dict[str, float] | None, J_base: float) -> str:
    """Where each of the base's routes ended (the ``base_retry`` record), the base's own end
    marked: ``""`` when there is no record (the second start switched off)."""
    if not retry:
        return ""
    labels = (
        ("J_route1", "CMA-ES then Levenberg-Marquardt"),
        ("J_route2", "Levenberg-Marquardt alone"),
        ("J_second", "second start"),
        ("J_horizons", "descent over growing horizons"),
    )
    ends = [(label, retry[k]) for k, label in labels if k in retry]
    kept = min(ends, key=lambda e: abs(e[1] - J_base))[0] if ends else ""
    parts = [f"{label} {f:.2f}" + (" (the base)" if label == kept else "") for label, f in ends]
    skipped = "; the two routes agree, no second start" if retry.get("skipped") else ""
    return "; ends: " + ", ".join(parts) + skipped if parts else ""


def _procedure_md(d: Diagnosis) -> list[str]:
    s = d.settings
    return [
        "## Procedure",
        "",
        f"{d.train_windows} training windows in two halves of {d.fit_windows} and "
        f"{d.heldout_windows}; base identification on all of them: {d.base.evaluations} "
        f"evaluations (CMA-ES {s.base_budget} then Levenberg-Marquardt, and "
        f"Levenberg-Marquardt alone for up to {s.base_lm_iterations} iterations; the "
        "lower end kept"
        + (
            f"; where they ended more than {100 * s.base_retry_agreement:g} % apart, a second "
            "CMA-ES start and the descent over the windows cut to "
            + ", ".join(f"{h:g}" for h in s.base_horizons)
            + " s in turn, then over the windows"
            if s.horizons_on
            else ""
        )
        + base_routes_text(d.extra.get("base_retry"), d.base.f)
        + "), J = "
        f"{d.base.f:.2f}. Control: fitted on each half from the base; each candidate from "
        "two starts, the control's fit of that half and the base, the first end kept unless the "
        f"other fits more than {100 * s.base_retry_agreement:.0f} % better (effect grid "
        f"{s.effect_only_budget} evaluations, then up to {s.polish_iterations} "
        "Levenberg-Marquardt iterations on base and effect jointly); both judged on the other "
        "half; "
        f"the {s.refine_top} leading candidates (marked *) and the control continued "
        f"with up to {s.refine_iterations} more iterations; "
        "dBIC from both fits. Re-identification on all training windows (up to "
        f"{s.final_polish_iterations} iterations); objective {s.objective}, "
        f"seed {s.seed}; {d.seconds:.0f} s in all. Ranking: lowest dBIC; accepted if "
        f"dBIC <= {d.threshold:.1f} ({_threshold_origin(d)}), a held-out gain above the "
        "null's (carries over) and held-out improvement >= "
        f"{100 * s.min_improvement:.0f} % (typical window: 1 - the geometric mean "
        "of the per-window ratios of J).",
        "",
    ]


def held_findings(d: Diagnosis) -> list[str]:
    """The names of the effects the diagnosed model carries, held at their values (a later
    round's earlier findings, or the effects of ``--params``)."""
    return [n for n, _ in d.base.params.effects]


def rounds_dict(rounds: Sequence[Diagnosis]) -> list[dict[str, Any]]:
    """Each round's verdict, finding, the model after on the training windows (J, against the
    floor) and the test recordings' J total before and after."""
    rows = []
    for k, r in enumerate(rounds, start=1):
        m = r.misfit
        rows.append(
            {
                "round": k,
                "dir": round_dir(Path("."), k).as_posix(),
                "verdict": r.verdict,
                "finding": r.finding_name,
                "J_train_after": float(r.after.f),
                "floor": m.floor if m is not None else None,
                "more_missing": r.more_missing,
                "J_test_before": {J: t.get("Total") for J, t in r.test_before.items()},
                "J_test_after": {J: t.get("Total") for J, t in r.test_after.items()},
            }
        )
    return rows


def rounds_md(rounds: Sequence[Diagnosis], here: int) -> list[str]:
    """The section on the diagnosis's rounds, in the report of round ``here`` (1-based)."""
    if len(rounds) < 2:
        return []
    obj = rounds[0].settings.objective
    md = [
        "## Rounds",
        "",
        "A finding that leaves the training windows above the noise floor is followed by another "
        "round: the model with the finding (held at its values, the base parameters refitted "
        "around it) is diagnosed for what is missing beyond it. The final model is the last "
        "round's with a finding.",
        "",
        f"| round | verdict | finding | training {obj} after (noise floor) | test {obj} before "
        "-> after | report |",
        "|---:|---|---|---|---|---|",
    ]
    for row in rounds_dict(rounds):
        k = row["round"]
        floor = f" ({row['floor']:.3g})" if row["floor"] is not None else ""
        tb, ta = row["J_test_before"].get(obj), row["J_test_after"].get(obj)
        test = f"{tb:.4g} -> {ta:.4g}" if tb is not None and ta is not None else "-"
        path = Path("." if here == 1 else "..", row["dir"], "report.md").as_posix()
        link = "this one" if k == here else f"[report]({path})"
        finding = f"`{row['finding']}`" if row["finding"] else "-"
        md.append(
            f"| {k} | `{row['verdict']}` | {finding} | {row['J_train_after']:.4g}{floor} | "
            f"{test} | {link} |"
        )
    return [*md, ""]


def report_md(
    d: Diagnosis,
    statement_text: str,
    test: Sequence[Recording],
    view: dict[str, Any],
    rounds: Sequence[Diagnosis] = (),
) -> str:
    """The text of ``report.md``: the verdict's ``statement_text``, the rounds (when there were
    several), then one section per stage."""
    held = held_findings(d)
    carries = (
        [
            "The model diagnosed carries "
            + ", ".join(f"`{n}`" for n in held)
            + ": held at its values, its base parameters refitted around it.",
            "",
        ]
        if held
        else []
    )
    here = next((k for k, r in enumerate(rounds, start=1) if r is d), 1)
    md = [
        "# Diagnosis report" + (f", round {here}" if len(rounds) > 1 else ""),
        "",
        f"**Verdict: `{d.verdict}`.** {statement_text}",
        "",
        *carries,
        *rounds_md(rounds, here),
        *_misfit_md(d),
        *_generalisation_md(d),
        "## Discovery: equation-level residuals regressed on the term library",
        "",
        *_discovery_md(d),
        *_regression_md(view),
        "",
        "## Acceptance threshold, calibrated on these windows",
        "",
        *_acceptance_md(d),
        "",
        *_location_md(d),
        "",
        *_candidates_md(d),
        *_test_md(d, test),
        *_ranges_md(d),
        *_shape_md(d),
        *_trust_md(d),
        *_procedure_md(d),
    ]
    return "\n".join(md)


def write_report(
    d: Diagnosis, test: Sequence[Recording], out: Path, rounds: Sequence[Diagnosis] = ()
) -> dict[str, Any]:
    """Write report.json, report.md, the parameter files and the plots into ``out``; returns
    the report dict (with the figures' file names). ``rounds``: every round of the diagnosis
    ``d`` is one of (:func:`sweep.diagnose.run.diagnose_rounds`), shown in each report."""
    out.mkdir(parents=True, exist_ok=True)
    data = report_dict(d)
    data["held_findings"] = held_findings(d)
    if len(rounds) > 1:
        data["rounds"] = rounds_dict(rounds)
    (out / "report.json").write_text(json.dumps(data, indent=2, default=float) + "\n")
    d.before.params.save_json(out / "params_before.json", stage="base model, re-identified")
    d.after.params.save_json(
        out / "params_after.json", stage=f"with effect {d.verdict_effect or d.verdict}"
    )
    view = d.proposal.extra.get("regression", {}) if d.proposal is not None else {}
    figures = write_figures(d, test, out, view)
    (out / "report.md").write_text(report_md(d, data["statement"], test, view, rounds))
    data["figures"] = figures
    return data
