"""The Tracker contract in memory (no MLflow): a test double for the sweep logic."""

from __future__ import annotations

import json
import tempfile
import threading
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from sweep.service.outcome import JobOutcome, ScoreTable, config_hash
from sweep.service.tables import job_note, sweep_note
from sweep.service.tracking import (
    MAX_ERROR_TAG,
    NOTE_TAG,
    PARENT_TAG,
    TrackingError,
    _Finished,
    _pairs,
    _table_frame,
    choose_finished,
    efd_metrics,
    flatten_config,
    history_metrics,
    job_params,
    newest_per_key,
    outcome_metrics,
    outcome_record,
    outcome_tags,
    scores_from_metrics,
    write_job_artifacts,
)


@dataclass
class NullRun:
    """A run kept by :class:`NullTracker`."""

    run_id: str
    name: str
    start_time: int
    tags: dict[str, str]
    params: dict[str, str] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    history: dict[str, list[tuple[int, float]]] = field(default_factory=dict)
    artifacts: dict[str, Any] = field(default_factory=dict)  # path -> bytes or DataFrame
    status: str = "RUNNING"


class NullTracker:
    """The Tracker contract in memory (no MLflow): for tests of the sweep logic.

    ``runs`` maps run ids to :class:`NullRun`; artifacts are kept as bytes (files) or DataFrames
    (tables) under the same paths as in MLflow.
    """

    def __init__(self, allow_config_change: bool = False) -> None:
        self.allow_config_change = allow_config_change
        self.runs: dict[str, NullRun] = {}
        self._sweep_id: str | None = None
        self._lock = threading.RLock()
        self._efd: dict[str, ScoreTable] = {}
        self._settings: dict[str, dict[str, Any]] = {}

    def _new_run(self, name: str, tags: dict[str, str]) -> NullRun:
        # strictly increasing start times, also when ``runs`` is shared with another tracker
        start = max((r.start_time for r in self.runs.values()), default=0) + 1
        run = NullRun(uuid.uuid4().hex, name, start, dict(tags))
        self.runs[run.run_id] = run
        return run

    def _get(self, run_id: str) -> NullRun:
        if run_id not in self.runs:
            raise TrackingError(f"no run {run_id}")
        return self.runs[run_id]

    def _children(self, parent_id: str | None, status: str = "FINISHED") -> list[NullRun]:
        return [
            r
            for r in self.runs.values()
            if r.status == status
            and "job_key" in r.tags
            and (parent_id is None or r.tags.get(PARENT_TAG) == parent_id)
        ]

    def find_sweep(self, name: str | None = None) -> str | None:
        """Id of the newest sweep called ``name`` (any name if None)."""
        with self._lock:
            sweeps = [
                r
                for r in self.runs.values()
                if r.tags.get("sweep") == "true" and name in (None, r.tags.get("sweep_name"))
            ]
            return max(sweeps, key=lambda r: r.start_time).run_id if sweeps else None

    def start_sweep(self, name: str, config: dict[str, Any], efd: ScoreTable) -> str:
        """Create the parent run, or resume the existing one of the same name."""
        with self._lock:
            run_id = self.find_sweep(name)
            if run_id is None:
                run = self._new_run(name, {"sweep": "true", "sweep_name": name})
            else:
                run = self.runs[run_id]
                run.status = "RUNNING"
                run.tags["resumed"] = str(int(run.tags.get("resumed", "0")) + 1)
            run.tags["config_hash"] = config_hash(config)
            self._efd[run.run_id] = efd
            self._settings[run.run_id] = dict(config)
            for k, v in flatten_config(config).items():
                run.params.setdefault(k, v)
            run.metrics.update(efd_metrics(efd))
            run.artifacts["config.json"] = json.dumps(config, default=str).encode()
            self._sweep_id = run.run_id
            return run.run_id

    def find_finished(
        self, job_key: str, config_hash: str, parent_id: str | None = None
    ) -> str | None:
        """Id of the newest FINISHED child run of ``job_key``, or None (see Tracker)."""
        with self._lock:
            runs = [
                _Finished(r.run_id, r.tags.get("config_hash", ""), r.start_time)
                for r in self._children(parent_id or self._sweep_id)
                if r.tags["job_key"] == job_key
            ]
        return choose_finished(job_key, config_hash, runs, self.allow_config_change)

    def log_job(self, parent_id: str, outcome: JobOutcome, artifacts_dir: Path | None) -> str:
        """Keep a finished job's tags, params, metrics, history and artifacts."""
        with self._lock:
            self._get(parent_id)
            name = f"{outcome.objective}-{outcome.train}-seed{outcome.seed}"
            efd = self._efd.get(parent_id) or self.efd_reference(parent_id)
            tags = {**outcome_tags(outcome, parent_id), NOTE_TAG: job_note(outcome, efd)}
            run = self._new_run(name, tags)
            run.params.update(job_params(outcome))
            run.metrics.update(outcome_metrics(outcome))
            for key, value, step in history_metrics(outcome.history):
                run.history.setdefault(key, []).append((step, value))
                run.metrics[key] = value
            with tempfile.TemporaryDirectory() as tmp:
                for path in write_job_artifacts(outcome, Path(tmp)):
                    run.artifacts[path.name] = path.read_bytes()
            if artifacts_dir is not None and Path(artifacts_dir).is_dir():
                for path in sorted(Path(artifacts_dir).rglob("*")):
                    if path.is_file():
                        rel = path.relative_to(artifacts_dir).as_posix()
                        run.artifacts[f"plots/{rel}"] = path.read_bytes()
            run.status = "FINISHED"
            return run.run_id

    def log_failure(
        self,
        parent_id: str,
        job_key: str,
        tags: dict[str, Any],
        config: dict[str, Any],
        error: str,
    ) -> str:
        """Keep a failed job (status FAILED, tag ``error``, artifact error.txt)."""
        with self._lock:
            self._get(parent_id)
            all_tags = {str(k): str(v) for k, v in tags.items()}
            all_tags.update(
                job_key=job_key,
                config_hash=config_hash(config),
                error=error[:MAX_ERROR_TAG],
                **{PARENT_TAG: parent_id},
            )
            run = self._new_run(job_key, all_tags)
            run.params.update(flatten_config(config))
            run.artifacts["error.txt"] = error.encode()
            run.status = "FAILED"
            return run.run_id

    def finish_sweep(
        self,
        parent_id: str,
        tables: Mapping[str, pd.DataFrame],
        files: Mapping[str, Path],
        terminate: bool = True,
    ) -> None:
        """Keep the tables (``summary/{name}.json``) and files (``summary/{file name}``)."""
        with self._lock:
            run = self._get(parent_id)
            for name, table in tables.items():
                run.artifacts[f"summary/{name}.json"] = _table_frame(table)
            for path in files.values():
                run.artifacts[f"summary/{Path(path).name}"] = Path(path).read_bytes()
            name = run.tags.get("sweep_name", run.name)
            settings = self._settings.get(parent_id) or dict(run.params)
            run.tags[NOTE_TAG] = sweep_note(name, tables, settings)
            if terminate:
                run.status = "FINISHED"

    def job_outcomes(self, parent_id: str) -> list[dict[str, Any]]:
        """FINISHED child runs of ``parent_id`` (newest per job_key) as outcome records."""
        with self._lock:
            return newest_per_key(
                [
                    (r.start_time, outcome_record(r.run_id, r.tags, r.metrics))
                    for r in self._children(parent_id)
                ]
            )

    def efd_reference(self, parent_id: str) -> ScoreTable:
        """The EFD reference values of the sweep."""
        with self._lock:
            return scores_from_metrics(self._get(parent_id).metrics, "efd")

    def job_histories(self, parent_id: str) -> dict[str, list[tuple[float, float]]]:
        """{job_key: [(evaluations, best J so far)]} of the newest FINISHED child per job."""
        with self._lock:
            out = {}
            for record in self.job_outcomes(parent_id):
                run = self.runs[record["run_id"]]
                out[record["job_key"]] = _pairs(
                    run.history.get("history/evaluations", []),
                    run.history.get("history/best_so_far", []),
                )
            return out
