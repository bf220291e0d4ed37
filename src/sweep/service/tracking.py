"""Experiment tracking: the only module of the project that imports mlflow.

A sweep is one MLflow *parent run* (tag ``sweep=true``, run name = sweep name) holding the EFD
reference metrics ``efd/{J}/{subset}`` and the sweep config; every job is a *child run* (tag
``mlflow.parentRunId``) with tags objective, train, seed, job_key, config_hash, the test metrics
``test/{J}/{subset}``, best_f, evaluations, seconds, rejected (0/1), restarts, the per-generation
history as stepped metrics ``history/...``, ``fraction_determined`` (the share of the parameters
the training data determine, :mod:`sweep.identification.uncertainty`) and the manoeuvres
of its final parameters ``manoeuvre/...`` (:func:`~sweep.service.outcome.manoeuvre_metric_name`,
with their intervals), and the artifacts best_params.json, best_params.csv, history.csv,
restarts.json, config.json, uncertainty.md and uncertainty.json (the intervals), manoeuvres.md
(the manoeuvre tables), and plots/ (with plots/manoeuvres.png). A job that raised is a child
run with status FAILED, tag ``error`` and artifact error.txt.

Resume: :meth:`Tracker.start_sweep` reuses a non-deleted parent run of the same name, and
:meth:`Tracker.find_finished` finds a job's FINISHED child run by its job_key. A finished run of
the same job_key whose config_hash differs raises :class:`ConfigChangedError`, unless the tracker
was created with ``allow_config_change=True``: then the job counts as not done and runs again;
the report uses the newest configuration's earliest finished run per job_key (more finished runs
of it are duplicates: counted in ``duplicates`` and ignored, see :func:`newest_per_key`).

:class:`MlflowTracker` meets the contract on any tracking URI (use SQLite,
``sqlite:///path/mlflow.db``, never the file store, or an ``mlflow server``: ``http://host:port``);
the tests keep an in-memory double of it (``tests/memory_tracker.py``). :class:`MlflowTracker`
pickles without its client, so it can be sent to Ray workers.

A tracking server that does not answer (stopped, restarting, the network down) is retried with
backoff for up to ``retry_seconds`` (``tracking.retry_seconds``, 300 s by default) per call, and
every retried call is idempotent: a child run is looked up by its job_key before it is created,
a metric step already in the run is not logged again, a table is rewritten rather than appended
to. When the budget runs out the call raises :class:`TrackingUnreachableError`, a one-line user
error: the jobs' checkpoints stay, and the same command run again logs what is missing.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar, cast, runtime_checkable

import pandas as pd
import requests
from mlflow import MlflowClient
from mlflow.entities import Metric, Param, Run, ViewType
from mlflow.exceptions import MlflowException

from mmg import Parameters
from sweep.errors import UserError
from sweep.service.outcome import (
    OBJECTIVE_NAMES,
    SUBSETS,
    JobOutcome,
    ScoreTable,
    config_hash,
    manoeuvre_metric_name,
    metric_name,
    source_version,
)
from sweep.service.tables import job_note, sweep_note

#: longest error text stored in the ``error`` tag (MLflow allows 8000 characters)
MAX_ERROR_TAG = 5000
#: longest parameter value MLflow accepts
MAX_PARAM_VALUE = 6000
PARENT_TAG = "mlflow.parentRunId"
#: per-generation history columns logged as stepped metrics ``history/{column}``
HISTORY_METRICS = ("best_so_far", "best_f", "median_f", "popsize", "sigma", "evaluations")
#: characters not kept in one part of a metric name: MLflow takes letters, digits, ``_``, ``.``,
#: ``-`` and spaces (``:`` too, but not on Windows; ``/`` separates the parts)
_METRIC_REFUSED = re.compile(r"[^\w.\- ]")


def metric_part(part: str, limit: int = 0) -> str:
    """``part`` as one part of an MLflow metric name, each character outside
    :data:`_METRIC_REFUSED`'s set made ``_`` (a learned shape's name,
    ``shape:N~beta[-0.6:0.6]/8``, or a file name). ``limit`` > 0: a longer part is cut to
    ``limit`` characters, its last 11 a hash of the whole ``part``, so that two long names
    (a library finding of many terms) stay two metrics."""
    out = _METRIC_REFUSED.sub("_", part)
    if 0 < limit < len(out):
        digest = hashlib.sha1(part.encode()).hexdigest()[:10]
        out = f"{out[: max(limit - 11, 0)]}_{digest}"
    return out


class ConfigChangedError(RuntimeError, UserError):
    """A finished run of the same job exists but was made with another configuration."""

    def __init__(self, job_key: str, old_hash: str, new_hash: str, run_id: str) -> None:
        super().__init__(
            f"job {job_key}: finished run {run_id} was made with config hash {old_hash}, "
            f"the job's config now hashes to {new_hash}; revert the config, use another sweep "
            f"name, or allow the change (allow_config_change=True) to run the job again"
        )
        self.job_key = job_key
        self.old_hash = old_hash
        self.new_hash = new_hash
        self.run_id = run_id


class TrackingError(RuntimeError):
    """The tracking store cannot do what was asked (unknown run, deleted experiment, bad URI)."""


#: how long a tracking server that does not answer is retried, per call (``tracking.retry_seconds``)
RETRY_SECONDS = 300.0
#: the longest pause between two tries of a call to a tracking server that does not answer (s)
MAX_RETRY_PAUSE = 10.0


class TrackingUnreachableError(TrackingError, UserError):
    """The tracking server did not answer within the retry budget (a one-line error)."""

    def __init__(self, uri: str, seconds: float) -> None:
        super().__init__(
            f"tracking server {uri} unreachable for {seconds:.0f} s; the jobs' results are kept "
            f"in the sweep directory; run the same command again when it is back"
        )
        self.uri = uri
        self.seconds = seconds


#: errors that mean "no answer" (refused, reset, timed out, 5xx), never a refusal of the request
_NO_ANSWER: tuple[type[BaseException], ...] = (
    requests.exceptions.ConnectionError,
    requests.exceptions.Timeout,
    requests.exceptions.RetryError,
    requests.exceptions.ChunkedEncodingError,
    ConnectionError,
    TimeoutError,
)


def no_answer(exc: BaseException) -> BaseException | None:
    """The error in ``exc``'s chain (itself or one it was raised from) that says the tracking
    server did not answer (connection refused or reset, a timeout, retries of 429/5xx spent),
    or None: an answer refusing the request (an unknown run, a bad value) is no such error."""
    seen: set[int] = set()
    err: BaseException | None = exc
    while err is not None and id(err) not in seen:
        if isinstance(err, TrackingUnreachableError):
            return None  # an inner call has already spent the budget
        if isinstance(err, _NO_ANSWER):
            return err
        if isinstance(err, MlflowException) and err.error_code == "TEMPORARILY_UNAVAILABLE":
            return err
        seen.add(id(err))
        err = err.__cause__ or (None if err.__suppress_context__ else err.__context__)
    return None


_T = TypeVar("_T")


@runtime_checkable
class Tracker(Protocol):
    """What the sweep needs from experiment tracking (see the module docstring)."""

    def start_sweep(self, name: str, config: dict[str, Any], efd: ScoreTable) -> str:
        """Create (or resume) the sweep's parent run; returns its id."""
        ...

    def find_finished(
        self, job_key: str, config_hash: str, parent_id: str | None = None
    ) -> str | None:
        """Id of the FINISHED child run of ``job_key`` (newest), or None.

        Searches the children of ``parent_id``, else of the sweep this tracker started, else
        the whole experiment. Raises ConfigChangedError on a finished run with another hash.
        """
        ...

    def log_job(self, parent_id: str, outcome: JobOutcome, artifacts_dir: Path | None) -> str:
        """Record a finished job as a child run (status FINISHED); returns its id."""
        ...

    def log_failure(
        self,
        parent_id: str,
        job_key: str,
        tags: dict[str, Any],
        config: dict[str, Any],
        error: str,
    ) -> str:
        """Record a failed job as a child run (status FAILED); returns its id."""
        ...

    def finish_sweep(
        self,
        parent_id: str,
        tables: Mapping[str, pd.DataFrame],
        files: Mapping[str, Path],
        terminate: bool = True,
    ) -> None:
        """Attach the summary tables and files under ``summary/``; mark the sweep FINISHED."""
        ...

    def job_outcomes(self, parent_id: str) -> list[dict[str, Any]]:
        """The FINISHED child runs (newest per job_key) as plain records (see outcome_record)."""
        ...

    def efd_reference(self, parent_id: str) -> ScoreTable:
        """The sweep's EFD reference values {J: {subset: value}}."""
        ...

    def job_histories(self, parent_id: str) -> dict[str, list[tuple[float, float]]]:
        """{job_key: [(evaluations, best J so far) per generation]} of the FINISHED children."""
        ...


# ---------------------------------------------------------------- shared, backend-free helpers

#: MLflow's run description (the note on a run's overview page)
NOTE_TAG = "mlflow.note.content"
#: MLflow 3's experiment kind: a model-training experiment opens on its runs table
EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")


#: the saved view of the runs table that ``python -m sweep.ui`` opens (MLflow keeps saved views
#: as experiment tags ``mlflow.sharedViewState.<key>``; ``?viewStateShareKey=<key>`` opens one)
SWEEP_VIEW_KEY = "mmg-sweep-tables"
SWEEP_VIEW_TAG = f"mlflow.sharedViewState.{SWEEP_VIEW_KEY}"
SWEEP_VIEW_NAME = "Sweep: test J2, J1, J3 by objective, training set and seed"
#: the columns of that view: what the question needs, beside the run names
SWEEP_VIEW_COLUMNS = (
    "params.`objective`",
    "params.`train`",
    "params.`seed`",
    *(f"metrics.`{metric_name('test', J, 'total')}`" for J in ("J2", "J1", "J3")),
    "metrics.`best_f`",
    "metrics.`restarts`",
)


def sweep_view_tag(now_ms: int | None = None) -> tuple[str, str]:
    """(key, value) of the experiment tag holding the sweep's saved view of the runs table.

    The value is MLflow's saved-view record: a name, times, and the view state (columns and
    order) as ``deflate;`` + base64 of the zlib-compressed JSON, the format the UI writes."""
    import base64
    import zlib

    state = {
        "selectedColumns": list(SWEEP_VIEW_COLUMNS),
        "columnOrder": list(SWEEP_VIEW_COLUMNS),  # params first, then J2, J1, J3
        "orderByKey": "attributes.start_time",
        "orderByAsc": False,
        "runsHiddenMode": "SHOW_ALL",
    }
    packed = base64.b64encode(zlib.compress(json.dumps(state).encode())).decode()
    now = int(time.time() * 1000) if now_ms is None else int(now_ms)
    value = {
        "name": SWEEP_VIEW_NAME,
        "createdAt": now,
        "updatedAt": now,
        "state": f"deflate;{packed}",
    }
    return SWEEP_VIEW_TAG, json.dumps(value)


def job_params(outcome: JobOutcome) -> dict[str, str]:
    """The child run's params: the flattened job config, and objective, train and seed as
    plain params (so that compare, group-by and parallel coordinates can use them)."""
    params = flatten_config(outcome.config)
    params.update(objective=outcome.objective, train=outcome.train, seed=str(outcome.seed))
    return params


def _pairs(
    evaluations: Sequence[tuple[int, float]], best: Sequence[tuple[int, float]]
) -> list[tuple[float, float]]:
    by_step = dict(evaluations)
    return [(float(by_step[k]), float(v)) for k, v in sorted(best) if k in by_step]


def default_tracking_uri(cwd: str | os.PathLike[str] | None = None) -> str:
    """``sqlite:///<cwd>/mlflow.db`` (MLflow's own default), with an absolute path."""
    return f"sqlite:///{os.path.abspath(cwd if cwd is not None else os.getcwd())}/mlflow.db"


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI (None for other URIs and in-memory SQLite)."""
    if not uri.startswith("sqlite:///"):
        return None
    path = uri[len("sqlite:///") :].split("?", 1)[0]
    return Path(path) if path and path != ":memory:" else None


def flatten_config(config: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Nested config -> {"a.b.c": "value"} (lists as JSON), values cut to MLflow's limit."""
    out: dict[str, str] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            out.update(flatten_config(value, name + "."))
            continue
        text = value if isinstance(value, str) else json.dumps(value, default=str)
        if len(text) > MAX_PARAM_VALUE:
            text = text[: MAX_PARAM_VALUE - 3] + "..."
        out[name] = text
    return out


def score_metrics(kind: str, scores: ScoreTable) -> dict[str, float]:
    """{"{kind}/J1/B-S": value, ...} for every objective and subset present (inverse of
    :func:`scores_from_metrics`)."""
    return {
        metric_name(kind, J, s): float(scores[J][s])
        for J in OBJECTIVE_NAMES
        if J in scores
        for s in SUBSETS
        if s in scores[J]
    }


def efd_metrics(efd: ScoreTable) -> dict[str, float]:
    """{"efd/J1/B-S": value, ...} for every objective and subset present."""
    return score_metrics("efd", efd)


def scores_from_metrics(metrics: Mapping[str, float], kind: str) -> ScoreTable:
    """Inverse of the metric naming: {J: {subset: value}} from ``{kind}/{J}/{subset}`` metrics."""
    out: ScoreTable = {}
    for J in OBJECTIVE_NAMES:
        names = {s: f"{kind}/{J}/{s}" for s in SUBSETS}
        row = {s: float(metrics[n]) for s, n in names.items() if n in metrics}
        if row:
            out[J] = row
    return out


def outcome_tags(outcome: JobOutcome, parent_id: str) -> dict[str, str]:
    """The child run's tags (``checkpoint.recovery`` only when a checkpoint was rejected)."""
    tags = {
        "objective": outcome.objective,
        "train": outcome.train,
        "seed": str(outcome.seed),
        "job_key": outcome.job_key,
        "config_hash": outcome.config_hash,
        "stop_reason": outcome.stop_reason,
        "rejected": "true" if outcome.rejected else "false",
        "retries": str(outcome.retries),
        "mmg_sweep_version": source_version()["version"],
        "git_commit": source_version()["commit"],
        PARENT_TAG: parent_id,
    }
    if outcome.checkpoint_recovery:
        tags["checkpoint.recovery"] = outcome.checkpoint_recovery
    if outcome.uncertainty and "error" in outcome.uncertainty:
        tags["uncertainty.error"] = str(outcome.uncertainty["error"])[:MAX_ERROR_TAG]
    if outcome.manoeuvres and "error" in outcome.manoeuvres:
        tags["manoeuvres.error"] = str(outcome.manoeuvres["error"])[:MAX_ERROR_TAG]
    return tags


def outcome_metrics(outcome: JobOutcome) -> dict[str, float]:
    """The child run's scalar metrics: test/{J}/{subset}, best_f, evaluations, seconds, ..."""
    metrics = score_metrics("test", outcome.test)
    if outcome.polished:
        pol = outcome.polished
        metrics.update(score_metrics("polish", pol["test"]))
        metrics.update(
            polish_f=float(pol["f"]),
            polish_evaluations=float(pol["evaluations"]),
            polish_seconds=float(pol["seconds"]),
        )
    unc = outcome.uncertainty
    if unc and "error" not in unc:
        metrics.update(
            fraction_determined=float(unc["fraction_determined"]),
            uncertainty_seconds=float(unc["seconds"]),
        )
    man = outcome.manoeuvres
    if man and "error" not in man:
        metrics.update({manoeuvre_metric_name(k): float(v) for k, v in man["metrics"].items()})
        metrics["manoeuvre_seconds"] = float(man["seconds"])
    metrics.update(
        best_f=float(outcome.f),
        evaluations=float(outcome.evaluations),
        seconds=float(outcome.seconds),
        rejected=1.0 if outcome.rejected else 0.0,
        restarts=float(len(outcome.restarts)),
        sim_seconds=float(outcome.sim_seconds),
        retries=float(outcome.retries),
        checkpoint_rejected=float(outcome.checkpoint_rejected),
    )
    return metrics


def history_metrics(history: Sequence[Mapping[str, float]]) -> list[tuple[str, float, int]]:
    """(``history/{column}``, value, step) per generation; step = generation index from 0."""
    return [
        (f"history/{col}", float(row[col]), step)
        for step, row in enumerate(history)
        for col in HISTORY_METRICS
        if col in row
    ]


def write_job_artifacts(outcome: JobOutcome, out: Path) -> list[Path]:
    """best_params.json, best_params.csv, history.csv, restarts.json, config.json in ``out``."""
    meta: dict[str, Any] = {
        "objective": outcome.objective,
        "train": outcome.train,
        "seed": outcome.seed,
        "job_key": outcome.job_key,
        "config_hash": outcome.config_hash,
        "f": outcome.f,
        "evaluations": outcome.evaluations,
    }
    meta["commit"] = source_version()["commit"]
    meta["version"] = source_version()["version"]
    paths = [out / n for n in ("best_params.json", "best_params.csv", "history.csv")]
    outcome.params.save_json(paths[0], **meta)
    values = outcome.params.to_dict()
    with paths[1].open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["name", "value"])
        writer.writerows((k, repr(float(v))) for k, v in values["theta"].items())
        for effect, params in values["effects"].items():
            writer.writerows((f"{effect}.{k}", repr(float(v))) for k, v in params.items())
    pd.DataFrame(outcome.history).to_csv(paths[2], index=False)
    if outcome.polished:  # the refined parameters beside the CMA-ES result
        refined = out / "polished_params.json"
        Parameters.from_dict(outcome.polished["params"]).save_json(
            refined,
            **meta,
            f_cmaes=outcome.polished["f_start"],
            f_polished=outcome.polished["f"],
        )
        paths.append(refined)
    for name, data in (("restarts.json", outcome.restarts), ("config.json", outcome.config)):
        path = out / name
        path.write_text(json.dumps(data, indent=2, sort_keys=True, default=str) + "\n")
        paths.append(path)
    paths += _uncertainty_artifacts(outcome, out)
    paths += _manoeuvre_artifacts(outcome, out)
    return paths


def _manoeuvre_artifacts(outcome: JobOutcome, out: Path) -> list[Path]:
    """manoeuvres.md (the standard manoeuvres and the test set's turning and zigzag runs of the
    job's final parameters, with intervals), or manoeuvres_error.txt; nothing without them."""
    man = outcome.manoeuvres
    if not man:
        return []
    if "error" in man:
        path = out / "manoeuvres_error.txt"
        path.write_text(str(man["error"]) + "\n")
        return [path]
    path = out / "manoeuvres.md"
    path.write_text(f"# Manoeuvres of {outcome.job_key} ({man['params']})\n\n{man['markdown']}")
    return [path]


def _uncertainty_artifacts(outcome: JobOutcome, out: Path) -> list[Path]:
    """uncertainty.json and uncertainty.md (the intervals of the job's final parameters), or
    uncertainty_error.txt when they could not be computed; nothing for an older outcome."""
    unc = outcome.uncertainty
    if not unc:
        return []
    if "error" in unc:
        path = out / "uncertainty_error.txt"
        path.write_text(str(unc["error"]) + "\n")
        return [path]
    data = {k: v for k, v in unc.items() if k != "markdown"}
    table, summary = out / "uncertainty.md", out / "uncertainty.json"
    table.write_text(f"# Intervals of {outcome.job_key} ({unc['params']})\n\n{unc['markdown']}")
    summary.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    return [table, summary]


def outcome_record(
    run_id: str, tags: Mapping[str, str], metrics: Mapping[str, float]
) -> dict[str, Any]:
    """A finished job as the report reads it.

    Keys: run_id, job_key, objective, train, seed (int), config_hash, stop_reason, f,
    evaluations (int), seconds, rejected (bool), test ({J: {subset: value}}), polish (the same
    after the refinement of ``cmaes.polish``; empty without it), metrics (all).
    """
    return {
        "run_id": run_id,
        "job_key": tags.get("job_key", ""),
        "objective": tags.get("objective", ""),
        "train": tags.get("train", ""),
        "seed": int(tags.get("seed", "0")),
        "config_hash": tags.get("config_hash", ""),
        "stop_reason": tags.get("stop_reason", ""),
        "f": float(metrics.get("best_f", float("nan"))),
        "evaluations": int(metrics.get("evaluations", 0)),
        "seconds": float(metrics.get("seconds", float("nan"))),
        "rejected": bool(metrics.get("rejected", 0.0)),
        "test": scores_from_metrics(metrics, "test"),
        "polish": scores_from_metrics(metrics, "polish"),
        "metrics": dict(metrics),
    }


@dataclass(frozen=True)
class _Finished:
    run_id: str
    config_hash: str
    start_time: int


def choose_finished(
    job_key: str, config_hash: str, runs: Sequence[_Finished], allow_change: bool
) -> str | None:
    """The newest finished run with ``config_hash``; ConfigChangedError if only others exist."""
    newest = sorted(runs, key=lambda r: r.start_time, reverse=True)
    for run in newest:
        if run.config_hash == config_hash:
            return run.run_id
    if newest and not allow_change:
        raise ConfigChangedError(job_key, newest[0].config_hash, config_hash, newest[0].run_id)
    return None


def newest_per_key(records: Sequence[tuple[int, dict[str, Any]]]) -> list[dict[str, Any]]:
    """One (start_time, record) per job_key, ordered by job_key: of the newest run's config
    (config_hash), the earliest run; the other runs of that config (duplicates of one job)
    are counted in the record's ``duplicates`` (only present when there are some)."""
    by_key: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    for start, rec in records:
        by_key.setdefault(rec["job_key"], []).append((start, rec))
    out = []
    for key in sorted(by_key):
        runs = sorted(by_key[key], key=lambda r: r[0])
        newest = runs[-1][1].get("config_hash")
        same = [rec for _, rec in runs if rec.get("config_hash") == newest]
        chosen = same[0] if len(same) == 1 else {**same[0], "duplicates": len(same) - 1}
        out.append(chosen)
    return out


def _check_quote(kind: str, value: str) -> None:
    if "'" in value or "\\" in value:
        raise ValueError(f"{kind} {value!r} must not contain quotes or backslashes")


def _table_frame(table: pd.DataFrame) -> pd.DataFrame:
    """A summary table with its row labels as the first column (for a JSON table artifact)."""
    frame = table.reset_index() if table.index.name or table.index.nlevels > 1 else table.copy()
    frame.columns = [str(c) for c in frame.columns]
    for col in frame.columns:  # pandas 3 "str" columns as object: what MLflow's log_table expects
        if pd.api.types.is_string_dtype(frame[col].dtype):
            frame[col] = frame[col].astype(object)
    return frame


def _now_ms() -> int:
    return int(time.time() * 1000)


# ---------------------------------------------------------------- MLflow


class MlflowTracker:
    """Tracker on an MLflow tracking store (SQLite: ``sqlite:///path/mlflow.db``).

    For a SQLite URI, a new experiment stores its artifacts in ``<db dir>/mlartifacts/<name>``.
    The client is made on first use; a pickled tracker carries only the URI and its settings.

    Every call that gets no answer from the store is tried again with backoff (1, 2, 4, ...
    up to 10 s apart) for up to ``retry_seconds``, then raises :class:`TrackingUnreachableError`;
    ``notify`` (default: a line on stderr) hears when a server stops and starts answering.
    With an ``http(s)://`` URI, MLflow's own retries (``MLFLOW_HTTP_REQUEST_MAX_RETRIES``) default
    to 0, so that this budget is the one that counts; set the variable to keep MLflow's.
    """

    def __init__(
        self,
        uri: str,
        experiment: str = "mmg-sweep",
        allow_config_change: bool = False,
        retry_seconds: float = RETRY_SECONDS,
        notify: Callable[[str], None] | None = None,
    ) -> None:
        self.uri = uri
        self.experiment = experiment
        self.allow_config_change = allow_config_change
        self.retry_seconds = float(retry_seconds)
        self.notify = notify
        self._client: MlflowClient | None = None
        self._experiment_id: str | None = None
        self._sweep_id: str | None = None
        self._run_experiments: dict[str, str] = {}
        self._efd: dict[str, ScoreTable] = {}
        self._settings: dict[str, dict[str, Any]] = {}

    def __getstate__(self) -> dict[str, Any]:
        keep = (
            "uri",
            "experiment",
            "allow_config_change",
            "retry_seconds",
            "_experiment_id",
            "_sweep_id",
        )
        return {k: self.__dict__[k] for k in keep}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.__dict__.setdefault("retry_seconds", RETRY_SECONDS)
        self.notify = None
        self._client = None
        self._run_experiments = {}
        self._efd = {}
        self._settings = {}

    def __repr__(self) -> str:
        return f"MlflowTracker({self.uri!r}, experiment={self.experiment!r})"

    @property
    def client(self) -> MlflowClient:
        """The MLflow client (made on first use), each of whose calls retries a store that does
        not answer (see the class docstring): for idempotent calls only."""
        return cast(MlflowClient, _RetryingClient(self))

    @property
    def raw_client(self) -> MlflowClient:
        """The MLflow client without retries (for the steps of a call retried as a whole)."""
        if self._client is None:
            if self.uri.startswith(("http://", "https://")):
                os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0")
            try:
                self._client = MlflowClient(tracking_uri=self.uri)
            except MlflowException as exc:
                raise TrackingError(f"{self.uri}: {exc.message}") from exc
        return self._client

    def retry(self, call: Callable[[], _T], what: str = "call") -> _T:
        """``call()``, tried again with backoff while the store does not answer, for up to
        ``retry_seconds`` (from the first failure); TrackingUnreachableError after that.
        ``call`` must be idempotent: it may have taken effect before its answer was lost."""
        first: float | None = None
        pause = 1.0
        while True:
            try:
                result = call()
            except Exception as exc:
                cause = no_answer(exc)
                if cause is None:
                    raise
                now = time.monotonic()
                if first is None:
                    first = now
                    self._say(
                        f"warning: tracking server {self.uri} does not answer ({what}: "
                        f"{type(cause).__name__}); retrying for up to {self.retry_seconds:.0f} s"
                    )
                left = first + self.retry_seconds - now
                if left <= 0:
                    raise TrackingUnreachableError(self.uri, self.retry_seconds) from None
                time.sleep(min(pause, left))
                pause = min(2.0 * pause, MAX_RETRY_PAUSE)
                continue
            if first is not None:
                self._say(
                    f"tracking server {self.uri} answers again after "
                    f"{time.monotonic() - first:.0f} s ({what})"
                )
            return result

    def _say(self, text: str) -> None:
        if self.notify is not None:
            self.notify(text)
        else:
            print(text, file=sys.stderr, flush=True)

    @contextlib.contextmanager
    def _mlflow_errors(self) -> Iterator[None]:
        try:
            yield
        except MlflowException as exc:
            raise TrackingError(f"{self.uri}: {exc.message}") from exc

    # -- experiment and runs

    def experiment_id(self, create: bool = False) -> str | None:
        """Id of the tracker's experiment (made if ``create``; None if absent otherwise)."""
        if self._experiment_id is not None:
            return self._experiment_id
        with self._mlflow_errors():
            exp = self.client.get_experiment_by_name(self.experiment)
            if exp is None and create:
                # another process may make it meanwhile: then read it back
                with contextlib.suppress(MlflowException):
                    self.client.create_experiment(
                        self.experiment,
                        artifact_location=self._artifact_location(),
                        tags=dict([EXPERIMENT_KIND, sweep_view_tag()]),
                    )
                exp = self.client.get_experiment_by_name(self.experiment)
            if exp is not None and create:
                # an experiment made before (or by plain MLflow): open it on the runs table,
                # with the sweep's saved view of it
                for key, value in (EXPERIMENT_KIND, sweep_view_tag()):
                    if exp.tags.get(key) is None:
                        self.client.set_experiment_tag(exp.experiment_id, key, value)
        if exp is None:
            return None
        if exp.lifecycle_stage != "active":
            raise TrackingError(
                f"experiment {self.experiment!r} in {self.uri} is deleted: restore it "
                f"(mlflow experiments restore) or remove it for good (mlflow gc)"
            )
        self._experiment_id = str(exp.experiment_id)
        return self._experiment_id

    def has_sweep_view(self) -> bool:
        """Whether the tracker's experiment holds the sweep's saved view of the runs table."""
        exp = self.experiment_id(create=False)
        if exp is None:
            return False
        with self._mlflow_errors():
            tags = self.client.get_experiment(exp).tags
        return SWEEP_VIEW_TAG in tags

    def _artifact_location(self) -> str | None:
        db = sqlite_path(self.uri)
        if db is None:
            return None
        return Path(os.path.abspath(db)).parent.joinpath("mlartifacts", self.experiment).as_uri()

    def _run(self, run_id: str) -> Run:
        with self._mlflow_errors():
            return self.client.get_run(run_id)

    def _experiment_of(self, run_id: str) -> str:
        if run_id not in self._run_experiments:
            self._run_experiments[run_id] = str(self._run(run_id).info.experiment_id)
        return self._run_experiments[run_id]

    def _search(
        self, experiment_id: str, filter_string: str, order: str = "", retry: bool = True
    ) -> list[Run]:
        client = self.client if retry else self.raw_client
        runs: list[Run] = []
        token: str | None = None
        with self._mlflow_errors():
            while True:
                page = client.search_runs(
                    [experiment_id],
                    filter_string,
                    run_view_type=ViewType.ACTIVE_ONLY,
                    max_results=1000,
                    order_by=[order] if order else None,
                    page_token=token,
                )
                runs.extend(page)
                token = page.token
                if not token:
                    return runs

    def find_sweep(self, name: str | None = None) -> str | None:
        """Id of the newest non-deleted sweep (parent run) called ``name`` (any name if None)."""
        exp = self.experiment_id(create=False)
        if exp is None:
            return None
        query = "tags.sweep = 'true'"
        if name is not None:
            _check_quote("sweep name", name)
            query += f" and tags.sweep_name = '{name}'"
        runs = self._search(exp, query, "attributes.start_time DESC")
        return runs[0].info.run_id if runs else None

    def sweep_name(self, run_id: str) -> str:
        """The name of sweep ``run_id``; TrackingError if there is no such sweep."""
        try:
            run = self._run(run_id)
        except TrackingError as exc:
            raise TrackingError(f"no run {run_id} in {self.uri}") from exc
        if run.data.tags.get("sweep") != "true" or run.info.lifecycle_stage != "active":
            raise TrackingError(f"run {run_id} in {self.uri} is not a sweep (no tag sweep=true)")
        return run.data.tags.get("sweep_name", run.info.run_name or run_id)

    # -- the Tracker contract

    def start_sweep(self, name: str, config: dict[str, Any], efd: ScoreTable) -> str:
        """Create the sweep's parent run, or resume the existing one of the same name."""
        _check_quote("sweep name", name)
        exp = self.experiment_id(create=True)
        assert exp is not None
        h = config_hash(config)
        params = flatten_config(config)
        metrics = efd_metrics(efd)
        run_id = self.find_sweep(name)
        created = run_id is None
        if run_id is None:  # looked up again before each try: a lost answer makes no second run
            run_id = self.retry(lambda: self._sweep_run(exp, name, h), "create the sweep run")
        with self._mlflow_errors():
            if created:
                known_params: dict[str, str] = {}
                known_metrics: dict[str, float] = {}
            else:
                run = self.client.get_run(run_id)
                self.client.update_run(run_id, status="RUNNING")
                self.client.set_tag(run_id, "config_hash", h)
                resumed = int(run.data.tags.get("resumed", "0")) + 1
                self.client.set_tag(run_id, "resumed", str(resumed))
                known_params = run.data.params
                known_metrics = run.data.metrics
            now = _now_ms()
            self.client.log_batch(
                run_id,
                metrics=[
                    Metric(k, v, now, 0) for k, v in metrics.items() if known_metrics.get(k) != v
                ],
                params=[Param(k, v) for k, v in params.items() if k not in known_params],
            )
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / "config.json"
                path.write_text(json.dumps(config, indent=2, sort_keys=True, default=str) + "\n")
                self.client.log_artifact(run_id, str(path))
        self._sweep_id = run_id
        self._run_experiments[run_id] = exp
        self._efd[run_id] = efd
        self._settings[run_id] = dict(config)
        return run_id

    def _sweep_run(self, exp: str, name: str, h: str) -> str:
        """The sweep run called ``name``, made if absent (one step, without retries)."""
        query = f"tags.sweep = 'true' and tags.sweep_name = '{name}'"
        found = self._search(exp, query, "attributes.start_time DESC", retry=False)
        if found:
            return str(found[0].info.run_id)
        tags = {"sweep": "true", "sweep_name": name, "config_hash": h}
        with self._mlflow_errors():
            return str(self.raw_client.create_run(exp, tags=tags, run_name=name).info.run_id)

    def _child_run(
        self, exp: str, parent_id: str, tags: Mapping[str, str], name: str
    ) -> tuple[str, bool]:
        """(id, reused) of the RUNNING child of ``parent_id`` with the job_key and config_hash
        of ``tags`` (left by a call whose answer was lost, or by a command stopped while it
        logged), else of a child made now (one step, without retries)."""
        query = (
            f"tags.job_key = '{tags['job_key']}' and tags.config_hash = '{tags['config_hash']}' "
            f"and tags.{PARENT_TAG} = '{parent_id}' and attributes.status = 'RUNNING'"
        )
        found = self._search(exp, query, "attributes.start_time DESC", retry=False)
        if found:
            return str(found[0].info.run_id), True
        with self._mlflow_errors():
            run = self.raw_client.create_run(exp, tags=dict(tags), run_name=name)
        return str(run.info.run_id), False

    def _not_logged(
        self, run_id: str, metrics: list[Metric], history: list[Metric]
    ) -> tuple[list[Metric], list[Metric]]:
        """The metrics (step 0) and history steps that run ``run_id`` does not hold yet."""
        run = self.client.get_run(run_id)
        metrics = [m for m in metrics if m.key not in run.data.metrics]
        steps = {
            key: {m.step for m in self.client.get_metric_history(run_id, key)}
            for key in {m.key for m in history}
            if key in run.data.metrics
        }
        return metrics, [m for m in history if m.step not in steps.get(m.key, ())]

    def find_finished(
        self, job_key: str, config_hash: str, parent_id: str | None = None
    ) -> str | None:
        """Id of the newest FINISHED child run of ``job_key``, or None (see Tracker)."""
        _check_quote("job key", job_key)
        parent = parent_id or self._sweep_id
        exp = self._experiment_of(parent) if parent else self.experiment_id(create=False)
        if exp is None:
            return None
        query = f"tags.job_key = '{job_key}' and attributes.status = 'FINISHED'"
        if parent:
            query += f" and tags.{PARENT_TAG} = '{parent}'"
        runs = [
            _Finished(r.info.run_id, r.data.tags.get("config_hash", ""), r.info.start_time or 0)
            for r in self._search(exp, query)
        ]
        return choose_finished(job_key, config_hash, runs, self.allow_config_change)

    def log_job(self, parent_id: str, outcome: JobOutcome, artifacts_dir: Path | None) -> str:
        """Child run of a finished job: tags, params, metrics, history, artifacts; FINISHED."""
        exp = self._experiment_of(parent_id)
        name = f"{outcome.objective}-{outcome.train}-seed{outcome.seed}"
        efd = self._efd.get(parent_id)
        if efd is None:
            efd = self._efd[parent_id] = self.efd_reference(parent_id)
        tags = {**outcome_tags(outcome, parent_id), NOTE_TAG: job_note(outcome, efd)}
        run_id, reused = self.retry(
            lambda: self._child_run(exp, parent_id, tags, name), f"log {outcome.job_key}"
        )
        try:
            now = _now_ms()  # the same in every try: a batch logged twice is stored once
            metrics = [Metric(k, v, now, 0) for k, v in outcome_metrics(outcome).items()]
            history = [Metric(k, v, now, s) for k, v, s in history_metrics(outcome.history)]
            if reused:
                metrics, history = self._not_logged(run_id, metrics, history)
            self.client.log_batch(
                run_id,
                metrics=metrics,
                params=[Param(k, v) for k, v in job_params(outcome).items()],
            )
            self.client.log_batch(run_id, metrics=history)
            with tempfile.TemporaryDirectory() as tmp:
                write_job_artifacts(outcome, Path(tmp))
                self.client.log_artifacts(run_id, tmp)
            if artifacts_dir is not None and Path(artifacts_dir).is_dir():
                self.client.log_artifacts(run_id, str(artifacts_dir), artifact_path="plots")
        except TrackingUnreachableError:
            raise  # left RUNNING: the same command run again finds it and logs what is missing
        except BaseException:
            self.client.set_terminated(run_id, "FAILED")
            raise
        self.client.set_terminated(run_id, "FINISHED")
        return run_id

    def log_failure(
        self,
        parent_id: str,
        job_key: str,
        tags: dict[str, Any],
        config: dict[str, Any],
        error: str,
    ) -> str:
        """Child run with status FAILED, tag ``error`` (cut to 5000 characters), error.txt."""
        exp = self._experiment_of(parent_id)
        all_tags = {str(k): str(v) for k, v in tags.items()}
        all_tags.update(
            job_key=job_key,
            config_hash=config_hash(config),
            error=error[:MAX_ERROR_TAG],
            **{PARENT_TAG: parent_id},
        )
        run_id, reused = self.retry(
            lambda: self._child_run(exp, parent_id, all_tags, job_key), f"log {job_key}"
        )
        with self._mlflow_errors():
            try:
                if reused:
                    self.client.set_tag(run_id, "error", all_tags["error"])
                self.client.log_batch(
                    run_id, params=[Param(k, v) for k, v in flatten_config(config).items()]
                )
                with tempfile.TemporaryDirectory() as tmp:
                    Path(tmp, "error.txt").write_text(error)
                    Path(tmp, "config.json").write_text(
                        json.dumps(config, indent=2, sort_keys=True, default=str) + "\n"
                    )
                    self.client.log_artifacts(run_id, tmp)
            except TrackingUnreachableError:
                raise  # left RUNNING: the same command run again finds it
            except BaseException:
                self.client.set_terminated(run_id, "FAILED")
                raise
            self.client.set_terminated(run_id, "FAILED")
        return run_id

    def finish_sweep(
        self,
        parent_id: str,
        tables: Mapping[str, pd.DataFrame],
        files: Mapping[str, Path],
        terminate: bool = True,
    ) -> None:
        """Tables as ``summary/{name}.json`` (MLflow tables, replaced when logged again), files
        under ``summary/``; the parent run is marked FINISHED unless ``terminate`` is False."""
        with self._mlflow_errors():
            for name, table in tables.items():
                self._log_table(parent_id, _table_frame(table), f"summary/{name}.json")
            for path in files.values():
                self.client.log_artifact(parent_id, str(path), artifact_path="summary")
            run = self.client.get_run(parent_id)
            name = run.data.tags.get("sweep_name", run.info.run_name or parent_id)
            settings = self._settings.get(parent_id) or dict(run.data.params)
            self.client.set_tag(parent_id, NOTE_TAG, sweep_note(name, tables, settings))
            if terminate:
                self.client.set_terminated(parent_id, "FINISHED")

    def _log_table(self, run_id: str, frame: pd.DataFrame, artifact_file: str) -> None:
        # one retried step: a try after a lost answer finds the table and replaces it
        self.retry(lambda: self._log_table_once(run_id, frame, artifact_file), artifact_file)

    def _log_table_once(self, run_id: str, frame: pd.DataFrame, artifact_file: str) -> None:
        folder, name = artifact_file.rsplit("/", 1)
        client = self.raw_client
        present = {a.path for a in client.list_artifacts(run_id, folder)}
        if artifact_file not in present:
            client.log_table(run_id, frame, artifact_file)
            return
        # log_table would append to the existing table: write it in the same format instead
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / name
            frame.to_json(path, orient="split", index=False, date_format="iso")
            client.log_artifact(run_id, str(path), artifact_path=folder)

    def job_outcomes(self, parent_id: str) -> list[dict[str, Any]]:
        """FINISHED child runs of ``parent_id`` (newest per job_key) as outcome records."""
        exp = self._experiment_of(parent_id)
        query = f"tags.{PARENT_TAG} = '{parent_id}' and attributes.status = 'FINISHED'"
        return newest_per_key(
            [
                (r.info.start_time or 0, outcome_record(r.info.run_id, r.data.tags, r.data.metrics))
                for r in self._search(exp, query)
                if "job_key" in r.data.tags
            ]
        )

    def efd_reference(self, parent_id: str) -> ScoreTable:
        """The EFD metrics of the sweep's parent run as {J: {subset: value}}."""
        return scores_from_metrics(self._run(parent_id).data.metrics, "efd")

    def job_histories(self, parent_id: str) -> dict[str, list[tuple[float, float]]]:
        """{job_key: [(evaluations, best J so far)]} of the newest FINISHED child per job."""
        out: dict[str, list[tuple[float, float]]] = {}
        with self._mlflow_errors():
            for record in self.job_outcomes(parent_id):
                run_id = record["run_id"]
                ev = self.client.get_metric_history(run_id, "history/evaluations")
                best = self.client.get_metric_history(run_id, "history/best_so_far")
                out[record["job_key"]] = _pairs(
                    [(m.step, m.value) for m in ev], [(m.step, m.value) for m in best]
                )
        return out

    def log_diagnosis(
        self,
        name: str,
        params: Mapping[str, Any],
        metrics: Mapping[str, float],
        tags: Mapping[str, str],
        artifacts_dir: Path,
    ) -> str:
        """One FINISHED run (tag ``diagnosis=true``) holding a diagnosis: its settings as
        params, scores as metrics, the verdict as a tag and the report files as artifacts."""
        exp = self.experiment_id(create=True)
        assert exp is not None
        all_tags = {"diagnosis": "true", **source_tags(), **tags}
        with self._mlflow_errors():
            run = self.client.create_run(exp, run_name=name, tags=all_tags)
            rid = run.info.run_id
            now = _now_ms()
            self.client.log_batch(
                rid,
                metrics=[Metric(k, float(v), now, 0) for k, v in metrics.items()],
                params=[Param(k, str(v)[:MAX_PARAM_VALUE]) for k, v in params.items()],
            )
            self.client.log_artifacts(rid, str(artifacts_dir))
            self.client.set_terminated(rid, "FINISHED")
        return str(rid)


class _RetryingClient:
    """An MLflow client whose every call is :meth:`MlflowTracker.retry`-ed (idempotent calls)."""

    def __init__(self, tracker: MlflowTracker) -> None:
        self._tracker = tracker

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._tracker.raw_client, name)
        if not callable(attr):
            return attr

        def call(*args: Any, **kwargs: Any) -> Any:
            return self._tracker.retry(lambda: attr(*args, **kwargs), name)

        return call


def source_tags() -> dict[str, str]:
    """git commit and package version of the running source."""
    v = source_version()
    return {"git_commit": v["commit"], "mmg_sweep_version": v["version"]}
