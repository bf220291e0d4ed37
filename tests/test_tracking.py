"""sweep.service.tracking: the Tracker contract on MLflow (one SQLite store per session) and in
memory."""

from __future__ import annotations

import json
import pickle
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from mmg import Parameters, efd_parameters
from sweep.service.outcome import (
    SUBSETS,
    JobOutcome,
    complete_subsets,
    config_hash,
    from_paper_layout,
    make_job_key,
    source_version,
)
from sweep.service.tracking import (
    ConfigChangedError,
    MlflowTracker,
    Tracker,
    TrackingError,
    default_tracking_uri,
    flatten_config,
    metric_part,
    sqlite_path,
)
from tests.memory_tracker import NullTracker

_STORE: dict[str, str] = {}


def shared_store(tmp_path_factory: pytest.TempPathFactory) -> str:
    """The session's one SQLite tracking store (making one costs 6-7.5 s of migrations)."""
    if "uri" not in _STORE:
        root = tmp_path_factory.mktemp("mlflow")
        uri = f"sqlite:///{root}/mlflow.db"
        MlflowTracker(uri).client.search_experiments()  # creates the schema
        _STORE["uri"] = uri
    return _STORE["uri"]


@pytest.fixture(scope="session")
def mlflow_uri(tmp_path_factory: pytest.TempPathFactory) -> str:
    return shared_store(tmp_path_factory)


def fresh_experiment() -> str:
    return f"test-{uuid.uuid4().hex[:10]}"


@pytest.fixture(params=["null", "mlflow"])
def tracker(request: pytest.FixtureRequest, mlflow_uri: str) -> Tracker:
    if request.param == "null":
        return NullTracker()
    return MlflowTracker(mlflow_uri, fresh_experiment())


def scores(scale: float) -> dict[str, dict[str, float]]:
    """{J: {subset: value}} with distinct values (B and total derived)."""
    base = {"B-S": 1.0, "B-P": 2.0, "R": 3.0, "T": 4.0, "Z": 5.0}
    return {
        J: complete_subsets({s: scale * (10 * j + v) for s, v in base.items()})
        for j, J in enumerate(("J1", "J2", "J3"), start=1)
    }


EFD = scores(10.0)


def history(n: int = 25) -> list[dict[str, float]]:
    """Two restarts (popsize 20 then 40), a decreasing best."""
    rows, evals, best = [], 0, np.inf
    for i in range(n):
        restart = 0 if i < 10 else 1
        pop = 20 * 2**restart
        evals += pop
        f = 100.0 / (1 + i) + (30.0 if i == 10 else 0.0)
        best = min(best, f)
        rows.append(
            {
                "restart": float(restart),
                "popsize": float(pop),
                "generation": float(i + 1 if restart == 0 else i - 9),
                "evaluations": float(evals),
                "best_f": f,
                "median_f": 2 * f,
                "best_so_far": best,
                "sigma": 0.1 / (1 + i),
            }
        )
    return rows


def make_outcome(
    objective: str = "J2",
    train: str = "R",
    seed: int = 0,
    scale: float = 1.0,
    rejected: bool = False,
    budget: int = 500,
) -> JobOutcome:
    config = {
        "objective": objective,
        "train": train,
        "seed": seed,
        "budget": {"evaluations": budget, "seconds": None},
        "cmaes": {"sigma0": 0.1, "bound_handling": "penalty"},
        "commit": "abc123",
    }
    rows = history()
    return JobOutcome(
        job_key=make_job_key(objective=objective, seed=seed, train=train),
        objective=objective,
        train=train,
        seed=seed,
        config=config,
        config_hash=config_hash(config),
        params=efd_parameters().replace(N_r=-0.1 - 0.01 * seed),
        f=rows[-1]["best_so_far"],
        evaluations=int(rows[-1]["evaluations"]),
        seconds=1.5,
        rejected=rejected,
        stop_reason="budget",
        restarts=[{"index": 0, "popsize": 20}, {"index": 1, "popsize": 40}],
        history=rows,
        test=scores(scale),
    )


# ---------------------------------------------------------------- helpers


def test_config_hash_and_job_key() -> None:
    a = {"x": 1, "y": {"b": 2.0, "a": [1, 2]}}
    b = {"y": {"a": [1, 2], "b": 2.0}, "x": 1}
    assert config_hash(a) == config_hash(b) and len(config_hash(a)) == 64
    assert config_hash(a) != config_hash({**a, "x": 2})
    assert config_hash({"n": np.int64(3), "p": Path("/a")}) == config_hash({"n": 3, "p": "/a"})
    assert make_job_key(train="R", seed=0, objective="J2") == "objective=J2,seed=0,train=R"


def test_flatten_and_uris() -> None:
    flat = flatten_config({"a": {"b": 1, "c": {"d": "x"}}, "e": [1, 2], "f": None, "g": "s"})
    assert flat == {"a.b": "1", "a.c.d": "x", "e": "[1, 2]", "f": "null", "g": "s"}
    assert len(flatten_config({"long": "x" * 7000})["long"]) == 6000
    assert default_tracking_uri("/tmp/work") == "sqlite:////tmp/work/mlflow.db"
    assert sqlite_path("sqlite:////tmp/work/mlflow.db") == Path("/tmp/work/mlflow.db")
    assert sqlite_path("http://localhost:5000") is None


def test_from_paper_layout() -> None:
    table = {"J1": {"Test-B-S": 1.0, "Test-B-P": 2.0, "Test-B-S + Test-B-P": 3.0, "Test-R": 4.0}}
    assert from_paper_layout(table) == {"J1": {"B-S": 1.0, "B-P": 2.0, "B": 3.0, "R": 4.0}}


# ---------------------------------------------------------------- the contract, both backends


def test_sweep_is_created_then_resumed(tracker: Tracker) -> None:
    assert isinstance(tracker, Tracker)
    parent = tracker.start_sweep("paper", {"seeds": 3}, EFD)
    assert tracker.efd_reference(parent) == EFD
    assert tracker.start_sweep("paper", {"seeds": 3}, EFD) == parent
    assert tracker.start_sweep("other", {"seeds": 3}, EFD) != parent


def test_find_finished_and_config_change(tracker: Tracker) -> None:
    parent = tracker.start_sweep("s", {}, EFD)
    outcome = make_outcome()
    assert tracker.find_finished(outcome.job_key, outcome.config_hash) is None
    run_id = tracker.log_job(parent, outcome, None)
    assert tracker.find_finished(outcome.job_key, outcome.config_hash) == run_id
    assert tracker.find_finished(outcome.job_key, outcome.config_hash, parent) == run_id
    assert tracker.find_finished("objective=J9,seed=0,train=R", outcome.config_hash) is None
    changed = make_outcome(budget=999)
    with pytest.raises(ConfigChangedError) as err:
        tracker.find_finished(changed.job_key, changed.config_hash)
    assert outcome.config_hash in str(err.value) and changed.config_hash in str(err.value)
    assert err.value.run_id == run_id
    # another sweep does not see this sweep's jobs
    tracker.start_sweep("s2", {}, EFD)
    assert tracker.find_finished(changed.job_key, changed.config_hash) is None


def test_allowed_config_change_reruns_and_report_keeps_newest(mlflow_uri: str) -> None:
    for tracker in (NullTracker(True), MlflowTracker(mlflow_uri, fresh_experiment(), True)):
        parent = tracker.start_sweep("s", {}, EFD)
        tracker.log_job(parent, make_outcome(scale=1.0), None)
        changed = make_outcome(budget=999, scale=2.0)
        assert tracker.find_finished(changed.job_key, changed.config_hash) is None
        new_id = tracker.log_job(parent, changed, None)
        assert tracker.find_finished(changed.job_key, changed.config_hash) == new_id
        (record,) = tracker.job_outcomes(parent)
        assert record["run_id"] == new_id and record["config_hash"] == changed.config_hash


def test_failures_are_recorded_and_not_finished(tracker: Tracker) -> None:
    parent = tracker.start_sweep("s", {}, EFD)
    config = {"objective": "J1", "seed": 1}
    key = make_job_key(objective="J1", seed=1, train="R")
    tags = {"objective": "J1", "train": "R", "seed": 1}
    run_id = tracker.log_failure(parent, key, tags, config, "Traceback\n" + "x" * 9000)
    assert isinstance(run_id, str)
    assert tracker.find_finished(key, config_hash(config)) is None
    assert tracker.job_outcomes(parent) == []


def test_job_outcomes_records(tracker: Tracker) -> None:
    parent = tracker.start_sweep("s", {}, EFD)
    tracker.log_job(parent, make_outcome("J1", "TR", 0, scale=1.0), None)
    tracker.log_job(parent, make_outcome("J1", "TR", 1, scale=2.0, rejected=True), None)
    records = tracker.job_outcomes(parent)
    assert [r["job_key"] for r in records] == [
        "objective=J1,seed=0,train=TR",
        "objective=J1,seed=1,train=TR",
    ]
    first, second = records
    assert first["test"] == scores(1.0) and second["test"] == scores(2.0)
    assert (first["objective"], first["train"], first["seed"]) == ("J1", "TR", 0)
    assert first["rejected"] is False and second["rejected"] is True
    assert first["evaluations"] == 25 * 0 + 10 * 20 + 15 * 40
    assert first["f"] == pytest.approx(make_outcome().f)
    assert first["polish"] == {}


def test_a_polished_job_reads_back_as_two_table_rows(tracker: Tracker) -> None:
    """cmaes.polish: the refined result's test scores go to the store as polish/* metrics and
    come back as their own row of the summary tables, right after the CMA-ES row."""
    from sweep.service.tables import summary_tables

    parent = tracker.start_sweep("s", {}, EFD)
    for seed in (0, 1):
        out = make_outcome("J2", "R", seed, scale=1.0 + seed)
        out.polished = {
            "f_start": out.f,
            "f": 0.5 * out.f,
            "evaluations": 250,
            "iterations": 3,
            "seconds": 1.0,
            "params": out.params.to_dict(),
            "test": scores(0.5 + 0.25 * seed),
        }
        tracker.log_job(parent, out, None)
    records = tracker.job_outcomes(parent)
    assert [r["polish"] for r in records] == [scores(0.5), scores(0.75)]
    assert records[0]["metrics"]["polish_f"] == pytest.approx(0.5 * make_outcome().f)
    table = summary_tables(records, EFD)["J2"]
    assert list(table.index) == ["EFD", "J2-R", "J2-R+LM"]
    assert table.loc["J2-R+LM", "Total mean"] == pytest.approx(
        (scores(0.5)["J2"]["total"] + scores(0.75)["J2"]["total"]) / 2
    )
    assert table.loc["J2-R", "Total mean"] == pytest.approx(
        (scores(1.0)["J2"]["total"] + scores(2.0)["J2"]["total"]) / 2
    )


def test_null_tracker_keeps_artifacts(tmp_path: Path) -> None:
    tracker = NullTracker()
    parent = tracker.start_sweep("s", {}, EFD)
    (tmp_path / "conv.png").write_bytes(b"png")
    run_id = tracker.log_job(parent, make_outcome(), tmp_path)
    run = tracker.runs[run_id]
    assert run.status == "FINISHED" and run.tags["mlflow.parentRunId"] == parent
    assert {"best_params.json", "history.csv", "plots/conv.png"} <= set(run.artifacts)
    assert [s for s, _ in run.history["history/best_so_far"]] == list(range(25))
    tracker.finish_sweep(parent, {"J2": pd.DataFrame({"a": [1.0]})}, {})
    assert tracker.runs[parent].status == "FINISHED"
    assert isinstance(tracker.runs[parent].artifacts["summary/J2.json"], pd.DataFrame)


# ---------------------------------------------------------------- MLflow specifics


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory, mlflow_uri: str) -> dict[str, Any]:
    """One sweep with one finished job (with a plot) and one failure, on the shared store."""
    tracker = MlflowTracker(mlflow_uri, fresh_experiment())
    parent = tracker.start_sweep("paper", {"budget": 500, "seeds": [0, 1]}, EFD)
    plots = tmp_path_factory.mktemp("plots")
    (plots / "convergence.png").write_bytes(b"\x89PNG fake")
    outcome = make_outcome()
    child = tracker.log_job(parent, outcome, plots)
    failed = tracker.log_failure(
        parent, "objective=J3,seed=2,train=R", {"objective": "J3"}, {"seed": 2}, "boom" * 2000
    )
    return {"tracker": tracker, "parent": parent, "child": child, "failed": failed, "o": outcome}


def test_parent_run_tags_metrics_and_artifact_root(logged: dict[str, Any], mlflow_uri: str) -> None:
    tracker: MlflowTracker = logged["tracker"]
    run = tracker.client.get_run(logged["parent"])
    assert run.data.tags["sweep"] == "true" and run.info.run_name == "paper"
    for J in ("J1", "J2", "J3"):
        for s in SUBSETS:
            assert run.data.metrics[f"efd/{J}/{s}"] == EFD[J][s]
    assert run.data.params["budget"] == "500"
    exp = tracker.client.get_experiment(run.info.experiment_id)
    db_dir = sqlite_path(mlflow_uri).parent  # type: ignore[union-attr]
    assert exp.artifact_location == (db_dir / "mlartifacts" / tracker.experiment).as_uri()


def test_child_run_tags_and_metrics(logged: dict[str, Any]) -> None:
    tracker: MlflowTracker = logged["tracker"]
    outcome: JobOutcome = logged["o"]
    run = tracker.client.get_run(logged["child"])
    assert run.info.status == "FINISHED"
    tags = run.data.tags
    assert tags["mlflow.parentRunId"] == logged["parent"]
    assert (tags["objective"], tags["train"], tags["seed"]) == ("J2", "R", "0")
    assert tags["job_key"] == "objective=J2,seed=0,train=R"
    assert tags["config_hash"] == outcome.config_hash
    test_metrics = {k: v for k, v in run.data.metrics.items() if k.startswith("test/")}
    assert len(test_metrics) == 21
    for J in ("J1", "J2", "J3"):
        for s in ("B-S", "B-P", "B", "R", "T", "Z", "total"):
            assert test_metrics[f"test/{J}/{s}"] == outcome.test[J][s]
    assert run.data.metrics["best_f"] == outcome.f
    assert run.data.metrics["evaluations"] == outcome.evaluations
    assert run.data.metrics["rejected"] == 0.0
    assert run.data.params["budget.evaluations"] == "500"
    assert run.data.params["cmaes.bound_handling"] == "penalty"


def test_history_metrics_have_steps(logged: dict[str, Any]) -> None:
    tracker: MlflowTracker = logged["tracker"]
    rows = logged["o"].history
    for name in ("best_so_far", "best_f", "popsize", "sigma"):
        hist = tracker.client.get_metric_history(logged["child"], f"history/{name}")
        got = sorted((m.step, m.value) for m in hist)
        assert got == [(i, row[name]) for i, row in enumerate(rows)]


def test_child_artifacts(logged: dict[str, Any], tmp_path: Path) -> None:
    tracker: MlflowTracker = logged["tracker"]
    outcome: JobOutcome = logged["o"]
    run_id = logged["child"]
    names = {a.path for a in tracker.client.list_artifacts(run_id)}
    expected = {"best_params.json", "best_params.csv", "history.csv", "restarts.json"}
    assert expected | {"config.json", "plots"} <= names
    assert [a.path for a in tracker.client.list_artifacts(run_id, "plots")] == [
        "plots/convergence.png"
    ]
    path = tracker.client.download_artifacts(run_id, "best_params.json", str(tmp_path))
    params = Parameters.load_json(path)
    assert np.array_equal(params.vector(), outcome.params.vector())
    meta = json.loads(Path(path).read_text())["metadata"]
    assert meta["job_key"] == outcome.job_key
    assert meta["commit"] == source_version()["commit"]  # the source tree, not the config
    assert meta["version"] == source_version()["version"]
    assert meta["config_hash"] == outcome.config_hash and meta["f"] == outcome.f
    csv_path = tracker.client.download_artifacts(run_id, "best_params.csv", str(tmp_path))
    table = pd.read_csv(csv_path)
    assert list(table.columns) == ["name", "value"] and len(table) == 57
    assert table.set_index("name")["value"]["N_r"] == pytest.approx(-0.1)
    hist = pd.read_csv(tracker.client.download_artifacts(run_id, "history.csv", str(tmp_path)))
    assert len(hist) == len(outcome.history)


def test_failed_run(logged: dict[str, Any], tmp_path: Path) -> None:
    tracker: MlflowTracker = logged["tracker"]
    run = tracker.client.get_run(logged["failed"])
    assert run.info.status == "FAILED"
    assert run.data.tags["error"] == ("boom" * 2000)[:5000]
    assert run.data.tags["mlflow.parentRunId"] == logged["parent"]
    path = tracker.client.download_artifacts(logged["failed"], "error.txt", str(tmp_path))
    assert Path(path).read_text() == "boom" * 2000


def test_finish_sweep_tables_read_back(mlflow_uri: str, tmp_path: Path) -> None:
    tracker = MlflowTracker(mlflow_uri, fresh_experiment())
    parent = tracker.start_sweep("s", {}, EFD)
    table = pd.DataFrame(
        {"Total mean": [3.0, np.nan], "n": pd.array([pd.NA, 2], dtype="Int64")},
        index=pd.Index(["EFD", "J2-R"], name="Case"),
    )
    extra = tmp_path / "J2.md"
    extra.write_text("| a |\n")
    for _ in range(2):  # logging again replaces the table instead of appending to it
        tracker.finish_sweep(parent, {"J2": table}, {"J2.md": extra})
    client = tracker.client
    assert client.get_run(parent).info.status == "FINISHED"
    # (MlflowClient.load_table searches with the global tracking URI: read the file instead)
    logged = json.loads(client.get_run(parent).data.tags["mlflow.loggedArtifacts"])
    assert {"path": "summary/J2.json", "type": "table"} in logged
    path = client.download_artifacts(parent, "summary/J2.json", str(tmp_path))
    back = pd.read_json(path, orient="split")
    assert list(back["Case"]) == ["EFD", "J2-R"]
    assert back["Total mean"].iloc[0] == 3.0 and np.isnan(back["Total mean"].iloc[1])
    assert {a.path for a in client.list_artifacts(parent, "summary")} == {
        "summary/J2.json",
        "summary/J2.md",
    }


def test_tracker_pickles_without_client(logged: dict[str, Any]) -> None:
    tracker: MlflowTracker = logged["tracker"]
    copy = pickle.loads(pickle.dumps(tracker))
    assert copy.uri == tracker.uri and copy._client is None
    outcome: JobOutcome = logged["o"]
    assert copy.find_finished(outcome.job_key, outcome.config_hash) == logged["child"]


def test_unknown_runs_and_sweeps(logged: dict[str, Any], mlflow_uri: str) -> None:
    tracker: MlflowTracker = logged["tracker"]
    assert tracker.find_sweep("nope") is None
    assert tracker.find_sweep() == logged["parent"]
    assert tracker.sweep_name(logged["parent"]) == "paper"
    with pytest.raises(TrackingError, match="not a sweep"):
        tracker.sweep_name(logged["child"])
    with pytest.raises(TrackingError, match="no run"):
        tracker.sweep_name("0" * 32)
    assert MlflowTracker(mlflow_uri, "never-made").find_sweep() is None
    with pytest.raises(ValueError, match="quotes"):
        tracker.find_finished("a'b", "h")


def test_a_learned_shapes_name_is_a_metric_of_a_logged_diagnosis(
    mlflow_uri: str, tmp_path: Path
) -> None:
    """A diagnosis logs a metric per candidate: a learned shape's name (brackets, tildes, plus
    signs, a slash before its basis count) becomes one valid part of the metric name, and two
    shapes stay apart (MLflow refused the raw name and the logging failed), as do two library
    findings (all were logged as ``discovered`` and the last one won), also when their names
    are cut to the length of a metric's part."""
    many = "+".join(f"N_t{i}" for i in range(60))  # a library finding of many terms
    names = [
        "shape:D~ed[-4.25845:4.25845]/16+N~beta[-2.91794:3.02378]/8",
        "shape:YN~beta[-2.91794:3.02378]:up(-1.73)*Y_H@U2",
        "rudder_offset",
        "discovered:N_vvv+N_dddu+Y_nv",
        "discovered:N_s3b",
        f"discovered:{many}+Y_a",
        f"discovered:{many}+Y_b",
    ]
    parts = [metric_part(n, limit=200) for n in names]
    assert parts[2] == "rudder_offset" and parts[4] == "discovered_N_s3b"
    assert metric_part(names[0], limit=200) == metric_part(names[0])  # short: as it is
    # every candidate its own metric, the long ones cut to 200 characters and kept apart
    assert len(set(parts)) == len(names) and not any("/" in p for p in parts)
    assert len(parts[5]) == len(parts[6]) == 200
    metrics = {f"improvement/{p}": float(i) for i, p in enumerate(parts)}
    (tmp_path / "report.md").write_text("report")
    tracker = MlflowTracker(mlflow_uri, fresh_experiment())
    rid = tracker.log_diagnosis(
        "diagnose-x", {"train": "R"}, metrics, {"verdict": "none"}, tmp_path
    )
    assert tracker.client.get_run(rid).data.metrics == metrics
