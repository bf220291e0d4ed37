"""The schema of a sweep's configuration, checked before anything starts.

Hydra composes each job's configuration from ``conf/``; :func:`validate` checks the composed,
resolved values against the rules below and raises :class:`ConfigError` naming the key, the
value found and what is allowed. ``python -m sweep`` prints that one line and exits with status 2
before Ray starts or an MLflow run is created (:mod:`sweep.errors`).

Every rule is (key, check, what is allowed). Keys the schema does not name are left alone, so a
user may carry notes or extra keys in a config file.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, get_args

from mmg import catalog
from sweep.data.objective import OBJECTIVES
from sweep.errors import UserError
from sweep.identification.cmaes import BoundHandling

_MISSING = object()


class ConfigError(ValueError, UserError):
    """A configuration value outside what the sweep accepts (a user mistake: exit 2)."""

    def __init__(self, key: str, value: Any, allowed: str) -> None:
        shown = "missing" if value is _MISSING else f"{value!r}"
        super().__init__(f"config key {key} = {shown}: {allowed}")
        self.key = key
        self.value = value
        self.allowed = allowed


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(float(v))


def _positive_int(v: Any) -> bool:
    return _is_int(v) and v > 0


def _optional(check: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda v: v is None or check(v)


def _text(v: Any) -> bool:
    return isinstance(v, str) and bool(v.strip())


def _name(v: Any) -> bool:
    return _text(v) and "/" not in v and "\\" not in v and v not in (".", "..")


def _storage(v: Any) -> bool:
    from sweep.service import storage

    if not _text(v):
        return False
    try:
        storage.check(v)
    except ValueError:
        return False
    return True


def _effects(v: Any) -> bool:
    from mmg import get_effect

    if not isinstance(v, list | tuple) or not all(isinstance(e, str) and e for e in v):
        return False
    try:
        for name in v:
            get_effect(name)
    except (KeyError, ValueError):
        return False
    return len(set(v)) == len(v)


def _address(v: Any) -> bool:
    return v is None or (isinstance(v, str) and (v == "" or v == "auto" or ":" in v))


@dataclass(frozen=True)
class Rule:
    """One validation rule of the composed configuration: a key, its check and what it allows.

    ``allowed`` is what the one-line error says the key accepts (``config key seed = -1: a
    non-negative integer (seed=0,1,2)``); a key that is not ``required`` may be absent.
    """

    key: str  # dotted path in the composed configuration
    check: Callable[[Any], bool]
    allowed: str
    required: bool = True


#: every rule :func:`validate` checks, in order
RULES: tuple[Rule, ...] = (
    Rule("seed", lambda v: _is_int(v) and v >= 0, "a non-negative integer (seed=0,1,2)"),
    Rule(
        "objective.name",
        lambda v: v in OBJECTIVES,
        f"one of {', '.join(OBJECTIVES)} (objective=J1|J2|J3)",
    ),
    Rule("train.key", _name, "a short name without '/' (the training set's key)"),
    Rule(
        "train.files",
        lambda v: isinstance(v, list | tuple) and len(v) > 0 and all(_text(f) for f in v),
        "a non-empty list of recording paths (relative to the data root)",
    ),
    Rule(
        "test.subsets",
        lambda v: isinstance(v, Mapping) and len(v) > 0 and all(_text(f) for f in v.values()),
        "a non-empty mapping of test-subset names to recording paths",
    ),
    Rule(
        "budget.max_evaluations",
        _positive_int,
        "a positive integer >= cmaes.popsize_start (one CMA-ES generation)",
    ),
    Rule(
        "budget.max_seconds",
        _optional(lambda v: _is_number(v) and v > 0),
        "null (no time limit) or a positive number of seconds",
        required=False,
    ),
    Rule(
        "cmaes.sigma0",
        lambda v: _is_number(v) and 0.0 < v <= 1.0,
        "a number in (0, 1] (the initial step size in the normalised box)",
    ),
    Rule(
        "cmaes.bound_handling",
        lambda v: v in get_args(BoundHandling),
        f"one of {', '.join(get_args(BoundHandling))}",
    ),
    Rule(
        "cmaes.popsize_start",
        lambda v: _is_int(v) and v >= 4,
        "an integer >= 4 (the first restart's population)",
    ),
    Rule("cmaes.popsize_max", _positive_int, "a positive integer >= cmaes.popsize_start"),
    Rule(
        "cmaes.polish",
        lambda v: isinstance(v, bool) or (_is_int(v) and v >= 0),
        "true, false or a number of Levenberg-Marquardt iterations >= 0 (after CMA-ES)",
        required=False,
    ),
    Rule("sweep.name", _name, "a non-empty name without '/' (the MLflow parent run)"),
    Rule(
        "sweep.allow_config_change",
        lambda v: isinstance(v, bool),
        "true or false",
        required=False,
    ),
    Rule(
        "sweep.progress_seconds",
        lambda v: _is_number(v) and v > 0,
        "a positive number of seconds",
        required=False,
    ),
    Rule(
        "sweep.max_retries",
        lambda v: _is_int(v) and v >= 0,
        "a non-negative integer (resubmissions of a job lost to the infrastructure)",
        required=False,
    ),
    Rule(
        "sweep.checkpoint_seconds",
        lambda v: _is_number(v) and v >= 0,
        "a number of seconds >= 0 between a job's checkpoints (0: after every generation)",
        required=False,
    ),
    Rule(
        "sweep.lease_seconds",
        lambda v: _is_number(v) and v >= 1,
        "a number of seconds >= 1: how long a driver's claim on a job lasts without its "
        "heartbeat (renewed every third of it)",
        required=False,
    ),
    Rule(
        "effects",
        _effects,
        f"a list of distinct effect names: the catalog's ({', '.join(catalog())}) or "
        "discovered:<terms> of the term library (e.g. 'effects=[\"discovered:N_s3b\"]')",
        required=False,
    ),
    Rule(
        "sweep.storage",
        _optional(_storage),
        "null (the job directories) or a directory / URI every node reaches "
        "(s3://bucket/prefix, gs://..., hdfs://..., file:///shared/dir)",
        required=False,
    ),
    Rule(
        "ray.address",
        _address,
        "empty or null (a private local Ray), auto, or host:port of a running cluster",
        required=False,
    ),
    Rule("ray.num_cpus", _optional(_positive_int), "null or a positive integer", required=False),
    Rule("ray.workers_per_job", _positive_int, "a positive integer", required=False),
    Rule(
        "ray.cpus_per_worker",
        _optional(lambda v: _is_number(v) and 1e-4 <= float(v) <= 64),
        "null (automatic) or a number of CPUs per evaluation worker in [0.0001, 64]",
        required=False,
    ),
    Rule(
        "ray.max_concurrent_jobs",
        _optional(_positive_int),
        "null (as many as the cluster's CPUs allow) or a positive integer",
        required=False,
    ),
    Rule("tracking.uri", _text, "a non-empty MLflow tracking URI", required=False),
    Rule("tracking.experiment", _text, "a non-empty experiment name", required=False),
    Rule(
        "tracking.retry_seconds",
        lambda v: _is_number(v) and v >= 0,
        "a number of seconds >= 0 (how long a tracking server that does not answer is retried)",
        required=False,
    ),
)


def _lookup(cfg: Mapping[str, Any], key: str) -> Any:
    node: Any = cfg
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return _MISSING
        node = node[part]
    return node


def validate(cfg: Mapping[str, Any]) -> None:
    """Check a composed, resolved job configuration; ConfigError on the first bad value."""
    for rule in RULES:
        value = _lookup(cfg, rule.key)
        if value is _MISSING:
            if rule.required:
                raise ConfigError(rule.key, value, rule.allowed)
            continue
        if not rule.check(value):
            raise ConfigError(rule.key, value, rule.allowed)
    start, most = _lookup(cfg, "cmaes.popsize_start"), _lookup(cfg, "cmaes.popsize_max")
    if most < start:
        raise ConfigError("cmaes.popsize_max", most, f"an integer >= cmaes.popsize_start ({start})")
    budget = _lookup(cfg, "budget.max_evaluations")
    if budget < start:
        raise ConfigError(
            "budget.max_evaluations",
            budget,
            f"an integer >= cmaes.popsize_start ({start}): one CMA-ES generation",
        )
