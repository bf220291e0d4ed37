"""The outcome of one identification job: the data contract between the sweep, tracking and report.

A job is one (objective, training set, seed) triple with its composed configuration. Its outcome
holds the best parameters, the optimiser's record (restarts, per-generation history) and the
objectives J1, J2, J3 of the best parameters on the paper's test set, per subset:

==========  =========================  ===================================
subset      table column (paper)       metric name
==========  =========================  ===================================
``B-S``     Test-B-S                   ``test/{J}/B-S``
``B-P``     Test-B-P                   ``test/{J}/B-P``
``B``       Test-B-S + Test-B-P        ``test/{J}/B``
``R``       Test-R                     ``test/{J}/R``
``T``       Test-T                     ``test/{J}/T``
``Z``       Test-Z                     ``test/{J}/Z``
``total``   Total                      ``test/{J}/total``
==========  =========================  ===================================

The EFD reference values of a sweep are named ``efd/{J}/{subset}``. The manoeuvres of a job's
parameters are named ``manoeuvre/{manoeuvre}.{quantity}`` (full scale, with ``_lo``, ``_hi`` and
``_margin``) and ``manoeuvre/recorded.{run}.{quantity}`` (with ``_measured``), see
:func:`manoeuvre_metric_name`.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import math
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mmg.params import Parameters

#: the objectives, in table order
OBJECTIVE_NAMES = ("J1", "J2", "J3")
#: the paper's training sets, in table order
TRAIN_NAMES = ("R", "TR", "TZR")
#: test subsets (metric suffixes); "B" is Test-B-S + Test-B-P
SUBSETS = ("B-S", "B-P", "B", "R", "T", "Z", "total")
#: subset -> the paper's column name (Tables 6-8)
COLUMNS = {
    "B-S": "Test-B-S",
    "B-P": "Test-B-P",
    "B": "Test-B-S + Test-B-P",
    "R": "Test-R",
    "T": "Test-T",
    "Z": "Test-Z",
    "total": "Total",
}

#: objective values by objective and test subset, {J: {subset: value}} (``SUBSETS`` names)
ScoreTable = dict[str, dict[str, float]]


@dataclass
class JobOutcome:
    """Everything one finished job reports (plain data apart from ``params``)."""

    job_key: str  # stable key, e.g. "objective=J2,seed=0,train=R" (see make_job_key)
    objective: str  # J1 | J2 | J3
    train: str  # R | TR | TZR
    seed: int
    config: dict[str, Any]  # the composed job config (JSON-able)
    config_hash: str  # config_hash(config)
    params: Parameters  # best parameters
    f: float  # best objective value on the training set
    evaluations: int
    seconds: float
    rejected: bool  # the paper's post-filter (sweep.identification.cmaes.Box.rejected)
    stop_reason: str
    restarts: list[dict[str, Any]] = field(
        default_factory=list
    )  # sweep.identification.cmaes.restart_table
    history: list[dict[str, float]] = field(default_factory=list)  # one row per generation
    test: ScoreTable = field(default_factory=dict)  # {J: {subset: value}}
    sim_seconds: float = 0.0  # CPU time spent evaluating the objective (simulator), all workers
    retries: int = 0  # resubmissions after the job was lost to the infrastructure
    #: evaluation workers lost (a crash, a lost node) and replaced; their chunks were evaluated
    #: in the coordinator, so no generation was lost (0 for an outcome from before the count)
    workers_replaced: int = 0
    #: ``cmaes.polish``: the Levenberg-Marquardt refinement of the CMA-ES result (``params`` and
    #: ``test`` above stay the CMA-ES result): f_start, f, evaluations, iterations, seconds,
    #: params (:meth:`Parameters.to_dict`), test {J: {subset: value}}; None without it
    polished: dict[str, Any] | None = None
    #: how the job started when its checkpoint was rejected: "previous: truncated" (resumed from
    #: the previous checkpoint), "fresh: not authenticated, ..." (no good one left); "" if not
    checkpoint_recovery: str = ""
    checkpoint_rejected: int = 0  # checkpoints set aside (damaged, forged, another job's)
    #: the intervals of the job's final parameters (the refined ones with ``cmaes.polish``) on
    #: its training set: :meth:`~sweep.identification.uncertainty.Uncertainty.as_dict` plus
    #: ``markdown`` (the table) and ``params`` ("cmaes" or "polished"); ``{"error": ...}`` when
    #: they could not be computed; None for an outcome from before they existed
    uncertainty: dict[str, Any] | None = None
    #: the standard manoeuvres and the test set's turning and zigzag runs of the same
    #: parameters, with intervals from draws of ``uncertainty``: ``metrics``
    #: (:func:`~sweep.data.manoeuvre_tables.manoeuvre_metrics`), ``markdown`` (the tables),
    #: ``samples``, ``seed``, ``seconds``, ``params``; ``{"error": ...}`` when they could not be
    #: computed; None without them
    manoeuvres: dict[str, Any] | None = None


def _plain(value: Any) -> Any:
    """JSON fallback for numpy scalars and paths; anything else is an error."""
    if hasattr(value, "item") and callable(value.item):
        return value.item()
    if isinstance(value, PurePath):
        return str(value)
    raise TypeError(f"config value {value!r} of type {type(value).__name__} is not JSON-able")


@functools.cache
def source_version() -> dict[str, str]:
    """The installed package version and the git commit of the source tree ("unknown" outside
    a checkout): recorded with every job, kept out of the config hash."""
    try:
        version = importlib.metadata.version("mmg-sweep")
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5,
        )
        commit = out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        commit = "unknown"
    return {"version": version, "commit": commit}


def canonical_json(config: Mapping[str, Any]) -> str:
    """The config as compact JSON with sorted keys (the form that is hashed)."""
    return json.dumps(
        config, sort_keys=True, separators=(",", ":"), ensure_ascii=True, default=_plain
    )


def config_hash(config: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of the canonical JSON of ``config``; independent of key order."""
    return hashlib.sha256(canonical_json(config).encode()).hexdigest()


def make_job_key(**fields: Any) -> str:
    """``make_job_key(objective="J2", train="R", seed=0)`` -> "objective=J2,seed=0,train=R"."""
    return ",".join(f"{k}={fields[k]}" for k in sorted(fields))


def metric_name(kind: str, objective: str, subset: str) -> str:
    """``metric_name("test", "J2", "B")`` -> "test/J2/B"; kind "test" (a job), "polish" (the job
    after its refinement, ``cmaes.polish``) or "efd" (sweep)."""
    if (
        kind not in ("test", "polish", "efd")
        or objective not in OBJECTIVE_NAMES
        or subset not in SUBSETS
    ):
        raise ValueError(f"no metric {kind}/{objective}/{subset}")
    return f"{kind}/{objective}/{subset}"


#: prefix of a job's manoeuvre metrics in tracking
MANOEUVRE_PREFIX = "manoeuvre/"


def manoeuvre_metric_name(key: str) -> str:
    """The tracking name of a manoeuvre metric: ``"manoeuvre.turning.advance"`` ->
    "manoeuvre/turning.advance", ``"recorded.Test-T.advance_hi"`` ->
    "manoeuvre/recorded.Test-T.advance_hi"."""
    return MANOEUVRE_PREFIX + key.removeprefix("manoeuvre.")


def complete_subsets(values: Mapping[str, float]) -> dict[str, float]:
    """Values per subset with "B" (B-S + B-P) and "total" filled in when absent."""
    out = {k: float(v) for k, v in values.items()}
    if "B" not in out and "B-S" in out and "B-P" in out:
        out["B"] = out["B-S"] + out["B-P"]
    parts = ("B-S", "B-P", "R", "T", "Z")
    if "total" not in out and all(p in out for p in parts):
        out["total"] = math.fsum(out[p] for p in parts)
    return out


def from_paper_layout(table: Mapping[str, Mapping[str, float]]) -> ScoreTable:
    """{J: {column: value}} (``sweep.evaluate.paper_layout``) -> {J: {subset: value}}."""
    inverse = {column: subset for subset, column in COLUMNS.items()}
    return {
        J: complete_subsets({inverse[c]: float(v) for c, v in row.items() if c in inverse})
        for J, row in table.items()
    }
