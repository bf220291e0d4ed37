"""Summary tables (the paper's Tables 6-8) of a sweep, and the notes of its MLflow runs.

Library: :func:`summary_tables`, :func:`write_tables`, :func:`format_table`, and the run
descriptions :func:`job_note` and :func:`sweep_note` that the tracker writes
(:mod:`sweep.service.tracking` imports this module, never the other way round); the command
``python -m sweep.report`` regenerates a sweep's tables from MLflow.

Table layout, per objective J used for *evaluation*: rows "EFD", then the (objective, training set)
cases J1-R, J1-TR, J1-TZR, J2-R, ..., J3-TZR that are present (a sweep with ``cmaes.polish``
also has the rows J2-R+LM, ...: the same jobs after the Levenberg-Marquardt refinement of their
CMA-ES result, each right after its CMA-ES row); for each paper column
(:data:`sweep.service.outcome.COLUMNS`) the mean over seeds, the standard deviation (ddof=1; NaN for
fewer than two seeds) and the rank of the mean among the cases (1 = lowest; EFD is not ranked),
then ``n`` (seeds used) and ``rejected`` (seeds removed by the paper's post-filter, never
averaged). Rank 1 is shown in bold, rank 2 underlined, as in the paper. Values are the
objectives' own (dimensionless).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from html import escape
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sweep.data.manoeuvre_tables import UNITS
from sweep.data.manoeuvres import QUANTITIES, QUANTITY
from sweep.service.outcome import (
    COLUMNS,
    MANOEUVRE_PREFIX,
    OBJECTIVE_NAMES,
    SUBSETS,
    TRAIN_NAMES,
    JobOutcome,
    ScoreTable,
    complete_subsets,
    manoeuvre_metric_name,
)

__all__ = [
    "EFD_ROW",
    "MANOEUVRE_TABLE",
    "POLISHED_SUFFIX",
    "best_case",
    "case_name",
    "column_name",
    "display_table",
    "format_table",
    "job_note",
    "manoeuvre_markdown",
    "manoeuvre_table",
    "summary_tables",
    "sweep_note",
    "write_manoeuvre_table",
    "write_tables",
]

EFD_ROW = "EFD"
STATS = ("mean", "std", "rank")


def column_name(column: str, stat: str) -> str:
    """Flat column of a summary table: ``column_name("Test-R", "std")`` -> "Test-R std"."""
    return f"{column} {stat}"


#: row-label suffix of the results after the Levenberg-Marquardt refinement (``cmaes.polish``)
POLISHED_SUFFIX = "+LM"


def case_name(objective: str, train: str, variant: str = "") -> str:
    """Row label of an identified case, e.g. "J2-R", or "J2-R+LM" for the refined results."""
    return f"{objective}-{train}{variant}"


def _flat_scores(data: Mapping[str, Any], kind: str) -> dict[str, dict[str, float]]:
    """{J: {subset: value}} from flat metrics "{kind}/J/subset", at the top level of ``data``
    or under its "metrics"."""
    out: dict[str, dict[str, float]] = {}
    for key, value in {**data, **data.get("metrics", {})}.items():
        parts = str(key).split("/")
        if len(parts) == 3 and parts[0] == kind:
            out.setdefault(parts[1], {})[parts[2]] = float(value)
    return out


def _records(outcome: JobOutcome | Mapping[str, Any]) -> list[dict[str, Any]]:
    """The job's record and, when the job refined its CMA-ES result (``cmaes.polish``), the
    refined result's record (variant ``+LM``: its own row in the tables)."""
    main = _record(outcome)
    if isinstance(outcome, JobOutcome):
        polished = outcome.polished["test"] if outcome.polished else {}
    else:
        polished = dict(outcome.get("polish") or {}) or _flat_scores(outcome, "polish")
    if not polished:
        return [main]
    refined = {
        **main,
        "variant": POLISHED_SUFFIX,
        "test": {J: complete_subsets(v) for J, v in polished.items()},
    }
    return [main, refined]


def _record(outcome: JobOutcome | Mapping[str, Any]) -> dict[str, Any]:
    """objective, train, seed, rejected and test {J: {subset: value}} of one outcome."""
    data: dict[str, Any]
    if isinstance(outcome, JobOutcome):
        data = {
            "objective": outcome.objective,
            "train": outcome.train,
            "seed": outcome.seed,
            "rejected": outcome.rejected,
            "test": outcome.test,
        }
    else:
        data = dict(outcome)
    test = data.get("test") or _flat_scores(data, "test")
    rejected = data.get("rejected", False)
    if isinstance(rejected, str):
        rejected = rejected.strip().lower() in ("1", "true", "yes")
    return {
        "objective": str(data["objective"]),
        "train": str(data["train"]),
        "variant": "",
        "seed": data.get("seed"),
        "rejected": bool(rejected),
        "test": {J: complete_subsets(v) for J, v in test.items()},
    }


def _ordered_cases(records: Iterable[Mapping[str, Any]]) -> list[tuple[str, str, str]]:
    """(objective, train, variant) present, in the paper's order (a refined row right after its
    CMA-ES row); others after, sorted."""
    present = {(r["objective"], r["train"], r.get("variant", "")) for r in records}

    def order(case: tuple[str, str, str]) -> tuple[int, str, int, str, str]:
        J, train, variant = case
        j = OBJECTIVE_NAMES.index(J) if J in OBJECTIVE_NAMES else len(OBJECTIVE_NAMES)
        t = TRAIN_NAMES.index(train) if train in TRAIN_NAMES else len(TRAIN_NAMES)
        return (j, J, t, train, variant)

    return sorted(present, key=order)


def summary_tables(
    outcomes: Sequence[JobOutcome] | Sequence[Mapping[str, Any]], efd: ScoreTable
) -> dict[str, pd.DataFrame]:
    """{J: table} for J1, J2, J3 in the paper's layout (see the module docstring).

    ``outcomes``: JobOutcome objects or records of
    :meth:`sweep.service.tracking.Tracker.job_outcomes`
    (or any mapping with objective, train, rejected and test {J: {subset: value}} or flat
    ``test/{J}/{subset}`` entries). ``efd``: {J: {subset: value}} of the EFD model.
    """
    records = [r for o in outcomes for r in _records(o)]
    cases = _ordered_cases(records)
    tables: dict[str, pd.DataFrame] = {}
    for J in OBJECTIVE_NAMES:
        rows: dict[str, dict[str, Any]] = {}
        if J in efd:
            ref = complete_subsets(efd[J])
            rows[EFD_ROW] = {
                **{column_name(COLUMNS[s], "mean"): ref.get(s, math.nan) for s in SUBSETS},
                "n": pd.NA,
                "rejected": pd.NA,
            }
        for objective, train, variant in cases:
            group = [
                r
                for r in records
                if (r["objective"], r["train"], r.get("variant", "")) == (objective, train, variant)
            ]
            kept = [r["test"][J] for r in group if not r["rejected"] and J in r["test"]]
            row: dict[str, Any] = {}
            for s in SUBSETS:
                values = np.array([v[s] for v in kept if s in v], dtype=np.float64)
                row[column_name(COLUMNS[s], "mean")] = values.mean() if values.size else math.nan
                row[column_name(COLUMNS[s], "std")] = (
                    values.std(ddof=1) if values.size >= 2 else math.nan
                )
            row["n"] = len(kept)
            row["rejected"] = sum(r["rejected"] for r in group)
            rows[case_name(objective, train, variant)] = row
        tables[J] = _finish_table(rows)
    return tables


def _finish_table(rows: dict[str, dict[str, Any]]) -> pd.DataFrame:
    """Columns in order (mean, std, rank per paper column; n; rejected), ranks computed."""
    order = [column_name(c, stat) for c in COLUMNS.values() for stat in STATS] + ["n", "rejected"]
    table = pd.DataFrame.from_dict(rows, orient="index")
    table = table.reindex(columns=order)
    table.index = pd.Index(list(rows), name="Case")
    identified = table.index != EFD_ROW
    for c in COLUMNS.values():
        for stat in ("mean", "std"):
            table[column_name(c, stat)] = table[column_name(c, stat)].astype("float64")
        ranks = table.loc[identified, column_name(c, "mean")].rank(method="min")
        table[column_name(c, "rank")] = ranks.reindex(table.index).astype("Int64")
    for count in ("n", "rejected"):
        table[count] = table[count].astype("Int64")
    return table


def _cell(mean: float, std: float) -> str:
    if not np.isfinite(mean):
        return "-"
    return f"{mean:.1f}" if not np.isfinite(std) else f"{mean:.1f} ({std:.1f})"


MARKS = {
    "markdown": ("**{}**", "<u>{}</u>"),
    "html": ("<b>{}</b>", "<u>{}</u>"),
    "text": ("{} [1]", "{} [2]"),
}


def display_table(table: pd.DataFrame, style: str = "markdown") -> pd.DataFrame:
    """Cells "mean (std)" with the best case marked (bold / [1]) and the second (underlined /
    [2]); ``style`` is "markdown", "html" or "text". Columns: the paper's, then n, rejected."""
    best, second = MARKS[style]
    out = pd.DataFrame(index=table.index, dtype=object)
    for c in COLUMNS.values():
        means = table[column_name(c, "mean")].to_numpy(dtype=np.float64, na_value=np.nan)
        stds = table[column_name(c, "std")].to_numpy(dtype=np.float64, na_value=np.nan)
        ranks = table[column_name(c, "rank")].to_numpy(dtype=np.float64, na_value=np.nan)
        cells = []
        for mean, std, rank in zip(means, stds, ranks, strict=True):
            text = _cell(mean, std)
            if rank in (1.0, 2.0):
                text = (best if rank == 1.0 else second).format(text)
            cells.append(text)
        out[c] = cells
    for count in ("n", "rejected"):
        out[count] = ["" if pd.isna(v) else str(int(v)) for v in table[count]]
    return out


def format_table(table: pd.DataFrame, title: str = "") -> str:
    """The table as text for a terminal ([1] best, [2] second best)."""
    shown = display_table(table, "text")
    if shown.empty:
        return f"{title}\n(no results)" if title else "(no results)"
    body = shown.to_markdown(tablefmt="simple", colalign=("left",) + ("right",) * shown.shape[1])
    return f"{title}\n{body}" if title else body


def write_tables(
    tables: Mapping[str, pd.DataFrame], out_dir: str | Path, notes: Sequence[str] = ()
) -> dict[str, Path]:
    """{J}.csv, {J}.parquet, {J}.md and {J}.html per table; returns {file name: path}.

    ``notes``: lines said under the .md and .html tables (e.g. duplicate runs ignored)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    for J, table in tables.items():
        paths = {ext: out / f"{J}.{ext}" for ext in ("csv", "parquet", "md", "html")}
        table.to_csv(paths["csv"])
        table.to_parquet(paths["parquet"])
        md = display_table(table, "markdown")
        align = ("left",) + ("right",) * md.shape[1]
        caption = (
            f"{J} on the test set: mean (standard deviation) over seeds; **best**, <u>second</u>."
        )
        below = "".join(f"\n- {note}" for note in notes) + ("\n" if notes else "")
        paths["md"].write_text(f"{caption}\n\n{md.to_markdown(colalign=align)}\n{below}")
        html = display_table(table, "html").to_html(escape=False, border=0)
        paths["html"].write_text(
            f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{J}</title></head>\n"
            f"<body>\n<p>{J} on the test set: mean (standard deviation) over seeds; "
            f"<b>best</b>, <u>second</u>.</p>\n{html}\n"
            + "".join(f"<p>{escape(note)}</p>\n" for note in notes)
            + "</body></html>\n"
        )
        files.update({p.name: p for p in paths.values()})
    return files


# ---------------------------------------------------------------- the manoeuvres of a sweep

#: name of the manoeuvre table among a sweep's summary tables (``summary/manoeuvres.json``)
MANOEUVRE_TABLE = "manoeuvres"
#: the statistics of a case's column group in the manoeuvre table
MANOEUVRE_STATS = ("mean", "std", "lo", "hi", "n")
#: the column of the recorded runs' measurements
MEASURED = "measured"


def _manoeuvre_values(outcome: JobOutcome | Mapping[str, Any]) -> dict[str, float]:
    """A job's manoeuvre metrics (``manoeuvre/...``), from an outcome or a tracker record."""
    if isinstance(outcome, JobOutcome):
        man = outcome.manoeuvres or {}
        raw = man.get("metrics", {}) if "error" not in man else {}
        return {manoeuvre_metric_name(k): float(v) for k, v in raw.items()}
    flat = {**outcome, **(outcome.get("metrics") or {})}
    return {str(k): float(v) for k, v in flat.items() if str(k).startswith(MANOEUVRE_PREFIX)}


def _quantity_rows(names: Iterable[str]) -> list[tuple[str, str, str, str]]:
    """(key, manoeuvre, quantity, unit) of the standard quantities, then of the recorded runs'
    (``recorded.<run>.<quantity>``) present in ``names`` (metric names without the prefix)."""
    rows = [(q.key, q.manoeuvre, q.label, UNITS[q.kind]) for q in QUANTITIES]
    runs: dict[str, list[str]] = {}
    for name in names:
        if name.startswith("recorded.") and not name.endswith(("_lo", "_hi", "_measured")):
            run, _, key = name.removeprefix("recorded.").rpartition(".")
            runs.setdefault(run, []).append(key)
    order = {q.key.partition(".")[2]: i for i, q in enumerate(QUANTITIES)}
    for run in sorted(runs):
        for key in sorted(runs[run], key=lambda k: order.get(k, len(order))):
            q = QUANTITY.get(f"turning.{key}") or QUANTITY.get(f"zigzag10.{key}")
            if q is not None:
                what = "turning" if q.key.startswith("turning") else "zigzag"
                rows.append((f"recorded.{run}.{key}", f"{run} ({what})", q.label, UNITS[q.kind]))
    return rows


def manoeuvre_table(
    outcomes: Sequence[JobOutcome] | Sequence[Mapping[str, Any]],
    efd: Mapping[str, float] | None = None,
) -> pd.DataFrame:
    """The manoeuvres of a sweep's models: one row per quantity (the standard manoeuvres at
    full scale, then each recorded run of the test set at model scale; index: the quantity's
    key), columns ``manoeuvre``, ``quantity``, ``unit``, ``measured`` (the recorded runs'
    measurements), ``EFD`` (the EFD model's point value: it has no identification
    uncertainty), then per case (objective and training set, as in :func:`summary_tables`;
    the job's final parameters, the refined ones with ``cmaes.polish``) the mean and standard
    deviation over its seeds (ddof=1), the means over its seeds of each job's interval (5-95 %
    over the draws of its parameters' intervals), ``lo`` and ``hi``, and ``n`` (seeds with the
    quantity). Jobs the paper's post-filter rejected are left out. ``efd``: the EFD model's
    ``manoeuvre/...`` metrics (None: no EFD column). Empty without manoeuvres."""
    records = [(_record(o), _manoeuvre_values(o)) for o in outcomes]
    records = [(r, v) for r, v in records if v and not r["rejected"]]
    if not records:
        return pd.DataFrame()
    names = {k.removeprefix(MANOEUVRE_PREFIX) for _, v in records for k in v}
    quantities = _quantity_rows(names)
    every = {**(efd or {}), **{k: x for _, v in records for k, x in v.items()}}
    table = pd.DataFrame(
        {
            "manoeuvre": [m for _, m, _, _ in quantities],
            "quantity": [q for _, _, q, _ in quantities],
            "unit": [u for _, _, _, u in quantities],
            MEASURED: [
                every.get(f"{MANOEUVRE_PREFIX}{k}_measured", math.nan) for k, *_ in quantities
            ],
        },
        index=pd.Index([k for k, *_ in quantities], name="key"),
    )
    if efd is not None:
        table[EFD_ROW] = [float(efd.get(MANOEUVRE_PREFIX + k, math.nan)) for k, *_ in quantities]
    for objective, train, _ in _ordered_cases(r for r, _ in records):
        group = [v for r, v in records if (r["objective"], r["train"]) == (objective, train)]
        case = case_name(objective, train)
        for stat in MANOEUVRE_STATS:
            table[f"{case} {stat}"] = [
                _seed_stat(group, MANOEUVRE_PREFIX + k, stat) for k, *_ in quantities
            ]
    keep = table.drop(columns=["manoeuvre", "quantity", "unit"]).notna().any(axis=1)
    return table[keep]


def _seed_stat(group: Sequence[Mapping[str, float]], name: str, stat: str) -> float:
    """``stat`` of the metric ``name`` over the jobs of one case (NaN when none has it)."""
    key = {"lo": f"{name}_lo", "hi": f"{name}_hi"}.get(stat, name)
    values = np.array([v[key] for v in group if key in v], dtype=np.float64)
    if stat == "n":
        return float(values.size)
    if stat == "std":
        return float(values.std(ddof=1)) if values.size >= 2 else math.nan
    return float(values.mean()) if values.size else math.nan


def _manoeuvre_cell(row: pd.Series, case: str) -> str:
    mean, std = row.get(f"{case} mean", math.nan), row.get(f"{case} std", math.nan)
    lo, hi = row.get(f"{case} lo", math.nan), row.get(f"{case} hi", math.nan)
    if not np.isfinite(mean):
        return "-"
    text = f"{mean:.2f}" + (f" ({std:.2f})" if np.isfinite(std) else "")
    return text + (f" [{lo:.2f}, {hi:.2f}]" if np.isfinite(lo) and np.isfinite(hi) else "")


def manoeuvre_markdown(table: pd.DataFrame) -> str:
    """The manoeuvre table as Markdown: per case "mean (std) [lo, hi]" beside the measurement
    and EFD."""
    if table.empty:
        return "(no manoeuvres)\n"
    cases = [c.removesuffix(" mean") for c in table.columns if str(c).endswith(" mean")]
    fixed = [c for c in (MEASURED, EFD_ROW) if c in table.columns]
    head = "| manoeuvre | quantity | unit | " + " | ".join(fixed + cases) + " |"
    lines = [head, "|---|---|---|" + "---:|" * (len(fixed) + len(cases))]
    for _, row in table.iterrows():
        cells = [str(row["manoeuvre"]), str(row["quantity"]), str(row["unit"])]
        cells += [_text_value(row[c]) for c in fixed]
        cells += [_manoeuvre_cell(row, case) for case in cases]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _text_value(value: Any) -> str:
    x = float(value)
    return f"{x:.2f}" if np.isfinite(x) else "-"


def write_manoeuvre_table(table: pd.DataFrame, out_dir: str | Path) -> dict[str, Path]:
    """manoeuvres.csv and manoeuvres.md (with its caption); returns {file name: path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv, md = out / f"{MANOEUVRE_TABLE}.csv", out / f"{MANOEUVRE_TABLE}.md"
    table.to_csv(csv)
    md.write_text(
        "Manoeuvres of the identified models: mean (standard deviation) over seeds and [the "
        "means over seeds of each model's 5-95 % interval over draws of its parameters' "
        "intervals]; the standard manoeuvres at full scale, the test set's recorded runs at "
        "model scale (lengths in ship lengths, times in seconds, angles in degrees, speed loss "
        "in per cent). EFD: point values (it has no identification uncertainty).\n\n"
        + manoeuvre_markdown(table)
    )
    return {csv.name: csv, md.name: md}


# ---------------------------------------------------------------- run descriptions (MLflow notes)


def _num(v: Any) -> str:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return "-"
    return f"{x:.1f}" if np.isfinite(x) else "-"


def job_note(outcome: JobOutcome, efd: ScoreTable) -> str:
    """A child run's description (Markdown): its test row beside EFD for J1-J3, the stop
    reason and the restarts."""
    head = "| | " + " | ".join(COLUMNS[s] for s in SUBSETS) + " |"
    rule = "|---|" + "---:|" * len(SUBSETS)
    lines = [
        f"**{outcome.objective} on Train-{outcome.train}, seed {outcome.seed}**: best training "
        f"{outcome.objective} = {outcome.f:.4g} after {outcome.evaluations:,} evaluations "
        f"({outcome.seconds:.0f} s); stopped by {outcome.stop_reason}; "
        f"{len(outcome.restarts)} restart(s)"
        + ("; **rejected** by the paper's post-filter" if outcome.rejected else "")
        + (f"; resubmitted {outcome.retries} time(s) after a loss" if outcome.retries else "")
        + (
            f"; {outcome.workers_replaced} evaluation worker(s) lost and replaced"
            if outcome.workers_replaced
            else ""
        ),
        "",
    ]
    if outcome.polished:
        pol = outcome.polished
        lines += [
            f"Refined by Levenberg-Marquardt (`cmaes.polish`): training {outcome.objective} "
            f"{pol['f_start']:.4g} -> {pol['f']:.4g} in {pol['iterations']} iterations, "
            f'{pol["evaluations"]:,} evaluations ({pol["seconds"]:.0f} s); row "+ LM" below.',
            "",
        ]
    for J in OBJECTIVE_NAMES:
        if J not in outcome.test:
            continue
        mine = complete_subsets(outcome.test[J])
        ref = complete_subsets(efd.get(J, {}))
        lines += [
            f"{J} on the test set:",
            "",
            head,
            rule,
            "| this job | " + " | ".join(_num(mine.get(s)) for s in SUBSETS) + " |",
            *(
                ["| + LM | " + " | ".join(_num(lm.get(s)) for s in SUBSETS) + " |"]
                if (lm := complete_subsets((outcome.polished or {}).get("test", {}).get(J, {})))
                else []
            ),
            "| EFD | " + " | ".join(_num(ref.get(s)) for s in SUBSETS) + " |",
            "",
        ]
    if outcome.restarts:
        lines += [
            "| restart | population | generations | evaluations | best f | stop |",
            "|---:|---:|---:|---:|---:|---|",
        ]
        for r in outcome.restarts:
            stop = ", ".join(str(k) for k in (r.get("stop") or {})) or "-"
            lines.append(
                f"| {r.get('index', '')} | {r.get('popsize', '')} | {r.get('generations', '')} "
                f"| {r.get('evaluations', '')} | {float(r.get('best_f', math.nan)):.4g} | {stop} |"
            )
    return "\n".join(lines) + "\n"


def best_case(table: pd.DataFrame, column: str = "Total") -> tuple[str, float, float] | None:
    """(case, mean, std) of the lowest mean in ``column`` (EFD excluded), or None."""
    mean = column_name(column, "mean")
    if mean not in table.columns:
        return None
    rows = table.drop(index=EFD_ROW, errors="ignore")
    rows = rows[np.isfinite(rows[mean].to_numpy(dtype=np.float64, na_value=np.nan))]
    if rows.empty:
        return None
    case = str(rows[mean].astype("float64").idxmin())
    std = float(rows.loc[case, column_name(column, "std")])
    return case, float(rows.loc[case, mean]), std


def sweep_note(name: str, tables: Mapping[str, pd.DataFrame], settings: Mapping[str, Any]) -> str:
    """The parent run's description (Markdown): which objective and training set generalise
    best, then the J2, J1 and J3 tables (mean (std) over seeds, EFD row, best in bold) and the
    sweep's settings."""
    lines = [f"## Sweep {name}", ""]
    if "J2" in tables:
        best = best_case(tables["J2"])
        efd = tables["J2"].get(column_name("Total", "mean"))
        if best is not None:
            case, mean, std = best
            ref = float(efd.get(EFD_ROW, math.nan)) if efd is not None else math.nan
            spread = f" (std {std:.1f} over seeds)" if np.isfinite(std) else ""
            lines += [
                f"**Best generalisation (J2, whole test set): {case}**, {mean:.1f}{spread}"
                + (f"; EFD {ref:.1f}" if np.isfinite(ref) else "")
                + ".",
                "",
            ]
    for J in ("J2", *(j for j in OBJECTIVE_NAMES if j != "J2")):  # the question's table first
        if J not in tables:
            continue
        paper_layout = column_name("Total", "rank") in tables[J].columns
        md = display_table(tables[J], "markdown") if paper_layout else tables[J]
        align = ("left",) + ("right",) * md.shape[1]
        lines += [
            f"### {J} on the test set: mean (std) over seeds; **best**, <u>second</u>",
            "",
            md.to_markdown(colalign=align),
            "",
        ]
    if settings:
        lines += ["### Settings", ""]
        lines += [f"- `{k}`: {v}" for k, v in settings.items()]
    return "\n".join(lines) + "\n"
