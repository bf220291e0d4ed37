"""Configuration checked before anything starts: one line naming the key, exit 2, no MLflow run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from sweep.__main__ import CONF
from sweep.service.schema import ConfigError, validate


def _composed(overrides: list[str]) -> dict:
    from hydra_plugins.mmg_sweep_launcher.mmg_ray_launcher import job_config

    with initialize_config_dir(config_dir=CONF, version_base=None):
        # the default tracking URI needs Hydra's runtime directory, which compose() has not
        cfg = compose(config_name="config", overrides=["tracking.uri=sqlite:///x.db", *overrides])
    return job_config(cfg)


def test_the_shipped_configurations_pass():
    for objective in ("J1", "J2", "J3"):
        for train in ("R", "TR", "TZR"):
            for budget in ("smoke", "short", "medium", "paper"):
                overrides = [f"objective={objective}", f"train={train}", f"budget={budget}"]
                validate(_composed(overrides))


@pytest.mark.parametrize(
    ("override", "key", "hint"),
    [
        ("budget.max_evaluations=-5", "budget.max_evaluations", "positive integer"),
        ("budget.max_evaluations=10", "budget.max_evaluations", ">= cmaes.popsize_start (20)"),
        ("budget.max_seconds=0", "budget.max_seconds", "positive number"),
        ("cmaes.sigma0=0", "cmaes.sigma0", "(0, 1]"),
        ("cmaes.sigma0=1.5", "cmaes.sigma0", "(0, 1]"),
        ("cmaes.bound_handling=reflect", "cmaes.bound_handling", "penalty, transform, none"),
        ("cmaes.popsize_max=10", "cmaes.popsize_max", ">= cmaes.popsize_start (20)"),
        ("cmaes.popsize_start=2.5", "cmaes.popsize_start", "integer >= 4"),
        ("seed=abc", "seed", "non-negative integer"),
        ("seed=-1", "seed", "non-negative integer"),
        ("seed=1.5", "seed", "non-negative integer"),
        ("ray.workers_per_job=0", "ray.workers_per_job", "positive integer"),
        ("ray.cpus_per_worker=0", "ray.cpus_per_worker", "CPUs per evaluation worker"),
        ("ray.address=nowhere", "ray.address", "host:port"),
        ("sweep.name=a/b", "sweep.name", "without '/'"),
        ("sweep.max_retries=-1", "sweep.max_retries", "non-negative integer"),
        ("sweep.checkpoint_seconds=-1", "sweep.checkpoint_seconds", "seconds >= 0"),
        ("objective.name=J4", "objective.name", "J1, J2, J3"),
        ("train.files=[]", "train.files", "non-empty list"),
        ("effects=[warp_drive]", "effects", "current, heading_bias, propeller_walk"),
        ("effects=[discovered:N_warp]", "effects", "discovered:<terms>"),
    ],
)
def test_a_bad_value_names_its_key_and_what_is_allowed(override, key, hint):
    cfg = _composed([override])
    with pytest.raises(ConfigError) as err:
        validate(cfg)
    assert err.value.key == key
    text = str(err.value)
    assert text.startswith(f"config key {key} = ") and hint in text
    assert "\n" not in text


def test_the_command_exits_2_with_one_line_and_creates_no_mlflow_run(tmp_path, data_dir: Path):
    env = dict(os.environ, MMG_DATA_DIR=str(data_dir), RAY_AUTH_MODE="disabled")
    for args in (["-m", "seed=0,abc"], ["budget.max_evaluations=-5"]):
        proc = subprocess.run(
            [sys.executable, "-m", "sweep", *args, "budget=smoke", "sweep.name=bad"],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert proc.returncode == 2, proc.stderr[-2000:]
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        assert lines[-1].startswith("error: config key "), proc.stderr[-2000:]
        assert "Traceback" not in proc.stderr
        assert not (tmp_path / "mlflow.db").exists()
        assert not list(tmp_path.rglob("*.pkl"))  # no job started
