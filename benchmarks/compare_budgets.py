"""Same jobs, two budgets: does a larger CMA-ES budget lower the test-set J?

Reads two sweeps' MLflow stores (finished job runs, matched by their job key such as
``objective=J1,seed=0,train=R``) and prints, per job present in both, the final training objective
and the test-set J2 total of each, and the ratios (second / first).

    python benchmarks/compare_budgets.py --a sqlite:////tmp/grid/mlflow.db \\
        --b sqlite:////tmp/grid100k/mlflow.db [--experiment mmg-sweep]
"""

from __future__ import annotations

import argparse
import statistics

from mlflow import MlflowClient


def finished_jobs(uri: str, experiment: str) -> dict[str, dict[str, float]]:
    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        raise SystemExit(f"{uri}: no experiment {experiment!r}")
    out: dict[str, dict[str, float]] = {}
    for run in client.search_runs([exp.experiment_id], "attributes.status = 'FINISHED'"):
        m = run.data.metrics
        key = run.data.tags.get("job_key") or run.info.run_name
        if "test/J2/total" in m and "best_f" in m:
            out[key] = m
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--a", required=True, help="tracking URI of the smaller budget")
    ap.add_argument("--b", required=True, help="tracking URI of the larger budget")
    ap.add_argument("--experiment", default="mmg-sweep")
    args = ap.parse_args(argv)
    a, b = finished_jobs(args.a, args.experiment), finished_jobs(args.b, args.experiment)
    common = sorted(set(a) & set(b))
    if not common:
        raise SystemExit("no job finished in both stores")
    print(
        f"{'job':34s} {'evals':>15s} {'train J':>19s} {'ratio':>6s} {'test J2':>19s} {'ratio':>6s}"
    )
    train_r, test_r = [], []
    for k in common:
        ma, mb = a[k], b[k]
        tr, te = mb["best_f"] / ma["best_f"], mb["test/J2/total"] / ma["test/J2/total"]
        train_r.append(tr)
        test_r.append(te)
        print(
            f"{k:34s} {ma['evaluations']:7.0f}>{mb['evaluations']:7.0f} "
            f"{ma['best_f']:9.1f}>{mb['best_f']:9.1f} {tr:6.3f} "
            f"{ma['test/J2/total']:9.1f}>{mb['test/J2/total']:9.1f} {te:6.3f}"
        )
    worse = sum(r > 1.0 for r in test_r)
    print(
        f"{len(common)} jobs: training objective ratio median {statistics.median(train_r):.3f} "
        f"(range {min(train_r):.3f}-{max(train_r):.3f}); test J2 ratio median "
        f"{statistics.median(test_r):.3f} (range {min(test_r):.3f}-{max(test_r):.3f}); "
        f"test J2 worse with the larger budget in {worse} of {len(common)}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
