"""Publish a finished sweep beside the paper's numbers: ``docs/results.md`` and its figures.

Usage::

    python -m sweep.publish --sweep NAME [--tracking-uri URI] [--out docs]
                            [--params-out results/best_params.json] [--discussion FILE]

Reads the sweep's MLflow runs and writes the three tables in the paper's layout (each cell
"ours mean (std) / paper mean"), each pair's Total relative to the EFD Total, the best pair's
(lowest mean J2 Total) best parameters as JSON (with the metadata that lets
``python -m sweep.evaluate --params <it> --set test`` reproduce them) and its plots, the wall
times, and the ``--discussion`` Markdown verbatim.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import statistics
import sys
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mmg.params import Parameters
from sweep.service.outcome import COLUMNS, SUBSETS

#: test subsets in the column order of the paper's Tables 6-8
PAPER_ORDER = ("B-S", "B-P", "B", "R", "T", "Z", "total")
#: the nine (objective, training set) pairs, "J1-R" ... "J3-TZR"
CASES = tuple(f"{J}-{T}" for J in ("J1", "J2", "J3") for T in ("R", "TR", "TZR"))

# Miyauchi et al. (2022), Tables 6-8: means over three seeds (columns in PAPER_ORDER), and the
# standard deviation of the Total. Table 6 prints the J2-TZR row as "J1-TZR" (a typo).
_P = dict[str, tuple[float, ...]]
PAPER: dict[str, _P] = {
    "J1": {
        "EFD": (251.9, 44.2, 296.1, 147.6, 843.8, 153.6, 1441.1),
        "J1-R": (144.4, 55.2, 199.6, 66.5, 167.4, 64.1, 497.7),
        "J1-TR": (126.7, 78.1, 204.8, 88.2, 156.6, 71.4, 521.0),
        "J1-TZR": (146.2, 76.8, 222.9, 80.6, 217.9, 57.3, 578.7),
        "J2-R": (108.5, 58.8, 167.3, 74.3, 183.7, 67.9, 493.2),
        "J2-TR": (99.4, 64.6, 164.0, 80.3, 229.2, 65.0, 538.5),
        "J2-TZR": (174.3, 65.7, 240.0, 74.8, 208.6, 68.8, 592.2),
        "J3-R": (154.2, 85.4, 239.5, 144.9, 256.6, 74.2, 715.2),
        "J3-TR": (281.0, 57.7, 338.7, 220.6, 586.5, 69.9, 1215.7),
        "J3-TZR": (270.2, 312.5, 582.7, 236.1, 233.3, 92.1, 1144.3),
    },
    "J2": {
        "EFD": (737.2, 453.1, 1190.3, 478.8, 1259.5, 709.3, 3637.9),
        "J1-R": (485.0, 183.3, 668.4, 159.5, 253.0, 597.5, 1678.3),
        "J1-TR": (431.9, 387.4, 819.4, 206.9, 207.4, 608.7, 1842.3),
        "J1-TZR": (428.4, 331.1, 795.5, 176.9, 339.0, 583.7, 1859.0),
        "J2-R": (359.9, 224.9, 584.8, 154.6, 259.8, 605.5, 1604.7),
        "J2-TR": (310.0, 258.7, 568.8, 178.3, 308.5, 604.2, 1659.7),
        "J2-TZR": (523.8, 266.8, 790.0, 206.9, 274.0, 555.7, 1827.2),
        "J3-R": (415.5, 392.2, 807.7, 300.9, 335.3, 561.3, 2005.2),
        "J3-TR": (647.7, 332.6, 980.3, 432.8, 1049.1, 500.3, 2962.5),
        "J3-TZR": (677.9, 791.4, 1469.3, 534.0, 301.0, 650.6, 2955.0),
    },
    "J3": {
        "EFD": (485.3, 408.9, 894.2, 331.2, 415.7, 555.7, 2196.9),
        "J1-R": (340.6, 128.2, 468.8, 92.9, 85.5, 533.4, 1180.6),
        "J1-TR": (305.3, 309.3, 614.6, 118.7, 50.8, 537.3, 1321.4),
        "J1-TZR": (282.2, 254.3, 536.5, 96.3, 121.1, 526.4, 1280.3),
        "J2-R": (251.4, 166.1, 417.5, 80.3, 76.1, 537.6, 1111.5),
        "J2-TR": (210.6, 194.1, 404.7, 98.0, 79.3, 539.2, 1121.2),
        "J2-TZR": (349.5, 201.1, 550.6, 132.1, 65.4, 487.0, 1235.0),
        "J3-R": (261.3, 306.8, 568.1, 156.1, 78.8, 487.1, 1290.0),
        "J3-TR": (366.6, 274.9, 641.6, 212.2, 462.6, 430.4, 1746.7),
        "J3-TZR": (407.7, 479.0, 886.7, 297.8, 67.7, 558.5, 1810.7),
    },
}


def case_stats(
    outcomes: Sequence[Mapping[str, Any]],
) -> dict[str, dict[str, dict[str, tuple[float, float, int]]]]:
    """{J: {case: {subset: (mean, std, n)}}} over the non-rejected seeds of each case."""
    out: dict[str, dict[str, dict[str, tuple[float, float, int]]]] = {}
    for J in ("J1", "J2", "J3"):
        out[J] = {}
        for case in CASES:
            obj, train = case.split("-")
            runs = [
                o
                for o in outcomes
                if o["objective"] == obj and o["train"] == train and not o["rejected"]
            ]
            if not runs:
                continue
            out[J][case] = {}
            for s in SUBSETS:
                values = [float(o["test"][J][s]) for o in runs]
                std = statistics.stdev(values) if len(values) > 1 else math.nan
                out[J][case][s] = (statistics.fmean(values), std, len(values))
    return out


def _cell(mean: float, std: float) -> str:
    return f"{mean:.1f}" if math.isnan(std) else f"{mean:.1f} ({std:.1f})"


def tables_markdown(stats: Mapping[str, Any], efd: Mapping[str, Mapping[str, float]]) -> str:
    """The three tables, cells "ours mean (std) / paper mean"; best ours per column in bold."""
    lines: list[str] = []
    for J in ("J1", "J2", "J3"):
        cases = [c for c in CASES if c in stats[J]]
        best = {s: min(cases, key=lambda c: stats[J][c][s][0]) for s in PAPER_ORDER}
        lines.append(f"### {J} on the test set (ours / paper)\n")
        lines.append("| Case | " + " | ".join(COLUMNS[s] for s in PAPER_ORDER) + " |")
        lines.append("|---|" + "---:|" * len(PAPER_ORDER))
        efd_cells = [
            f"{efd[J][s]:.1f} / {PAPER[J]['EFD'][i]:.1f}" for i, s in enumerate(PAPER_ORDER)
        ]
        lines.append("| EFD | " + " | ".join(efd_cells) + " |")
        for c in cases:
            cells = []
            for i, s in enumerate(PAPER_ORDER):
                mean, std, _ = stats[J][c][s]
                text = _cell(mean, std)
                if best[s] == c:
                    text = f"**{text}**"
                cells.append(f"{text} / {PAPER[J][c][i]:.1f}")
            lines.append(f"| {c} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def ratios_markdown(stats: Mapping[str, Any], efd: Mapping[str, Mapping[str, float]]) -> str:
    """Each pair's Total divided by the EFD Total, ours and the paper's."""
    lines = [
        "| Case | J1 ours | J1 paper | J2 ours | J2 paper | J3 ours | J3 paper |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for c in CASES:
        if c not in stats["J2"]:
            continue
        cells = []
        for J in ("J1", "J2", "J3"):
            ours = stats[J][c]["total"][0] / efd[J]["total"]
            paper = PAPER[J][c][-1] / PAPER[J]["EFD"][-1]
            cells += [f"{ours:.2f}", f"{paper:.2f}"]
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m sweep.publish``: write ``results.md``, the best parameters and the figures.

    Returns the exit status: 0 on success, 2 when the sweep is unknown or has no finished job.
    """
    from sweep.service.tracking import MlflowTracker, default_tracking_uri

    ap = argparse.ArgumentParser(
        prog="python -m sweep.publish", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--sweep", required=True)
    ap.add_argument("--tracking-uri", default=None)
    ap.add_argument("--experiment", default="mmg-sweep")
    ap.add_argument("--out", default="docs")
    ap.add_argument("--params-out", default="results/best_params.json")
    ap.add_argument("--discussion", default=None, help="Markdown file included as the discussion")
    ap.add_argument(
        "--commit", default=None, help="source commit of the sweep, if its runs did not record it"
    )
    args = ap.parse_args(argv)

    tracker = MlflowTracker(args.tracking_uri or default_tracking_uri(), args.experiment)
    parent = tracker.find_sweep(args.sweep)
    if parent is None:
        print(f"error: no sweep named {args.sweep!r} in {tracker.uri}", file=sys.stderr)
        return 2
    outcomes = tracker.job_outcomes(parent)
    if not outcomes:
        print(f"error: sweep {args.sweep!r} has no finished job", file=sys.stderr)
        return 2
    efd = tracker.efd_reference(parent)
    stats = case_stats(outcomes)
    out = Path(args.out)
    figures = out / "figures"
    figures.mkdir(parents=True, exist_ok=True)

    best_case = min(stats["J2"], key=lambda c: stats["J2"][c]["total"][0])
    obj, train = best_case.split("-")
    candidates = [o for o in outcomes if o["objective"] == obj and o["train"] == train]
    best = min((o for o in candidates if not o["rejected"]), key=lambda o: o["test"]["J2"]["total"])
    client = tracker.client
    with tempfile.TemporaryDirectory() as tmp:
        local = Path(client.download_artifacts(best["run_id"], "", tmp))
        params = Parameters.load_json(local / "best_params.json")
        meta = json.loads((local / "best_params.json").read_text()).get("metadata", {})
        for png in sorted(local.rglob("*.png")):
            shutil.copy(png, figures / png.name)
    run = client.get_run(best["run_id"])
    budget = run.data.params.get("budget.max_evaluations", meta.get("budget", "?"))
    shipped = Path(args.params_out)
    shipped.parent.mkdir(parents=True, exist_ok=True)
    params.save_json(
        shipped,
        objective=obj,
        train=train,
        seed=int(best["seed"]),
        budget=budget,
        sweep=args.sweep,
        job_key=best["job_key"],
        commit=args.commit or run.data.tags.get("git_commit") or meta.get("commit", "unknown"),
        test=best["test"],
    )

    seconds = [float(o["seconds"]) for o in outcomes]
    p_info = client.get_run(parent).info
    grid_s = ((p_info.end_time or p_info.start_time) - p_info.start_time) / 1000.0
    lines = [
        "# Results: the paper's study on the real recordings",
        "",
        f"Sweep `{args.sweep}`: {len(outcomes)} finished jobs (objectives J1, J2, J3 x training "
        f"sets R, TR, TZR x seeds), {budget} evaluations per job. Generated by "
        f"`python -m sweep.publish --sweep {args.sweep}` from the MLflow runs.",
        "",
        "## Tables 6-8: J1, J2, J3 on the test set",
        "",
        "Mean (standard deviation) over seeds, ours / the paper's mean. Bold: our best per column.",
        "",
        tables_markdown(stats, efd),
        "## Total relative to the EFD model",
        "",
        ratios_markdown(stats, efd),
        "",
        f"## The best pair: {best_case} (seed {best['seed']})",
        "",
        f"Parameters: [`{shipped}`](../{shipped}) "
        f"(`python -m sweep.evaluate --params {shipped} --set test` reproduces the row below).",
        "",
        "| | " + " | ".join(COLUMNS[s] for s in PAPER_ORDER) + " |",
        "|---|" + "---:|" * len(PAPER_ORDER),
    ]
    for J in ("J1", "J2", "J3"):
        lines.append(
            f"| {J} | " + " | ".join(f"{best['test'][J][s]:.1f}" for s in PAPER_ORDER) + " |"
        )
    lines += ["", "| parameter | EFD | identified |", "|---|---:|---:|"]
    from mmg.params import efd_parameters

    efd_vec = efd_parameters().theta._asdict()
    for name, value in params.theta._asdict().items():
        lines.append(f"| `{name}` | {efd_vec[name]:.5g} | {value:.5g} |")
    lines += ["", "### Figures", ""]
    for png in sorted(figures.glob("*.png")):
        lines.append(f"![{png.stem}](figures/{png.name})")
    lines += [
        "",
        "## Wall time",
        "",
        f"Grid: {grid_s / 60:.0f} min on the 2-core development machine. Per job: "
        f"mean {statistics.fmean(seconds):.0f} s, min {min(seconds):.0f} s, "
        f"max {max(seconds):.0f} s (optimisation only; two jobs ran at a time).",
        "",
    ]
    if args.discussion:
        lines += ["## Discussion", "", Path(args.discussion).read_text().strip(), ""]
    (out / "results.md").write_text("\n".join(lines))
    print(f"wrote {out / 'results.md'}, {shipped} and {len(list(figures.glob('*.png')))} figures")
    return 0


if __name__ == "__main__":
    sys.exit(main())
