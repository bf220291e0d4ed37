"""sweep.report: the paper's summary tables, their files, the figures and the report command."""

from __future__ import annotations

import math
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from sweep.report import main
from sweep.service.figures import plot_convergence, plot_trajectories
from sweep.service.outcome import COLUMNS, JobOutcome
from sweep.service.tables import display_table, summary_tables, write_tables
from sweep.service.tracking import MlflowTracker
from tests.memory_tracker import NullTracker
from tests.test_tracking import EFD, history, make_outcome, shared_store

PNG = b"\x89PNG\r\n\x1a\n"


def scores(bs: float, bp: float, r: float, t: float = 40.0, z: float = 50.0) -> dict[str, Any]:
    """The same per-subset values for J1, J2 and J3 (B and total filled in by the report)."""
    row = {"B-S": bs, "B-P": bp, "R": r, "T": t, "Z": z}
    return {J: dict(row) for J in ("J1", "J2", "J3")}


def record(objective: str, train: str, seed: int, test: dict, rejected: bool = False) -> dict:
    return {
        "objective": objective,
        "train": train,
        "seed": seed,
        "rejected": rejected,
        "test": test,
    }


OUTCOMES = [
    record("J2", "R", 0, scores(8, 30, 20)),
    record("J1", "R", 0, scores(10, 20, 30)),
    record("J2", "R", 1, scores(9, 31, 21)),
    record("J3", "TZR", 0, scores(11, 5, 25)),
    record("J2", "R", 2, scores(10, 32, 22)),
    record("J1", "R", 1, scores(14, 20, 30)),
    record("J2", "R", 3, scores(1, 1, 1, 1, 1), rejected=True),
]
EFD_SCORES = scores(20, 40, 50, 60, 70)


@pytest.fixture(scope="module")
def tables() -> dict[str, pd.DataFrame]:
    return summary_tables(OUTCOMES, EFD_SCORES)


def at(table, case, column):
    """One cell (untyped on purpose: pandas-stubs types DataFrame.at as any scalar)."""
    return table.at[case, column]


def col(column: str, stat: str) -> str:
    return f"{COLUMNS[column]} {stat}"


def test_layout_rows_and_columns(tables: dict[str, pd.DataFrame]) -> None:
    assert list(tables) == ["J1", "J2", "J3"]
    table = tables["J2"]
    assert list(table.index) == ["EFD", "J1-R", "J2-R", "J3-TZR"]
    expected = [f"{c} {s}" for c in COLUMNS.values() for s in ("mean", "std", "rank")]
    assert list(table.columns) == [*expected, "n", "rejected"]
    assert list(table["n"].iloc[1:]) == [2, 3, 1] and list(table["rejected"].iloc[1:]) == [0, 1, 0]
    assert pd.isna(at(table, "EFD", "n"))


def test_means_and_stds_by_hand(tables: dict[str, pd.DataFrame]) -> None:
    t = tables["J2"]
    # EFD row: the reference values, B and total derived, no spread
    assert at(t, "EFD", col("B", "mean")) == 60.0 and at(t, "EFD", col("total", "mean")) == 240.0
    assert math.isnan(at(t, "EFD", col("total", "std")))
    # J2-R: seeds 0-2 (seed 3 is rejected and must not pull the means down)
    assert at(t, "J2-R", col("B-S", "mean")) == pytest.approx(9.0)
    assert at(t, "J2-R", col("B-S", "std")) == pytest.approx(1.0)
    assert at(t, "J2-R", col("B", "mean")) == pytest.approx(40.0)
    assert at(t, "J2-R", col("B", "std")) == pytest.approx(2.0)
    assert at(t, "J2-R", col("total", "mean")) == pytest.approx(151.0)
    assert at(t, "J2-R", col("total", "std")) == pytest.approx(3.0)
    # J1-R: two seeds, B-S 10 and 14
    assert at(t, "J1-R", col("B-S", "mean")) == pytest.approx(12.0)
    assert at(t, "J1-R", col("B-S", "std")) == pytest.approx(math.sqrt(8.0))
    assert at(t, "J1-R", col("B-P", "std")) == 0.0
    # J3-TZR: one seed, no standard deviation
    assert at(t, "J3-TZR", col("total", "mean")) == pytest.approx(131.0)
    assert math.isnan(at(t, "J3-TZR", col("total", "std")))


def test_best_and_second_best(tables: dict[str, pd.DataFrame]) -> None:
    t = tables["J2"]

    def ranks(subset: str) -> dict[str, Any]:
        return {case: at(t, case, col(subset, "rank")) for case in t.index}

    assert ranks("B-S")["EFD"] is pd.NA  # EFD is never ranked (its totals are the highest anyway)
    assert ranks("B-S") | {"EFD": 0} == {"EFD": 0, "J1-R": 3, "J2-R": 1, "J3-TZR": 2}
    assert ranks("B-P") | {"EFD": 0} == {"EFD": 0, "J1-R": 2, "J2-R": 3, "J3-TZR": 1}
    assert ranks("total") | {"EFD": 0} == {"EFD": 0, "J1-R": 3, "J2-R": 2, "J3-TZR": 1}
    assert set(ranks("T").values()) - {pd.NA} == {1}  # a tie: all best, no second
    shown = display_table(t, "markdown")
    assert shown.at["J2-R", "Test-B-S"] == "**9.0 (1.0)**"
    assert shown.at["J3-TZR", "Test-B-S"] == "<u>11.0</u>"
    assert shown.at["J1-R", "Test-B-S"] == "12.0 (2.8)"
    assert shown.at["EFD", "Total"] == "240.0"


def test_rejected_only_case_and_order() -> None:
    outcomes = [
        record("J3", "R", 0, scores(1, 1, 1)),
        record("J1", "TZR", 0, scores(1, 1, 1)),
        record("J2", "TR", 0, scores(1, 1, 1), rejected=True),
        record("J1", "R", 0, scores(1, 1, 1)),
        record("J1", "TR", 0, scores(1, 1, 1)),
    ]
    t = summary_tables(outcomes, {})["J1"]
    assert list(t.index) == ["J1-R", "J1-TR", "J1-TZR", "J2-TR", "J3-R"]  # no EFD given
    assert at(t, "J2-TR", "n") == 0 and at(t, "J2-TR", "rejected") == 1
    assert math.isnan(at(t, "J2-TR", col("total", "mean")))
    assert at(t, "J2-TR", col("total", "rank")) is pd.NA


def test_accepts_outcomes_and_flat_metric_records() -> None:
    objects: list[JobOutcome] = [make_outcome(seed=0, scale=1.0), make_outcome(seed=1, scale=3.0)]
    flat = []
    for o in objects:
        metrics = {f"test/{J}/{s}": v for J, row in o.test.items() for s, v in row.items()}
        flat.append({"objective": o.objective, "train": o.train, "rejected": 0.0, **metrics})
    from_objects = summary_tables(objects, EFD)["J2"]
    pd.testing.assert_frame_equal(from_objects, summary_tables(flat, EFD)["J2"])
    assert at(from_objects, "J2-R", "Total mean") == pytest.approx(230.0)  # 115 and 345
    assert at(from_objects, "J2-R", "Total std") == pytest.approx(115.0 * math.sqrt(2.0))


def test_written_files(tables: dict[str, pd.DataFrame], tmp_path: Path) -> None:
    files = write_tables(tables, tmp_path / "summary")
    names = {f"{J}.{ext}" for J in ("J1", "J2", "J3") for ext in ("csv", "parquet", "md", "html")}
    assert set(files) == names and all(p.is_file() for p in files.values())
    csv = pd.read_csv(files["J2.csv"], index_col="Case")
    assert at(csv, "J2-R", "Test-B-S mean") == pytest.approx(9.0)
    assert at(csv, "J2-R", "Test-B-S std") == pytest.approx(1.0)
    assert at(csv, "J2-R", "Test-B-S rank") == 1
    pd.testing.assert_frame_equal(pd.read_parquet(files["J2.parquet"]), tables["J2"])
    md = files["J2.md"].read_text()
    assert "| EFD" in md and "**9.0 (1.0)**" in md and "<u>11.0</u>" in md
    html = files["J2.html"].read_text()
    assert "<b>9.0 (1.0)</b>" in html and "<u>11.0</u>" in html


def test_convergence_plot(tmp_path: Path) -> None:
    path = plot_convergence(history(), tmp_path / "conv.png", title="J1-R seed 0")
    assert path.read_bytes()[:8] == PNG
    with pytest.raises(ValueError, match="empty"):
        plot_convergence([], tmp_path / "none.png")


def test_trajectory_plot(tmp_path: Path) -> None:
    t = np.linspace(0.0, 10.0, 101)
    rec = np.column_stack([np.sin(t), 0.3 + 0 * t, 1 - np.cos(t), 0 * t, t, 1.0 + 0 * t])
    sim = rec + 0.05
    sim[80:] = np.nan  # diverged
    path = plot_trajectories(rec, {"identified": sim, "EFD": rec * 1.1}, tmp_path / "tr.png", "T")
    assert path.read_bytes()[:8] == PNG
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        plot_trajectories(rec[:, :4], {}, tmp_path / "bad.png")


# ---------------------------------------------------------------- the command, on MLflow


@pytest.fixture(scope="module")
def filled_store(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A partial sweep on the session's store: three finished jobs and one failure."""
    uri = shared_store(tmp_path_factory)
    experiment = f"report-{uuid.uuid4().hex[:10]}"
    tracker = MlflowTracker(uri, experiment)
    parent = tracker.start_sweep("paper", {"seeds": [0, 1]}, EFD)
    children = [
        tracker.log_job(parent, make_outcome("J2", "R", 0, scale=1.0), None),
        tracker.log_job(parent, make_outcome("J2", "R", 1, scale=3.0), None),
        tracker.log_job(parent, make_outcome("J1", "TR", 0, scale=2.0), None),
    ]
    tracker.log_failure(parent, "objective=J3,seed=0,train=R", {}, {}, "boom")
    return {"uri": uri, "experiment": experiment, "parent": parent, "children": children}


def test_report_command_end_to_end(filled_store: dict[str, Any], tmp_path: Path, capsys) -> None:
    uri, exp, parent = filled_store["uri"], filled_store["experiment"], filled_store["parent"]
    out = tmp_path / "out"
    args = ["--tracking-uri", uri, "--experiment", exp, "--sweep", "paper", "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "J2 on the test set, sweep paper (3 jobs)" in printed
    assert "230.0 (162.6)" in printed and "EFD" in printed and "J1-TR" in printed
    table = pd.read_csv(out / "J2.csv", index_col="Case")
    assert list(table.index) == ["EFD", "J1-TR", "J2-R"]
    assert at(table, "J2-R", "Total mean") == pytest.approx(230.0)
    assert at(table, "J2-R", "n") == 2 and at(table, "EFD", "Total mean") == EFD["J2"]["total"]
    client = MlflowTracker(uri, exp).client
    logged = {a.path for a in client.list_artifacts(parent, "summary")}
    assert {"summary/J2.json", "summary/J2.md", "summary/J1.parquet"} <= logged
    assert client.get_run(parent).info.status == "RUNNING"  # a report does not end a sweep
    # the newest sweep by default, the run id explicitly, and without logging
    assert main(["--tracking-uri", uri, "--experiment", exp, "--out", str(tmp_path / "b")]) == 0
    args = ["--tracking-uri", uri, "--experiment", exp, "--run-id", parent, "--no-log"]
    assert main([*args, "--out", str(tmp_path / "c")]) == 0
    assert (tmp_path / "c" / "J3.html").is_file()


def test_report_command_errors(filled_store: dict[str, Any], tmp_path: Path, capsys) -> None:
    uri, exp = filled_store["uri"], filled_store["experiment"]
    base = ["--tracking-uri", uri, "--experiment", exp, "--out", str(tmp_path / "o")]
    assert main([*base[:4], "--run-id", filled_store["children"][0], *base[4:]]) == 2
    assert "is not a sweep" in capsys.readouterr().err
    missing = tmp_path / "none" / "mlflow.db"
    assert main(["--tracking-uri", f"sqlite:///{missing}", "--out", str(tmp_path / "o")]) == 2
    assert "no MLflow store" in capsys.readouterr().err and not missing.exists()
    # the real entry point: one line on stderr, status 2, no traceback
    proc = subprocess.run(
        [sys.executable, "-m", "sweep.report", *base[:4], "--sweep", "nope", *base[4:]],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "error: sweep 'nope' not found" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "o").exists()


def test_null_tracker_records_make_the_same_table() -> None:
    tracker = NullTracker()
    parent = tracker.start_sweep("s", {}, EFD)
    objects = [make_outcome(seed=0, scale=1.0), make_outcome(seed=1, scale=3.0)]
    for o in objects:
        tracker.log_job(parent, o, None)
    pd.testing.assert_frame_equal(
        summary_tables(tracker.job_outcomes(parent), tracker.efd_reference(parent))["J2"],
        summary_tables(objects, EFD)["J2"],
    )


def test_the_explainable_share_says_what_its_gain_is_measured_against():
    """A held-out gain of the learned shapes is measured against the base refitted on the other
    half of the runs. When that refit makes the held-out windows' J far above the base's own
    (on the real Train-R about 8 x), the report says so, and says which part of the
    gain goes beyond the base's whole J there: that part can only undo the refit's drift."""
    from sweep.diagnose.report import drift_text

    real = {
        "heldout": 9251.0,
        "base": 1166.6,
        "ratio": 9251.0 / 1166.6,
        "window": "w1",
        "share": 0.8,
    }
    text = drift_text(real, 0.6053)
    assert "7.9 x the base's own (w1: 80 % of it)" in text
    assert "with the correction it is still 3.1 x." in text
    assert "5.6e+03, is 4.8 x the base's whole J there (1.17e+03)" in text
    assert "at least 79 % of it undoes the refit's drift" in text
    # a gain within the base's J: the drift is stated, no share is claimed
    assert drift_text(real, 0.05).endswith(
        "(w1: 80 % of it); with the correction it is still 7.5 x."
    )
    # a refit that stays near the base: nothing to say
    near = {**real, "heldout": 1500.0, "ratio": 1500.0 / 1166.6}
    assert drift_text(near, 0.6) == ""
    # no correction chosen: the drift alone
    assert drift_text(real, 0.0).endswith("(w1: 80 % of it).")
    assert drift_text(None, 0.6) == ""
    # the real Train-TZR: one turning window; the lower bound is rounded down, not up to 100 %
    tzr = {"heldout": 2.9e6, "base": 1522.0, "ratio": 2.9e6 / 1522.0, "window": "w2", "share": 1.0}
    text = drift_text(tzr, 0.9)
    assert "1905 x the base's own (w2: 100 % of it); with the correction it is still 191 x." in text
    assert "at least 99 % of it" in text
