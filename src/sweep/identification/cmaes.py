"""Restart CMA-ES over the normalised search box (paper section 3.2-3.3).

The paper runs CMA-ES with box constraints and the restart strategy of Auger & Hansen (2005):
the population starts at 20 and doubles at every restart, up to 720. pycma's own IPOP (``fmin2``
with ``incpopsize``) has no cap, so this module is the restart layer: it builds a fresh
``cma.CMAEvolutionStrategy`` per restart, keeps the best solution across restarts, records every
restart's termination reason, and stops on a budget of function evaluations or wall-clock time.

Search space: y in [0, 1]^n with theta = lower + y (upper - lower) (the paper's domain,
:func:`mmg.bounds`); the initial mean is the EFD vector (``x0="efd"``) or any given vector.

Box constraints (setting ``bound_handling``):

- ``"penalty"`` (default): pycma's ``BoundPenalty``, Hansen et al. (2009) with pycma's
  modifications: candidates are evaluated at their projection onto the box and ranked by
  f + an adaptive quadratic penalty on the distance to it. This is the handler that the paper's
  "modified box constraint" (Sakamoto & Akimoto 2017) modifies, and the closest one with a
  maintained implementation: both repair to the box and rank with an adapted penalty; Sakamoto &
  Akimoto additionally adapt the penalty weights with the distribution's variance. The
  distribution mean may leave the box, as in the paper.
- ``"transform"``: pycma's ``BoundTransform`` (a smooth periodic map into the box).
- ``"none"``: no handling; candidates are evaluated where sampled (the model then runs with
  parameters outside the paper's domain).

Post-filter (paper section 5): a result (the best evaluated parameters) with some
theta_j > 10 |upper_j| or theta_j < -10 |lower_j| is reported as ``rejected`` (the paper removed
such seeds from its tables and used other results "without correction"). With ``penalty`` or
``transform`` every evaluated point lies in the box, so only ``none`` can produce a rejected
result; the final distribution mean is checked too and reported as ``mean_outside``.

Reproducibility: one integer seed fixes everything. Restart r draws its generator from
``numpy.random.SeedSequence(seed).spawn``; pycma samples with that generator (``randn`` option),
never numpy's global state. A checkpoint holds the strategy (pickled, with its generator), the
restart index, the evaluations used, the best so far and the history, so that a resumed run ends
exactly where an uninterrupted one would, whichever generation it resumes from. It is written
after the first generation, then at most every ``checkpoint_seconds`` (default
:data:`CHECKPOINT_SECONDS`; a lost job repeats at most that much work) and at the end of every
restart. It is written signed (:mod:`sweep.identification.checkpoint`) with the previous one kept
beside it; a checkpoint that is damaged, forged or another job's is set aside unread and the run
resumes from the previous one, or afresh.
"""

from __future__ import annotations

import math
import pickle
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import cma
import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from sweep.identification.checkpoint import Checkpoint, CheckpointError, Recovery, open_sealed
from sweep.identification.checkpoint import checkpoint_key as default_checkpoint_key
from sweep.identification.store import Store, as_store

FloatArray = NDArray[np.float64]
BoundHandling = Literal["penalty", "transform", "none"]

#: paper: initial population 20, doubled at each restart, at most 720
POPSIZE_START = 20
POPSIZE_MAX = 720
#: seconds between checkpoints within a restart (0: after every generation)
CHECKPOINT_SECONDS = 5.0


def population_schedule(restart: int, start: int = POPSIZE_START, cap: int = POPSIZE_MAX) -> int:
    """Population size of restart ``restart`` (0-based): start * 2^restart, capped."""
    return int(min(start * 2**restart, cap))


@dataclass(frozen=True)
class Settings:
    """Options of one optimisation job (all plain data, stored with the checkpoint)."""

    seed: int = 0
    max_evaluations: int = 100_000
    max_seconds: float | None = None
    sigma0: float = 0.03  # initial step size in the normalised box (see README: 0.03 vs 0.1)
    popsize_start: int = POPSIZE_START
    popsize_max: int = POPSIZE_MAX
    max_restarts: int = 100
    bound_handling: BoundHandling = "penalty"
    tolfun: float = 1e-11
    tolx: float = 1e-11
    #: per-coordinate multipliers of sigma0 (pycma's CMA_stds); None: all 1
    stds: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.bound_handling not in ("penalty", "transform", "none"):
            raise ValueError("bound_handling must be penalty, transform or none")
        if self.max_evaluations < self.popsize_start:
            raise ValueError("max_evaluations is smaller than one generation")
        if not 0.0 < self.sigma0 <= 1.0:
            raise ValueError("sigma0 must lie in (0, 1] (normalised box)")


@dataclass
class RestartRecord:
    """One restart: its population, generations, evaluations, best f and why it stopped."""

    index: int
    popsize: int
    generations: int = 0
    evaluations: int = 0
    best_f: float = math.inf
    stop: dict[str, Any] = field(default_factory=dict)


@dataclass
class State:
    """Everything needed to continue a job exactly: the checkpoint."""

    settings: Settings
    n: int
    restart: int = 0
    evaluations: int = 0
    es_pickle: bytes | None = None
    best_y: FloatArray | None = None
    best_f: float = math.inf
    best_restart: int = -1
    best_mean_y: FloatArray | None = None
    restarts: list[RestartRecord] = field(default_factory=list)
    history: list[dict[str, float]] = field(default_factory=list)
    seconds: float = 0.0
    finished: bool = False
    stop_reason: str = ""


@dataclass(frozen=True)
class Result:
    """Outcome of a job, in the parameter space (theta) and the normalised box (y)."""

    theta: FloatArray  # best evaluated parameters (C,) = (n,)
    f: float
    mean_theta: FloatArray  # final distribution mean of the restart that found the best
    evaluations: int
    restarts: list[RestartRecord]
    history: list[dict[str, float]]
    rejected: bool  # the paper's post-filter applied to theta
    mean_outside: bool  # the final mean fails the same test (information only)
    seconds: float
    stop_reason: str
    #: how this call got its starting checkpoint when the newest one was rejected (else None)
    recovery: Recovery | None = None


class Box:
    """Map between the parameter space and the normalised box [0, 1]^n."""

    def __init__(self, lower: FloatArray, upper: FloatArray) -> None:
        self.lower = np.asarray(lower, dtype=np.float64)
        self.upper = np.asarray(upper, dtype=np.float64)
        if self.lower.shape != self.upper.shape or np.any(self.upper <= self.lower):
            raise ValueError("bounds must have equal shapes with upper > lower")

    @property
    def n(self) -> int:
        """The number of dimensions."""
        return int(self.lower.size)

    def to_theta(self, y: Any) -> FloatArray:
        """Parameters (..., n) of normalised coordinates ``y`` (..., n)."""
        return self.lower + np.asarray(y, dtype=np.float64) * (self.upper - self.lower)

    def to_y(self, theta: Any) -> FloatArray:
        """Normalised coordinates (..., n) of parameters ``theta`` (..., n)."""
        return (np.asarray(theta, dtype=np.float64) - self.lower) / (self.upper - self.lower)

    def rejected(self, theta: Any) -> bool:
        """The paper's post-filter: some theta_j more than 10 times beyond its bound."""
        t = np.asarray(theta, dtype=np.float64)
        return bool(np.any(t > 10.0 * np.abs(self.upper)) or np.any(t < -10.0 * np.abs(self.lower)))


class BoundPenalty(cma.BoundPenalty):
    """pycma's ``BoundPenalty`` with its ``repair`` (the projection onto the box) done by numpy.

    pycma's own repair loops over the coordinates in Python, calling ``max`` and ``min`` per
    coordinate; it is called for every candidate in ``ask`` and again in ``tell``, which made it
    7.5 % of a job's time at population 20 (1.25 s of 16.6 s for 6,000 evaluations). The
    projection is the same: each coordinate raised to its lower bound, then lowered to its
    upper bound."""

    def repair(self, x: Any, copy_if_changed: bool = True) -> Any:
        """``x`` (n,) projected onto the box (a copy unless ``copy_if_changed`` is False)."""
        if not self.has_bounds():
            return x
        x = np.array(x, dtype=np.float64, copy=True) if copy_if_changed else x
        lower, upper = self._box(len(x))
        np.maximum(x, lower, out=x)
        np.minimum(x, upper, out=x)
        return x

    def _box(self, n: int) -> tuple[FloatArray, FloatArray]:
        """The lower and upper bound vectors in n dimensions (pycma rebuilds them per call)."""
        cache: dict[int, tuple[FloatArray, FloatArray]] = self.__dict__.setdefault("_box_of", {})
        if n not in cache:
            cache[n] = (self.get_bounds("lower", n), self.get_bounds("upper", n))
        return cache[n]


def _new_strategy(state: State, y0: FloatArray) -> cma.CMAEvolutionStrategy:
    s = state.settings
    seeds = np.random.SeedSequence(s.seed).spawn(state.restart + 1)
    child = int(seeds[state.restart].generate_state(1)[0])
    rng = np.random.RandomState(child)
    opts: dict[str, Any] = {
        "popsize": population_schedule(state.restart, s.popsize_start, s.popsize_max),
        "seed": child,  # pycma also seeds numpy's global generator with it: deterministic anyway
        "randn": rng.randn,
        "verbose": -9,
        "tolfun": s.tolfun,
        "tolx": s.tolx,
        "maxfevals": math.inf,  # the job's budget is enforced here, across restarts
    }
    if s.stds is not None:
        if len(s.stds) != y0.size:
            raise ValueError(f"settings.stds has {len(s.stds)} entries for {y0.size} coordinates")
        opts["CMA_stds"] = list(s.stds)
    if s.bound_handling == "penalty":
        opts.update(BoundaryHandler=BoundPenalty, bounds=[0.0, 1.0])
    elif s.bound_handling == "transform":
        opts.update(BoundaryHandler=cma.BoundTransform, bounds=[0.0, 1.0])
    return cma.CMAEvolutionStrategy(y0, s.sigma0, opts)


#: where a checkpoint is: a local path, a store, or a store with its key and job
CheckpointLike = str | Path | Store | Checkpoint


def _checkpoint(path: CheckpointLike, key: bytes | None = None, job: str = "") -> Checkpoint:
    """``path`` as a signed :class:`Checkpoint` (the user's key unless ``key`` is given)."""
    if isinstance(path, Checkpoint):
        return path
    return Checkpoint(as_store(path), default_checkpoint_key() if key is None else key, job)


def save_checkpoint(state: State, path: CheckpointLike) -> None:
    """Write signed and atomically, keeping the previous checkpoint beside it; ``path`` is a
    local file, a :class:`~sweep.identification.store.Store` (e.g. a storage URI's) or a
    :class:`~sweep.identification.checkpoint.Checkpoint` (a store with its key and job)."""
    _checkpoint(path).save(pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL))


#: the only globals a checkpoint's state may name (its dataclasses and numpy's arrays); the
#: strategy inside is pycma's own pickle, read only from an authenticated checkpoint
_ALLOWED = {
    (__name__, "State"),
    (__name__, "Settings"),
    (__name__, "RestartRecord"),
    ("numpy", "dtype"),
    ("numpy", "ndarray"),
    ("numpy._core.numeric", "_frombuffer"),
    ("numpy.core.numeric", "_frombuffer"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy.core.multiarray", "scalar"),
}


class _Unpickler(pickle.Unpickler):
    """Reads a checkpoint's state and refuses any other global (defence in depth: the envelope
    has already authenticated the bytes)."""

    def find_class(self, module: str, name: str) -> Any:
        """The class ``name`` of ``module`` if the state may hold it."""
        if (module, name) not in _ALLOWED:
            raise pickle.UnpicklingError(f"{module}.{name} is not part of a checkpoint")
        return super().find_class(module, name)


def _state_of(payload: bytes, name: str) -> State:
    """The state an authenticated payload holds; :class:`CheckpointError` ("other format") if it
    holds something else (e.g. written by another version of this module)."""
    import io

    try:
        state = _Unpickler(io.BytesIO(payload)).load()
    except Exception:  # any failure to read it: not a state this code can continue
        raise CheckpointError(name, "other format") from None
    if not isinstance(state, State):
        raise CheckpointError(name, "other format")
    return state


def load_checkpoint(
    path: str | Path | Store, key: bytes | None = None, job: str | None = None
) -> State:
    """The state the checkpoint at ``path`` (a local file or a store) holds, verified with ``key``
    (None: the user's) and written for the job ``job`` (None: any job); raises
    :class:`~sweep.identification.checkpoint.CheckpointError` (a ValueError) if it is damaged,
    forged, another job's or holds something else. Nothing is set aside."""
    store = as_store(path)
    key = default_checkpoint_key() if key is None else key
    return _state_of(open_sealed(store.read_bytes(), key, job, str(store)), str(store))


Evaluate = Callable[[FloatArray], FloatArray]
Progress = Callable[[State, dict[str, float]], None]


def optimise(
    evaluate: Evaluate,
    box: Box,
    x0: FloatArray,
    settings: Settings,
    checkpoint: CheckpointLike | None = None,
    progress: Progress | None = None,
    stop_after_generations: int | None = None,
    checkpoint_seconds: float = CHECKPOINT_SECONDS,
    checkpoint_key: bytes | None = None,
    checkpoint_job: str = "",
) -> Result:
    """Run (or resume from ``checkpoint``) a restart CMA-ES job.

    ``evaluate(thetas (C, n)) -> (C,)`` objective values (finite; penalties for failures).
    ``x0`` (n,) the initial mean in parameter space. ``checkpoint``: a local file or a
    :class:`~sweep.identification.store.Store` the caller provides (None: no checkpoint); the
    previous checkpoint is kept beside it (``<name>.prev``).
    ``stop_after_generations`` interrupts the run
    after that many generations of this call (for tests of resume), leaving a checkpoint.
    ``checkpoint_seconds``: the longest time between two checkpoints within a restart (0: after
    every generation); the first generation of a call and the end of a restart always write one.
    ``checkpoint_key``: the key that signs and verifies the checkpoint (None: the user's,
    :func:`~sweep.identification.checkpoint.checkpoint_key`); ``checkpoint_job``: the job's
    identity it is written for (a sweep's config hash). A checkpoint that is damaged, forged or
    another job's is set aside (one line on stderr, ``Result.recovery``) and the run resumes from
    the previous one, or afresh; one of this job written with other settings is refused
    (ValueError).
    """
    if not checkpoint_seconds >= 0.0:
        raise ValueError(f"checkpoint_seconds must be >= 0, not {checkpoint_seconds}")
    state: State | None = None
    recovery: Recovery | None = None
    ck: Checkpoint | None = None
    if checkpoint is not None:
        ck = _checkpoint(checkpoint, checkpoint_key, checkpoint_job)
        state, recovery = ck.load(_state_of)
        if state is not None and (state.settings != settings or state.n != box.n):
            raise ValueError(
                f"{checkpoint}: checkpoint was written with other settings "
                f"({state.settings}); remove it or use the same settings"
            )
    if state is None:
        state = State(settings=settings, n=box.n)
    y0 = np.clip(box.to_y(x0), 0.0, 1.0)
    # CMA-ES decomposes a 57 x 57 covariance every generation: too small for BLAS threads, and
    # with the cores busy (the kernel's threads, another job) waking them cost 24 ms a time
    # against 1 ms on one thread, 4.6 x the per-generation overhead (README, performance)
    with threadpool_limits(limits=1, user_api="blas"):
        return _optimise(
            evaluate,
            box,
            y0,
            settings,
            state,
            ck,
            progress,
            stop_after_generations,
            checkpoint_seconds,
            recovery,
        )


def _tell(es: Any, Y: FloatArray, f: FloatArray) -> bool:
    """Tell the strategy its generation's values; True when it cannot go on: pycma's boundary
    handling scales its penalty by the spread of the middle half of its first generations'
    values and raises when there was none (most of the population at one value: diverged to
    the penalty, or an objective that does not depend on the searched parameters). The
    restart stops there ("flat"); what was evaluated counts."""
    try:
        es.tell(list(Y), f.tolist())
    except ValueError as err:
        if "no feasible solution sampled" not in str(err):
            raise
        return True
    return False


def _optimise(
    evaluate: Evaluate,
    box: Box,
    y0: FloatArray,
    settings: Settings,
    state: State,
    checkpoint: Checkpoint | None,
    progress: Progress | None,
    stop_after_generations: int | None,
    checkpoint_seconds: float,
    recovery: Recovery | None,
) -> Result:
    t_start = time.perf_counter() - state.seconds
    generations_here = 0
    last_write = -math.inf  # the first generation of this call writes one
    s = settings
    while not state.finished:
        if state.es_pickle is None:
            if state.restart >= s.max_restarts:
                state.finished, state.stop_reason = True, "max_restarts"
                break
            es = _new_strategy(state, y0)
            state.restarts.append(RestartRecord(state.restart, es.popsize))
        else:
            es = pickle.loads(state.es_pickle)
        record = state.restarts[-1]
        stop: dict[str, Any] = {}
        while True:
            if state.evaluations + es.popsize > s.max_evaluations:
                stop = {"budget": s.max_evaluations}
                break
            if s.max_seconds is not None and time.perf_counter() - t_start > s.max_seconds:
                stop = {"wall_clock": s.max_seconds}
                break
            Y = np.asarray(es.ask())
            f = np.asarray(evaluate(box.to_theta(Y)), dtype=np.float64)
            if f.shape != (Y.shape[0],):
                raise ValueError(f"evaluate returned shape {f.shape} for {Y.shape[0]} candidates")
            f = np.where(np.isfinite(f), f, np.finfo(np.float64).max / 1e3)
            flat = _tell(es, Y, f)
            state.evaluations += len(f)
            record.generations += 1
            record.evaluations += len(f)
            i = int(np.argmin(f))
            if f[i] < record.best_f:
                record.best_f = float(f[i])
            if f[i] < state.best_f:
                state.best_f = float(f[i])
                state.best_y = Y[i].copy()
                state.best_restart = state.restart
            if state.best_restart == state.restart:
                state.best_mean_y = np.asarray(es.mean, dtype=np.float64).copy()
            row = {
                "restart": float(state.restart),
                "popsize": float(es.popsize),
                "generation": float(record.generations),
                "evaluations": float(state.evaluations),
                "best_f": float(f[i]),
                "median_f": float(np.median(f)),
                "best_so_far": state.best_f,
                "sigma": float(es.sigma),
            }
            state.history.append(row)
            stop = {"flat": 1} if flat else dict(es.stop())
            state.seconds = time.perf_counter() - t_start
            if stop:
                break
            generations_here += 1
            interrupt = stop_after_generations is not None and (
                generations_here >= stop_after_generations
            )
            now = time.perf_counter()
            if checkpoint is not None and (interrupt or now - last_write >= checkpoint_seconds):
                state.es_pickle = es.pickle_dumps()  # about 1 MB at population 720
                save_checkpoint(state, checkpoint)
                last_write = now
            elif interrupt:
                state.es_pickle = es.pickle_dumps()
            if progress is not None:
                progress(state, row)
            if interrupt:
                return _result(state, box, recovery)
        record.stop = {k: _plain(v) for k, v in stop.items()}
        state.es_pickle = None
        if "budget" in stop or "wall_clock" in stop:
            state.finished = True
            state.stop_reason = next(iter(stop))
        else:
            state.restart += 1
        state.seconds = time.perf_counter() - t_start
        if checkpoint is not None:
            save_checkpoint(state, checkpoint)
    return _result(state, box, recovery)


def _plain(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_plain(x) for x in v]
    return v


def _result(state: State, box: Box, recovery: Recovery | None = None) -> Result:
    if state.best_y is None:
        raise RuntimeError("no generation was evaluated")
    theta = box.to_theta(state.best_y)
    mean = box.to_theta(state.best_mean_y if state.best_mean_y is not None else state.best_y)
    return Result(
        theta=theta,
        f=state.best_f,
        mean_theta=mean,
        evaluations=state.evaluations,
        restarts=list(state.restarts),
        history=list(state.history),
        rejected=box.rejected(theta),
        mean_outside=box.rejected(mean),
        seconds=state.seconds,
        stop_reason=state.stop_reason,
        recovery=recovery,
    )


def restart_table(result: Result) -> list[dict[str, Any]]:
    """The restarts as plain dictionaries (for logging)."""
    return [asdict(r) for r in result.restarts]
