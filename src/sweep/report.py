"""Summary tables (the paper's Tables 6-8) and figures (Figs. 5-8) of a sweep.

Library: :func:`summary_tables`, :func:`write_tables`, :func:`plot_convergence`,
:func:`plot_trajectories`. Command line::

    python -m sweep.report [--tracking-uri URI] [--experiment NAME] [--sweep NAME | --run-id ID]
                           --out DIR [--no-log]

regenerates the tables of a finished or partial sweep from MLflow (the newest sweep if neither
``--sweep`` nor ``--run-id`` is given), prints the J2 table, writes J{1,2,3}.{csv,parquet,md,html}
to DIR and logs them to the sweep's parent run under ``summary/`` (without changing its status).
An unknown sweep or store exits with status 2 and a one-line message.

Table layout, per objective J used for *evaluation*: rows "EFD", then the (objective, training set)
cases J1-R, J1-TR, J1-TZR, J2-R, ..., J3-TZR that are present (a sweep with ``cmaes.polish``
also has the rows J2-R+LM, ...: the same jobs after the Levenberg-Marquardt refinement of their
CMA-ES result, each right after its CMA-ES row); for each paper column
(:data:`sweep.service.outcome.COLUMNS`) the mean over seeds, the standard deviation (ddof=1; NaN for
fewer than two seeds) and the rank of the mean among the cases (1 = lowest; EFD is not ranked),
then ``n`` (seeds used) and ``rejected`` (seeds removed by the paper's post-filter, never
averaged). Rank 1 is shown in bold, rank 2 underlined, as in the paper.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from numpy.typing import NDArray

from sweep.service.outcome import (
    COLUMNS,
    OBJECTIVE_NAMES,
    SUBSETS,
    TRAIN_NAMES,
    JobOutcome,
    ScoreTable,
    complete_subsets,
)

__all__ = [
    "COLUMNS",
    "SUBSETS",
    "JobOutcome",
    "display_table",
    "main",
    "plot_convergence",
    "plot_trajectories",
    "summary_tables",
    "write_tables",
]

FloatArray = NDArray[np.float64]
EFD_ROW = "EFD"
STATS = ("mean", "std", "rank")


class ReportError(Exception):
    """A user mistake (unknown store or sweep), reported as one line."""


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


def write_tables(tables: Mapping[str, pd.DataFrame], out_dir: str | Path) -> dict[str, Path]:
    """{J}.csv, {J}.parquet, {J}.md and {J}.html per table; returns {file name: path}."""
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
        paths["md"].write_text(f"{caption}\n\n{md.to_markdown(colalign=align)}\n")
        html = display_table(table, "html").to_html(escape=False, border=0)
        paths["html"].write_text(
            f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{J}</title></head>\n"
            f"<body>\n<p>{J} on the test set: mean (standard deviation) over seeds; "
            f"<b>best</b>, <u>second</u>.</p>\n{html}\n</body></html>\n"
        )
        files.update({p.name: p for p in paths.values()})
    return files


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
        + (f"; resubmitted {outcome.retries} time(s) after a loss" if outcome.retries else ""),
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


# ---------------------------------------------------------------- figures


def plot_sweep(
    tables: Mapping[str, pd.DataFrame],
    histories: Mapping[str, Sequence[tuple[float, float]]],
    path: str | Path,
) -> Path:
    """The sweep at a glance: for J1, J2 and J3, bars per test subset for every
    objective-training pair (mean over seeds, the seeds' standard deviation as error bars) with
    the EFD value as a line; below, the convergence of every job (best J so far against
    evaluations, log scale), coloured by objective."""
    Js = [J for J in OBJECTIVE_NAMES if J in tables]
    fig = Figure(figsize=(5.2 * max(1, len(Js)), 8.0))
    gs = fig.add_gridspec(2, max(1, len(Js)), height_ratios=[1.2, 1.0])
    subsets = [s for s in SUBSETS if s not in ("B", "total")]
    for i, J in enumerate(Js):
        ax = fig.add_subplot(gs[0, i])
        table = tables[J]
        cases = [c for c in table.index if c != EFD_ROW]
        width = 0.8 / max(1, len(cases))
        x = np.arange(len(subsets))
        for k, case in enumerate(cases):
            row = table.loc[case]
            means = row[[column_name(COLUMNS[s], "mean") for s in subsets]].to_numpy(
                dtype=np.float64, na_value=np.nan
            )
            stds = np.nan_to_num(
                row[[column_name(COLUMNS[s], "std") for s in subsets]].to_numpy(
                    dtype=np.float64, na_value=np.nan
                )
            )
            ax.bar(x + (k - (len(cases) - 1) / 2) * width, means, width, yerr=stds,
                   label=case, capsize=2)  # fmt: skip
        if EFD_ROW in table.index:
            refs = table.loc[EFD_ROW, [column_name(COLUMNS[s], "mean") for s in subsets]]
            for j, ref in enumerate(refs.to_numpy(dtype=np.float64)):
                ax.hlines(ref, j - 0.45, j + 0.45, colors="k", linestyles="--", lw=1)
            ax.plot([], [], "k--", lw=1, label="EFD")
        ax.set_xticks(x, [COLUMNS[s] for s in subsets], rotation=30, fontsize=8)
        ax.set_yscale("log")
        ax.set_title(f"{J} on the test set (mean, seed std)", fontsize=10)
        if i == 0:
            ax.legend(fontsize=7, ncol=2)
    ax = fig.add_subplot(gs[1, :])
    colours = {J: f"C{k}" for k, J in enumerate(OBJECTIVE_NAMES)}
    for key, rows in sorted(histories.items()):
        if not rows:
            continue
        J = next((J for J in OBJECTIVE_NAMES if f"objective={J}" in key), "")
        ev = [r[0] for r in rows]
        best = [r[1] for r in rows]
        ax.plot(ev, best, lw=0.9, color=colours.get(J, "0.4"), alpha=0.8)
    for J, c in colours.items():
        ax.plot([], [], color=c, label=f"objective {J}")
    ax.set_yscale("log")
    ax.set_xlabel("evaluations")
    ax.set_ylabel("best training J so far")
    ax.set_title("convergence of every job", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return Path(path)


# ---------------------------------------------------------------- figures (per job)


def plot_convergence(
    history: Sequence[Mapping[str, float]], path: str | Path, title: str = ""
) -> Path:
    """The paper's Fig. 5: J of each generation's best and min J so far vs evaluations.

    ``history``: rows with evaluations, best_f, best_so_far and restart (the history of
    sweep.identification.cmaes).
    Restarts are dashed vertical lines; the optimum is marked. Returns ``path``.
    """
    if not history:
        raise ValueError("empty history: nothing to plot")
    evals = np.array([row["evaluations"] for row in history], dtype=np.float64)
    best = np.array([row["best_f"] for row in history], dtype=np.float64)
    so_far = np.array([row["best_so_far"] for row in history], dtype=np.float64)
    restart = np.array([row.get("restart", 0.0) for row in history], dtype=np.float64)
    fig = Figure(figsize=(7.0, 4.0), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(evals, best, lw=0.8, color="tab:blue", label="J of the generation's best")
    ax.plot(evals, so_far, lw=1.6, color="tab:red", label="min J so far")
    for k, i in enumerate(np.flatnonzero(np.diff(restart) != 0) + 1):
        ax.axvline(evals[i - 1], color="0.5", lw=0.7, ls="--", label="restart" if k == 0 else None)
    i_opt = int(np.flatnonzero(so_far == so_far[-1])[0])
    ax.plot(evals[i_opt], so_far[i_opt], "o", color="tab:red", ms=5)
    ax.annotate(
        f"optimum {so_far[i_opt]:.4g} at {int(evals[i_opt])} evaluations",
        (evals[i_opt], so_far[i_opt]),
        textcoords="offset points",
        xytext=(-4, 8) if evals[i_opt] > 0.5 * evals[-1] else (4, 8),
        ha="right" if evals[i_opt] > 0.5 * evals[-1] else "left",
        fontsize=8,
    )
    if np.all(best > 0):
        ax.set_yscale("log")
    ax.set_xlabel("function evaluations")
    ax.set_ylabel("J")
    if title:
        ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    out = Path(path)
    fig.savefig(out, dpi=120)
    return out


def plot_trajectories(
    recorded_x: Any,
    simulated: Mapping[str, Any],
    path: str | Path,
    title: str = "",
    dt: float = 0.1,
) -> Path:
    """The paper's Figs. 6-8: the x0-y0 track (equal aspect, x0 up) over time series of u, v_m,
    r and psi, recorded (black) against each simulated model.

    ``recorded_x`` (N, 6) states (x0, u, y0, v_m, psi, r); ``simulated`` {label: (M, 6)} with
    NaN after a divergence allowed; ``dt`` [s] the sample interval. Returns ``path``.
    """
    rec = np.asarray(recorded_x, dtype=np.float64)
    sims = {label: np.asarray(x, dtype=np.float64) for label, x in simulated.items()}
    for label, x in {"recorded_x": rec, **sims}.items():
        if x.ndim != 2 or x.shape[1] != 6:
            raise ValueError(f"{label}: expected states of shape (N, 6), got {x.shape}")
    fig = Figure(figsize=(10.0, 10.0), layout="constrained")
    grid = fig.add_gridspec(3, 2, height_ratios=(1.6, 1.0, 1.0))
    track = fig.add_subplot(grid[0, :])
    series = [fig.add_subplot(grid[1 + i // 2, i % 2]) for i in range(4)]
    lines: list[tuple[str, FloatArray, dict[str, Any]]] = [
        ("recorded", rec, {"color": "black", "lw": 1.4})
    ]
    lines += [(label, x, {"lw": 1.0}) for label, x in sims.items()]
    panels = [  # (state index, scale, axis label)
        (1, 1.0, "u [m/s]"),
        (3, 1.0, "v_m [m/s]"),
        (5, 180.0 / np.pi, "r [deg/s]"),
        (4, 180.0 / np.pi, "psi [deg]"),
    ]
    for label, x, style in lines:
        t = np.arange(x.shape[0]) * dt
        (line,) = track.plot(x[:, 2], x[:, 0], label=label, **style)
        track.plot(x[0, 2], x[0, 0], "o", color=line.get_color(), ms=4)
        for ax, (j, scale, _) in zip(series, panels, strict=True):
            ax.plot(t, x[:, j] * scale, color=line.get_color(), lw=style["lw"])
    track.set_aspect("equal", adjustable="datalim")
    track.set_xlabel("y0 [m]")
    track.set_ylabel("x0 [m]")
    track.legend(fontsize=8)
    track.grid(alpha=0.3)
    for ax, (_, _, ylabel) in zip(series, panels, strict=True):
        ax.set_xlabel("t [s]")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    out = Path(path)
    fig.savefig(out, dpi=110)
    return out


# ---------------------------------------------------------------- command line


def run(argv: Sequence[str] | None = None) -> dict[str, pd.DataFrame]:
    """Parse arguments, read the sweep, print, write and log; returns the tables."""
    from sweep.service.tracking import MlflowTracker, default_tracking_uri, sqlite_path

    ap = argparse.ArgumentParser(prog="python -m sweep.report", description=__doc__.splitlines()[0])
    ap.add_argument("--tracking-uri", help="MLflow tracking URI (default sqlite:///./mlflow.db)")
    ap.add_argument("--experiment", default="mmg-sweep", help="MLflow experiment name")
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--sweep", help="sweep name (default: the newest sweep)")
    which.add_argument("--run-id", help="the sweep's parent run id")
    ap.add_argument("--out", required=True, help="directory for the table files")
    ap.add_argument("--no-log", action="store_true", help="do not log the files to MLflow")
    args = ap.parse_args(argv)

    uri = args.tracking_uri or default_tracking_uri()
    db = sqlite_path(uri)
    if db is not None and not db.is_file():
        raise ReportError(f"no MLflow store at {db} (tracking URI {uri})")
    if args.sweep is not None and ("'" in args.sweep or "\\" in args.sweep):
        raise ReportError(f"sweep names contain no quotes or backslashes: {args.sweep!r}")
    tracker = MlflowTracker(uri, args.experiment)
    if args.run_id:
        parent = args.run_id
        name = tracker.sweep_name(parent)
    else:
        found = tracker.find_sweep(args.sweep)
        if found is None:
            what = f"sweep {args.sweep!r}" if args.sweep else "no sweep"
            raise ReportError(f"{what} not found in experiment {args.experiment!r} at {uri}")
        parent, name = found, args.sweep or tracker.sweep_name(found)
    outcomes = tracker.job_outcomes(parent)
    tables = summary_tables(outcomes, tracker.efd_reference(parent))
    print(format_table(tables["J2"], f"J2 on the test set, sweep {name} ({len(outcomes)} jobs)"))
    files = write_tables(tables, args.out)
    if not args.no_log:
        tracker.finish_sweep(parent, tables, files, terminate=False)
    print(
        f"wrote {len(files)} files to {args.out}"
        + ("" if args.no_log else f"; logged to run {parent}")
    )
    return tables


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: exit status 0, or 2 with a one-line message for an unknown store or sweep."""
    from sweep.service.tracking import TrackingError

    try:
        run(argv)
    except (ReportError, TrackingError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
