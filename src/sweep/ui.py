"""``python -m sweep.ui``: the MLflow UI on a sweep's store, opened on the sweep's runs table.

MLflow 3's UI starts on its generative-AI view unless the page is opened as a model-training
workflow; the address printed (and opened in a browser when one is available) goes straight to
the experiment's runs table, in the saved view a sweep stores with its experiment::

    python -m sweep.ui [--tracking-uri sqlite:///mlflow.db] [--experiment mmg-sweep]
                       [--host 127.0.0.1] [--port 5000] [--no-browser]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Sequence

#: the query that makes MLflow 3's UI show the model-training view (runs table)
WORKFLOW_QUERY = "workflowType=machine_learning"


def runs_url(base: str, experiment_id: str | None, view: str | None = None) -> str:
    """The address of the experiment's runs table (the experiment list if it has no id), in
    the saved view ``view`` when given (its columns: objective, training set, seed, test J)."""
    base = base.rstrip("/")
    if experiment_id is None:
        return f"{base}/#/experiments?{WORKFLOW_QUERY}"
    shown = f"viewStateShareKey={view}&" if view else ""
    return f"{base}/#/experiments/{experiment_id}/runs?{shown}{WORKFLOW_QUERY}"


def experiment_id(uri: str, experiment: str) -> str | None:
    """The MLflow id of ``experiment`` in the store ``uri`` (None if it does not exist)."""
    from sweep.service.tracking import MlflowTracker

    return MlflowTracker(uri, experiment).experiment_id(create=False)


def view_of(uri: str, experiment: str) -> str | None:
    """The key of the sweep's saved view when the experiment has it (made by a sweep)."""
    from sweep.service.tracking import SWEEP_VIEW_KEY, MlflowTracker

    return SWEEP_VIEW_KEY if MlflowTracker(uri, experiment).has_sweep_view() else None


def main(argv: Sequence[str] | None = None) -> int:
    """Start ``mlflow ui`` on the store and print the runs table's address; the exit status.

    2 when there is no store or it cannot be read, 130 after Ctrl-C, else the server's status.
    """
    from sweep.service.tracking import default_tracking_uri, sqlite_path

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracking-uri", default=default_tracking_uri())
    ap.add_argument("--experiment", default="mmg-sweep")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=5000)
    ap.add_argument("--no-browser", action="store_true")
    args = ap.parse_args(argv)
    db = sqlite_path(args.tracking_uri)
    if db is not None and not db.exists():
        print(
            f"error: no MLflow store at {db}: run a sweep first (python -m sweep -m ...)",
            file=sys.stderr,
        )
        return 2
    from sweep.service.tracking import TrackingError

    try:
        exp = experiment_id(args.tracking_uri, args.experiment)
        view = view_of(args.tracking_uri, args.experiment)
    except TrackingError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    url = runs_url(f"http://{args.host}:{args.port}", exp, view)
    print(f"MLflow UI: {url}  (the sweep's runs table; Ctrl-C stops the server)", flush=True)
    env = dict(os.environ, MLFLOW_SERVER_ENABLE_JOB_EXECUTION="false")
    command = [
        sys.executable, "-m", "mlflow", "ui", "--backend-store-uri", args.tracking_uri,
        "--host", args.host, "--port", str(args.port), "--workers", "1",
    ]  # fmt: skip
    server = subprocess.Popen(command, env=env)
    timer = None
    if not args.no_browser:
        import threading
        import webbrowser

        timer = threading.Timer(4.0, lambda: webbrowser.open(url))
        timer.daemon = True
        timer.start()
    try:
        return server.wait()
    except KeyboardInterrupt:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
        return 130
    finally:
        if timer is not None:
            timer.cancel()


if __name__ == "__main__":
    sys.exit(main())
