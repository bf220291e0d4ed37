"""The paper's 27-job grid at a reduced budget: wall time and share of time in the simulator.

Usage: ``python benchmarks/sweep_grid.py [--evaluations 1000] [--workdir DIR] [OVERRIDE ...]``
(recordings from $MMG_DATA_DIR, else ../shared/data/frt-ds-esso). Further Hydra overrides
replace the grid's, e.g. ``seed=0,1,2 objective=J2 train=R ray.cpus_per_worker=1`` (three jobs,
one CPU per worker: the rounds unbalanced, for comparison with the default).

Runs ``python -m sweep -m objective=J1,J2,J3 train=R,TR,TZR seed=0,1,2`` with
``budget.max_evaluations`` set, in a fresh working directory (its own MLflow store), and prints
the grid's wall time, the evaluations per second of the whole grid, the share of the machine's
CPU time spent in the simulator (the objective's kernel calls, summed over all evaluation
workers, divided by wall time x CPUs), and the wall time this rate implies for the paper's budget
of 27 x 100,000 evaluations.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--evaluations", type=int, default=1000, help="per job")
    ap.add_argument("--workdir", default=None, help="default: a temporary directory")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides (key=value)")
    args = ap.parse_args()
    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    env = dict(os.environ, RAY_AUTH_MODE="disabled")
    env.setdefault("MMG_DATA_DIR", str(default_root))
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="mmg-sweep-bench-"))
    workdir.mkdir(parents=True, exist_ok=True)
    name = f"bench-{args.evaluations}"
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
    command = [
        sys.executable, "-m", "sweep", "-m", *(f"{k}={v}" for k, v in grid.items()),
        "budget=short", f"budget.max_evaluations={args.evaluations}", f"sweep.name={name}",
        *extra,
    ]  # fmt: skip
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
    print(f"grid: {len(runs)} jobs x {args.evaluations} evaluations, {cpus} CPUs ({workdir})")
    print(f"command: {' '.join(command[1:])}")
    print(f"wall time {wall:.0f} s; {rate:.0f} evaluations/s over the whole grid")
    print(f"optimiser time summed over jobs: {job_seconds:.0f} s")
    print(f"simulator share of the machine's CPU time: {sim / (wall * cpus):.1%}")
    print(
        f"implied wall time of the paper's budget (27 x 100,000 evaluations): "
        f"{27 * 100_000 / rate / 3600:.2f} h"
        + ("" if jobs == 27 else " (from a grid of other jobs: indicative only)")
    )


if __name__ == "__main__":
    main()
