"""The sweep orchestration without Ray or MLflow: skip, refuse, fail, resume, summarise."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import yaml

from mmg import bounds, efd_parameters
from sweep.cmaes import Box, optimise
from sweep.datasets import CONF_DIR, load_split
from sweep.job import JobSpec, settings_of
from sweep.objective import Objective
from sweep.outcome import SUBSETS
from sweep.service import LocalExecutor, Progress, efd_reference, run_sweep, spec_from_config
from sweep.tracking import ConfigChangedError, NullTracker
from sweep.workers import InProcess


def _cfg(objective: str, seed: int, budget: int, train: str = "R") -> dict:
    load = lambda p: yaml.safe_load((CONF_DIR / p).read_text())  # noqa: E731
    return {
        "objective": {"name": objective},
        "train": load(f"train/{train}.yaml"),
        "test": load("test/paper.yaml"),
        "budget": {"name": "tiny", "max_evaluations": budget, "max_seconds": None},
        "cmaes": {"sigma0": 0.03, "bound_handling": "penalty", "popsize_start": 20,
                  "popsize_max": 720},
        "seed": seed,
        "data": {"root": None},
    }  # fmt: skip


@pytest.fixture(scope="module")
def efd(data_dir):
    return efd_reference(yaml.safe_load((CONF_DIR / "test/paper.yaml").read_text()), str(data_dir))


def _specs(tmp: Path, data_dir, budget=40, objectives=("J1", "J2")) -> list[JobSpec]:
    out = []
    for J in objectives:
        cfg = _cfg(J, 0, budget)
        cfg["data"]["root"] = str(data_dir)
        out.append(spec_from_config(cfg, tmp / f"objective={J},seed=0,train=R"))
    return out


def _run(specs, tracker, efd, tmp, executor=None):
    return run_sweep(
        "test-sweep", specs, executor or LocalExecutor(plots=False), tracker, efd, tmp,
        progress=Progress(io.StringIO()),
    )  # fmt: skip


def test_sweep_logs_jobs_summarises_and_skips_them_on_a_rerun(tmp_path, data_dir, efd):
    tracker = NullTracker()
    specs = _specs(tmp_path, data_dir)
    first = _run(specs, tracker, efd, tmp_path)
    assert first.ok and sorted(first.finished) == sorted(s.key for s in specs)
    records = tracker.job_outcomes(first.parent_id)
    assert len(records) == 2
    for J in ("J1", "J2", "J3"):
        for subset in SUBSETS:
            assert f"test/{J}/{subset}" in records[0]["metrics"]
    assert set(first.files) >= {"J1.csv", "J2.md", "J3.html", "J2.parquet"}
    assert "EFD" in (tmp_path / "summary" / "J2.md").read_text()
    n_runs = len(tracker.runs)
    again = _run(specs, tracker, efd, tmp_path)
    assert sorted(again.skipped) == sorted(s.key for s in specs) and not again.finished
    assert len(tracker.runs) == n_runs  # nothing new ran
    assert again.parent_id == first.parent_id  # the same parent run, resumed


def test_changed_config_is_refused_before_anything_runs(tmp_path, data_dir, efd):
    tracker = NullTracker()
    _run(_specs(tmp_path, data_dir, objectives=("J1",)), tracker, efd, tmp_path)
    changed = _specs(tmp_path / "b", data_dir, budget=60, objectives=("J1",))
    with pytest.raises(ConfigChangedError):
        _run(changed, tracker, efd, tmp_path)
    allowed = NullTracker(allow_config_change=True)
    allowed.runs = tracker.runs
    assert _run(changed, allowed, efd, tmp_path).finished == [changed[0].key]


def test_a_failing_job_is_recorded_and_the_others_finish(tmp_path, data_dir, efd):
    tracker = NullTracker()
    good, bad = _specs(tmp_path, data_dir)
    broken_cfg = dict(bad.config)
    broken_cfg["train"] = {"key": "R", "name": "Train-R", "files": ["data/random/missing.csv"]}
    bad = JobSpec(bad.key, bad.objective, bad.train, bad.seed, broken_cfg, bad.job_dir,
                  bad.data_root)  # fmt: skip
    summary = _run([bad, good], tracker, efd, tmp_path)
    assert not summary.ok
    assert summary.finished == [good.key] and list(summary.failed) == [bad.key]
    failed = [r for r in tracker.runs.values() if r.status == "FAILED"]
    assert len(failed) == 1 and "missing.csv" in failed[0].tags["error"]


def test_an_interrupted_job_resumes_from_its_checkpoint(tmp_path, data_dir, efd):
    spec = _specs(tmp_path / "a", data_dir, budget=100, objectives=("J2",))[0]
    fresh = _specs(tmp_path / "b", data_dir, budget=100, objectives=("J2",))[0]
    # interrupt: two generations into the job, as a killed process would leave it
    train = load_split("R").load(data_dir)
    obj = Objective(list(train.values()), "J2")
    lo, hi = bounds()
    spec.job_dir.mkdir(parents=True)
    optimise(
        InProcess(obj), Box(lo, hi), efd_parameters().vector(), settings_of(spec.config, 0),
        checkpoint=spec.job_dir / "checkpoint.pkl", stop_after_generations=2,
    )  # fmt: skip
    t_resumed, t_fresh = NullTracker(), NullTracker()
    _run([spec], t_resumed, efd, tmp_path)
    _run([fresh], t_fresh, efd, tmp_path)
    a = t_resumed.job_outcomes(next(iter(t_resumed.runs)))
    b = t_fresh.job_outcomes(next(iter(t_fresh.runs)))
    assert a[0]["metrics"]["best_f"] == b[0]["metrics"]["best_f"]
    assert a[0]["metrics"]["test/J2/total"] == pytest.approx(b[0]["metrics"]["test/J2/total"])
    assert np.isfinite(a[0]["metrics"]["test/J2/total"])
