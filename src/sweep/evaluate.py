"""Evaluate a parameter set on recordings: J1, J2, J3 in the layout of the paper's Tables 6-8.

Usage::

    python -m sweep.evaluate --params {efd|PATH.json} (--set test | --recordings PATH [PATH ...])
                             [--json OUT] [--data-root DIR]

``--set test`` is the paper's test set under the data root (``--data-root``, else $MMG_DATA_DIR,
else the user cache; see :func:`sweep.data.datasets.data_root`); ``--set R|TR|TZR`` a training set.
``--recordings`` takes CSV/Parquet files or directories. The printed table has one row per
objective; for the test set the columns are those of the paper (Test-B-S, Test-B-P,
Test-B-S + Test-B-P, Test-R, Test-T, Test-Z, Total), otherwise one column per recording file and
Total. ``--json OUT`` writes ``{"J1": {column: value}, "J2": {...}, "J3": {...}}``.

A user mistake (a bad recording, a bad parameter file, missing data) exits with status 2 and a
message that names the file and the problem; never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

from mmg import Effect, get_effect
from mmg.params import Parameters
from sweep.data.datasets import load_split
from sweep.data.objective import OBJECTIVES, Objective
from sweep.data.parameters import load_parameters
from sweep.data.recordings import Recording, read_recordings
from sweep.errors import USER_ERRORS, UserError

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


def run(argv: Sequence[str] | None = None) -> Table:
    """Parse arguments, evaluate, print; returns the table (raises UserError on bad input)."""
    ap = argparse.ArgumentParser(
        prog="python -m sweep.evaluate", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--params", required=True, help="'efd' or a parameter JSON file")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--set", dest="set_name", help="'test' (the paper's test set), R, TR or TZR")
    src.add_argument("--recordings", nargs="+", help="CSV/Parquet files or directories")
    ap.add_argument("--json", dest="json_out", help="write the table as JSON to this file")
    ap.add_argument("--data-root", help="data directory (default: $MMG_DATA_DIR or user cache)")
    args = ap.parse_args(argv)

    params = load_parameters(args.params)
    if args.set_name:
        name = "paper" if args.set_name.lower() == "test" else args.set_name
        recs, labels, is_test = _recordings_from_set(name, args.data_root)
    else:
        missing = [p for p in args.recordings if not Path(p).exists()]
        if missing:
            raise UserError(f"{missing[0]}: no such file or directory")
        recs = read_recordings(args.recordings)
        if not recs:
            raise UserError(f"no CSV or Parquet recordings found in {' '.join(args.recordings)}")
        labels = [r.path.name if r.path else r.name for r in recs]
        is_test = False
    table = evaluate_table(params, recs, labels)
    if is_test:
        table = paper_layout(table)
    title = f"J1, J2, J3 of {args.params} on {args.set_name or 'the recordings'}"
    print(format_table(table, title))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(table, indent=2) + "\n")
    return table


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: exit status 0, or 2 with a one-line message for a user mistake."""
    warnings.simplefilter("default")
    try:
        run(argv)
    except USER_ERRORS as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
