"""How far to trust a diagnosed model: its parameters' intervals and what they do to the standard
manoeuvres, as a JSON-ready summary for the models before and after a diagnosis.

:func:`trust_of` judges one parameter set on the windows it was fitted on
(:func:`sweep.identification.uncertainty.parameter_uncertainty`: intervals, statuses and the
directions the data leave flat), draws parameter vectors from those intervals and runs the
standard manoeuvres (and, given recorded runs, the recorded turning and zigzag runs) on the
estimate and every draw (:mod:`sweep.data.standard_manoeuvres`), so that each manoeuvre quantity
has a point value and a 5-95 % interval. :func:`trust_markdown` sets several summaries side by
side. About 1-3 s for the intervals and 1 s for 50 draws' manoeuvres on one core.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mmg import Effect, Parameters, get_effect
from sweep.data.manoeuvre_tables import recorded_table, standard_table
from sweep.data.recordings import Recording
from sweep.data.standard_manoeuvres import RecordedRun, compare_recorded, predict_standard
from sweep.identification.uncertainty import DETERMINED, parameter_uncertainty

#: parameter vectors drawn from the intervals for the manoeuvres' intervals
DRAWS = 50

__all__ = ["DRAWS", "trust_markdown", "trust_of"]


def _plain(value: Any) -> Any:
    """NaN and infinities as None (JSON holds neither), numpy scalars as Python numbers."""
    if isinstance(value, (float, np.floating)):
        x = float(value)
        return x if math.isfinite(x) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _rows(rows: Sequence[Mapping[str, Any]], keys: Sequence[str]) -> list[dict[str, Any]]:
    return [{k: _plain(r[k]) for k in keys if k in r} for r in rows]


def trust_of(
    params: Parameters,
    windows: Sequence[Recording],
    objective: str,
    rng: np.random.Generator,
    runs: Sequence[RecordedRun] = (),
    draws: int = DRAWS,
) -> dict[str, Any]:
    """A JSON-ready summary of how well ``windows`` (the recordings or windows ``params`` were
    fitted on with ``objective``) determine ``params`` (with the effects it carries) and what
    that leaves of the standard manoeuvres:

    - ``fraction_determined``, ``counts`` (parameters per status), ``parameters`` (how many),
      ``objective``, ``f``, ``level`` (the intervals' coverage), ``subsequences``;
    - ``flat_directions``: the parameters that trade off (``names``, ``sentence``,
      ``collinearity``; None for a direction the data do not see at all);
    - ``effects``: the intervals of the effects' parameters (name, estimate, lower, upper,
      status); ``effect_covariance``: their covariance (names, matrix, quantile);
    - ``manoeuvres``: the standard manoeuvres at full scale (key, manoeuvre, quantity, unit,
      value, lo, hi, samples and, for the IMO criteria, limit, margin and verdict), intervals
      over ``draws`` vectors drawn with ``rng`` from the parameters' intervals;
    - ``recorded``: the recorded ``runs`` against the model (measured, predicted, lo, hi,
      inside), empty without runs; ``draws`` and ``seconds``.

    Failure is a value: ``{"error": "...", "params": ...}`` when the intervals or the
    manoeuvres cannot be computed (e.g. too few windows left)."""
    t0 = time.perf_counter()
    try:
        effects: tuple[Effect, ...] = tuple(get_effect(name) for name, _ in params.effects)
        u = parameter_uncertainty(params, windows, objective, effects)
        samples = u.sample(draws, rng) if draws > 0 else None
        pred = predict_standard(params, samples, effects)
        comparisons = compare_recorded(params, runs, samples, effects) if runs else []
    except Exception as exc:  # a summary for a report: say what went wrong, do not stop it
        return {"error": f"{type(exc).__name__}: {exc}"}
    base = len(u.names) - sum(len(e.param_names) for e in effects)
    standard_keys = ("key", "manoeuvre", "quantity", "unit", "value", "lo", "hi", "samples")
    recorded_keys = ("run", "manoeuvre", "quantity", "key", "unit", "measured", "predicted")
    return {
        "objective": u.objective,
        "f": _plain(u.f),
        "level": u.level,
        "subsequences": int(u.meta.get("subsequences", 0)),
        "parameters": len(u.names),
        "fraction_determined": u.fraction_determined,
        "counts": u.counts,
        "flat_directions": [
            {
                "names": d.names,
                "sentence": d.sentence(),
                "collinearity": _plain(d.collinearity),
            }
            for d in u.flat
        ],
        "effects": _rows(
            u.rows()[base:], ("name", "estimate", "lower", "upper", "half_width_share", "status")
        ),
        "effect_covariance": _effect_covariance(u, base),
        "manoeuvres": _rows(
            standard_table(pred),
            (*standard_keys, "limit", "margin", "margin_interval", "verdict"),
        ),
        "recorded": _rows(
            recorded_table(comparisons, L=params.ship.L_pp),
            (*recorded_keys, "lo", "hi", "samples", "inside"),
        ),
        "draws": 0 if samples is None else int(samples.shape[0]),
        "seconds": time.perf_counter() - t0,
    }


def _effect_covariance(u: Any, base: int) -> dict[str, Any]:
    """The covariance of the effects' parameters in their units (``names``: the parameters'
    own names, ``matrix``) and the intervals' half-width in standard deviations
    (``quantile``): what a learned shape's confidence band is drawn from."""
    width = np.asarray(u.box_upper - u.box_lower)[base:]
    C = np.asarray(u.cov)[base:, base:] * np.outer(width, width)
    return {
        "names": [n.rsplit(".", 1)[-1] for n in u.names[base:]],
        "matrix": [[_plain(v) for v in row] for row in C],
        "quantile": _plain(u.quantile),
    }


def _interval(row: Mapping[str, Any]) -> str:
    value = row.get("value", row.get("predicted"))
    text = "-" if value is None else f"{value:.2f}"
    if row.get("samples") and row.get("lo") is not None and row.get("hi") is not None:
        text += f" [{row['lo']:.2f}, {row['hi']:.2f}]"
    return text


def trust_markdown(summaries: Mapping[str, Mapping[str, Any]]) -> str:
    """Summaries of :func:`trust_of` side by side ({model name: summary}, e.g. "before" and
    "after"), as Markdown: the parameters determined and the flat directions, then the standard
    manoeuvres (value [5-95 % interval]) and their IMO verdicts."""
    names = list(summaries)
    lines = ["| | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    cells = []
    for n in names:
        s = summaries[n]
        if "error" in s:
            cells.append(f"not computed ({s['error']})")
        else:
            cells.append(
                f"{s['counts'][DETERMINED]} of {s['parameters']} ({s['subsequences']} windows)"
            )
    lines.append("| parameters determined | " + " | ".join(cells) + " |")
    flat = [
        "; ".join(d["sentence"] for d in summaries[n].get("flat_directions", [])) or "-"
        for n in names
    ]
    lines.append("| trade off | " + " | ".join(flat) + " |")
    effects = [
        ", ".join(
            f"{e['name']} {e['estimate']:.3g} [{e['lower']:.3g}, {e['upper']:.3g}]"
            for e in summaries[n].get("effects", [])
        )
        or "-"
        for n in names
    ]
    lines.append("| effect parameters | " + " | ".join(effects) + " |")
    ok = [n for n in names if "manoeuvres" in summaries[n]]
    if ok:
        lines += ["", "| manoeuvre | quantity | unit | " + " | ".join(ok) + " |"]
        lines.append("|---|---|---|" + "---:|" * len(ok))
        for i, row in enumerate(summaries[ok[0]]["manoeuvres"]):
            rows = [summaries[n]["manoeuvres"][i] for n in ok]
            values = [_interval(r) + (f" ({r['verdict']})" if "verdict" in r else "") for r in rows]
            lines.append(
                f"| {row['manoeuvre']} | {row['quantity']} | {row['unit']} | "
                + " | ".join(values)
                + " |"
            )
    return "\n".join(lines) + "\n"
