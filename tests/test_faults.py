"""Faults on a real Ray cluster on loopback: a worker node killed mid-sweep, the driver killed.

The test starts a head node and a worker node with ``ray start --block`` (own ports and temp
dir, one CPU each), runs ``python -m sweep -m ...`` against it with checkpoints in a storage
directory (``sweep.storage``), and kills the worker node's whole process group with SIGKILL
once both jobs are under way: its raylet, its evaluation worker and the job coordinator that
ran there (coordinators are spread over the nodes) die as on a lost machine. Every job must
finish, none fail, and the results must equal an uninterrupted run's bit for bit. Then the
driver itself is killed with SIGKILL mid-sweep and the same command run again: it finishes,
with the same results. Everything started is torn down by process group.
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from sweep.data.datasets import CONF_DIR
from sweep.identification.cmaes import load_checkpoint
from sweep.service.orchestration import (
    LocalExecutor,
    Progress,
    efd_reference,
    run_sweep,
    spec_from_config,
)
from tests.memory_tracker import NullTracker

pytestmark = pytest.mark.integration  # a real Ray cluster

BUDGET = 1500
JOBS = ("J1", "J2")


def _free_ports(n: int) -> list[int]:
    socks, ports = [], []
    for _ in range(n):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        socks.append(s)
        ports.append(s.getsockname()[1])
    for s in socks:
        s.close()
    return ports


def _node_ports(p: list[int]) -> list[str]:
    """The per-node port flags from six free ports (taken in one call with the others, so that
    no two are the same)."""
    return [
        f"--node-manager-port={p[0]}",
        f"--object-manager-port={p[1]}",
        f"--runtime-env-agent-port={p[2]}",
        f"--dashboard-agent-grpc-port={p[3]}",
        f"--dashboard-agent-listen-port={p[4]}",
        f"--metrics-export-port={p[5]}",
    ]


class Cluster:
    """A head and a worker node on loopback, each a ``ray start --block`` process group."""

    def __init__(self, tmp: Path) -> None:
        self.env = dict(os.environ, RAY_AUTH_MODE="disabled", RAY_USAGE_STATS_ENABLED="0")
        # every port of both nodes in one call: distinct (a later call could return a port freed
        # by an earlier one)
        ports = _free_ports(14)
        self.port, self.client_port = ports[0], ports[1]
        self.head_ports, self.worker_ports = ports[2:8], ports[8:14]
        self.address = f"127.0.0.1:{self.port}"
        # Ray's socket paths must stay under 108 characters: a short directory in /tmp
        self.temp = Path(tempfile.mkdtemp(prefix="rayf", dir="/tmp"))
        self.logs = tmp
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def _start(self, name: str, args: list[str]) -> None:
        with (self.logs / f"{name}.log").open("wb") as log:  # the child keeps its own handle
            self.procs[name] = subprocess.Popen(
                ["ray", "start", "--block", "--num-cpus=1", "--disable-usage-stats",
                 "--node-ip-address=127.0.0.1", *args],
                env=self.env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                cwd=self.logs,
            )  # fmt: skip

    def start(self) -> None:
        self._start(
            "head",
            ["--head", f"--port={self.port}", f"--temp-dir={self.temp}",
             "--include-dashboard=false", f"--ray-client-server-port={self.client_port}",
             *_node_ports(self.head_ports)],
        )  # fmt: skip
        self._wait_nodes(1)
        self._start("worker", [f"--address={self.address}", *_node_ports(self.worker_ports)])
        self._wait_nodes(2)

    def _wait_nodes(self, n: int, timeout: float = 90.0) -> None:
        code = (
            "import ray, sys; ray.init(address=sys.argv[1], log_to_driver=False); "
            "print(sum(1 for x in ray.nodes() if x['Alive']))"
        )
        t0 = time.time()
        while time.time() - t0 < timeout:
            for name, proc in self.procs.items():
                if proc.poll() is not None:
                    log = (self.logs / f"{name}.log").read_text()[-3000:]
                    raise RuntimeError(f"ray start ({name}) exited {proc.returncode}: {log}")
            out = subprocess.run(
                [sys.executable, "-c", code, self.address],
                env=self.env, capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            if out.returncode == 0 and out.stdout.strip().splitlines()[-1:] == [str(n)]:
                return
            time.sleep(1.0)
        raise RuntimeError(f"the cluster did not reach {n} node(s): {out.stderr[-2000:]}")

    def kill(self, name: str) -> None:
        """SIGKILL to every process of the node at once, as when its machine is lost: the
        ``ray start`` group and the actors' workers, which run in groups of their own in the
        same session (killed with the group alone, a busy actor outlived its raylet long enough
        to answer the calls of a short sweep, and nothing was lost)."""
        proc = self.procs.pop(name)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        subprocess.run(["pkill", "-9", "-s", str(proc.pid)], check=False)
        proc.wait(timeout=30)

    def stop(self) -> None:
        for name in list(self.procs):
            self.kill(name)
        subprocess.run(["pkill", "-9", "-f", str(self.temp)], check=False)
        shutil.rmtree(self.temp, ignore_errors=True)


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    c = Cluster(tmp_path)
    try:
        c.start()
        yield c
    finally:
        c.stop()


def _command(address: str, storage: Path, name: str) -> list[str]:
    """The sweep of the fault tests. Its checkpoints are written after every generation: at the
    default (at most every 5 s) a job's first checkpoint after its first generation was its
    last, written when all 1,500 evaluations were done (about 2 s on a warm cache), so a fault
    "mid-sweep" came after the work and nothing was lost to it."""
    return [
        sys.executable, "-m", "sweep", "-m", f"objective={','.join(JOBS)}", "train=R", "seed=0",
        "budget=smoke", f"budget.max_evaluations={BUDGET}", f"ray.address={address}",
        f"sweep.name={name}", f"sweep.storage={storage}", "sweep.progress_seconds=1",
        "sweep.checkpoint_seconds=0",
    ]  # fmt: skip


def _evaluations(storage: Path, name: str) -> dict[str, int]:
    out = {}
    for path in (storage / name).glob("*/checkpoint.pkl"):
        try:
            out[path.parent.name] = int(load_checkpoint(path).evaluations)
        except Exception:  # being replaced right now
            continue
    return out


def _wait_progress(storage: Path, name: str, at_least: int, proc: subprocess.Popen) -> None:
    t0 = time.time()
    while time.time() - t0 < 300:
        done = _evaluations(storage, name)
        if len(done) == len(JOBS) and min(done.values()) >= at_least:
            return
        if proc.poll() is not None:
            raise AssertionError(f"the sweep ended before the fault: {proc.returncode}")
        time.sleep(0.2)
    raise AssertionError(f"no progress to {at_least} evaluations: {done}")


def _best(cwd: Path, name: str) -> dict[str, float]:
    import mlflow

    client = mlflow.MlflowClient(f"sqlite:///{cwd / 'mlflow.db'}")
    exp = client.get_experiment_by_name("mmg-sweep")
    assert exp is not None
    (parent,) = client.search_runs([exp.experiment_id], f"attributes.run_name = '{name}'")
    runs = client.search_runs(
        [exp.experiment_id],
        f"tags.mlflow.parentRunId = '{parent.info.run_id}' and attributes.status = 'FINISHED'",
    )
    assert len(runs) == len(JOBS), "a job finished twice, or not at all"
    return {r.data.tags["job_key"]: r.data.metrics["best_f"] for r in runs}


@pytest.fixture(scope="module")
def reference(data_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, float]:
    """best_f of each job from an uninterrupted run in this process."""
    load = lambda p: yaml.safe_load((CONF_DIR / p).read_text())  # noqa: E731
    tmp = tmp_path_factory.mktemp("reference")
    specs = []
    for J in JOBS:
        cfg = {
            "objective": {"name": J}, "train": load("train/R.yaml"),
            "test": load("test/paper.yaml"),
            "budget": {"name": "smoke", "max_evaluations": BUDGET, "max_seconds": None},
            "cmaes": yaml.safe_load((CONF_DIR / "config.yaml").read_text())["cmaes"],
            "seed": 0, "data": {"root": str(data_dir)},
        }  # fmt: skip
        specs.append(spec_from_config(cfg, tmp / J))
    efd = efd_reference(specs[0].config["test"], str(data_dir))
    tracker = NullTracker()
    summary = run_sweep(
        "reference", specs, LocalExecutor(plots=False), tracker, efd, tmp,
        progress=Progress(io.StringIO()),
    )  # fmt: skip
    assert summary.ok
    return {r["job_key"]: r["f"] for r in tracker.job_outcomes(summary.parent_id)}


def test_a_lost_worker_node_and_a_killed_driver_lose_no_job(
    cluster: Cluster, tmp_path: Path, data_dir: Path, reference: dict[str, float]
) -> None:
    env = dict(cluster.env, MMG_DATA_DIR=str(data_dir))
    storage = tmp_path / "store"
    cwd = tmp_path / "work"
    cwd.mkdir()

    # 1. the worker node dies mid-sweep
    log = (tmp_path / "sweep1.log").open("w")
    proc = subprocess.Popen(
        _command(cluster.address, storage, "node-loss"), cwd=cwd, env=env,
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    try:
        _wait_progress(storage, "node-loss", 200, proc)
        t_fault = time.time()
        cluster.kill("worker")
        rc = proc.wait(timeout=600)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        log.close()
    out = (tmp_path / "sweep1.log").read_text()
    assert rc == 0, out[-4000:]
    # the coordinator on the lost node (coordinators are spread) was resubmitted, or, had
    # both coordinators been on the head, the evaluation worker there (each node holds one of
    # the two) was replaced: the job's outcome counts it and the driver reports it (a value,
    # not a forwarded log line that Ray may still hold back when the driver ends)
    assert "resubmitted" in out or "evaluation worker lost" in out, out[-4000:]
    best = _best(cwd, "node-loss")
    assert best == reference, (best, reference)
    print(f"node loss: recovered in {time.time() - t_fault:.0f} s after the fault")

    # 2. the driver is killed with SIGKILL; the same command again finishes every job
    proc = subprocess.Popen(
        _command(cluster.address, storage, "driver-loss"), cwd=cwd, env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        _wait_progress(storage, "driver-loss", 200, proc)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    rerun = subprocess.run(
        _command(cluster.address, storage, "driver-loss"), cwd=cwd, env=env,
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert rerun.returncode == 0, rerun.stderr[-4000:]
    assert _best(cwd, "driver-loss") == reference


def test_an_empty_address_starts_a_private_ray_beside_a_registered_dead_cluster(
    tmp_path: Path,
) -> None:
    """A head started with `ray start` and then killed stays registered in Ray's default temp
    directory; `ray.address` empty must still start a private local Ray (plain ``ray.init()``
    would try to join the dead cluster and fail, or hang)."""
    registry = Path("/tmp/ray/ray_current_cluster")
    saved = registry.read_bytes() if registry.exists() else None
    env = dict(os.environ, RAY_AUTH_MODE="disabled", RAY_USAGE_STATS_ENABLED="0")
    env.pop("RAY_ADDRESS", None)
    ports = _free_ports(8)
    port = ports[0]
    head = subprocess.Popen(
        ["ray", "start", "--head", "--block", f"--port={port}", "--num-cpus=1",
         "--include-dashboard=false", "--disable-usage-stats", "--node-ip-address=127.0.0.1",
         f"--ray-client-server-port={ports[1]}", *_node_ports(ports[2:8])],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        t0 = time.time()
        while time.time() - t0 < 90 and not (
            registry.exists() and registry.read_text().strip().endswith(f":{port}")
        ):
            time.sleep(0.5)
        assert registry.read_text().strip().endswith(f":{port}")
        os.killpg(head.pid, signal.SIGKILL)  # stopped, still registered
        head.wait(timeout=30)
        code = (
            "import time, ray; from sweep.service.raycluster import RayExecutor; t = time.time(); "
            "e = RayExecutor(num_cpus=1); "
            "print(len(ray.nodes()), ray.get_runtime_context().gcs_address, time.time() - t); "
            "e.shutdown()"
        )
        out = subprocess.run(
            [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
            timeout=180,
        )  # fmt: skip
        assert out.returncode == 0, out.stderr[-3000:]
        nodes, gcs, seconds = out.stdout.split()[-3:]
        assert nodes == "1" and not gcs.endswith(f":{port}")
        assert float(seconds) < 60.0
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(head.pid, signal.SIGKILL)
        if saved is None:
            registry.unlink(missing_ok=True)
        else:
            registry.write_bytes(saved)
