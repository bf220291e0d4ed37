"""A finished job's outcome kept in its directory until the tracker has it.

The driver writes ``<job dir>/outcome.json`` (atomically) as soon as a job ends, then logs the
job and removes the file. A driver killed in between leaves the file; the next run of the
sweep finds it, logs the job from it (once: not if the tracker already has a finished run of
the job) and does not run the job again. The file is JSON (plain data; nothing in it runs).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from mmg import Parameters
from sweep.service import storage
from sweep.service.outcome import JobOutcome, canonical_json

#: the file name of a finished job's outcome waiting to be logged, in its job directory
OUTCOME_FILE = "outcome.json"


def outcome_to_json(outcome: JobOutcome) -> str:
    """The outcome as JSON text (``params`` as :meth:`Parameters.to_dict`); floats exact."""
    data: dict[str, Any] = {
        f.name: getattr(outcome, f.name) for f in dataclasses.fields(outcome) if f.name != "params"
    }
    data["params"] = outcome.params.to_dict()
    return json.dumps(json.loads(canonical_json(data)), indent=1, sort_keys=True)


def outcome_from_json(text: str) -> JobOutcome:
    """Inverse of :func:`outcome_to_json` (ValueError if the text is not an outcome)."""
    try:
        data = json.loads(text)
        data["params"] = Parameters.from_dict(data["params"], "outcome.json")
        return JobOutcome(**data)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"not a job outcome: {exc}") from exc


def keep(job_dir: Path, outcome: JobOutcome) -> Path:
    """Write the outcome to ``job_dir/outcome.json`` (atomically); returns the path."""
    path = Path(job_dir) / OUTCOME_FILE
    storage.write_bytes(path, outcome_to_json(outcome).encode())
    return path


def kept(job_dir: Path, config_hash: str) -> JobOutcome | None:
    """The outcome waiting in ``job_dir`` for a job of ``config_hash``, or None (none there,
    unreadable, or another configuration's)."""
    path = Path(job_dir) / OUTCOME_FILE
    if not path.is_file():
        return None
    try:
        outcome = outcome_from_json(path.read_text())
    except (OSError, ValueError):
        return None
    return outcome if outcome.config_hash == config_hash else None


def forget(job_dir: Path) -> None:
    """Remove the kept outcome (once the tracker has the job)."""
    (Path(job_dir) / OUTCOME_FILE).unlink(missing_ok=True)
