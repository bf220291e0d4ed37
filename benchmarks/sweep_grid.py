"""The paper's 27-job grid at a reduced budget: wall time and share of time in the simulator.

Usage: ``python benchmarks/sweep_grid.py [--evaluations N[,N ...]] [--workdir DIR] [OVERRIDE ...]``
(recordings from $MMG_DATA_DIR, else ../shared/data/frt-ds-esso). Further Hydra overrides
replace the grid's, e.g. ``seed=0,1,2 objective=J2 train=R ray.cpus_per_worker=1`` (three jobs,
one CPU per worker: the rounds unbalanced, for comparison with the default).

Runs ``python -m sweep -m objective=J1,J2,J3 train=R,TR,TZR seed=0,1,2`` with
``budget.max_evaluations`` set, in a fresh working directory (its own MLflow store), and prints
the grid's wall time, the evaluations per second of the whole grid, the share of the machine's
CPU time spent in the simulator (the objective's kernel calls, summed over all evaluation
workers, divided by wall time x CPUs), and the wall time this rate implies for the paper's budget
of 27 x 100,000 evaluations. With several budgets (``--evaluations 3000,30000``) it runs one grid
each and also fits wall = fixed + marginal x evaluations per job: a job's start-up, test
evaluation and plots do not grow with its budget, so the line extrapolates better than the rate
of one grid (larger populations, more common at the full budget, cost less per evaluation, so
both stay on the safe side).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: the paper's budget per job
PAPER_EVALUATIONS = 100_000


def run_grid(
    evaluations: int, grid: dict[str, str], extra: list[str], workdir: Path, env: dict[str, str]
) -> dict[str, float]:
    """One sweep of the grid at ``evaluations`` per job in ``workdir``; its figures."""
    name = f"bench-{evaluations}"
    command = [
        sys.executable, "-m", "sweep", "-m", *(f"{k}={v}" for k, v in grid.items()),
        "budget=short", f"budget.max_evaluations={evaluations}", f"sweep.name={name}",
        *extra,
    ]  # fmt: skip
    workdir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    proc = subprocess.run(command, cwd=workdir, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"sweep failed ({proc.returncode}):\n{proc.stderr[-3000:]}")

    import mlflow

    client = mlflow.MlflowClient(f"sqlite:///{workdir}/mlflow.db")
    exp = client.get_experiment_by_name("mmg-sweep")
    assert exp is not None
    runs = [r for r in client.search_runs([exp.experiment_id]) if "job_key" in r.data.tags]
    cpus = os.cpu_count() or 1
    evals = sum(r.data.metrics["evaluations"] for r in runs)
    sim = sum(r.data.metrics.get("sim_seconds", 0.0) for r in runs)
    job_seconds = sum(r.data.metrics["seconds"] for r in runs)
    rate = evals / wall
    print(f"grid: {len(runs)} jobs x {evaluations} evaluations, {cpus} CPUs ({workdir})")
    print(f"command: {' '.join(command[1:])}")
    print(f"wall time {wall:.0f} s; {rate:.0f} evaluations/s over the whole grid")
    print(f"optimiser time summed over jobs: {job_seconds:.0f} s")
    print(f"simulator share of the machine's CPU time: {sim / (wall * cpus):.1%}")
    return {"evaluations": float(evaluations), "wall": wall, "rate": rate}


def fixed_and_marginal(points: list[dict[str, float]]) -> tuple[float, float]:
    """Least-squares line wall = fixed + marginal x evaluations per job through the grids."""
    E = [p["evaluations"] for p in points]
    W = [p["wall"] for p in points]
    n = len(E)
    mean_e, mean_w = sum(E) / n, sum(W) / n
    marginal = sum((e - mean_e) * (w - mean_w) for e, w in zip(E, W, strict=True)) / sum(
        (e - mean_e) ** 2 for e in E
    )
    return mean_w - marginal * mean_e, marginal


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--evaluations",
        default="1000",
        help="per job; several, comma-separated (3000,30000): one grid each and a fitted line",
    )
    ap.add_argument("--workdir", default=None, help="default: a temporary directory")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides (key=value)")
    args = ap.parse_args()
    try:
        budgets = [int(e) for e in args.evaluations.split(",")]
    except ValueError:
        ap.error(f"--evaluations: integers separated by commas, not {args.evaluations!r}")
    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    env = dict(os.environ, RAY_AUTH_MODE="disabled")
    env.setdefault("MMG_DATA_DIR", str(default_root))
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="mmg-sweep-bench-"))
    grid = {"objective": "J1,J2,J3", "train": "R,TR,TZR", "seed": "0,1,2"}
    extra = []
    for o in args.overrides:
        key = o.split("=", 1)[0]
        if key in grid:
            grid[key] = o.split("=", 1)[1]
        else:
            extra.append(o)
    jobs = 1
    for v in grid.values():
        jobs *= len(v.split(","))
    note = "" if jobs == 27 else " (from a grid of other jobs: indicative only)"
    points = [run_grid(e, grid, extra, workdir / str(e), env) for e in budgets]
    paper = f"the paper's budget ({jobs} x {PAPER_EVALUATIONS:,} evaluations)"
    last = points[-1]
    print(
        f"implied wall time of {paper}, at the rate of the {int(last['evaluations']):,}-evaluation "
        f"grid: {jobs * PAPER_EVALUATIONS / last['rate'] / 3600:.2f} h{note}"
    )
    if len({p["evaluations"] for p in points}) >= 2:
        # a job's start-up, test evaluation and plots do not grow with its budget: a line
        # through the grids separates them from the cost per evaluation
        fixed, marginal = fixed_and_marginal(points)
        if marginal <= 0.0:
            print("fixed + per-evaluation fit: the budgets are too small to separate the two")
            return
        print(
            f"fixed + per-evaluation fit: {fixed:.0f} s + {marginal * 1e3:.1f} ms of wall time "
            f"per evaluation of each job; implied wall time of {paper}: "
            f"{(fixed + marginal * PAPER_EVALUATIONS) / 3600:.2f} h{note}"
        )


if __name__ == "__main__":
    main()
