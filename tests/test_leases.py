"""One driver per job at a time: leases, a second driver on the same sweep, a driver killed
between a job's end and its logging, duplicate runs in a store."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from mmg import bounds, efd_parameters
from sweep.data.datasets import CONF_DIR, load_split
from sweep.data.objective import Objective
from sweep.identification.cmaes import Box, optimise
from sweep.identification.workers import InProcess
from sweep.service import pending, storage
from sweep.service.job import JobSpec, settings_of
from sweep.service.lease import Driver, Holder, Lease
from sweep.service.orchestration import LocalExecutor, Progress, run_sweep, spec_from_config
from sweep.service.outcome import OBJECTIVE_NAMES, SUBSETS, JobOutcome
from sweep.service.schema import RULES
from sweep.service.tables import column_name
from tests.conftest import kernels
from tests.memory_tracker import NullTracker

EFD = {J: {s: 100.0 for s in SUBSETS} for J in OBJECTIVE_NAMES}
ELSEWHERE = Driver("another-host.example", 4242, "elsewhere")


def _specs(root: Path, seeds=(0, 1, 2), lease_seconds: float = 30.0) -> list[JobSpec]:
    """Jobs J2-R seed 0, 1, 2 in ``root`` (no data is read: their runs are canned)."""
    out = []
    for seed in seeds:
        cfg = {"objective": "J2", "train": {"key": "R"}, "test": {}, "seed": seed,
               "budget": {"max_evaluations": 40}, "cmaes": {"popsize_start": 20}}  # fmt: skip
        out.append(
            JobSpec(
                f"objective=J2,seed={seed},train=R",
                "J2",
                "R",
                seed,
                cfg,
                root / f"objective=J2,seed={seed}",
                lease_seconds=lease_seconds,
            )
        )
    return out


def _outcome(spec: JobSpec) -> JobOutcome:
    value = 50.0 + spec.seed
    return JobOutcome(
        job_key=spec.key, objective=spec.objective, train=spec.train, seed=spec.seed,
        config=dict(spec.config), config_hash=spec.config_hash, params=efd_parameters(),
        f=value, evaluations=40, seconds=0.1, rejected=False, stop_reason="max_evaluations",
        history=[{"evaluations": 20.0, "best_so_far": value + 1}, {"evaluations": 40.0,
                 "best_so_far": value}],
        test={J: {s: value for s in SUBSETS} for J in OBJECTIVE_NAMES},
    )  # fmt: skip


def runs_of(spec: JobSpec) -> int:
    """How often the job ran (its job-side counter)."""
    path = spec.job_dir / "runs.txt"
    return len(path.read_text().splitlines()) if path.is_file() else 0


class CannedExecutor(LocalExecutor):
    """Runs a job by counting it in ``<job dir>/runs.txt``, taking ``seconds`` and returning
    a canned outcome (no kernel, no data)."""

    def __init__(self, seconds: float = 0.5) -> None:
        super().__init__(plots=False)
        self.seconds = seconds

    def submit(self, spec: JobSpec) -> int:
        spec.job_dir.mkdir(parents=True, exist_ok=True)
        with (spec.job_dir / "runs.txt").open("a") as fh:
            fh.write(f"{os.getpid()} {threading.get_ident()}\n")
        time.sleep(self.seconds)
        handle = self._next
        self._next += 1
        self._done[handle] = (_outcome(spec), {})
        return handle


def _sweep(specs, tracker, root: Path, executor=None, stream=None):
    return run_sweep("leased", specs, executor or CannedExecutor(), tracker, EFD, root,
                     progress=Progress(stream or io.StringIO()))  # fmt: skip


# ---------------------------------------------------------------- the lease itself


@pytest.mark.parametrize("uri", [False, True], ids=["path", "file-uri"])
def test_a_live_lease_is_respected_a_released_or_expired_one_taken(tmp_path, uri):
    where = f"file://{tmp_path}/lease" if uri else str(tmp_path / "lease")
    a, b = Driver.this(), Driver("h", 1, "b")
    # (a lease of 3 s: one of 0.6 s expired between two calls on a CI machine whose other core
    # compiled kernels)
    mine, theirs = Lease(where, a, seconds=3.0), Lease(where, b, seconds=3.0)
    assert mine.acquire() is None and mine.generation == 0
    held = theirs.acquire()
    assert isinstance(held, Holder) and held.driver == a and held.live()
    assert mine.renew()
    mine.release()
    assert theirs.acquire() is None and theirs.generation == 1  # released: a new generation
    time.sleep(3.2)  # b's heartbeat stopped: expired
    assert mine.acquire() is None and mine.generation == 2
    assert not theirs.renew()  # b stalled past its expiry and learns it lost the job
    assert storage.list_names(where) == ["00000002.json"]  # older generations cleared


def test_the_lease_of_a_process_of_this_host_that_is_gone_is_taken_at_once(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    ghost = Driver(Driver.this().host, int(dead.stdout), "ghost")
    Lease(str(tmp_path), ghost, seconds=3600).acquire()
    assert Lease(str(tmp_path), Driver.this()).acquire() is None


@pytest.mark.parametrize("expired", [False, True], ids=["free", "expired"])
def test_of_drivers_claiming_one_job_at_once_exactly_one_gets_it(tmp_path, expired):
    if expired:
        Lease(str(tmp_path), ELSEWHERE, seconds=-1.0).acquire()
    barrier = threading.Barrier(8)
    got: list[bool] = []

    def claim() -> None:
        lease = Lease(str(tmp_path), Driver("h", 1, os.urandom(6).hex()))
        barrier.wait()
        got.append(lease.acquire() is None)

    threads = [threading.Thread(target=claim) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(got) == [False] * 7 + [True]


def test_a_claim_made_below_a_higher_generation_does_not_hold_the_job(tmp_path, monkeypatch):
    """A listing made while another driver takes the next generation and removes the one before
    can show neither file; the driver that saw no lease then makes generation 0 again while
    the other holds generation 1. (Eight drivers claiming an expired lease at once did so about
    twice in a hundred rounds on a loaded machine.) Its claim is not the highest: it does not
    hold the job, and it is told who does."""
    Lease(str(tmp_path), ELSEWHERE, seconds=-1.0).acquire()  # generation 0, expired
    other = Driver("h", 1, "other")
    assert Lease(str(tmp_path), other).acquire() is None  # generation 1; 0 is removed
    late = Lease(str(tmp_path), Driver("h", 1, "late"))
    real, calls = late.holder, []

    def listing_that_missed_both_files() -> Holder | None:  # the first look only
        calls.append(1)
        return None if len(calls) == 1 else real()

    monkeypatch.setattr(late, "holder", listing_that_missed_both_files)
    holder = late.acquire()
    assert holder is not None and holder.driver == other and holder.generation == 1
    assert late.generation is None
    current = Lease(str(tmp_path), other).holder()
    assert current is not None and current.driver == other


def test_sweep_lease_seconds_is_checked_and_reaches_the_job(tmp_path):
    rule = next(r for r in RULES if r.key == "sweep.lease_seconds")
    assert [rule.check(v) for v in (30, 1.0, 0.5, 0, -3, True, "30")] == [
        True, True, False, False, False, False, False
    ]  # fmt: skip
    assert _specs(tmp_path, seeds=(0,))[0].lease_directory == str(
        tmp_path / "objective=J2,seed=0" / "lease"
    )


# ---------------------------------------------------------------- drivers on one sweep


def test_two_drivers_at_once_run_each_job_once_and_log_it_once(tmp_path):
    """Two identical sweeps started together on one sweep directory and one SQLite MLflow
    store: every job runs once, MLflow holds one FINISHED child per job under one parent, and
    both drivers end with the full summary (n = 3 seeds, not 6)."""
    from sweep.service.tracking import MlflowTracker

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    specs = _specs(tmp_path / "multirun")
    summaries: list = []

    def driver() -> None:
        summaries.append(_sweep(specs, MlflowTracker(uri), tmp_path / "multirun"))

    threads = [threading.Thread(target=driver) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert [runs_of(s) for s in specs] == [1, 1, 1]
    a, b = summaries
    assert a.parent_id == b.parent_id
    assert sorted(a.finished + b.finished) == sorted(s.key for s in specs)
    assert sorted(a.skipped + b.skipped) == sorted(s.key for s in specs)
    tracker = MlflowTracker(uri)
    children = tracker.client.search_runs(
        [str(tracker.experiment_id())], f"tags.mlflow.parentRunId = '{a.parent_id}'"
    )
    assert sorted(r.data.tags["job_key"] for r in children) == sorted(s.key for s in specs)
    assert {r.info.status for r in children} == {"FINISHED"}
    for summary in summaries:
        assert summary.tables["J2"].loc["J2-R", "n"] == 3 and not summary.notes
    # the drivers logged the summary one after the other: each table once, rows not doubled
    # (MLflow appends a table logged at the same moment by two clients to the other's)
    for name, table in a.tables.items():
        path = tracker.raw_client.download_artifacts(
            a.parent_id, f"summary/{name}.json", str(tmp_path)
        )
        assert len(json.loads(Path(path).read_text())["data"]) == len(table), name


def test_a_job_a_live_driver_holds_is_waited_for_and_not_run(tmp_path):
    """Another driver holds a job (its heartbeat goes on): the sweep runs the others, waits,
    and when that driver has logged the job and let go, counts it as done by it."""
    specs = _specs(tmp_path)
    other = Lease(specs[0].lease_directory, ELSEWHERE, seconds=1.0)
    assert other.acquire() is None
    tracker = NullTracker()
    stream = io.StringIO()
    done: list = []
    thread = threading.Thread(target=lambda: done.append(_sweep(specs, tracker, tmp_path,
                                                                 stream=stream)))  # fmt: skip
    thread.start()
    for _ in range(20):  # the other driver is busy for 2 s, renewing its lease
        time.sleep(0.1)
        other.renew()
    assert thread.is_alive() and runs_of(specs[0]) == 0
    parent = tracker.find_sweep("leased")
    assert parent is not None
    tracker.log_job(parent, _outcome(specs[0]), None)  # the other driver logs its job
    other.release()
    thread.join(timeout=30)
    (summary,) = done
    assert runs_of(specs[0]) == 0 and [runs_of(s) for s in specs[1:]] == [1, 1]
    assert summary.skipped == [specs[0].key] and summary.tables["J2"].loc["J2-R", "n"] == 3
    assert f"{specs[0].key}: held by driver elsewhere" in stream.getvalue()
    assert f"{specs[0].key}: finished by another driver" in stream.getvalue()


@pytest.mark.kernels(*kernels((), "simulate", "moments"))
def test_the_job_of_a_driver_whose_lease_expired_is_taken_over_from_its_checkpoint(
    tmp_path, data_dir, checkpoint_writes
):
    """A driver on another host stopped two generations into a job; its lease (1 s) is live
    when the sweep starts: the sweep waits for it to expire, then resumes the job from the
    checkpoint it left."""
    load = lambda p: yaml.safe_load((CONF_DIR / p).read_text())  # noqa: E731
    cfg = {"objective": {"name": "J2"}, "train": load("train/R.yaml"),
           "test": load("test/paper.yaml"), "seed": 0, "data": {"root": str(data_dir)},
           "budget": {"name": "tiny", "max_evaluations": 100, "max_seconds": None},
           "cmaes": {"sigma0": 0.03, "bound_handling": "penalty", "popsize_start": 20,
                     "popsize_max": 720}, "sweep": {"lease_seconds": 1.0}}  # fmt: skip
    spec = spec_from_config(cfg, tmp_path / "objective=J2,seed=0,train=R")
    assert spec.lease_seconds == 1.0
    obj = Objective(list(load_split("R").load(data_dir).values()), "J2")
    spec.job_dir.mkdir(parents=True)
    optimise(InProcess(obj), Box(*bounds()), efd_parameters().vector(),
             settings_of(spec.config, 0), checkpoint=spec.job_dir / "checkpoint.pkl",
             stop_after_generations=2, checkpoint_seconds=0.0,
             checkpoint_job=spec.config_hash, checkpoint_key=spec.checkpoint_key)  # fmt: skip
    left = checkpoint_writes[-1]
    checkpoint_writes.clear()
    assert Lease(spec.lease_directory, ELSEWHERE, seconds=1.0).acquire() is None
    t0 = time.monotonic()
    summary = run_sweep("takeover", [spec], LocalExecutor(plots=False), NullTracker(), EFD,
                        tmp_path, progress=Progress(io.StringIO()))  # fmt: skip
    assert time.monotonic() - t0 > 0.5  # it waited for the lease to expire
    assert summary.finished == [spec.key]
    assert checkpoint_writes and checkpoint_writes[0] > left  # resumed, not started afresh
    assert np.isfinite(summary.tables["J2"].loc["J2-R", column_name("Total", "mean")])


# ---------------------------------------------------------------- no job logged twice


def test_a_job_already_logged_when_it_ends_is_not_logged_again(tmp_path):
    """A driver that stalled past its lease finishes a job another driver took over and
    logged: it does not log a second run."""
    tracker = NullTracker()
    (spec,) = _specs(tmp_path, seeds=(0,))

    class Overtaken(CannedExecutor):
        def submit(self, spec: JobSpec) -> int:
            handle = super().submit(spec)
            tracker.log_job(str(tracker.find_sweep("leased")), _outcome(spec), None)
            return handle

    stream = io.StringIO()
    summary = _sweep([spec], tracker, tmp_path, Overtaken(0.0), stream)
    finished = [r for r in tracker.runs.values() if r.status == "FINISHED" and "job_key" in r.tags]
    assert len(finished) == 1 and summary.skipped == [spec.key] and not summary.finished
    assert "not logged again" in stream.getvalue()
    assert not (spec.job_dir / pending.OUTCOME_FILE).exists()


def test_duplicate_runs_in_a_store_count_once_the_earliest_and_are_named(tmp_path):
    """A store with two FINISHED runs of one job (an older version, two drivers at once): the
    tables count the job once, from the earliest run, and say that a duplicate was ignored."""
    tracker = NullTracker()
    specs = _specs(tmp_path, seeds=(0, 1))
    parent = tracker.start_sweep("leased", {}, EFD)
    first = tracker.log_job(parent, _outcome(specs[0]), None)
    later = _outcome(specs[0])
    later.test = {J: {s: 1e6 for s in SUBSETS} for J in OBJECTIVE_NAMES}
    tracker.log_job(parent, later, None)
    stream = io.StringIO()
    summary = _sweep(specs, tracker, tmp_path, stream=stream)
    assert summary.finished == [specs[1].key] and summary.skipped == [specs[0].key]
    table = summary.tables["J2"]
    assert table.loc["J2-R", "n"] == 2
    assert table.loc["J2-R", column_name("Total", "mean")] == pytest.approx(50.5)
    note = f"1 duplicate run of job {specs[0].key} ignored (the tables use the earliest finished, run {first})"  # noqa: E501
    assert summary.notes == [note] and note in stream.getvalue()
    assert note in (tmp_path / "summary" / "J2.md").read_text()


# ---------------------------------------------------------------- a driver killed before logging

KILLED_DRIVER = """
import sys, time
from pathlib import Path
from sweep.service.tracking import MlflowTracker
from tests.test_leases import _specs, _sweep

class Dying(MlflowTracker):
    def log_job(self, parent_id, outcome, artifacts_dir):
        Path(sys.argv[2]).write_text("ending")  # the job has ended; the driver is killed now
        time.sleep(600)

root = Path(sys.argv[1])
_sweep(_specs(root / "multirun", seeds=(0, 1)), Dying(f"sqlite:///{root}/mlflow.db"), root)
"""


def test_a_driver_killed_between_a_jobs_end_and_its_logging_leaves_it_logged_once(tmp_path):
    """SIGKILL after the first job ended, before MLflow has it: the rerun logs that job once
    from the outcome it left (without running it again) and runs the other."""
    from sweep.service.tracking import MlflowTracker

    marker = tmp_path / "ended"
    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(repo / "src"), str(repo)])}
    proc = subprocess.Popen([sys.executable, "-c", KILLED_DRIVER, str(tmp_path), str(marker)],
                            env=env, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        for _ in range(1200):
            if marker.exists() or proc.poll() is not None:
                break
            time.sleep(0.1)
        assert marker.exists(), proc.communicate()[1] if proc.poll() is not None else "no marker"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    specs = _specs(tmp_path / "multirun", seeds=(0, 1))
    assert (specs[0].job_dir / pending.OUTCOME_FILE).is_file()
    assert [runs_of(s) for s in specs] == [1, 0]
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    stream = io.StringIO()
    summary = _sweep(specs, MlflowTracker(uri), tmp_path, stream=stream)  # the killed one's
    assert [runs_of(s) for s in specs] == [1, 1]  # lease is taken at once: its pid is gone
    assert sorted(summary.finished) == sorted(s.key for s in specs)
    assert "logged now from" in stream.getvalue()
    assert not (specs[0].job_dir / pending.OUTCOME_FILE).exists()
    tracker = MlflowTracker(uri)
    runs = tracker.client.search_runs(
        [str(tracker.experiment_id())], f"tags.mlflow.parentRunId = '{summary.parent_id}'"
    )
    assert sorted(r.data.tags["job_key"] for r in runs if r.info.status == "FINISHED") == sorted(
        s.key for s in specs
    )
    again = _sweep(specs, MlflowTracker(uri), tmp_path)
    assert sorted(again.skipped) == sorted(s.key for s in specs) and not again.finished


def test_two_drivers_that_end_at_once_log_the_summary_one_after_the_other(tmp_path):
    """Both drivers log the summary tables to the parent run at the same moment. MLflow logs a
    new table by reading the run's list of tables and writing it back: two clients at once
    failed one's insert (the sweep stopped with an error) or appended one's rows to the other's
    table (each of 3 runs without the lease). Under the lease of the sweep each table is logged
    once with its rows."""
    import pandas as pd

    from sweep.service.orchestration import _Claims
    from sweep.service.tracking import MlflowTracker

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    specs = _specs(tmp_path / "multirun")
    parent = MlflowTracker(uri).start_sweep("leased", {}, EFD)
    tables = {f"T{i}": pd.DataFrame({"a": [float(i), 2.0], "b": ["x", "y"]}) for i in range(24)}
    barrier = threading.Barrier(2)
    errors: list[BaseException] = []

    def driver() -> None:
        claims = _Claims(specs, Progress(io.StringIO()))
        tracker = MlflowTracker(uri)
        barrier.wait()
        try:
            claims.finish_sweep(tracker, parent, tables, {})
        except Exception as exc:
            errors.append(exc)
        finally:
            claims.close()

    threads = [threading.Thread(target=driver) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    client = MlflowTracker(uri).raw_client
    for name in tables:
        path = client.download_artifacts(parent, f"summary/{name}.json", str(tmp_path))
        assert len(json.loads(Path(path).read_text())["data"]) == 2, name
