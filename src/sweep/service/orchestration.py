"""The sweep: run many jobs with bounded concurrency, skip finished ones, survive failures.

:func:`run_sweep` is the orchestration, independent of Ray, MLflow and Hydra: it talks to an
:class:`Executor` (where jobs run: :class:`LocalExecutor` here,
``sweep.service.raycluster.RayExecutor`` for Ray) and a tracker (``sweep.service.tracking``: MLflow,
or an in-memory one for tests).

- One parent run per sweep (reused when the same sweep name runs again); one child run per job.
- Before anything runs, each job is looked up by its key: a finished job with the same config
  hash is skipped; one whose config changed is refused (``ConfigChangedError``) unless allowed.
- Jobs resume from their checkpoints (the job directory is stable: ``multirun/<sweep>/<job>``).
- One driver per job at a time: a job is claimed by a lease (:mod:`sweep.service.lease`) before
  it runs; a job another live driver holds is waited for (and counted as skipped when that
  driver logged it), the job of a driver whose lease expired is taken over and resumes from its
  checkpoint. Before a job is logged, a finished run of it in the tracker is looked for: a job
  is never logged twice.
- A job's outcome is kept in its directory (:mod:`sweep.service.pending`) from its end until it
  is logged: a driver killed in between leaves it, and the next run logs it from there.
- A failing job is recorded with its error and the others go on; the summary counts it.
- Progress: jobs done / running / failed / pending, an ETA from the evaluations done so far, and
  per running job its restart, population size, evaluations and best f.
- Ctrl-C cancels the running jobs (their checkpoints stay) and re-raises.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
import traceback
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TextIO

from mmg import efd_parameters
from sweep.data.datasets import split_from_mapping
from sweep.data.recordings import RecordingWarning
from sweep.identification.cmaes import CHECKPOINT_SECONDS
from sweep.identification.workers import InProcess
from sweep.service import pending, storage
from sweep.service.job import JobSpec, job_key, run_job, test_metrics
from sweep.service.lease import LEASE_SECONDS, Driver, Heartbeat, Holder, Lease
from sweep.service.outcome import JobOutcome, manoeuvre_metric_name

#: seconds before a lost job's first resubmission, doubled at each further one: Ray declares a
#: lost node dead only after it missed its health checks (about 15 s by default); a job
#: resubmitted sooner may be placed on that node again and lost again
RETRY_DELAY = 15.0


class Executor(Protocol):
    """Where jobs run. Handles are opaque; ``wait`` returns (handle, outcome or exception)."""

    def submit(self, spec: JobSpec) -> Any:
        """Start the job; returns its handle."""
        ...

    def wait(self, handles: Sequence[Any], timeout: float) -> list[tuple[Any, Any]]:
        """The jobs among ``handles`` that ended within ``timeout`` seconds, as (handle, outcome
        or exception) pairs; an outcome is (JobOutcome, {plot file name: PNG bytes})."""
        ...

    def status(self, handle: Any) -> Mapping[str, float] | None:
        """The running job's latest progress row (restart, popsize, evaluations, best_so_far,
        ...; see :func:`sweep.service.job.run_job`), or None before its first generation."""
        ...

    def cancel(self, handles: Sequence[Any]) -> None:
        """Stop the jobs (their checkpoints stay)."""
        ...

    def capacity(self) -> int:
        """How many jobs can run at once."""
        ...

    def lost(self, error: BaseException) -> bool:
        """Whether ``error`` means the job was lost to the infrastructure (a node, an actor, a
        worker killed for memory) rather than raised by the job's own code: then it is
        resubmitted, and resumes from its checkpoint."""
        ...


class LocalExecutor:
    """Runs each job in this process when submitted (sequential; for tests and single runs)."""

    def __init__(
        self, threads: int | None = None, plots: bool = True, uncertainty: bool | None = None
    ) -> None:
        self.threads = threads
        self.plots = plots
        self.uncertainty = uncertainty  # the intervals of each job's parameters (None: as plots)
        self._done: dict[int, Any] = {}
        self._status: dict[int, dict[str, float]] = {}
        self._next = 0

    def submit(self, spec: JobSpec) -> int:
        """Run the job to its end now; returns its handle (its outcome or error waits there)."""
        handle = self._next
        self._next += 1

        def status(row: dict[str, float]) -> None:
            self._status[handle] = row

        try:
            self._done[handle] = run_job(
                spec, lambda obj: InProcess(obj, self.threads), status, self.plots, self.uncertainty
            )
        except Exception as exc:  # a failed job is a value
            exc.add_note(traceback.format_exc())
            self._done[handle] = exc
        return handle

    def wait(self, handles: Sequence[Any], timeout: float) -> list[tuple[Any, Any]]:
        """Every finished job among ``handles`` (all of them: jobs run when submitted)."""
        return [(h, self._done.pop(h)) for h in handles if h in self._done]

    def status(self, handle: Any) -> Mapping[str, float] | None:
        """The job's last progress row."""
        return self._status.get(handle)

    def cancel(self, handles: Sequence[Any]) -> None:
        """Jobs run synchronously: nothing is left to cancel."""

    def capacity(self) -> int:
        """One job at a time."""
        return 1

    def lost(self, error: BaseException) -> bool:
        """In this process a failure is always the job's own."""
        return False


@dataclass
class SweepSummary:
    """What a sweep did."""

    parent_id: str
    finished: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)
    retries: dict[str, int] = field(default_factory=dict)  # resubmissions per job key
    tables: dict[str, Any] = field(default_factory=dict)  # {J or "manoeuvres": table}
    notes: list[str] = field(default_factory=list)  # said under the tables (duplicates ignored)
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        """Whether no job failed."""
        return not self.failed


def spec_from_config(cfg: Mapping[str, Any], job_dir: Path) -> JobSpec:
    """A JobSpec from a composed (resolved, plain) sweep config of one job."""
    objective = str(cfg["objective"]["name"])
    train = str(cfg["train"]["key"])
    seed = int(cfg["seed"])
    config = {
        "objective": objective,
        "train": dict(cfg["train"]),
        "test": dict(cfg["test"]),
        "budget": dict(cfg["budget"]),
        # cmaes.polish only when on: plain jobs keep their configs (and hashes)
        "cmaes": {k: v for k, v in dict(cfg["cmaes"]).items() if k != "polish" or v},
        "seed": seed,
    }
    if cfg.get("effects"):  # only when set: plain jobs keep their configs (and hashes)
        config["effects"] = [str(e) for e in cfg["effects"]]
    root = cfg.get("data", {}).get("root")
    sweep_cfg = cfg.get("sweep") or {}
    store = sweep_cfg.get("storage")
    key = job_key(objective, train, seed)
    # the same directory name as the job's own directory (the overrides that define the job):
    # a changed override is a new checkpoint with storage as without it
    checkpoint = (
        storage.join(
            storage.absolute(str(store)),
            str(sweep_cfg.get("name", "default")),
            Path(job_dir).name,
            "checkpoint.pkl",
        )
        if store
        else None
    )
    return JobSpec(
        key=key,
        objective=objective,
        train=train,
        seed=seed,
        config=config,
        job_dir=Path(job_dir),
        data_root=str(root) if root else None,
        checkpoint=checkpoint,
        checkpoint_seconds=float(sweep_cfg.get("checkpoint_seconds", CHECKPOINT_SECONDS)),
        lease_seconds=float(sweep_cfg.get("lease_seconds", LEASE_SECONDS)),
    )


def check_recordings(specs: Sequence[JobSpec], stream: TextIO = sys.stderr) -> None:
    """Read every recording the jobs will use, once, in the driver: a bad file fails here,
    before anything runs (RecordingError, a user error), and each data warning (trailing empty
    rows dropped, ...) is printed once instead of by every job that reads the file."""
    seen: set[str] = set()
    loaded: set[tuple[str, str | None]] = set()
    for spec in specs:
        for what, cfg in (
            ("train=" + spec.train, spec.config["train"]),
            ("test", spec.config["test"]),
        ):
            key = (repr(sorted(dict(cfg).items())), spec.data_root)
            if key in loaded:
                continue
            loaded.add(key)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", RecordingWarning)
                split_from_mapping(dict(cfg), what).load(spec.data_root)
            for w in caught:
                text = str(w.message)
                if issubclass(w.category, RecordingWarning) and text not in seen:
                    seen.add(text)
                    print(f"warning: {text}", file=stream)


def efd_reference(
    test_cfg: Mapping[str, Any], data_root: str | None
) -> dict[str, dict[str, float]]:
    """J1, J2, J3 of the EFD model on the test set (the reference row of the tables)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)  # said once by check_recordings
        test = split_from_mapping(dict(test_cfg), "test").load(data_root)
    return test_metrics(efd_parameters(), test)


def efd_manoeuvres(test_cfg: Mapping[str, Any], data_root: str | None) -> dict[str, float]:
    """The EFD model's manoeuvres (the standard ones and the test set's turning and zigzag runs)
    as ``manoeuvre/...`` metrics: the EFD column of the manoeuvre table (point values: the EFD
    parameters have no identification uncertainty)."""
    from sweep.data.manoeuvre_tables import manoeuvre_metrics
    from sweep.data.standard_manoeuvres import compare_recorded, find_manoeuvre, predict_standard

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)  # said once by check_recordings
        test = split_from_mapping(dict(test_cfg), "test").load(data_root)
    found = (find_manoeuvre(rec, label) for label, rec in test.items())
    efd = efd_parameters()
    comparisons = compare_recorded(efd, [r for r in found if r is not None])
    metrics = manoeuvre_metrics(predict_standard(efd), comparisons)
    return {manoeuvre_metric_name(k): v for k, v in metrics.items()}


class Progress:
    """A live display on a terminal; one line every ``every`` seconds otherwise (logs, CI)."""

    def __init__(self, stream: TextIO = sys.stderr, every: float = 2.0, log_every: float = 15.0):
        self.stream = stream
        self.every = every if stream.isatty() else log_every
        self.tty = stream.isatty()
        self._last = 0.0
        self._lines = 0

    def show(self, text: str, force: bool = False) -> None:
        """Replace the display by ``text`` (at most every ``every`` seconds unless ``force``)."""
        now = time.perf_counter()
        if not force and now - self._last < self.every:
            return
        self._last = now
        if self.tty and self._lines:
            self.stream.write(f"\x1b[{self._lines}F\x1b[J")  # back up and clear the last block
        self.stream.write(text + "\n")
        self.stream.flush()
        self._lines = text.count("\n") + 1 if self.tty else 0

    def note(self, text: str) -> None:
        """A line that stays above the live display (an event: a retry, a warning)."""
        if self.tty and self._lines:
            self.stream.write(f"\x1b[{self._lines}F\x1b[J")
        self.stream.write(text + "\n")
        self.stream.flush()
        self._lines = 0
        self._last = 0.0  # redraw the display below it at the next update


def _eta(done_evals: float, total_evals: float, elapsed: float) -> str:
    if done_evals <= 0 or elapsed <= 0:
        return "ETA --"
    seconds = (total_evals - done_evals) / (done_evals / elapsed)
    return f"ETA {int(seconds // 60)}m{int(seconds % 60):02d}s"


def balanced_concurrency(n_jobs: int, slots: int, max_factor: float = 1.5) -> int:
    """Jobs to run at once on ``slots`` job slots (CPUs // workers per job) so that the last
    round does not leave slots idle: the k in [slots, max_factor x slots] that minimises
    ceil(n_jobs / k) x max(1, k / slots), the wall time of n_jobs equal jobs in rounds of k
    sharing the slots (the smallest such k on a tie).

    27 jobs on 2 slots: 14 rounds of 2 leave one core idle for the last job's whole run
    (14 job-lengths); 9 rounds of 3 sharing the 2 cores take 13.5, and a third job also fills
    the gaps while the others' coordinators step CMA-ES.
    """
    if n_jobs <= slots or slots <= 0:
        return max(1, slots)
    best_k, best_t = slots, float(math.ceil(n_jobs / slots))
    for k in range(slots + 1, int(max_factor * slots) + 1):
        t = math.ceil(n_jobs / k) * k / slots
        if t < best_t - 1e-9:
            best_k, best_t = k, t
    return best_k


class _Claims:
    """The leases of one driver's jobs (:mod:`sweep.service.lease`): claimed before a job runs,
    kept alive by a heartbeat, released at its end; the jobs other live drivers hold."""

    def __init__(self, specs: Sequence[JobSpec], progress: Progress) -> None:
        self.driver = Driver.this()
        self.specs = list(specs)
        self.progress = progress
        self.seconds = min((s.lease_seconds for s in specs), default=LEASE_SECONDS)
        self.heartbeat = Heartbeat(self.seconds / 3.0)
        self.leases: dict[str, Lease] = {}
        self.held: dict[str, tuple[JobSpec, Holder]] = {}  # waiting for another driver
        self._looked = time.monotonic()

    def claim(self, spec: JobSpec) -> bool:
        """Whether this driver now holds ``spec``'s job (else it waits in ``held``)."""
        lease = Lease(spec.lease_directory, self.driver, spec.lease_seconds)
        holder = lease.acquire()
        if holder is not None:
            if spec.key not in self.held:
                self.progress.note(
                    f"{spec.key}: held by driver {holder.driver}; waiting for it to end"
                )
            self.held[spec.key] = (spec, holder)
            return False
        self.held.pop(spec.key, None)
        self.leases[spec.key] = lease
        self.heartbeat.add(lease)
        return True

    def freed(self) -> list[JobSpec]:
        """The held jobs whose lease is no longer live (released, expired, its driver gone),
        looked at every few seconds: to be claimed again."""
        now = time.monotonic()
        if not self.held or now - self._looked < min(2.0, self.seconds / 3.0):
            return []
        self._looked = now
        out = []
        for key, (spec, _) in list(self.held.items()):
            current = Lease(spec.lease_directory, self.driver).holder()
            if current is None or not current.live():
                out.append(spec)
            else:
                self.held[key] = (spec, current)
        return out

    def release(self, spec: JobSpec) -> None:
        """Give ``spec``'s job up (said if its lease had been taken over meanwhile)."""
        lease = self.leases.pop(spec.key, None)
        if lease is None:
            return
        self.heartbeat.remove(lease)
        if lease.directory in self.heartbeat.lost:
            self.progress.note(
                f"{spec.key}: its lease expired while it ran (this driver stalled for over "
                f"{lease.seconds:g} s) and another driver may have taken the job over"
            )
        lease.release()

    def start_sweep(
        self, tracker: Any, name: str, config: dict[str, Any], efd: dict[str, dict[str, float]]
    ) -> str:
        """``tracker.start_sweep`` under the lease of the sweep (:meth:`sweep_lease`), so that
        two drivers started at once make one parent run, not two."""
        with self.sweep_lease():
            return str(tracker.start_sweep(name, config, efd))

    def finish_sweep(
        self, tracker: Any, parent: str, tables: dict[str, Any], files: dict[str, Path]
    ) -> None:
        """``tracker.finish_sweep`` under the lease of the sweep, so that two drivers that end
        at once log the summary one after the other: MLflow logs a new table by reading the
        run's list of tables and writing it back, and two at once made one driver's insert
        fail (the sweep stopped with an error) or appended one driver's rows to the other's."""
        with self.sweep_lease():
            tracker.finish_sweep(parent, tables, files)

    @contextlib.contextmanager
    def sweep_lease(self) -> Iterator[None]:
        """Hold the lease of the sweep (``parent-lease`` beside the jobs' directories; waiting
        while another driver holds it), kept alive by the heartbeat."""
        if not self.specs:
            yield
            return
        jobs = self.specs[0].lease_directory.rsplit("/", 2)[0]
        lease = Lease(storage.join(jobs, "parent-lease"), self.driver, self.seconds)
        while lease.acquire() is not None:
            time.sleep(0.2)  # another driver is making, resuming or summing up the parent run
        self.heartbeat.add(lease)
        try:
            yield
        finally:
            self.heartbeat.remove(lease)
            lease.release()

    def close(self) -> None:
        """Release every lease still held and stop the heartbeat."""
        for lease in list(self.leases.values()):
            with contextlib.suppress(OSError):
                lease.release()
        self.leases.clear()
        self.heartbeat.stop()


def run_sweep(
    name: str,
    specs: Sequence[JobSpec],
    executor: Executor,
    tracker: Any,
    efd: Mapping[str, Mapping[str, float]],
    out_dir: Path,
    sweep_config: Mapping[str, Any] | None = None,
    max_concurrent: int | None = None,
    progress: Progress | None = None,
    on_outcome: Callable[[JobOutcome], None] | None = None,
    max_retries: int = 3,
    retry_delay: float = RETRY_DELAY,
) -> SweepSummary:
    """Run the jobs; log each to the tracker; write and log the summary tables at the end.

    A job lost to the infrastructure (``executor.lost``) is resubmitted, up to ``max_retries``
    times, after ``retry_delay`` seconds doubled at each retry (a lost node is declared dead
    only after its missed health checks: resubmitted at once, the job could land on it again),
    and resumes from its last checkpoint wherever it lands; an error of the job's own
    code fails the job at once. Each job is claimed by a lease first: jobs another live driver
    holds are waited for, so that the summary covers every job once."""
    t0 = time.perf_counter()
    efd_table = {k: dict(v) for k, v in efd.items()}
    progress = progress or Progress()
    claims = _Claims(specs, progress)
    try:
        parent = claims.start_sweep(tracker, name, dict(sweep_config or {}), efd_table)
        summary = SweepSummary(parent_id=parent)
        todo: list[JobSpec] = []
        for spec in specs:  # refuse changed configs before anything runs
            if tracker.find_finished(spec.key, spec.config_hash, parent):
                summary.skipped.append(spec.key)
            else:
                todo.append(spec)
    except BaseException:
        claims.close()
        raise
    budget = {s.key: float(s.config["budget"]["max_evaluations"]) for s in specs}
    total_evals = sum(budget[s.key] for s in todo)
    done_evals = 0.0
    limit = max(1, max_concurrent or executor.capacity())
    running: dict[Any, JobSpec] = {}
    not_before: dict[str, float] = {}  # a lost job's resubmission waits until then
    try:
        while todo or running or claims.held:
            todo[:0] = claims.freed()
            while len(running) < limit:
                now = time.monotonic()
                ready = [k for k, s in enumerate(todo) if not_before.get(s.key, 0.0) <= now]
                if not ready:
                    break
                spec = todo.pop(ready[0])
                if not claims.claim(spec):
                    continue
                if _settled(spec, tracker, parent, summary, progress, on_outcome):
                    claims.release(spec)
                    done_evals += budget[spec.key]
                    continue
                running[executor.submit(spec)] = spec
            for handle, result in executor.wait(list(running), timeout=0.5):
                spec = running.pop(handle)
                if (
                    isinstance(result, BaseException)
                    and executor.lost(result)
                    and summary.retries.get(spec.key, 0) < max_retries
                ):
                    n = summary.retries[spec.key] = summary.retries.get(spec.key, 0) + 1
                    delay = retry_delay * 2 ** (n - 1)
                    not_before[spec.key] = time.monotonic() + delay
                    progress.note(
                        f"{spec.key}: lost ({type(result).__name__}: "
                        f"{str(result).splitlines()[0][:160] if str(result) else ''}); "
                        f"resubmitted ({n}/{max_retries}) in {delay:.3g} s, resumes from its "
                        "checkpoint"
                    )
                    todo.insert(0, spec)
                    continue
                done_evals += budget[spec.key]
                _record_result(spec, result, tracker, parent, summary, progress, on_outcome)
                claims.release(spec)
            live = sum(float((executor.status(h) or {}).get("evaluations", 0.0)) for h in running)
            eta = _eta(done_evals + live, total_evals, time.perf_counter() - t0)
            lines = _status_lines(executor, running, len(todo), summary, budget, eta, claims.held)
            progress.show("\n".join(lines), force=not running and not todo and not claims.held)
            if claims.held and not running and not todo:
                time.sleep(0.5)  # only other drivers' jobs are left: wait for them
            elif todo and not running:
                time.sleep(0.2)  # only resubmissions that wait are left
        test = (dict(specs[0].config["test"]), specs[0].data_root) if specs else None
        _write_summary(tracker, parent, efd_table, out_dir, summary, progress, claims, test)
    except KeyboardInterrupt:
        executor.cancel(list(running))
        raise
    finally:
        claims.close()
    summary.seconds = time.perf_counter() - t0
    return summary


def _settled(
    spec: JobSpec,
    tracker: Any,
    parent: str,
    summary: SweepSummary,
    progress: Progress,
    on_outcome: Callable[[JobOutcome], None] | None,
) -> bool:
    """Whether a job just claimed needs no run: another driver logged it meanwhile (skipped),
    or it ended before its driver could log it (logged now from the outcome it left)."""
    if tracker.find_finished(spec.key, spec.config_hash, parent):
        summary.skipped.append(spec.key)
        progress.note(f"{spec.key}: finished by another driver")
        pending.forget(spec.job_dir)
        return True
    outcome = pending.kept(spec.job_dir, spec.config_hash)
    if outcome is None:
        return False
    progress.note(
        f"{spec.key}: ended before its driver logged it; logged now from "
        f"{spec.job_dir / pending.OUTCOME_FILE} (not run again)"
    )
    _log_outcome(spec, outcome, tracker, parent, summary, progress, on_outcome)
    return True


def _record_result(
    spec: JobSpec,
    result: Any,
    tracker: Any,
    parent: str,
    summary: SweepSummary,
    progress: Progress,
    on_outcome: Callable[[JobOutcome], None] | None,
) -> None:
    """Log a job that ended: its error as a failed run, or its outcome with its plot files
    (written to ``job_dir/plots``); counted in ``summary``."""
    if isinstance(result, BaseException):
        error = "".join(traceback.format_exception(result))
        tracker.log_failure(
            parent,
            spec.key,
            {"objective": spec.objective, "train": spec.train, "seed": str(spec.seed)},
            dict(spec.config),
            error,
        )
        summary.failed[spec.key] = f"{type(result).__name__}: {result}"
        return
    outcome, files = result
    outcome.retries = summary.retries.get(spec.key, 0)
    if outcome.workers_replaced:
        progress.note(
            f"{spec.key}: evaluation worker lost {outcome.workers_replaced} time(s) (a crash or "
            "a lost node); its chunks were evaluated in the coordinator, the worker replaced"
        )
    plots = spec.job_dir / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    for fname, data in files.items():
        (plots / fname).write_bytes(data)
    pending.keep(spec.job_dir, outcome)  # durable before it is logged
    _log_outcome(spec, outcome, tracker, parent, summary, progress, on_outcome)


def _log_outcome(
    spec: JobSpec,
    outcome: JobOutcome,
    tracker: Any,
    parent: str,
    summary: SweepSummary,
    progress: Progress,
    on_outcome: Callable[[JobOutcome], None] | None,
) -> None:
    """Log a finished job (its plots from ``job_dir/plots``) unless the tracker already has a
    finished run of it; then drop the outcome kept for the logging."""
    existing = tracker.find_finished(spec.key, spec.config_hash, parent)
    if existing:
        progress.note(f"{spec.key}: already logged (run {existing}); not logged again")
        summary.skipped.append(spec.key)
    else:
        tracker.log_job(parent, outcome, spec.job_dir / "plots")
        summary.finished.append(spec.key)
    pending.forget(spec.job_dir)
    if on_outcome is not None and not existing:
        on_outcome(outcome)


def _status_lines(
    executor: Executor,
    running: Mapping[Any, JobSpec],
    pending: int,
    summary: SweepSummary,
    budget: Mapping[str, float],
    eta: str,
    held: Mapping[str, tuple[JobSpec, Holder]] | None = None,
) -> list[str]:
    """The progress display: the jobs' counts and the ETA, then one line per running job (its
    restart, population, evaluations of its budget and best f, or its refinement's iteration)
    and one per job another driver holds."""
    held = held or {}
    lines = [
        f"jobs: {len(summary.finished)} done, {len(running)} running, "
        f"{len(summary.failed)} failed, {pending} pending, "
        f"{len(summary.skipped)} skipped"
        + (f", {len(held)} held by other drivers" if held else "")
        + f" | {eta}"
    ]
    for h, spec in running.items():
        st = executor.status(h) or {}
        if "lm_iteration" in st:  # cmaes.polish: the refinement after the restarts
            lines.append(
                f"  {spec.key}: Levenberg-Marquardt iteration "
                f"{int(st['lm_iteration'])}/{int(st.get('lm_iterations', 0))} "
                f"J {st['lm_f']:.1f} "
                f"(CMA-ES best {st.get('best_so_far', float('nan')):.1f})"
            )
        elif st:
            lines.append(
                f"  {spec.key}: restart {int(st.get('restart', 0))} "
                f"pop {int(st.get('popsize', 0))} "
                f"evals {int(st.get('evaluations', 0))}/{int(budget[spec.key])} "
                f"best {st.get('best_so_far', float('nan')):.1f}"
                + (f" (retry {summary.retries[spec.key]})" if summary.retries.get(spec.key) else "")
            )
        else:
            lines.append(f"  {spec.key}: starting")
    for key, (_, holder) in held.items():
        lines.append(f"  {key}: held by driver {holder.driver}")
    return lines


def _write_summary(
    tracker: Any,
    parent: str,
    efd_table: dict[str, dict[str, float]],
    out_dir: Path,
    summary: SweepSummary,
    progress: Progress,
    claims: _Claims,
    test: tuple[dict[str, Any], str | None] | None = None,
) -> None:
    """The summary tables of every logged job (and the sweep figure) to ``out_dir/summary``,
    logged to the parent run under the lease of the sweep (``claims``); nothing when no job
    has an outcome. With the jobs' manoeuvres also the manoeuvre table, beside the
    EFD model's on the ``test`` set (its config and data root), computed here once."""
    from sweep.service.figures import plot_sweep
    from sweep.service.tables import (
        MANOEUVRE_TABLE,
        manoeuvre_table,
        summary_tables,
        write_manoeuvre_table,
        write_tables,
    )

    outcomes = tracker.job_outcomes(parent)
    if not outcomes:
        return
    for record in outcomes:  # several finished runs of one job (older versions, two drivers)
        if record.get("duplicates"):
            n = int(record["duplicates"])
            summary.notes.append(
                f"{n} duplicate run{'s' if n > 1 else ''} of job {record['job_key']} ignored "
                f"(the tables use the earliest finished, run {record['run_id']})"
            )
            progress.note(summary.notes[-1])
    tables = summary_tables(outcomes, efd_table)
    summary.files = write_tables(tables, out_dir / "summary", summary.notes)
    try:
        figure = plot_sweep(
            tables, tracker.job_histories(parent), out_dir / "summary" / "sweep.png"
        )
        summary.files[figure.name] = figure
    except Exception as exc:  # the figure is a convenience: the tables must still land
        progress.note(f"warning: the sweep figure could not be drawn ({exc})")
    manoeuvres = manoeuvre_table(outcomes)
    if not manoeuvres.empty:
        efd = None
        try:
            efd = efd_manoeuvres(*test) if test is not None else None
        except Exception as exc:  # the EFD column is a reference: the table must still land
            progress.note(f"warning: the EFD model's manoeuvres could not be computed ({exc})")
        tables[MANOEUVRE_TABLE] = manoeuvre_table(outcomes, efd)
        summary.files.update(write_manoeuvre_table(tables[MANOEUVRE_TABLE], out_dir / "summary"))
    summary.tables = tables
    claims.finish_sweep(tracker, parent, tables, summary.files)
