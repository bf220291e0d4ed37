"""Tables of the standard manoeuvres (full scale, with intervals and the IMO criteria) and of the
recorded runs against the model, as rows of plain values (JSON-ready), their text form, and flat
metrics for tracking."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mmg.params import ESSO_OSAKA
from sweep.data.manoeuvres import (
    APPROACH_KNOTS,
    KNOT,
    L_FULL,
    QUANTITIES,
    QUANTITY,
    SCALE,
    TRACK_REACH_CEILING,
    imo_criteria,
    summarise,
    to_full_scale,
)
from sweep.data.standard_manoeuvres import Comparison, Prediction

INTERVAL = (0.05, 0.95)
"""Quantiles of the samples that bound a quantity's interval (a 90 % interval)."""

Row = dict[str, Any]

UNITS = {"length": "L", "time": "s", "angle": "deg", "ratio": "%"}
"""The tables' unit of each kind of quantity (lengths in ship lengths, ratios in per cent)."""


def _display(kind: str, value: float, L: float) -> float:
    """A value in the tables' units: lengths in ship lengths, ratios in per cent."""
    if kind == "length":
        return value / L
    return 100.0 * value if kind == "ratio" else value


def full_scale_l_over_v() -> float:
    """L / V of the full-scale ship at the approach speed [s] (82 s)."""
    return L_FULL / (APPROACH_KNOTS * KNOT)


def _verdict(value: float, lo: float, hi: float, limit: float, key: str) -> str:
    """ "pass", "fail" or, when the interval straddles the limit, "uncertain"; the track reach
    between 15 L and 20 L passes only with the Administration's relaxation for large ships."""
    if math.isnan(value):
        return "not reached"
    worst, best = (hi, lo) if not math.isnan(hi) else (value, value)
    if key == "stopping.track_reach" and limit < worst <= TRACK_REACH_CEILING:
        return "pass if relaxed"
    if worst <= limit:
        return "pass"
    return "fail" if best > limit else "uncertain"


def standard_table(pred: Prediction, interval: tuple[float, float] = INTERVAL) -> list[Row]:
    """One row per quantity of the standard manoeuvres at full scale: value of the estimate,
    the interval over the samples (NaN without samples) and the number of samples that reached
    the quantity, and for the criteria of MSC.137(76) the limit, the margin (limit - value, and
    limit - the interval's upper end) and a verdict. Lengths in ship lengths (``value_m`` in
    metres), times in seconds, angles in degrees, speed loss in per cent."""
    criteria = {c.key: c for c in imo_criteria(full_scale_l_over_v())}
    L = L_FULL
    rows = []
    for q in QUANTITIES:
        lanes = np.array([to_full_scale(q.key, v) for v in pred.values[q.key]])
        value = _display(q.kind, float(lanes[0]), L)
        stats = summarise(lanes[1:], interval) if pred.n_samples else None
        lo = _display(q.kind, stats["lo"], L) if stats else math.nan
        hi = _display(q.kind, stats["hi"], L) if stats else math.nan
        row: Row = {
            "key": q.key,
            "manoeuvre": q.manoeuvre,
            "quantity": q.label,
            "unit": UNITS[q.kind],
            "value": value,
            "lo": lo,
            "hi": hi,
            "samples": int(stats["n"]) if stats else 0,
        }
        if q.kind == "length":
            row["value_m"] = float(lanes[0])
        c = criteria.get(q.key)
        if c is not None:
            row |= {
                "limit": c.limit,
                "criterion": c.text,
                "margin": c.limit - value,
                "margin_interval": c.limit - hi,
                "verdict": _verdict(value, lo, hi, c.limit, q.key),
            }
        rows.append(row)
    return rows


def recorded_table(
    comparisons: Sequence[Comparison],
    interval: tuple[float, float] = INTERVAL,
    L: float = ESSO_OSAKA.L_pp,
) -> list[Row]:
    """One row per recorded run and quantity (model scale: lengths in ship lengths of L [m],
    times in seconds from the first execute): the measurement, the estimate's prediction, the
    interval over the samples and whether the measurement lies inside it (None without samples
    or when either is missing)."""
    rows = []
    for c in comparisons:
        group = "turning" if c.run.kind == "turning" else "zigzag10"
        for key, measured in c.measured.items():
            kind = QUANTITY[f"{group}.{key}"].kind
            lanes = c.predicted[key]
            stats = summarise(lanes[1:], interval) if lanes.size > 1 else None
            lo = _display(kind, stats["lo"], L) if stats else math.nan
            hi = _display(kind, stats["hi"], L) if stats else math.nan
            m = _display(kind, measured, L)
            inside = None if math.isnan(lo) or math.isnan(m) else bool(lo <= m <= hi)
            rows.append(
                {
                    "run": c.run.label,
                    "manoeuvre": c.run.title,
                    "quantity": QUANTITY[f"{group}.{key}"].label,
                    "key": key,
                    "unit": UNITS[kind],
                    "measured": m,
                    "predicted": _display(kind, float(lanes[0]), L),
                    "lo": lo,
                    "hi": hi,
                    "samples": int(stats["n"]) if stats else 0,
                    "inside": inside,
                }
            )
    return rows


def manoeuvre_metrics(pred: Prediction, comparisons: Sequence[Comparison] = ()) -> dict[str, float]:
    """Flat metrics for tracking: ``manoeuvre.<key>`` (full scale, table units) with ``_lo`` and
    ``_hi`` when there are samples, ``manoeuvre.<key>_margin`` for the IMO criteria, and
    ``recorded.<run>.<key>`` (predicted; ``_lo`` and ``_hi`` with samples) and
    ``..._measured`` for the recorded runs."""
    out: dict[str, float] = {}
    for row in standard_table(pred):
        name = f"manoeuvre.{row['key']}"
        out[name] = row["value"]
        if row["samples"]:
            out[f"{name}_lo"], out[f"{name}_hi"] = row["lo"], row["hi"]
        if "margin" in row:
            out[f"{name}_margin"] = row["margin"]
    for row in recorded_table(comparisons):
        name = f"recorded.{row['run']}.{row['key']}"
        out[name], out[f"{name}_measured"] = row["predicted"], row["measured"]
        if row["samples"]:
            out[f"{name}_lo"], out[f"{name}_hi"] = row["lo"], row["hi"]
    return {k: v for k, v in out.items() if not math.isnan(v)}


def _cell(value: float, digits: int = 2) -> str:
    return "-" if value is None or math.isnan(value) else f"{value:.{digits}f}"


def format_standard(rows: Sequence[Row], title: str = "") -> str:
    """The standard-manoeuvre table as fixed-width text."""
    head = f"{'manoeuvre':<15}{'quantity':<25}{'unit':>5}{'value':>9}{'interval':>19}"
    head += f"{'IMO limit':>11}{'margin':>9}  verdict"
    lines = [title] if title else []
    lines.append(head)
    for r in rows:
        interval = f"[{_cell(r['lo'])}, {_cell(r['hi'])}]" if r["samples"] else "-"
        line = f"{r['manoeuvre']:<15}{r['quantity']:<25}{r['unit']:>5}{_cell(r['value']):>9}"
        line += f"{interval:>19}"
        if "limit" in r:
            line += f"{_cell(r['limit'], 1):>11}{_cell(r['margin']):>9}  {r['verdict']}"
        lines.append(line)
    return "\n".join(lines)


def format_recorded(rows: Sequence[Row], title: str = "") -> str:
    """The recorded-against-predicted table as fixed-width text."""
    lines = [title] if title else []
    w = max([len(r["run"]) + 2 for r in rows] + [8])
    lines.append(
        f"{'run':<{w}}{'manoeuvre':<15}{'quantity':<25}{'unit':>5}{'measured':>10}"
        f"{'model':>9}{'interval':>19}  inside"
    )
    for r in rows:
        interval = f"[{_cell(r['lo'])}, {_cell(r['hi'])}]" if r["samples"] else "-"
        inside = {True: "yes", False: "NO", None: "-"}[r["inside"]]
        lines.append(
            f"{r['run']:<{w}}{r['manoeuvre']:<15}{r['quantity']:<25}{r['unit']:>5}"
            f"{_cell(r['measured']):>10}{_cell(r['predicted']):>9}{interval:>19}  {inside}"
        )
    return "\n".join(lines)


def _text(value: Any, digits: int = 2) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else (
        f"{value:.{digits}f}"
    )  # fmt: skip


def _value_cell(row: Row) -> str:
    """``value [lo, hi]`` of a row (its prediction for a recorded run's row)."""
    text = _text(row["value"] if "value" in row else row["predicted"])
    if row["samples"]:
        text += f" [{_text(row['lo'])}, {_text(row['hi'])}]"
    return text


def standard_markdown(tables: Mapping[str, Sequence[Row]]) -> str:
    """The standard manoeuvres of one or more models ({name: :func:`standard_table` rows}) as
    a Markdown table: one row per quantity, a value (and interval) column per model, the IMO
    limit and each model's margin and verdict."""
    names = list(tables)
    head = "| manoeuvre | quantity | unit | " + " | ".join(names) + " | IMO limit | "
    head += " | ".join(f"margin {n}" for n in names) + " |"
    lines = [head, "|---|---|---|" + "---:|" * (2 * len(names) + 1)]
    for i, row in enumerate(tables[names[0]]):
        cells = [row["manoeuvre"], row["quantity"], row["unit"]]
        cells += [_value_cell(tables[n][i]) for n in names]
        if "limit" in row:
            cells.append(f"{row['limit']:g}")
            cells += [f"{_text(tables[n][i]['margin'])} ({tables[n][i]['verdict']})" for n in names]
        else:
            cells += [""] * (1 + len(names))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def recorded_markdown(tables: Mapping[str, Sequence[Row]]) -> str:
    """The recorded runs against one or more models ({name: :func:`recorded_table` rows}) as a
    Markdown table: one row per run and quantity, the measurement and each model's prediction
    (with its interval and whether the measurement lies inside it)."""
    names = list(tables)
    lines = [
        "| run | manoeuvre | quantity | unit | measured | " + " | ".join(names) + " |",
        "|---|---|---|---|---:|" + "---:|" * len(names),
    ]
    for i, row in enumerate(tables[names[0]]):
        cells = [row["run"], row["manoeuvre"], row["quantity"], row["unit"], _text(row["measured"])]
        for n in names:
            r = tables[n][i]
            mark = "" if r["inside"] is None else (" (inside)" if r["inside"] else " (outside)")
            cells.append(_value_cell(r) + mark)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def settings_note(pred: Prediction) -> str:
    """One paragraph: the approach, the scale and the rudder and propeller of the manoeuvres."""
    s = pred.settings
    n = pred.n_approach[0]
    return (
        f"Full scale (lambda = {SCALE:.1f}, L = {L_FULL:g} m), approach {APPROACH_KNOTS:g} kn "
        f"({s.approach_speed:.3f} m/s at model scale, propeller {n:.2f} rev/s to hold it), calm, "
        f"rudder rate {math.degrees(s.rudder_rate) / math.sqrt(SCALE):.2f} deg/s, crash stop to "
        f"{s.n_astern:g} rev/s; L/V = {full_scale_l_over_v():.0f} s."
    )


__all__ = [
    "INTERVAL",
    "UNITS",
    "format_recorded",
    "format_standard",
    "full_scale_l_over_v",
    "manoeuvre_metrics",
    "recorded_markdown",
    "recorded_table",
    "settings_note",
    "standard_markdown",
    "standard_table",
]
