"""Identify the MMG parameters from recordings: one restart CMA-ES job.

Library: :func:`identify`. Command line::

    python -m sweep.identify --train R --objective J2 --budget 30000 --seed 0 --out DIR
                             [--workers N] [--sigma0 0.1] [--bound-handling penalty]
                             [--x0 efd|PATH.json] [--max-seconds S] [--data-root DIR]

writes ``DIR/best_params.json`` (loadable by ``python -m sweep.evaluate --params``),
``DIR/history.csv`` (one row per generation), ``DIR/result.json`` (restarts, stop reasons,
evaluations, wall time, post-filter), ``DIR/uncertainty.md`` and ``DIR/uncertainty.json`` (how
well the recordings determine each parameter: :mod:`sweep.identification.uncertainty`) and
``DIR/checkpoint.pkl``; run the same command again to resume an interrupted job from its
checkpoint.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from mmg.params import ParameterError, Parameters, bounds, efd_parameters
from sweep.data.datasets import DataNotFoundError, SplitError, load_split
from sweep.data.objective import Objective
from sweep.data.recordings import Recording, RecordingError, read_recordings
from sweep.identification.cmaes import Box, Result, Settings, State, optimise, restart_table
from sweep.identification.workers import make_evaluator
from sweep.service.outcome import source_version


def identify(
    recordings: Sequence[Recording],
    objective: str = "J2",
    settings: Settings | None = None,
    x0: Parameters | None = None,
    workers: int | None = 0,
    checkpoint: str | Path | None = None,
    progress: Any = None,
) -> tuple[Result, Parameters]:
    """Run one job; returns the optimiser's result and the best parameters as Parameters.

    ``workers``: 0 evaluates in this process, None one process per core, k that many.
    """
    settings = settings or Settings()
    start = x0 or efd_parameters()
    obj = Objective(recordings, objective, ship=start.ship)
    lo, hi = bounds()
    box = Box(lo, hi)
    with make_evaluator(obj, workers) as evaluate:
        result = optimise(evaluate, box, start.vector(), settings, checkpoint, progress)
    best = Parameters.from_vector(result.theta, ship=start.ship)
    return result, best


def git_commit() -> str:
    """The source tree's commit (``unknown`` outside a checkout)."""
    return source_version()["commit"]


def _printer(stream: Any = sys.stderr, every: float = 2.0) -> Any:
    last = [0.0]

    def show(state: State, row: dict[str, float]) -> None:
        """Print one generation's progress line, at most once every ``every`` seconds."""
        now = time.perf_counter()
        if now - last[0] < every:
            return
        last[0] = now
        print(
            f"restart {int(row['restart'])} pop {int(row['popsize'])} "
            f"gen {int(row['generation'])} evals {int(row['evaluations'])}/"
            f"{state.settings.max_evaluations} best {row['best_so_far']:.2f} "
            f"sigma {row['sigma']:.3g}",
            file=stream,
            flush=True,
        )

    return show


def write_outputs(
    out: Path, result: Result, best: Parameters, meta: dict[str, Any]
) -> dict[str, Any]:
    """best_params.json, history.csv and result.json in ``out``; returns the summary."""
    out.mkdir(parents=True, exist_ok=True)
    best.save_json(out / "best_params.json", **meta, f=result.f, evaluations=result.evaluations)
    pd.DataFrame(result.history).to_csv(out / "history.csv", index=False)
    summary = {
        **meta,
        "f": result.f,
        "evaluations": result.evaluations,
        "seconds": result.seconds,
        "stop_reason": result.stop_reason,
        "rejected": result.rejected,
        "mean_outside": result.mean_outside,
        "restarts": restart_table(result),
    }
    (out / "result.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    return summary


def write_uncertainty(
    out: Path, best: Parameters, recs: Sequence[Recording], objective: str
) -> None:
    """``uncertainty.md`` and ``uncertainty.json`` of ``best`` on ``recs`` in ``out``, and one
    line on stdout; a failure is written to ``uncertainty_error.txt`` and said, not raised
    (the identification's result stands)."""
    from sweep.identification.uncertainty import parameter_uncertainty

    try:
        u = parameter_uncertainty(best, recs, objective)
    except Exception as exc:  # the intervals are an addition: never lose the job's result
        (out / "uncertainty_error.txt").write_text(f"{type(exc).__name__}: {exc}\n")
        print(f"intervals not computed: {type(exc).__name__}: {exc}")
        return
    (out / "uncertainty.md").write_text(u.to_markdown() + "\n")
    (out / "uncertainty.json").write_text(json.dumps(u.as_dict(), indent=2, default=float) + "\n")
    print(
        f"intervals: {', '.join(f'{v} {k}' for k, v in u.counts.items())} of {len(u.names)} "
        "parameters "
        f"(fraction determined {u.fraction_determined:.2f}); {out / 'uncertainty.md'}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m sweep.identify``: parse the arguments, run one job, write its files.

    Returns the exit status: 0 on success, 2 for unusable inputs (a one-line error on stderr).
    """
    ap = argparse.ArgumentParser(
        prog="python -m sweep.identify", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--train", nargs="+", required=True, help="R, TR, TZR or CSV/Parquet paths")
    ap.add_argument("--objective", default="J2", choices=["J1", "J2", "J3"])
    ap.add_argument("--budget", type=int, default=30_000, help="function evaluations")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sigma0", type=float, default=Settings.sigma0)
    ap.add_argument("--bound-handling", default="penalty", choices=["penalty", "transform", "none"])
    ap.add_argument("--max-seconds", type=float, default=None)
    ap.add_argument("--workers", type=int, default=0, help="0: in process; k: k worker processes")
    ap.add_argument("--x0", default="efd", help="initial mean: efd or a parameter JSON file")
    ap.add_argument("--out", required=True, help="output directory (also holds the checkpoint)")
    ap.add_argument("--data-root", default=None)
    args = ap.parse_args(argv)
    try:
        if len(args.train) == 1 and not Path(args.train[0]).exists():
            recs = list(load_split(args.train[0]).load(args.data_root).values())
        else:
            recs = read_recordings(args.train)
        x0 = efd_parameters() if args.x0 == "efd" else Parameters.load_json(args.x0)
        settings = Settings(
            seed=args.seed,
            max_evaluations=args.budget,
            sigma0=args.sigma0,
            bound_handling=args.bound_handling,
            max_seconds=args.max_seconds,
        )
    except (ParameterError, RecordingError, DataNotFoundError, SplitError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result, best = identify(
        recs, args.objective, settings, x0, args.workers, out / "checkpoint.pkl", _printer()
    )
    meta = {
        "objective": args.objective,
        "train": " ".join(args.train),
        "seed": args.seed,
        "budget": args.budget,
        "commit": git_commit(),
    }
    summary = write_outputs(out, result, best, meta)
    write_uncertainty(out, best, recs, args.objective)
    print(
        f"best {args.objective} = {result.f:.2f} after {result.evaluations} evaluations, "
        f"{len(result.restarts)} restarts, {result.seconds:.0f} s"
        + (" (REJECTED by the post-filter)" if summary["rejected"] else "")
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
