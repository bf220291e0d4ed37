"""Summary tables (the paper's Tables 6-8) of a sweep, regenerated from MLflow.

The command line of :mod:`sweep.service.tables`::

    python -m sweep.report [--tracking-uri URI] [--experiment NAME] [--sweep NAME | --run-id ID]
                           --out DIR [--no-log]

regenerates the tables of a finished or partial sweep from MLflow (the newest sweep if neither
``--sweep`` nor ``--run-id`` is given), prints the J2 table, writes J{1,2,3}.{csv,parquet,md,html}
to DIR and logs them to the sweep's parent run under ``summary/`` (without changing its status).
An unknown sweep or store exits with status 2 and a one-line message. The tables' layout is
described in :mod:`sweep.service.tables`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import pandas as pd

from sweep.service.tables import format_table, summary_tables, write_tables
from sweep.service.tracking import MlflowTracker, TrackingError, default_tracking_uri, sqlite_path

__all__ = ["ReportError", "main", "run"]


class ReportError(Exception):
    """A user mistake (unknown store or sweep), reported as one line."""


def run(argv: Sequence[str] | None = None) -> dict[str, pd.DataFrame]:
    """Parse arguments, read the sweep, print, write and log; returns the tables ({J: table})."""
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
    try:
        run(argv)
    except (ReportError, TrackingError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
