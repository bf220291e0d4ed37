"""The CI smoke sweep: `python -m sweep -m ...` on the real data, through Hydra, Ray and MLflow.

Two jobs at budget=smoke (200 evaluations each). Checks that MLflow holds the parent run, one
child per job with every test-subset metric, the summary tables, and that a second run of the
same command skips the finished jobs.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from sweep.service.outcome import SUBSETS
from tests.conftest import run_smoke as _run

pytestmark = pytest.mark.integration  # sweeps on real Ray nodes, through Hydra and MLflow


def test_mlflow_holds_parent_children_metrics_and_tables(smoke):
    import mlflow

    cwd, _ = smoke
    client = mlflow.MlflowClient(f"sqlite:///{cwd}/mlflow.db")
    exp = client.get_experiment_by_name("mmg-sweep")
    assert exp is not None
    runs = client.search_runs([exp.experiment_id])
    parents = [r for r in runs if r.data.tags.get("sweep") == "true"]
    assert len(parents) == 1
    parent = parents[0]
    for J in ("J1", "J2", "J3"):
        for subset in SUBSETS:
            assert f"efd/{J}/{subset}" in parent.data.metrics
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    assert sorted(r.data.tags["job_key"] for r in children) == [
        "objective=J1,seed=0,train=R",
        "objective=J2,seed=0,train=R",
    ]
    for child in children:
        assert child.info.status == "FINISHED"
        assert len(child.data.tags["git_commit"]) == 40  # the source the job ran
        assert child.data.tags["mmg_sweep_version"] == "0.1.0"
        assert {child.data.tags[k] for k in ("objective", "train", "seed")} <= {
            "J1",
            "J2",
            "R",
            "0",
        }
        for J in ("J1", "J2", "J3"):
            for subset in SUBSETS:
                assert f"test/{J}/{subset}" in child.data.metrics
        names = {a.path for a in client.list_artifacts(child.info.run_id)}
        assert {"best_params.json", "history.csv", "uncertainty.md", "uncertainty.json"} <= names
        assert 0.0 <= child.data.metrics["fraction_determined"] <= 1.0
    summary = {a.path for a in client.list_artifacts(parent.info.run_id, "summary")}
    for J in ("J1", "J2", "J3"):
        for ext in ("csv", "md", "html", "parquet"):
            assert f"summary/{J}.{ext}" in summary
    table = (cwd / "multirun/ci-smoke/summary/J2.md").read_text()
    assert "EFD" in table and "J1-R" in table and "J2-R" in table


def test_the_comparison_is_on_the_first_screens(smoke):
    """The experiment opens as a model-training one; the parent's description holds the J
    tables and the answer (best pair); each child's description its test row beside EFD, its
    stop reason and restarts; objective, train and seed are params; the sweep figure is on
    the parent; the terminal prints the J2 table at the end."""
    import mlflow

    from sweep.service.tracking import EXPERIMENT_KIND, NOTE_TAG

    cwd, first = smoke
    client = mlflow.MlflowClient(f"sqlite:///{cwd}/mlflow.db")
    exp = client.get_experiment_by_name("mmg-sweep")
    assert exp is not None and exp.tags[EXPERIMENT_KIND[0]] == EXPERIMENT_KIND[1]
    # the saved view of the runs table (MLflow's record: deflate + base64 of the JSON state),
    # whose columns are metrics and params the runs really carry
    import base64
    import json
    import zlib

    view = json.loads(exp.tags["mlflow.sharedViewState.mmg-sweep-tables"])
    assert view["state"].startswith("deflate;") and view["name"].startswith("Sweep")
    state = json.loads(zlib.decompress(base64.b64decode(view["state"].split(";", 1)[1])))
    runs = client.search_runs([exp.experiment_id])
    child = next(r for r in runs if r.data.tags.get("mlflow.parentRunId"))
    for column in state["selectedColumns"]:
        kind, key = column.split(".", 1)
        assert key.strip("`") in getattr(child.data, kind), column
    parent = next(r for r in runs if r.data.tags.get("sweep") == "true")
    note = parent.data.tags[NOTE_TAG]
    assert "Best generalisation (J2, whole test set): J" in note
    for J in ("J1", "J2", "J3"):
        assert f"### {J} on the test set" in note
    assert "| EFD " in note and "| J1-R " in note and "| J2-R " in note and "**" in note
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    for child in children:
        params = child.data.params
        assert params["objective"] == child.data.tags["objective"]
        assert params["train"] == "R" and params["seed"] == "0"
        text = child.data.tags[NOTE_TAG]
        assert "| this job |" in text and "| EFD |" in text and "stopped by budget" in text
        assert "| restart | population |" in text
    summary = {a.path for a in client.list_artifacts(parent.info.run_id, "summary")}
    assert "summary/sweep.png" in summary
    assert (cwd / "multirun/ci-smoke/summary/sweep.png").stat().st_size > 20_000
    out = first.stderr
    assert "J2 on the test set" in out and "EFD" in out.split("J2 on the test set", 1)[1]


def test_best_parameters_are_loadable_by_evaluate(smoke, data_dir):
    import mlflow

    from mmg import Parameters

    cwd, _ = smoke
    client = mlflow.MlflowClient(f"sqlite:///{cwd}/mlflow.db")
    exp = client.get_experiment_by_name("mmg-sweep")
    assert exp is not None
    child = client.search_runs([exp.experiment_id], "tags.job_key = 'objective=J2,seed=0,train=R'")[
        0
    ]
    path = client.download_artifacts(child.info.run_id, "best_params.json", str(cwd))
    p = Parameters.load_json(path)
    from sweep.evaluate import main

    assert main(["--params", path, "--recordings", str(data_dir / "data/berthing")]) == 0
    assert p.vector().shape == (57,)


def test_second_run_skips_the_finished_jobs(smoke, data_dir):
    import mlflow

    cwd, _ = smoke
    second = _run(cwd, data_dir)
    assert second.returncode == 0, second.stderr[-3000:]
    assert "0 finished, 2 skipped, 0 failed" in second.stderr + second.stdout
    client = mlflow.MlflowClient(f"sqlite:///{cwd}/mlflow.db")
    exp = client.get_experiment_by_name("mmg-sweep")
    assert exp is not None
    assert len(client.search_runs([exp.experiment_id])) == 3  # no new child runs


def test_ctrl_c_stops_cleanly_keeps_the_checkpoint_and_a_rerun_finishes(tmp_path, data_dir):
    """SIGINT mid-job: exit 130, no process of the sweep left behind, the checkpoint kept."""
    import signal
    import time

    command = [
        sys.executable, "-m", "sweep", "-m", "objective=J1", "train=R", "seed=1",
        "budget=smoke", "budget.max_evaluations=4000", "sweep.name=ctrl-c", "ray.num_cpus=2",
    ]  # fmt: skip
    env = dict(os.environ, MMG_DATA_DIR=str(data_dir), RAY_AUTH_MODE="disabled")
    proc = subprocess.Popen(
        command, cwd=tmp_path, env=env, start_new_session=True,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    checkpoints = tmp_path / "multirun/ctrl-c"
    deadline = time.monotonic() + 300
    while not list(checkpoints.glob("*/checkpoint.pkl")):
        assert proc.poll() is None, proc.communicate()[0][-3000:]
        assert time.monotonic() < deadline, "no checkpoint appeared"
        time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, out[-3000:]
    assert "checkpoints kept" in out
    assert list(checkpoints.glob("*/checkpoint.pkl"))
    time.sleep(2)
    with pytest.raises(ProcessLookupError):  # Ray's processes went with the sweep
        os.killpg(proc.pid, 0)
    rerun = subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True,
                           timeout=600)  # fmt: skip
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert "1 finished, 0 skipped, 0 failed" in rerun.stderr + rerun.stdout
