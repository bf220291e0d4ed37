"""Evaluate a parameter set on recordings: J1, J2, J3 in the layout of the paper's Tables 6-8.

Usage::

    python -m sweep.evaluate --params {efd|PATH.json} (--set test | --recordings PATH [PATH ...])
                             [--manoeuvres [--intervals [SET] | --samples S.npy]
                                           [--figure PNG]]
                             [--json OUT] [--data-root DIR]
    python -m sweep.evaluate --params PATH.json --manoeuvres --intervals [SET]
                             [--objective J] [--draws 50] [--seed 0] ...

``--set test`` is the paper's test set under the data root (``--data-root``, else $MMG_DATA_DIR,
else the user cache; see :func:`sweep.data.datasets.data_root`); ``--set R|TR|TZR`` a training set.
``--recordings`` takes CSV/Parquet files or directories. The printed table has one row per
objective; for the test set the columns are those of the paper (Test-B-S, Test-B-P,
Test-B-S + Test-B-P, Test-R, Test-T, Test-Z, Total), otherwise one column per recording file and
Total. ``--json OUT`` writes ``{"J1": {column: value}, "J2": {...}, "J3": {...}}``.
A parameter set with a bounded effect (``<effect>@held(...)``, as the diagnosis writes it) also
names every recording that leaves the box of states the effect was fitted on (``departures`` in
the JSON).

``--manoeuvres`` adds the standard manoeuvres (turning circle, 10/10 and 20/20 zigzags, crash
stop) at full scale with the margins to the IMO criteria, and the turning and zigzag runs among
the recordings (without ``--set`` and ``--recordings``: the test set's Test-T and Test-Z)
against the model's prediction (:mod:`sweep.data.standard_manoeuvres`); in the JSON under
``"manoeuvres"``. Intervals need parameter samples. ``--intervals [SET]`` draws them from the
parameters' own uncertainty (:mod:`sweep.identification.uncertainty`, as
``python -m sweep.uncertainty`` computes it) on the training set SET (R, TR, TZR, or test), by
default the ``train`` the file's metadata names, with the objective ``--objective`` (default:
the file's, else J2): ``--draws`` vectors (50) from ``np.random.default_rng(--seed)`` (0).
``--samples S.npy`` takes them from a file instead (an array (S, n) of flat parameter vectors).
Without either the tables hold point values; the EFD parameters have no identification
uncertainty. ``--figure PNG`` draws the predicted manoeuvres over the recorded runs.

A user mistake (a bad recording, a bad parameter file, missing data) exits with status 2 and a
message that names the file and the problem; never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mmg import Effect, get_effect
from mmg.domain import split_name
from mmg.params import Parameters
from sweep.data.datasets import load_split
from sweep.data.manoeuvre_figures import plot_manoeuvres
from sweep.data.manoeuvre_tables import (
    format_recorded,
    format_standard,
    recorded_table,
    settings_note,
    standard_table,
)
from sweep.data.objective import OBJECTIVES, Objective
from sweep.data.parameters import load_parameters, parameter_metadata
from sweep.data.ranges import Ranges, departures
from sweep.data.recordings import Recording, read_recordings
from sweep.data.standard_manoeuvres import (
    RecordedRun,
    compare_recorded,
    find_manoeuvre,
    predict_standard,
)
from sweep.errors import UserError, command_status
from sweep.identification.uncertainty import NOT_OPTIMUM, parameter_uncertainty

#: the paper's column order (Tables 6-8)
TEST_COLUMNS = (
    "Test-B-S",
    "Test-B-P",
    "Test-B-S + Test-B-P",
    "Test-R",
    "Test-T",
    "Test-Z",
    "Total",
)

Table = dict[str, dict[str, float]]


def effects_of(params: Parameters) -> tuple[Effect, ...]:
    """The catalog effects a parameter set carries (``effects`` of its JSON), in its order."""
    try:
        return tuple(get_effect(name) for name, _ in params.effects)
    except KeyError as exc:
        raise UserError(str(exc.args[0])) from None


def evaluate_table(
    params: Parameters, recordings: Sequence[Recording], labels: Sequence[str]
) -> Table:
    """{J: {label: value}} plus "Total", for one parameter set (with the effects it carries)."""
    obj = Objective(recordings, labels=labels, effects=effects_of(params), ship=params.ship)
    raw = obj.table(params)
    table: Table = {}
    for J in OBJECTIVES:
        row = {label: float(raw[J][label][0]) for label in labels}
        row["Total"] = float(sum(row.values()))
        table[J] = row
    return table


def paper_layout(table: Table) -> Table:
    """Reorder a test-set table into the paper's columns, adding Test-B-S + Test-B-P."""
    out: Table = {}
    for J, row in table.items():
        full = dict(row)
        full["Test-B-S + Test-B-P"] = row["Test-B-S"] + row["Test-B-P"]
        out[J] = {c: full[c] for c in TEST_COLUMNS}
    return out


def format_table(table: Table, title: str = "") -> str:
    """A fixed-width text table, one row per objective, values with one decimal."""
    columns = list(next(iter(table.values())))
    widths = [max(len(c), 9) for c in columns]
    lines = [title] if title else []
    lines.append("    " + "  ".join(c.rjust(w) for c, w in zip(columns, widths, strict=True)))
    for J, row in table.items():
        cells = "  ".join(f"{row[c]:.1f}".rjust(w) for c, w in zip(columns, widths, strict=True))
        lines.append(f"{J:<4}{cells}")
    return "\n".join(lines)


def _recordings_from_set(name: str, root: str | None) -> tuple[list[Recording], list[str], bool]:
    split = load_split(name)
    loaded = split.load(root)
    is_test = set(loaded) == {"Test-R", "Test-T", "Test-Z", "Test-B-S", "Test-B-P"}
    if is_test:
        return list(loaded.values()), list(loaded), True
    recs = list(loaded.values())
    return recs, [Path(rel).name for rel in split.files], False


def load_samples(path: str) -> np.ndarray:
    """Parameter samples (S, n) from a .npy file (a UserError naming the file otherwise)."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: no such samples file (a .npy array of parameter vectors)")
    try:
        samples = np.load(p, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise UserError(f"{p}: not a .npy array of parameter vectors ({exc})") from None
    if samples.ndim != 2 or samples.dtype.kind not in "fi":
        raise UserError(f"{p}: expected a numeric array (S, n) of parameter vectors")
    return np.asarray(samples, dtype=np.float64)


def interval_samples(
    params: Parameters,
    spec: str,
    set_name: str,
    objective: str | None,
    draws: int,
    seed: int,
    root: str | None = None,
) -> tuple[np.ndarray, str]:
    """(draws, n) parameter vectors drawn from the intervals of ``params`` (the file ``spec``)
    on the training set ``set_name`` ("" : the file's metadata ``train``) with ``objective``
    (None: the file's, else J2), from ``np.random.default_rng(seed)``; and a sentence saying
    where they come from. UserError for EFD (not identified: no such uncertainty), a file that
    names no training set, or intervals that cannot be computed."""
    if spec.lower() == "efd":
        raise UserError(
            "efd: the captive-model parameters were not identified on recordings, so they have "
            "no identification uncertainty; --intervals needs identified parameters (or give "
            "--samples)"
        )
    if draws < 1:
        raise UserError(f"--draws {draws}: give at least one draw, e.g. 50")
    meta = parameter_metadata(spec)
    name = set_name or meta.get("train")
    if not isinstance(name, str) or not name:
        raise UserError(f"{spec} names no training set: give --intervals R|TR|TZR|test")
    J = objective or meta.get("objective") or "J2"
    if J not in OBJECTIVES:
        raise UserError(f"{spec}: unknown objective {J!r} in its metadata")
    split = "paper" if name.lower() == "test" else name
    recs = list(load_split(split).load(root).values())
    try:
        u = parameter_uncertainty(params, recs, str(J), effects_of(params))
    except ValueError as exc:
        raise UserError(f"{spec} on set {name}: {exc}") from None
    c = u.counts
    text = (
        f"The samples: {draws} draws (seed {seed}) from the parameters' "
        f"{round(100 * u.level)} % intervals on set {name} with {J} "
        f"({c['determined']} of {len(u.names)} parameters determined; "
        "python -m sweep.uncertainty prints them)."
    )
    if float(u.meta.get("newton_step_sd", 0.0)) > NOT_OPTIMUM:
        text += (
            f" Warning: these parameters are probably not an optimum of {J} on set {name}; "
            "the intervals describe the curvature there."
        )
    return u.sample(draws, np.random.default_rng(seed)), text


def manoeuvre_runs(recs: Sequence[Recording], labels: Sequence[str]) -> list[RecordedRun]:
    """The turning and zigzag runs among ``recs`` (the others are left out)."""
    found = (find_manoeuvre(rec, label) for rec, label in zip(recs, labels, strict=True))
    return [r for r in found if r is not None]


def manoeuvres(
    params: Parameters,
    runs: Sequence[RecordedRun],
    samples: Any = None,
    figure: str | None = None,
    name: str = "",
    source: str = "",
) -> dict[str, Any]:
    """Print the standard manoeuvres and the recorded runs against the model; return both
    tables as rows (``"standard"``, ``"recorded"``) with the settings (``"note"``).

    ``samples``: None, or parameter vectors (S, n) / a sequence of Parameters for intervals
    (e.g. drawn from the identification's uncertainty); ``source`` says where they come from."""
    effects = effects_of(params)
    pred = predict_standard(params, samples, effects)
    comparisons = compare_recorded(params, runs, samples, effects)
    standard, recorded = standard_table(pred), recorded_table(comparisons, L=params.ship.L_pp)
    note = settings_note(pred)
    if samples is None:
        note += (
            " Point values only: intervals need parameter samples (--intervals: drawn from "
            "the identification's uncertainty, or --samples)."
        )
    else:
        note += f" Intervals: 5-95 % over {pred.n_samples} parameter samples."
        note += f" {source}" if source else ""
    print(format_standard(standard, f"Standard manoeuvres of {name}"))
    print(note)
    if comparisons:
        print(format_recorded(recorded, "\nRecorded runs against the model (model scale)"))
    else:
        print("\nNo turning or zigzag run among the recordings.")
    if figure:
        plot_manoeuvres(pred, comparisons, figure, title=f"Manoeuvres of {name}")
    return {"note": note, "standard": _json_ready(standard), "recorded": _json_ready(recorded)}


def _json_ready(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows with NaN (a quantity not reached) as None, which JSON can hold."""
    return [
        {k: None if isinstance(v, float) and v != v else v for k, v in row.items()} for row in rows
    ]


def domain_departures(
    params: Parameters, recs: Sequence[Recording], labels: Sequence[str]
) -> list[dict[str, Any]]:
    """The recordings that leave the box of states a bounded effect of ``params`` was fitted
    on (``<effect>@held(...)``, :mod:`mmg.domain`), printed: effect, recording, variable and by
    how much."""
    out: list[dict[str, Any]] = []
    for name, _ in params.effects:
        inner, box = split_name(name)
        if box is None:
            continue
        found = departures(Ranges.of_domain(box), recs, labels, params.ship)
        how = (
            "held at its boundary value, above the top speed its non-dimensional force"
            if box.mode == "held"
            else "switched off"
        )
        if found:
            print(f"\nBeyond the states {inner} was fitted on ({how} there):")
        for d in found:
            print(f"  {d.text()}")
            out.append({"effect": name, **d.as_dict()})
    return out


def run(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Parse arguments, evaluate, print; returns the table (J1-J3 and, with --manoeuvres,
    ``"manoeuvres"``; raises UserError on bad input)."""
    ap = argparse.ArgumentParser(
        prog="python -m sweep.evaluate", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--params", required=True, help="'efd' or a parameter JSON file")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--set", dest="set_name", help="'test' (the paper's test set), R, TR or TZR")
    src.add_argument("--recordings", nargs="+", help="CSV/Parquet files or directories")
    ap.add_argument("--json", dest="json_out", help="write the table as JSON to this file")
    ap.add_argument("--data-root", help="data directory (default: $MMG_DATA_DIR or user cache)")
    ap.add_argument(
        "--manoeuvres", action="store_true", help="standard manoeuvres and recorded runs"
    )
    draw = ap.add_mutually_exclusive_group()
    draw.add_argument(
        "--intervals",
        nargs="?",
        const="",
        metavar="SET",
        help="with --manoeuvres: intervals from draws of the parameters' uncertainty on SET "
        "(R, TR, TZR, test; default: the training set of the file's metadata)",
    )
    draw.add_argument("--samples", help="with --manoeuvres: parameter samples (S, n) in a .npy")
    ap.add_argument(
        "--objective", choices=OBJECTIVES, help="with --intervals: default the file's, else J2"
    )
    ap.add_argument("--draws", type=int, default=50, help="with --intervals: draws (50)")
    ap.add_argument("--seed", type=int, default=0, help="with --intervals: seed of the draws (0)")
    ap.add_argument("--figure", help="with --manoeuvres: draw the manoeuvres to this PNG")
    args = ap.parse_args(argv)
    if not (args.set_name or args.recordings or args.manoeuvres):
        ap.error("one of the arguments --set --recordings --manoeuvres is required")
    drawn = args.intervals is not None
    if (args.samples or args.figure or drawn) and not args.manoeuvres:
        ap.error("--intervals, --samples and --figure go with --manoeuvres")

    params = load_parameters(args.params)
    samples = load_samples(args.samples) if args.samples else None
    source = ""
    if drawn:
        samples, source = interval_samples(
            params, args.params, args.intervals, args.objective, args.draws, args.seed,
            args.data_root,
        )  # fmt: skip
    if args.set_name:
        name = "paper" if args.set_name.lower() == "test" else args.set_name
        recs, labels, is_test = _recordings_from_set(name, args.data_root)
    elif args.recordings:
        missing = [p for p in args.recordings if not Path(p).exists()]
        if missing:
            raise UserError(f"{missing[0]}: no such file or directory")
        recs = read_recordings(args.recordings)
        if not recs:
            raise UserError(f"no CSV or Parquet recordings found in {' '.join(args.recordings)}")
        labels = [r.path.name if r.path else r.name for r in recs]
        is_test = False
    else:  # --manoeuvres alone: the test set's turning and zigzag runs
        loaded = load_split("paper").load(args.data_root)
        recs, labels, is_test = [loaded["Test-T"], loaded["Test-Z"]], ["Test-T", "Test-Z"], False
    out: dict[str, Any] = {}
    if args.set_name or args.recordings:
        table = evaluate_table(params, recs, labels)
        if is_test:
            table = paper_layout(table)
        title = f"J1, J2, J3 of {args.params} on {args.set_name or 'the recordings'}"
        print(format_table(table, title))
        out.update(table)
        beyond = domain_departures(params, recs, labels)
        if beyond:
            out["departures"] = beyond
    if args.manoeuvres:
        runs = manoeuvre_runs(recs, labels)
        out["manoeuvres"] = manoeuvres(params, runs, samples, args.figure, args.params, source)
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=2) + "\n")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: exit status 0, or 2 with a one-line message for a user mistake."""
    return command_status(run, argv)


if __name__ == "__main__":
    sys.exit(main())
