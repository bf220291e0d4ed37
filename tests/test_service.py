"""The sweep orchestration without Ray or MLflow: skip, refuse, fail, resume, summarise."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from mmg import bounds, efd_parameters
from sweep.data.datasets import CONF_DIR, load_split
from sweep.data.objective import Objective
from sweep.identification.cmaes import Box, optimise
from sweep.identification.workers import InProcess
from sweep.service.job import JobSpec, settings_of
from sweep.service.orchestration import (
    LocalExecutor,
    Progress,
    efd_reference,
    run_sweep,
    spec_from_config,
)
from sweep.service.outcome import SUBSETS
from sweep.service.tracking import ConfigChangedError
from tests.conftest import SHARED_EFFECTS, kernels
from tests.memory_tracker import NullTracker

pytestmark = pytest.mark.kernels(
    *kernels((), "simulate", "moments", "derivatives"), *kernels(SHARED_EFFECTS, "moments")
)


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
    first = _run(specs, tracker, efd, tmp_path, LocalExecutor(plots=False, uncertainty=True))
    assert first.ok and sorted(first.finished) == sorted(s.key for s in specs)
    records = tracker.job_outcomes(first.parent_id)
    assert len(records) == 2
    for J in ("J1", "J2", "J3"):
        for subset in SUBSETS:
            assert f"test/{J}/{subset}" in records[0]["metrics"]
    assert set(first.files) >= {"J1.csv", "J2.md", "J3.html", "J2.parquet"}
    assert "EFD" in (tmp_path / "summary" / "J2.md").read_text()
    # each child run has the intervals of its best parameters on its training set
    child = next(r for r in tracker.runs.values() if r.tags.get("job_key") == specs[1].key)
    intervals = json.loads(child.artifacts["uncertainty.json"])
    assert intervals["objective"] == "J2" and intervals["params"] == "cmaes"
    assert len(intervals["parameters"]) == 57 and intervals["meta"]["subsequences"] == 29
    assert child.metrics["fraction_determined"] == intervals["fraction_determined"]
    assert b"| C_D |" in child.artifacts["uncertainty.md"]
    # and the manoeuvres of those parameters, with intervals from 50 draws of them
    m = child.metrics
    assert m["manoeuvre/turning.advance_lo"] <= m["manoeuvre/turning.advance_hi"]
    assert "manoeuvre/zigzag10.overshoot_1_margin" in m
    assert "manoeuvre/recorded.Test-T.advance_measured" in m
    table = child.artifacts["manoeuvres.md"].decode()
    assert "over 50 draws" in table and "| Test-Z | zigzag 20/20 |" in table
    # the parent's manoeuvre table: each case's seeds beside EFD and the measurements
    md = (tmp_path / "summary" / "manoeuvres.md").read_text()
    assert "| measured | EFD | J1-R | J2-R |" in md and "| Test-T (turning) | advance | L |" in md
    parent = tracker.runs[first.parent_id]
    frame = parent.artifacts["summary/manoeuvres.json"].set_index("key")
    assert frame.loc["turning.advance", "J2-R mean"] == m["manoeuvre/turning.advance"]
    assert frame.loc["turning.advance", "J2-R lo"] == m["manoeuvre/turning.advance_lo"]
    assert np.isfinite(frame.loc["turning.advance", "EFD"])
    measured = frame.loc["recorded.Test-T.advance", "measured"]
    assert measured == m["manoeuvre/recorded.Test-T.advance_measured"]
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
        checkpoint_key=spec.checkpoint_key, checkpoint_job=spec.config_hash,
    )  # fmt: skip
    t_resumed, t_fresh = NullTracker(), NullTracker()
    _run([spec], t_resumed, efd, tmp_path)
    _run([fresh], t_fresh, efd, tmp_path)
    a = t_resumed.job_outcomes(next(iter(t_resumed.runs)))
    b = t_fresh.job_outcomes(next(iter(t_fresh.runs)))
    assert a[0]["metrics"]["best_f"] == b[0]["metrics"]["best_f"]
    assert a[0]["metrics"]["test/J2/total"] == pytest.approx(b[0]["metrics"]["test/J2/total"])
    assert np.isfinite(a[0]["metrics"]["test/J2/total"])
    assert a[0]["metrics"]["checkpoint_rejected"] == 0.0  # resumed, not started afresh


class _LostError(RuntimeError):
    """Stands for Ray's ActorDiedError in these tests (a double: the real one is in test_faults)."""


class LosingExecutor(LocalExecutor):
    """Loses the first ``times`` submissions of each job in ``lose`` after two generations of
    progress (leaving the checkpoint a killed node would leave), then runs it normally."""

    def __init__(self, lose: set[str], times: int, data_dir) -> None:
        super().__init__(plots=False)
        self.lose, self.times, self.data_dir = lose, times, data_dir
        self.submissions: dict[str, int] = {}

    def submit(self, spec: JobSpec) -> int:
        n = self.submissions[spec.key] = self.submissions.get(spec.key, 0) + 1
        if spec.key in self.lose and n <= self.times:
            train = load_split(spec.train).load(self.data_dir)
            obj = Objective(list(train.values()), spec.objective)
            lo, hi = bounds()
            spec.job_dir.mkdir(parents=True, exist_ok=True)
            optimise(
                InProcess(obj), Box(lo, hi), efd_parameters().vector(),
                settings_of(spec.config, spec.seed), checkpoint=spec.checkpoint_location,
                stop_after_generations=2, checkpoint_key=spec.checkpoint_key,
                checkpoint_job=spec.config_hash,
            )  # fmt: skip
            handle = self._next
            self._next += 1
            self._done[handle] = _LostError(f"the node of {spec.key} died")
            return handle
        return super().submit(spec)

    def lost(self, error: BaseException) -> bool:
        return isinstance(error, _LostError)


def test_a_lost_job_is_resubmitted_resumes_and_ends_as_an_uninterrupted_one(
    tmp_path, data_dir, efd
):
    """Lost twice (two generations each time), the job is resubmitted, resumes from its
    checkpoint, and ends bit for bit where an uninterrupted run ends; the retries are counted
    and shown; a job that is lost more often than max_retries fails with the loss named."""
    lost_spec, other = _specs(tmp_path / "a", data_dir, budget=100)
    fresh = _specs(tmp_path / "b", data_dir, budget=100)
    executor = LosingExecutor({lost_spec.key}, 2, data_dir)
    stream = io.StringIO()
    tracker = NullTracker()
    summary = run_sweep(
        "lossy", [lost_spec, other], executor, tracker, efd, tmp_path / "a",
        progress=Progress(stream), max_retries=3, retry_delay=0.5,
    )  # fmt: skip
    assert summary.ok and sorted(summary.finished) == sorted([lost_spec.key, other.key])
    assert summary.retries == {lost_spec.key: 2}
    assert executor.submissions == {lost_spec.key: 3, other.key: 1}
    assert stream.getvalue().count("resubmitted") == 2 and "_LostError" in stream.getvalue()
    assert "resubmitted (1/3) in 0.5 s" in stream.getvalue()  # then twice that
    assert "resubmitted (2/3) in 1 s" in stream.getvalue()
    t_fresh = NullTracker()
    run_sweep("clean", fresh, LocalExecutor(plots=False), t_fresh, efd, tmp_path / "b",
              progress=Progress(io.StringIO()))  # fmt: skip
    got = {r["job_key"]: r for r in tracker.job_outcomes(summary.parent_id)}
    ref = {r["job_key"]: r for r in t_fresh.job_outcomes(next(iter(t_fresh.runs)))}
    for key in got:
        assert got[key]["metrics"]["best_f"] == ref[key]["metrics"]["best_f"]
        assert got[key]["metrics"]["test/J2/total"] == ref[key]["metrics"]["test/J2/total"]
    assert got[lost_spec.key]["metrics"]["retries"] == 2.0
    # it resumed from the lost attempts' checkpoints (signed with the job's key), not afresh
    assert got[lost_spec.key]["metrics"]["checkpoint_rejected"] == 0.0
    child = next(r for r in tracker.runs.values() if r.tags.get("job_key") == lost_spec.key)
    assert child.tags["retries"] == "2"
    assert got[other.key]["metrics"]["retries"] == 0.0
    # lost more often than allowed: failed, with the loss in the message
    again = _specs(tmp_path / "c", data_dir, budget=100, objectives=("J1",))
    summary = run_sweep(
        "hopeless", again, LosingExecutor({again[0].key}, 5, data_dir), NullTracker(), efd,
        tmp_path / "c", progress=Progress(io.StringIO()), max_retries=1, retry_delay=0.0,
    )  # fmt: skip
    assert not summary.ok and "_LostError" in summary.failed[again[0].key]


def test_an_error_of_the_job_itself_is_not_retried(tmp_path, data_dir, efd):
    _, bad = _specs(tmp_path, data_dir)
    broken_cfg = dict(bad.config)
    broken_cfg["train"] = {"key": "R", "name": "Train-R", "files": ["data/random/missing.csv"]}
    bad = JobSpec(bad.key, bad.objective, bad.train, bad.seed, broken_cfg, bad.job_dir,
                  bad.data_root)  # fmt: skip
    executor = LosingExecutor(set(), 0, data_dir)
    summary = run_sweep("mixed", [bad], executor, NullTracker(), efd, tmp_path,
                        progress=Progress(io.StringIO()), max_retries=3)  # fmt: skip
    assert executor.submissions == {bad.key: 1} and not summary.retries
    assert list(summary.failed) == [bad.key]


def test_checkpoints_go_to_the_storage_uri_and_a_job_resumes_from_there(tmp_path, data_dir, efd):
    """sweep.storage: the checkpoint lives at storage/<sweep>/<job directory>/checkpoint.pkl
    (a file:// URI here), not in the job directory; a lost job resumes from it. A '#' or '?'
    in the sweep name stays part of the path (percent-encoded), and a relative directory is
    made absolute on the driver."""
    cfg = _cfg("J2", 0, 100)
    cfg["data"]["root"] = str(data_dir)
    cfg["sweep"] = {"name": "run#1?", "storage": f"file://{tmp_path / 'store'}"}
    spec = spec_from_config(cfg, tmp_path / "objective=J2,seed=0")
    assert spec.checkpoint == (
        f"file://{tmp_path}/store/run%231%3F/objective=J2,seed=0/checkpoint.pkl"
    )
    executor = LosingExecutor({spec.key}, 1, data_dir)
    summary = run_sweep("stored", [spec], executor, NullTracker(), efd, tmp_path,
                        progress=Progress(io.StringIO()))  # fmt: skip
    assert summary.ok and summary.retries == {spec.key: 1}
    assert (tmp_path / "store" / "run#1?" / "objective=J2,seed=0" / "checkpoint.pkl").is_file()
    assert not (tmp_path / "objective=J2,seed=0" / "checkpoint.pkl").exists()
    cfg["sweep"] = {"name": "x", "storage": "rel/store"}
    relative = spec_from_config(cfg, tmp_path / "j")
    assert relative.checkpoint is not None and Path(relative.checkpoint).is_absolute()


def test_a_job_spaces_its_checkpoints_as_sweep_checkpoint_seconds_says(
    tmp_path, data_dir, checkpoint_writes
):
    """sweep.checkpoint_seconds reaches the job: 0 writes after every generation (5 of
    population 20, then the end), a long interval after the first generation and at the end
    only; the default is CHECKPOINT_SECONDS. The results are the same."""
    from sweep.identification import cmaes
    from sweep.service.job import run_job

    cfg = _cfg("J2", 0, 100)
    cfg["data"]["root"] = str(data_dir)
    cfg["sweep"] = {"name": "spaced"}
    assert spec_from_config(cfg, tmp_path / "d").checkpoint_seconds == cmaes.CHECKPOINT_SECONDS
    best = []
    for seconds, expected in ((0.0, [20, 40, 60, 80, 100, 100]), (1e9, [20, 100])):
        cfg["sweep"]["checkpoint_seconds"] = seconds
        spec = spec_from_config(cfg, tmp_path / f"every-{seconds}")
        assert spec.checkpoint_seconds == seconds
        checkpoint_writes.clear()
        outcome, _ = run_job(spec, InProcess, plots=False)
        assert checkpoint_writes == expected
        best.append(outcome.f)
    assert best[0] == best[1]


def test_a_data_warning_is_said_once_by_the_driver(tmp_path, data_dir):
    """zigzag_31-Jul-2020_13_50_28 ends in 327 empty rows: three jobs on Train-TZR read it, the
    driver says it once; the jobs themselves stay quiet."""
    import warnings

    from sweep.data.recordings import RecordingWarning
    from sweep.service.orchestration import check_recordings

    specs = []
    for J in ("J1", "J2", "J3"):
        cfg = _cfg(J, 0, 40, train="TZR")
        cfg["data"]["root"] = str(data_dir)
        specs.append(spec_from_config(cfg, tmp_path / J))
    stream = io.StringIO()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordingWarning)  # nothing may escape as a warning
        check_recordings(specs, stream)
    lines = [ln for ln in stream.getvalue().splitlines() if ln.strip()]
    assert len(lines) == 1 and "327" in lines[0] and lines[0].startswith("warning: ")


def test_a_job_identifies_extra_effects_with_the_57_parameters(tmp_path, data_dir, efd):
    """effects = the shared kernel's (the catalog's and the generated terms N_dnn + Y_t): the job
    searches the effects' parameters with the 57 (from neutral, over their boxes), reports them
    in its parameters, and scores the test set with them; a plain job's config (and hash) has no
    effects entry."""
    cfg = _cfg("J2", 0, 60)
    cfg["data"]["root"] = str(data_dir)
    plain = spec_from_config(cfg, tmp_path / "plain")
    assert "effects" not in plain.config
    cfg["effects"] = list(SHARED_EFFECTS)
    spec = spec_from_config(cfg, tmp_path / "effects")
    assert spec.config["effects"] == list(SHARED_EFFECTS)
    assert spec.config_hash != plain.config_hash
    tracker = NullTracker()
    summary = run_sweep("with-effects", [spec], LocalExecutor(plots=False), tracker, efd,
                        tmp_path, progress=Progress(io.StringIO()))  # fmt: skip
    assert summary.ok, summary.failed
    (record,) = tracker.job_outcomes(summary.parent_id)
    child = tracker.runs[record["run_id"]]
    params = json.loads(child.artifacts["best_params.json"])
    assert set(params["effects"]) == set(SHARED_EFFECTS)
    c = params["effects"]["discovered:N_dnn+Y_t"]["C_N_dnn"]
    assert c != 0.0 and -1.0 <= c <= 1.0  # moved from neutral, inside its box
    assert np.isfinite(record["metrics"]["test/J2/total"])
    assert child.params["effects"] == json.dumps(list(SHARED_EFFECTS))


def test_cmaes_polish_refines_the_result_and_reports_it_as_its_own_row(tmp_path, data_dir, efd):
    """cmaes.polish=3: after the restarts, Levenberg-Marquardt continues from the CMA-ES result.
    The job keeps the CMA-ES result as its parameters and test row ("J2-R") and reports the
    refined one beside it ("J2-R+LM", polished_params.json, polish/* metrics), with a training
    J no higher. A job without it keeps its config (and hash): no polish key."""
    cfg = _cfg("J2", 0, 60)
    cfg["data"]["root"] = str(data_dir)
    cfg["cmaes"]["polish"] = False
    plain = spec_from_config(cfg, tmp_path / "plain")
    assert "polish" not in plain.config["cmaes"]
    cfg["cmaes"]["polish"] = 3
    spec = spec_from_config(cfg, tmp_path / "polish")
    assert spec.config["cmaes"]["polish"] == 3 and spec.config_hash != plain.config_hash
    tracker = NullTracker()
    executor = LocalExecutor(plots=False)
    summary = run_sweep("polish", [spec], executor, tracker, efd, tmp_path,
                        progress=Progress(io.StringIO()))  # fmt: skip
    assert summary.ok, summary.failed
    (record,) = tracker.job_outcomes(summary.parent_id)
    m = record["metrics"]
    # the job's last status is the refinement's (the progress display shows its iterations)
    last = executor.status(0)
    assert last is not None and 1 <= last["lm_iteration"] <= last["lm_iterations"] == 3
    assert last["lm_f"] == pytest.approx(m["polish_f"]) and last["evaluations"] == 60
    assert m["polish_f"] < m["best_f"]  # 60 CMA-ES evaluations leave LM plenty to gain
    assert m["polish_evaluations"] > 3 * 57
    assert record["polish"]["J2"]["total"] == m["polish/J2/total"] != m["test/J2/total"]
    child = tracker.runs[record["run_id"]]
    refined = json.loads(child.artifacts["polished_params.json"])
    assert refined["metadata"]["f_polished"] == pytest.approx(m["polish_f"])
    assert refined["theta"] != json.loads(child.artifacts["best_params.json"])["theta"]
    table = summary.tables["J2"]
    assert list(table.index) == ["EFD", "J2-R", "J2-R+LM"]
    assert table.loc["J2-R+LM", "Total mean"] == pytest.approx(m["polish/J2/total"])
    assert table.loc["J2-R", "Total mean"] == pytest.approx(m["test/J2/total"])


@pytest.mark.parametrize(
    ("jobs", "slots", "k"),
    [(27, 2, 3), (9, 2, 3), (3, 2, 3), (2, 2, 2), (1, 2, 2), (4, 2, 2), (5, 2, 2), (27, 8, 9),
     (7, 4, 4), (100, 1, 1)],
)  # fmt: skip
def test_jobs_at_once_leave_no_slot_idle_in_the_last_round(jobs, slots, k):
    from sweep.service.orchestration import balanced_concurrency

    assert balanced_concurrency(jobs, slots) == k


def test_27_jobs_on_2_cpus_run_3_at_a_time_on_shares_of_the_cores(tmp_path, data_dir):
    """A real local Ray: three jobs' evaluation workers (2/3 CPU each) start at once. (Each
    worker imports the model and loads its kernels: on a loaded 2-core machine the three took
    153 s to answer, so the wait allows 240 s.)"""
    import os
    import subprocess
    import sys

    code = (
        "import numpy as np, ray\n"
        "from sweep.service.raycluster import RayExecutor, RayEvaluator\n"
        "from sweep.data.datasets import load_split\n"
        "from sweep.data.objective import Objective\n"
        "from mmg import efd_parameters\n"
        "e = RayExecutor(num_cpus=2, jobs=27)\n"
        "obj = Objective(list(load_split('R').load().values())[:1], 'J2')\n"
        "evs = [RayEvaluator(obj, 1, e.cpus_per_worker) for _ in range(3)]\n"
        "theta = efd_parameters().vector()[None]\n"
        "refs = [ev.workers[0].evaluate.remote(theta) for ev in evs]\n"
        "ready, _ = ray.wait(refs, num_returns=3, timeout=240)\n"
        "f = [float(ray.get(r)[0]) for r in ready]\n"
        "print(e.capacity(), e.cpus_per_worker, len(ready), float(obj.evaluate(theta)[0]), *f)\n"
        "e.shutdown()\n"
    )
    env = dict(os.environ, MMG_DATA_DIR=str(data_dir), RAY_AUTH_MODE="disabled")
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=420,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    capacity, share, ready, f_here, *f_workers = out.stdout.split()[-7:]
    assert (int(capacity), float(share), int(ready)) == (3, 0.6666, 3)
    assert [float(f) for f in f_workers] == [float(f_here)] * 3  # same numbers on a share


def test_manoeuvres_that_fail_leave_the_job_its_result(data_dir, efd):
    """The manoeuvres of a job are a value too: intervals that cannot be read (here without
    their covariance) come back as an error, logged as a tag and manoeuvres_error.txt; with
    good intervals the same call gives the metrics, the table and the figure."""
    from sweep.service.job import job_manoeuvres
    from tests.test_tracking import make_outcome

    test = load_split("paper").load(str(data_dir))
    params = efd_parameters()
    value, files = job_manoeuvres(params, (), test, {"parameters": []}, 0, "cmaes", "title")
    assert value["error"].startswith("KeyError") and files == {}
    outcome = make_outcome()
    outcome.manoeuvres = value
    tracker = NullTracker()
    child = tracker.runs[tracker.log_job(tracker.start_sweep("s", {}, efd), outcome, None)]
    assert child.status == "FINISHED" and "test/J2/total" in child.metrics
    assert child.tags["manoeuvres.error"] == value["error"]
    assert b"KeyError" in child.artifacts["manoeuvres_error.txt"]
    assert not any(k.startswith("manoeuvre/") for k in child.metrics)
    # without intervals: point values, and the figure
    value, files = job_manoeuvres(params, (), test, None, 0, "cmaes", "EFD")
    assert value["samples"] == 0 and "point values" in value["markdown"]
    assert "manoeuvre.turning.advance_lo" not in value["metrics"]
    assert files["manoeuvres.png"].startswith(b"\x89PNG")


def test_intervals_that_fail_leave_the_job_its_result(data_dir, efd):
    """Failure is a value: intervals that cannot be computed (here a training set of one
    window: nothing to compare it with) come back as an error; the job is logged FINISHED with
    its results, the error as a tag and uncertainty_error.txt, and no fraction_determined."""
    from sweep.diagnose.windows import cut_windows
    from sweep.service.job import job_uncertainty
    from tests.test_tracking import make_outcome

    run = next(iter(load_split("R").load(str(data_dir)).values()))
    obj = Objective(cut_windows([run])[:1], "J1")
    lo, hi = bounds()
    value = job_uncertainty(obj, Box(lo, hi), efd_parameters().vector(), (), "cmaes")
    assert value["error"].startswith("ValueError: 1 of 1 subsequences left")
    outcome = make_outcome()
    outcome.uncertainty = value
    tracker = NullTracker()
    child = tracker.runs[tracker.log_job(tracker.start_sweep("s", {}, efd), outcome, None)]
    assert child.status == "FINISHED" and "test/J2/total" in child.metrics
    assert child.tags["uncertainty.error"] == value["error"]
    assert b"subsequences left" in child.artifacts["uncertainty_error.txt"]
    assert "fraction_determined" not in child.metrics and "uncertainty.json" not in child.artifacts
