"""One job of a sweep: identify on a training set, evaluate on the test set, judge the
parameters (intervals, standard manoeuvres), draw the plots.

A job is described by a :class:`JobSpec` (plain data: the job's composed configuration and its
directory) and run by :func:`run_job` wherever an executor puts it (this process, a Ray actor).
It knows nothing of Ray, MLflow or Hydra: evaluation goes through the evaluator it is given, and
the result comes back as a :class:`~sweep.service.outcome.JobOutcome` plus the plot files as
bytes (so that a job on another machine can hand them to the driver).
"""

from __future__ import annotations

import tempfile
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mmg import Effect, Parameters, efd_parameters, get_effect, simulate_batch
from sweep.data.datasets import split_from_mapping
from sweep.data.manoeuvre_tables import (
    manoeuvre_metrics,
    recorded_markdown,
    recorded_table,
    settings_note,
    standard_markdown,
    standard_table,
)
from sweep.data.objective import OBJECTIVES, Objective, split_recording
from sweep.data.recordings import Recording, RecordingWarning
from sweep.data.standard_manoeuvres import compare_recorded, find_manoeuvre, predict_standard
from sweep.identification.checkpoint import checkpoint_key
from sweep.identification.cmaes import (
    CHECKPOINT_SECONDS,
    Box,
    Settings,
    State,
    optimise,
    restart_table,
)
from sweep.identification.polish import LAMBDA_TRIALS, PolishSettings, polish
from sweep.identification.uncertainty import Uncertainty, model_names, uncertainty_at
from sweep.identification.vector import from_full_vector, full_vector, joint_box
from sweep.service.lease import LEASE_SECONDS
from sweep.service.outcome import SUBSETS, JobOutcome, complete_subsets, config_hash, make_job_key
from sweep.service.storage import Location

#: test-set labels of conf/test/paper.yaml -> metric suffixes
SUBSET_OF_LABEL = {
    "Test-B-S": "B-S",
    "Test-B-P": "B-P",
    "Test-R": "R",
    "Test-T": "T",
    "Test-Z": "Z",
}


@dataclass(frozen=True)
class JobSpec:
    """Everything a job needs, as plain data.

    ``config``: the job-relevant configuration (objective, train and test splits, budget, cmaes
    settings, seed); its hash identifies the job's result. ``job_dir`` holds the checkpoint.
    ``checkpoint_key`` signs and verifies the checkpoint: the key of the process that made the
    spec (the driver's, :func:`~sweep.identification.checkpoint.checkpoint_key`), so that a job
    verifies its checkpoints on any node; it travels with the spec, never to the storage.
    """

    key: str
    objective: str
    train: str
    seed: int
    config: Mapping[str, Any]
    job_dir: Path
    data_root: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    #: where the checkpoint lives: a path or storage URI (``sweep.storage``); None: job_dir
    checkpoint: str | None = None
    #: the longest time between two checkpoints (``sweep.checkpoint_seconds``)
    checkpoint_seconds: float = CHECKPOINT_SECONDS
    checkpoint_key: bytes = field(default_factory=checkpoint_key, repr=False, compare=False)
    #: how long a driver's claim on the job lasts without a heartbeat (``sweep.lease_seconds``)
    lease_seconds: float = LEASE_SECONDS

    @property
    def checkpoint_location(self) -> Location | Path:
        """Where the optimiser keeps the checkpoint: the storage location of ``checkpoint``, or
        ``job_dir/checkpoint.pkl`` (the previous one beside it, ``checkpoint.pkl.prev``)."""
        if self.checkpoint:
            return Location(self.checkpoint)
        return self.job_dir / "checkpoint.pkl"

    @property
    def lease_directory(self) -> str:
        """Where drivers claim the job (:mod:`sweep.service.lease`): ``lease/`` beside the
        checkpoint, in the sweep's storage or the job directory."""
        if self.checkpoint:
            return self.checkpoint.rsplit("/", 1)[0] + "/lease"
        return str(self.job_dir / "lease")

    @property
    def config_hash(self) -> str:
        """The hash of ``config`` that identifies the job's result."""
        return config_hash(dict(self.config))


def job_key(objective: str, train: str, seed: int) -> str:
    """The stable key of a job: ``objective=J2,seed=0,train=R`` (sorted like Hydra's dirs)."""
    return make_job_key(objective=objective, train=train, seed=seed)


#: Levenberg-Marquardt iterations of ``cmaes.polish=true``
POLISH_ITERATIONS = 100


def polish_iterations(config: Mapping[str, Any]) -> int:
    """Iterations of the refinement after CMA-ES: ``cmaes.polish`` true (the default number),
    a count, or false / 0 / absent (none: the paper's pure CMA-ES)."""
    value = config.get("cmaes", {}).get("polish", False)
    if isinstance(value, bool):
        return POLISH_ITERATIONS if value else 0
    return int(value)


def settings_of(config: Mapping[str, Any], seed: int) -> Settings:
    """The CMA-ES settings of a job's config (its ``budget`` and ``cmaes`` groups) and seed."""
    budget = config["budget"]
    cm = config["cmaes"]
    return Settings(
        seed=seed,
        max_evaluations=int(budget["max_evaluations"]),
        max_seconds=budget.get("max_seconds"),
        sigma0=float(cm["sigma0"]),
        bound_handling=cm["bound_handling"],
        popsize_start=int(cm["popsize_start"]),
        popsize_max=int(cm["popsize_max"]),
    )


def test_metrics(
    params: Parameters, test: Mapping[str, Recording], effects: tuple[Effect, ...] = ()
) -> dict[str, dict[str, float]]:
    """{J: {subset: value}} on the paper's test set, subsets B-S, B-P, B, R, T, Z, total."""
    labels = list(test)
    table = Objective(list(test.values()), labels=labels, effects=effects).table(params)
    out: dict[str, dict[str, float]] = {}
    for J in OBJECTIVES:
        row = complete_subsets({SUBSET_OF_LABEL[lab]: table[J][lab][0] for lab in labels})
        out[J] = {s: row[s] for s in SUBSETS}
    return out


def simulated_subsequences(
    rec: Recording, params: Parameters, effects: tuple[Effect, ...] = ()
) -> np.ndarray:
    """The recording re-simulated subsequence by subsequence (the paper's Figs. 6-8), (N, 6)."""
    out = np.full_like(rec.x, np.nan)
    for seg in split_recording(rec):
        sl = slice(seg.start, seg.start + seg.n_steps + 1)
        traj = simulate_batch(
            rec.x[None, seg.start],
            rec.u[None, sl][:, :-1],
            rec.w[None, sl][:, :-1],
            params,
            effects=effects,
            t0=rec.t[seg.start],
        ).states[0]
        out[sl] = traj
    return out


def draw_plots(
    history: list[dict[str, float]], params: Parameters, test: Mapping[str, Recording], title: str
) -> dict[str, bytes]:
    """Convergence and test trajectories (best vs EFD vs recorded) as PNG bytes by file name."""
    from sweep.service.figures import plot_convergence, plot_trajectories

    files: dict[str, bytes] = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "convergence.png"
        plot_convergence(history, path)
        files[path.name] = path.read_bytes()
        efd = efd_parameters()
        for label in ("Test-B-S", "Test-B-P", "Test-R"):
            if label not in test:
                continue
            rec = test[label]
            effects = tuple(get_effect(name) for name, _ in params.effects)
            sims = {
                "identified": simulated_subsequences(rec, params, effects),
                "EFD": simulated_subsequences(rec, efd),
            }
            path = Path(tmp) / f"trajectory_{label}.png"
            plot_trajectories(np.asarray(rec.x), sims, path, f"{title}: {label}")
            files[path.name] = path.read_bytes()
    return files


def job_uncertainty(
    objective: Objective, box: Box, theta: np.ndarray, effects: tuple[Effect, ...], which: str
) -> dict[str, Any]:
    """The intervals of a job's final parameters ``theta`` (57 + effect parameters) on its
    training set (:func:`sweep.identification.uncertainty.uncertainty_at`: 2 n + 1 simulations
    of the training set, a few per cent of the smallest budget), as plain data for the outcome
    (``which``: "cmaes" or "polished"). Failure is a value: ``{"error": ...}``, and the job's
    result stands."""
    try:
        u = uncertainty_at(objective, box, theta, model_names(effects))
    except Exception as exc:  # any failure here must not cost the job its result
        return {"error": f"{type(exc).__name__}: {exc}", "params": which}
    return {**u.as_dict(), "markdown": u.to_markdown(), "params": which}


#: parameter samples drawn from a job's intervals to give its manoeuvres intervals
MANOEUVRE_SAMPLES = 50


def manoeuvre_samples(intervals: Mapping[str, Any] | None, n: int, seed: int) -> np.ndarray | None:
    """(n, 57 + k) parameter vectors drawn from a job's intervals (the outcome's
    ``uncertainty``, :meth:`Uncertainty.sample` with ``np.random.default_rng(seed)``: the same
    draws from the logged ``uncertainty.json``); None without intervals or when they failed."""
    if not intervals or "error" in intervals or n <= 0:
        return None
    return Uncertainty.from_dict(dict(intervals)).sample(n, np.random.default_rng(seed))


def job_manoeuvres(
    params: Parameters,
    effects: tuple[Effect, ...],
    test: Mapping[str, Recording],
    intervals: Mapping[str, Any] | None,
    seed: int,
    which: str,
    figure: str = "",
    n_samples: int = MANOEUVRE_SAMPLES,
) -> tuple[dict[str, Any], dict[str, bytes]]:
    """The standard manoeuvres of a job's final parameters and the test set's turning and
    zigzag runs (Test-T, Test-Z) against them, with intervals from ``n_samples`` draws of the
    job's ``intervals`` (seeded by the job's ``seed``; point values without intervals), as
    plain data for the outcome, and, when ``figure`` (a title) is given, the figure as
    ``{"manoeuvres.png": bytes}``. About 1 s for 50 draws and 1 s for the figure on one core.
    Failure is a value: ``{"error": ...}``, and the job's result stands."""
    t0 = time.perf_counter()
    try:
        samples = manoeuvre_samples(intervals, n_samples, seed)
        found = (find_manoeuvre(rec, label) for label, rec in test.items())
        runs = [r for r in found if r is not None]
        pred = predict_standard(params, samples, effects)
        comparisons = compare_recorded(params, runs, samples, effects)
        standard = standard_markdown({"model": standard_table(pred)})
        recorded = recorded_markdown({"model": recorded_table(comparisons, L=params.ship.L_pp)})
        spread = (
            f"5-95 % over {pred.n_samples} draws of the parameters' intervals (seed {seed})"
            if samples is not None
            else "point values (no parameter intervals)"
        )
        markdown = (
            f"Standard manoeuvres, full scale; {spread}.\n\n{standard}\n\n{settings_note(pred)}\n"
        )
        if comparisons:
            markdown += f"\nThe test set's runs against the model (model scale).\n\n{recorded}\n"
        files: dict[str, bytes] = {}
        if figure:
            from sweep.data.manoeuvre_figures import plot_manoeuvres

            with tempfile.TemporaryDirectory() as tmp:
                path = plot_manoeuvres(
                    pred, comparisons, Path(tmp) / "manoeuvres.png", figure, params.ship.L_pp
                )
                files[path.name] = path.read_bytes()
        metrics = manoeuvre_metrics(pred, comparisons)
    except Exception as exc:  # any failure here must not cost the job its result
        return {"error": f"{type(exc).__name__}: {exc}", "params": which}, {}
    value = {
        "metrics": metrics,
        "markdown": markdown,
        "samples": 0 if samples is None else int(samples.shape[0]),
        "seed": seed,
        "params": which,
        "seconds": time.perf_counter() - t0,
    }
    return value, files


def judge(
    objective: Objective,
    box: Box,
    theta: np.ndarray,
    effects: tuple[Effect, ...],
    which: str,
    test: Mapping[str, Recording],
    seed: int,
    title: str = "",
) -> tuple[dict[str, Any], dict[str, Any], dict[str, bytes]]:
    """The intervals of a job's final parameters ``theta`` (:func:`job_uncertainty`) and their
    manoeuvres with intervals from draws of them (:func:`job_manoeuvres`), and with a
    ``title`` the manoeuvres' figure."""
    intervals = job_uncertainty(objective, box, theta, effects, which)
    params = from_full_vector(theta, efd_parameters(), effects)
    figure = f"{title}: manoeuvres" if title else ""
    manoeuvres, files = job_manoeuvres(params, effects, test, intervals, seed, which, figure)
    return intervals, manoeuvres, files


def job_recordings(spec: JobSpec) -> tuple[dict[str, Recording], dict[str, Recording]]:
    """The training and the test recordings of a job, by label."""
    with warnings.catch_warnings():
        # data warnings (dropped trailing rows, ...) are said once, by the driver
        # (check_recordings), not by every job that reads the file
        warnings.simplefilter("ignore", RecordingWarning)
        train = split_from_mapping(dict(spec.config["train"]), f"train={spec.train}")
        test = split_from_mapping(dict(spec.config["test"]), "test")
        return train.load(spec.data_root), test.load(spec.data_root)


Evaluator = Any  # callable thetas -> f with close(); see sweep.identification.workers
Status = Callable[[dict[str, float]], None]


def run_job(
    spec: JobSpec,
    make_evaluator: Callable[[Objective], Evaluator],
    status: Status | None = None,
    plots: bool = True,
    uncertainty: bool | None = None,
) -> tuple[JobOutcome, dict[str, bytes]]:
    """Identify, evaluate on the test set, judge the parameters, plot. Resumes from the spec's
    checkpoint (in its job directory, or in the sweep's storage), written after every
    generation; a checkpoint that is damaged, forged or another job's is set aside and the job
    resumes from the previous one, or afresh (the outcome's ``checkpoint_recovery`` and
    ``checkpoint_rejected`` say so). ``uncertainty``: the intervals and the manoeuvres of the
    final parameters (None: as ``plots``; the manoeuvres' figure only with ``plots``)."""
    cfg = spec.config
    train, test = job_recordings(spec)
    settings = settings_of(cfg, spec.seed)
    # extra effects (``effects=[...]``: catalog or discovered) are identified with the 57
    # parameters, their parameters searched over their own boxes from neutral
    effects = tuple(get_effect(str(name)) for name in cfg.get("effects") or ())
    objective = Objective(list(train.values()), spec.objective, effects=effects)
    box, x0 = joint_box(effects), full_vector(efd_parameters(), effects)
    if spec.checkpoint is None:  # with a storage URI the job needs no directory on its node
        spec.job_dir.mkdir(parents=True, exist_ok=True)

    last: dict[str, float] = {}

    def progress(state: State, row: dict[str, float]) -> None:
        last.update(row)
        if status is not None:
            status({**row, "budget": float(settings.max_evaluations)})

    def lm_progress(row: dict[str, float]) -> None:
        if status is not None:  # the CMA-ES figures stay; the refinement's are added
            status(
                {
                    **last,
                    "budget": float(settings.max_evaluations),
                    "lm_iteration": row["iteration"],
                    "lm_iterations": float(iterations),
                    "lm_f": row["f"],
                }
            )

    evaluator = make_evaluator(objective)
    try:
        result = optimise(
            evaluator,
            box,
            x0,
            settings,
            checkpoint=spec.checkpoint_location,
            progress=progress,
            checkpoint_seconds=spec.checkpoint_seconds,
            checkpoint_key=spec.checkpoint_key,
            checkpoint_job=spec.config_hash,
        )
    finally:
        evaluator.close()
    best = from_full_vector(result.theta, efd_parameters(), effects)
    polished: dict[str, Any] | None = None
    iterations = polish_iterations(cfg)
    if iterations > 0:
        # Levenberg-Marquardt from the CMA-ES result (deterministic: a job resumed after an
        # interruption repeats it from the same checkpointed result)
        lm = polish(
            objective,
            box,
            result.theta,
            PolishSettings(
                max_iterations=iterations,
                rtol=1e-4,
                max_evaluations=iterations * (box.lower.size + 1 + len(LAMBDA_TRIALS)) + 1,
            ),
            progress=lm_progress,
        )
        refined = from_full_vector(lm.theta, efd_parameters(), effects)
        polished = {
            "f_start": lm.f_start,
            "f": lm.f,
            "evaluations": lm.evaluations,
            "iterations": lm.iterations,
            "seconds": lm.seconds,
            "params": refined.to_dict(),
            "test": test_metrics(refined, test, effects),
        }
    # the intervals of the job's final parameters, once, on its training set, and the
    # manoeuvres those parameters predict, with intervals from draws of them
    final, which = (lm.theta, "polished") if iterations > 0 else (result.theta, "cmaes")
    wanted = plots if uncertainty is None else uncertainty  # the products for people
    intervals, manoeuvres, manoeuvre_files = (
        judge(objective, box, final, effects, which, test, spec.seed, spec.key if plots else "")
        if wanted
        else (None, None, {})
    )
    outcome = JobOutcome(
        job_key=spec.key,
        objective=spec.objective,
        train=spec.train,
        seed=spec.seed,
        config=dict(cfg),
        config_hash=spec.config_hash,
        params=best,
        f=result.f,
        evaluations=result.evaluations,
        seconds=result.seconds,
        rejected=result.rejected,
        stop_reason=result.stop_reason,
        restarts=restart_table(result),
        history=result.history,
        test=test_metrics(best, test, effects),
        sim_seconds=float(getattr(evaluator, "sim_seconds", 0.0)),  # read when closed
        workers_replaced=int(getattr(evaluator, "replaced", 0)),
        polished=polished,
        checkpoint_recovery=result.recovery.tag() if result.recovery else "",
        checkpoint_rejected=len(result.recovery.rejected) if result.recovery else 0,
        uncertainty=intervals,
        manoeuvres=manoeuvres,
    )
    files = draw_plots(result.history, best, test, spec.key) if plots else {}
    return outcome, {**files, **manoeuvre_files}
