"""How well recordings determine an identified model: 90 % intervals, statuses, trade-offs.

Usage::

    python -m sweep.uncertainty --params PATH.json [--set R|TR|TZR|test | --recordings PATH ...]
                                [--objective J1|J2|J3] [--level 0.9] [--json OUT]
                                [--markdown OUT] [--csv OUT] [--data-root DIR]

``--params`` should be an optimum of the objective on the recordings (a job's best parameters,
``sweep.identify``'s ``best_params.json``, a diagnosis's ``params_after.json``); the effects it
carries are judged with the 57 parameters. The recordings and the objective default to the
``train`` and ``objective`` the file's metadata names (a sweep's or ``sweep.identify``'s file
has them); otherwise give ``--set`` (a training set, or ``test``: the paper's test set) or
``--recordings`` (CSV/Parquet files or directories) and ``--objective`` (default J2).

Printed: the interval table (estimate, standard deviation, interval, half-width as a share of
the search box, status: determined, weakly determined or at a bound) and the combinations of
parameters that trade off; how they are computed and calibrated is in the user guide
(docs/guide/uncertainty.md) and :mod:`sweep.identification.uncertainty`. ``--json`` writes
:meth:`~sweep.identification.uncertainty.Uncertainty.as_dict`, ``--markdown`` the printed text,
``--csv`` the table.

A user mistake (a missing or bad file, an unknown set, too few windows) exits with status 2 and
a one-line message; never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from mmg.params import Parameters
from sweep.data.datasets import load_split
from sweep.data.objective import OBJECTIVES
from sweep.data.parameters import load_parameters, parameter_metadata
from sweep.data.recordings import Recording, read_recordings
from sweep.errors import UserError, command_status
from sweep.evaluate import effects_of
from sweep.identification.uncertainty import (
    Uncertainty,
    UncertaintySettings,
    parameter_uncertainty,
)


def _recordings(args: argparse.Namespace, meta: dict[str, object]) -> tuple[list[Recording], str]:
    """The recordings named on the command line (or in the file's metadata) and their label."""
    if args.recordings:
        missing = [p for p in args.recordings if not Path(p).exists()]
        if missing:
            raise UserError(f"{missing[0]}: no such file or directory")
        recs = read_recordings(args.recordings)
        if not recs:
            raise UserError(f"no CSV or Parquet recordings found in {' '.join(args.recordings)}")
        return recs, "the recordings"
    name = args.set_name or meta.get("train")
    if not isinstance(name, str) or not name:
        raise UserError(
            f"{args.params} names no training set: give --set R|TR|TZR|test or --recordings"
        )
    split = "paper" if name.lower() == "test" else name
    return list(load_split(split).load(args.data_root).values()), f"set {name}"


def run(argv: Sequence[str] | None = None) -> Uncertainty:
    """Parse arguments, compute, print, write; returns the intervals (UserError on bad input)."""
    ap = argparse.ArgumentParser(
        prog="python -m sweep.uncertainty", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--params", required=True, help="a parameter JSON file (or 'efd')")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--set", dest="set_name", help="R, TR, TZR or test (the paper's test set)")
    src.add_argument("--recordings", nargs="+", help="CSV/Parquet files or directories")
    ap.add_argument("--objective", choices=OBJECTIVES, help="default: the file's, else J2")
    ap.add_argument("--level", type=float, default=0.90, help="interval coverage (0.9)")
    ap.add_argument("--json", dest="json_out", help="write the intervals as JSON to this file")
    ap.add_argument("--markdown", dest="markdown_out", help="write the printed text here")
    ap.add_argument("--csv", dest="csv_out", help="write the interval table as CSV here")
    ap.add_argument("--data-root", help="data directory (default: $MMG_DATA_DIR or user cache)")
    args = ap.parse_args(argv)
    if not 0.0 < args.level < 1.0:
        raise UserError(f"--level {args.level}: give a coverage between 0 and 1, e.g. 0.9")

    params: Parameters = load_parameters(args.params)
    meta = parameter_metadata(args.params)
    objective = args.objective or meta.get("objective") or "J2"
    if objective not in OBJECTIVES:
        raise UserError(f"{args.params}: unknown objective {objective!r} in its metadata")
    recs, label = _recordings(args, meta)
    try:
        u = parameter_uncertainty(
            params,
            recs,
            str(objective),
            effects_of(params),
            UncertaintySettings(level=args.level),
        )
    except ValueError as exc:
        raise UserError(f"{args.params} on {label}: {exc}") from None
    text = f"# Intervals of {args.params} on {label}\n\n{u.to_markdown()}"
    print(text, end="")
    for out, content in (
        (args.json_out, json.dumps(u.as_dict(), indent=1, allow_nan=False) + "\n"),
        (args.markdown_out, text),
        (args.csv_out, u.to_csv()),
    ):
        if out:
            Path(out).write_text(content)
    return u


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: exit status 0, or 2 with a one-line message for a user mistake."""
    return command_status(run, argv)


if __name__ == "__main__":
    sys.exit(main())
