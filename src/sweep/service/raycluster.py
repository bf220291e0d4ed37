"""Ray: jobs as actors, population evaluation on worker actors. The only module importing ray.

Resources never deadlock: a job's coordinator actor (:class:`JobActor`) requests no CPU and only
steers CMA-ES; its ``workers_per_job`` evaluation workers (:class:`EvalWorker`) hold
``cpus_per_worker`` CPUs each and evaluate chunks of the population with the batched simulator
(one Numba thread each). At most (cluster CPUs) / (workers_per_job x cpus_per_worker) jobs run at
once, so every running job's workers fit. ``cpus_per_worker`` is 1 unless the number of jobs
would leave cores idle in the last round
(:func:`sweep.service.orchestration.balanced_concurrency`): 27 jobs on 2 CPUs run 3 at a time
with 2/3 CPU per worker.

A dead worker (a crash, a lost node) does not lose the generation: its chunk is evaluated in the
coordinator and the worker is replaced. A lost coordinator (its node died) is reported as lost
(:func:`is_lost`); the sweep resubmits the job, which resumes from its checkpoint on any node.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from typing import Any

import numba
import numpy as np
import ray

from sweep.data.objective import Objective
from sweep.identification.workers import safe_evaluate
from sweep.service.job import JobSpec, run_job
from sweep.service.orchestration import balanced_concurrency

log = logging.getLogger(__name__)
_remote: Any = ray.remote  # Ray's decorator overloads do not type actor classes

#: Ray's exceptions that mean "lost to the infrastructure", not "raised by our code": an actor
#: died or is unreachable (its node lost), a worker process crashed or was killed for memory,
#: an object's owner or its copies are gone, the local raylet died
LOST: tuple[type[BaseException], ...] = (
    ray.exceptions.RayActorError,  # ActorDiedError, ActorUnavailableError
    ray.exceptions.NodeDiedError,
    ray.exceptions.WorkerCrashedError,
    ray.exceptions.OutOfMemoryError,
    ray.exceptions.ObjectLostError,  # OwnerDiedError, ObjectReconstructionFailedError
    ray.exceptions.LocalRayletDiedError,
)


_EVAL_FAILURES: tuple[type[BaseException], ...] = (*LOST, ray.exceptions.RayTaskError)


def is_lost(error: BaseException) -> bool:
    """Whether ``error`` means lost to the infrastructure (also when a task re-raised it)."""
    if isinstance(error, LOST):
        return True
    cause = getattr(error, "cause", None)  # a RayTaskError carries the original exception
    return isinstance(cause, LOST)


class _EvalWorker:
    """Holds one copy of the objective; evaluates chunks of a population (1 CPU)."""

    def __init__(self, objective: Objective, threads: int = 1) -> None:
        numba.set_num_threads(max(1, threads))
        self.objective = objective

    def evaluate(self, thetas: np.ndarray) -> np.ndarray:
        """Objective values (C,) of the candidates ``thetas`` (C, n)."""
        return safe_evaluate(self.objective, thetas)

    def seconds(self) -> float:
        """CPU time spent in the objective (a share of a CPU waits: its wall time overcounts)."""
        return self.objective.cpu_seconds


#: the Ray actor class of :class:`_EvalWorker` (1 CPU unless ``options`` say otherwise)
EvalWorker: Any = _remote(num_cpus=1)(_EvalWorker)


class RayEvaluator:
    """Population evaluation on ``n`` :class:`EvalWorker` actors (the job's local workers)."""

    def __init__(self, objective: Objective, n: int, cpus_per_worker: float = 1.0) -> None:
        self.objective = objective
        self.cpus = cpus_per_worker
        self.threads = max(1, int(cpus_per_worker))  # a share of one CPU: one thread
        self._ref = ray.put(objective)
        self.workers = [self._start() for _ in range(max(1, n))]
        self.sim_seconds = 0.0  # collected from the workers when they are closed
        self.replaced = 0  # workers lost (or failed) and replaced; their chunks evaluated here

    def _start(self) -> Any:
        return EvalWorker.options(num_cpus=self.cpus).remote(self._ref, self.threads)

    def __call__(self, thetas: np.ndarray) -> np.ndarray:
        """Objective values (C,) of the candidates ``thetas`` (C, n), one chunk per worker.

        A chunk whose worker is lost or fails is evaluated here and the worker replaced.
        """
        X = np.asarray(thetas, dtype=np.float64)
        chunks = [c for c in np.array_split(X, min(len(self.workers), len(X))) if len(c)]
        refs = [w.evaluate.remote(c) for w, c in zip(self.workers, chunks, strict=False)]
        out: list[np.ndarray] = []
        for i, (ref, chunk) in enumerate(zip(refs, chunks, strict=True)):
            try:
                out.append(np.asarray(ray.get(ref), dtype=np.float64))
            except _EVAL_FAILURES as exc:
                log.warning(
                    "evaluation worker lost (%s); evaluating its chunk here",
                    type(exc).__name__,
                )
                out.append(safe_evaluate(self.objective, chunk))
                ray.kill(self.workers[i], no_restart=True)
                self.workers[i] = self._start()
                self.replaced += 1
        return np.concatenate(out)

    def close(self) -> None:
        """Add the workers' simulator CPU time to :attr:`sim_seconds` and stop them."""
        try:
            self.sim_seconds += float(sum(ray.get([w.seconds.remote() for w in self.workers])))
        except Exception:  # timing is best effort; a dead worker took its count with it
            log.warning("could not collect simulator time from the workers")
        for w in self.workers:
            ray.kill(w, no_restart=True)
        self.workers = []

    def __enter__(self) -> RayEvaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _JobActor:
    """Runs one job (restart CMA-ES) and answers status queries while it runs (0 CPU)."""

    def __init__(self) -> None:
        self._status: dict[str, float] = {}

    def run(self, spec: JobSpec, workers: int, plots: bool = True, cpus: float = 1.0) -> Any:
        """Run the job with ``workers`` evaluation actors of ``cpus`` CPUs each; its outcome."""
        return run_job(spec, lambda obj: RayEvaluator(obj, workers, cpus), self._set, plots)

    def _set(self, row: dict[str, float]) -> None:
        self._status = row

    def status(self) -> dict[str, float]:
        """The last progress row of the running job (empty before the first generation)."""
        return dict(self._status)


#: the Ray actor class of :class:`_JobActor`: no CPU, two concurrent calls (run and status)
JobActor: Any = _remote(num_cpus=0, max_concurrency=2)(_JobActor)


class RayExecutor:
    """An :class:`sweep.service.orchestration.Executor` on Ray (a local Ray, or a cluster by
    address)."""

    def __init__(
        self,
        address: str | None = None,
        num_cpus: int | None = None,
        workers_per_job: int = 1,
        plots: bool = True,
        env: Mapping[str, str] | None = None,
        jobs: int | None = None,
        cpus_per_worker: float | None = None,
    ) -> None:
        """``jobs``: how many the sweep will run (to balance the rounds); ``cpus_per_worker``:
        the CPU share of an evaluation worker, None: 1 unless balancing asks for less."""
        os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # local runs: no token file needed
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": True}
        if address or env:
            # a cluster's workers run in the nodes' own environments: they are given the
            # driver's MMG_* and NUMBA_* variables (the data and kernel directories); a local
            # Ray's workers inherit the driver's environment, and a runtime environment would
            # only start a setup process before every worker (1-2 s of a core each)
            env_vars = {k: v for k, v in os.environ.items() if k.startswith(("MMG_", "NUMBA_"))}
            env_vars.update(env or {})
            kwargs["runtime_env"] = {"env_vars": env_vars}
        if address:
            ray.init(address=address, **kwargs)
        else:
            # "local": a fresh private instance, never a cluster that `ray start` left registered
            # on this machine (running or stopped); "auto" keeps Ray's own discovery
            ray.init(address="local", num_cpus=num_cpus, **kwargs)
        self.workers_per_job = max(1, workers_per_job)
        self.plots = plots
        self._actors: dict[Any, Any] = {}
        if cpus_per_worker is None:
            cpus = float(ray.cluster_resources().get("CPU", 1))
            slots = max(1, int(cpus) // self.workers_per_job)
            k = balanced_concurrency(jobs, slots) if jobs else slots
            cpus_per_worker = min(1.0, cpus / (k * self.workers_per_job))
        # Ray counts CPUs to 1e-4: rounded down, k shares of cpus / k still fit
        self.cpus_per_worker = max(1e-4, math.floor(cpus_per_worker * 1e4) / 1e4)

    def capacity(self) -> int:
        """How many jobs fit at once: cluster CPUs / (workers per job x CPUs per worker)."""
        cpus = float(ray.cluster_resources().get("CPU", 1))
        return max(1, int(cpus / (self.workers_per_job * self.cpus_per_worker) + 1e-9))

    def lost(self, error: BaseException) -> bool:
        """Whether a job's error means lost to the infrastructure (resubmit it): :func:`is_lost`."""
        return is_lost(error)

    def submit(self, spec: JobSpec) -> Any:
        """Start the job on a new coordinator actor; the handle (an object ref) of its outcome."""
        # coordinators spread over the nodes: a lost node takes as few of them as it can
        actor = JobActor.options(scheduling_strategy="SPREAD").remote()
        ref = actor.run.remote(spec, self.workers_per_job, self.plots, self.cpus_per_worker)
        self._actors[ref] = actor
        return ref

    def wait(self, handles: Sequence[Any], timeout: float) -> list[tuple[Any, Any]]:
        """(handle, outcome or exception) of the jobs among ``handles`` that finish within
        ``timeout`` seconds; their coordinator actors are stopped."""
        if not handles:
            return []
        ready, _ = ray.wait(list(handles), num_returns=len(handles), timeout=timeout)
        out: list[tuple[Any, Any]] = []
        for ref in ready:
            try:
                result: Any = ray.get(ref)
            except Exception as exc:  # a failed job is a value
                result = exc.as_instanceof_cause() if hasattr(exc, "as_instanceof_cause") else exc
            actor = self._actors.pop(ref, None)
            if actor is not None:
                ray.kill(actor, no_restart=True)
            out.append((ref, result))
        return out

    def status(self, handle: Any) -> Mapping[str, float] | None:
        """The running job's last progress row; None when unknown or not answering in 2 s."""
        actor = self._actors.get(handle)
        if actor is None:
            return None
        try:
            return dict(ray.get(actor.status.remote(), timeout=2.0))
        except Exception:  # status is best effort
            return None

    def cancel(self, handles: Sequence[Any]) -> None:
        """Stop the jobs ``handles`` (their coordinators; checkpoints stay)."""
        for ref in handles:
            actor = self._actors.pop(ref, None)
            if actor is not None:
                ray.kill(actor, no_restart=True)

    def shutdown(self) -> None:
        """Cancel every running job and shut Ray down."""
        self.cancel(list(self._actors))
        ray.shutdown()
