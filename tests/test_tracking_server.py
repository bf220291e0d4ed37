"""A sweep tracked by an ``mlflow server`` that stops mid-sweep.

Each test starts a real ``mlflow server`` on loopback (its own port, a SQLite backend store and
served artifacts in a temporary directory; stopped by its process group id) and runs the real
command, ``python -m sweep -m ...`` through Hydra and Ray, one job at a time at budget=smoke.

- The server is killed after the first job is logged and started again 30 s later on the same
  port and store: the sweep finishes, every job is one FINISHED child run and every metric step
  is stored once.
- The server is killed and does not come back within ``tracking.retry_seconds=5``: the command
  says so in one line and exits with status 2; the same command run once the server is back
  logs the missing job, and every job is one child run.

The fast test checks the budget itself on a port where nothing listens.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from sweep.service.tracking import MlflowTracker, TrackingUnreachableError


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class Server:
    """An ``mlflow server`` on 127.0.0.1:``port`` whose store lives in ``root``."""

    def __init__(self, root: Path, port: int) -> None:
        self.root = root
        self.port = port
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def uri(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout: float = 90.0) -> None:
        """Start the server (same store every time) and wait until it answers /health."""
        self.root.mkdir(parents=True, exist_ok=True)
        cmd = [
            sys.executable, "-m", "mlflow", "server",
            "--backend-store-uri", f"sqlite:///{self.root}/mlflow.db",
            "--artifacts-destination", str(self.root / "artifacts"),
            "--host", "127.0.0.1", "--port", str(self.port), "--workers", "1",
        ]  # fmt: skip
        env = dict(os.environ, MLFLOW_SERVER_ENABLE_JOB_EXECUTION="false")
        with (self.root / "server.log").open("ab") as log:
            # its own process group: the server and its workers are stopped together, by pid
            self.proc = subprocess.Popen(
                cmd, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
            )
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, (self.root / "server.log").read_text()[-3000:]
            try:
                with urllib.request.urlopen(f"{self.uri}/health", timeout=2) as answer:
                    if answer.status == 200:
                        return
            except OSError:
                time.sleep(0.5)
        raise AssertionError(f"mlflow server did not answer on {self.uri} in {timeout} s")

    def kill(self) -> None:
        """SIGKILL the server's process group (a crash: nothing is flushed or closed)."""
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=30)
        self.proc = None


@pytest.fixture
def server(tmp_path: Path):
    srv = Server(tmp_path / "server", free_port())
    srv.start()
    yield srv
    srv.kill()


def sweep_command(uri: str, objectives: str, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "sweep", "-m", f"objective={objectives}", "train=R", "seed=0",
        "budget=smoke", "sweep.name=outage", "ray.num_cpus=2", "ray.max_concurrent_jobs=1",
        f"tracking.uri={uri}", *extra,
    ]  # fmt: skip


def start_sweep(
    cmd: list[str], cwd: Path, data_dir: Path, stderr: Any = subprocess.PIPE
) -> subprocess.Popen[str]:
    cwd.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, MMG_DATA_DIR=str(data_dir), RAY_AUTH_MODE="disabled")
    return subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=stderr, text=True)


def children(uri: str) -> list:
    """Every child run of the sweep ``outage`` (any status)."""
    import mlflow

    client = mlflow.MlflowClient(uri)
    exp = client.get_experiment_by_name("mmg-sweep")
    if exp is None:
        return []
    runs = client.search_runs([exp.experiment_id], max_results=1000)
    return [r for r in runs if "mlflow.parentRunId" in r.data.tags]


def wait_for_logged_job(uri: str, proc: subprocess.Popen[str], timeout: float = 240.0) -> None:
    """Until the sweep's first job is a FINISHED child run."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, (proc.communicate()[1] or "")[-3000:]
        if any(r.info.status == "FINISHED" for r in children(uri)):
            return
        time.sleep(0.5)
    proc.kill()
    raise AssertionError(f"no job logged in {timeout} s: {(proc.communicate()[1] or '')[-3000:]}")


def assert_logged_once(uri: str, keys: list[str]) -> None:
    """Each job is exactly one FINISHED child run, its metric steps stored once."""
    import mlflow

    client = mlflow.MlflowClient(uri)
    runs = children(uri)
    assert Counter(r.data.tags["job_key"] for r in runs) == Counter(keys)
    for run in runs:
        assert run.info.status == "FINISHED"
        rid = run.info.run_id
        steps = [m.step for m in client.get_metric_history(rid, "history/best_so_far")]
        assert steps and sorted(steps) == list(range(len(steps))), steps
        for key in ("best_f", "evaluations", "test/J2/total"):
            assert len(client.get_metric_history(rid, key)) == 1, key
        names = {a.path for a in client.list_artifacts(rid)}
        assert {"best_params.json", "history.csv", "plots"} <= names


KEYS = [f"objective={J},seed=0,train=R" for J in ("J1", "J2", "J3")]


def test_a_port_where_nothing_listens_is_retried_for_the_budget_then_named(capsys):
    uri = f"http://127.0.0.1:{free_port()}"
    tracker = MlflowTracker(uri, retry_seconds=2.0)
    t0 = time.monotonic()
    with pytest.raises(TrackingUnreachableError) as info:
        tracker.experiment_id(create=True)
    assert 2.0 <= time.monotonic() - t0 < 10.0  # the budget, not MLflow's own minutes of retries
    assert str(info.value) == (
        f"tracking server {uri} unreachable for 2 s; the jobs' results are kept in the sweep "
        "directory; run the same command again when it is back"
    )
    assert f"warning: tracking server {uri} does not answer" in capsys.readouterr().err


@pytest.mark.integration  # a real mlflow server, Hydra and Ray
def test_sweep_survives_a_30_s_server_outage(server: Server, tmp_path: Path, data_dir: Path):
    log = tmp_path / "sweep.err"
    with log.open("w") as stderr:
        proc = start_sweep(
            sweep_command(server.uri, "J1,J2,J3"), tmp_path / "cwd", data_dir, stderr=stderr
        )
        try:
            wait_for_logged_job(server.uri, proc)
            server.kill()
            # the next job meets the outage when it is logged (whenever it ends: on a loaded
            # machine, after more than 30 s), and the server stays away 30 s from then
            deadline = time.monotonic() + 300
            while f"tracking server {server.uri} does not answer" not in log.read_text():
                assert proc.poll() is None, log.read_text()[-3000:]
                assert time.monotonic() < deadline, "the sweep never met the outage"
                time.sleep(0.5)
            time.sleep(30)
            assert proc.poll() is None  # the sweep waits for the server, it does not stop
            server.start()
            proc.wait(timeout=400)
        finally:
            if proc.poll() is None:
                proc.kill()
    err = log.read_text()
    assert proc.returncode == 0, err[-3000:]
    assert f"tracking server {server.uri} answers again" in err
    assert_logged_once(server.uri, KEYS)
    import mlflow

    client = mlflow.MlflowClient(server.uri)
    parent = client.get_run(children(server.uri)[0].data.tags["mlflow.parentRunId"])
    assert parent.info.status == "FINISHED"
    summary = {a.path for a in client.list_artifacts(parent.info.run_id, "summary")}
    assert "summary/J2.json" in summary and "summary/J2.md" in summary


@pytest.mark.integration
def test_server_that_does_not_come_back_stops_the_command_in_one_line(
    server: Server, tmp_path: Path, data_dir: Path
):
    cwd = tmp_path / "cwd"
    cmd = sweep_command(server.uri, "J1,J2", "tracking.retry_seconds=5")
    proc = start_sweep(cmd, cwd, data_dir)
    try:
        wait_for_logged_job(server.uri, proc)
        server.kill()
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, err[-3000:]
    assert "Traceback" not in err
    last = [line for line in err.splitlines() if line.startswith("error:")]
    assert last == [
        f"error: tracking server {server.uri} unreachable for 5 s; the jobs' results are kept in "
        "the sweep directory; run the same command again when it is back"
    ]
    # the server is back: the same command logs the missing job (from its checkpoint)
    server.start()
    rerun = start_sweep(cmd, cwd, data_dir)
    _, err = rerun.communicate(timeout=400)
    assert rerun.returncode == 0, err[-3000:]
    assert "1 skipped" in err
    assert_logged_once(server.uri, KEYS[:2])
