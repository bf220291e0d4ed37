"""`python -m sweep.evaluate` end to end on the real test set, and its errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mmg import efd_parameters
from sweep.evaluate import TEST_COLUMNS, main
from tests.conftest import kernels

pytestmark = pytest.mark.kernels(*kernels((), "moments", "simulate", "derivatives"))

SHIPPED = Path(__file__).resolve().parents[1] / "results" / "best_params.json"


def test_efd_on_the_real_test_set(data_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MMG_DATA_DIR", str(data_dir))
    out = tmp_path / "efd.json"
    assert main(["--params", "efd", "--set", "test", "--json", str(out)]) == 0
    table = json.loads(out.read_text())
    assert list(table) == ["J1", "J2", "J3"]
    for J in table:
        assert list(table[J]) == list(TEST_COLUMNS)
        row = table[J]
        assert row["Test-B-S + Test-B-P"] == pytest.approx(row["Test-B-S"] + row["Test-B-P"])
        parts = ["Test-B-S", "Test-B-P", "Test-R", "Test-T", "Test-Z"]
        assert row["Total"] == pytest.approx(sum(row[c] for c in parts))
    for c in TEST_COLUMNS:
        assert table["J2"][c] == pytest.approx(table["J1"][c] + table["J3"][c], rel=1e-12)
    # the EFD figures of this implementation (README); the paper's are 1441.1 / 3637.9 / 2196.9
    assert table["J2"]["Total"] == pytest.approx(5498.6, abs=0.1)
    printed = capsys.readouterr().out
    assert "Test-B-S + Test-B-P" in printed and "5498.6" in printed


def test_parameters_file_and_recordings_directory(data_dir, tmp_path):
    p = efd_parameters().replace(a_H=0.2)
    p.save_json(tmp_path / "p.json")
    out = tmp_path / "j.json"
    args = ["--params", str(tmp_path / "p.json"), "--json", str(out)]
    rc = main([*args, "--recordings", str(data_dir / "data/berthing")])
    assert rc == 0
    table = json.loads(out.read_text())
    assert set(table["J1"]) == {
        "berthing_12-Nov-2020_11_49_21.csv",
        "berthing_12-Nov-2020_13_21_03.csv",
        "Total",
    }


def test_bad_parameter_file_exits_2_with_its_name(tmp_path, capsys, data_dir):
    bad = tmp_path / "bad.json"
    bad.write_text('{"theta": {"m_x": "heavy"}}')
    rc = main(["--params", str(bad), "--recordings", str(data_dir / "data/berthing")])
    err = capsys.readouterr().err
    assert rc == 2 and str(bad) in err and "missing parameter" in err


def test_malformed_recording_exits_2_naming_file_column_and_row(tmp_path, capsys, data_dir):
    src = data_dir / "data/berthing/berthing_12-Nov-2020_13_21_03.csv"
    lines = src.read_text().splitlines()[:400]
    cells = lines[200].split(",")
    cells[7] = "fast"  # n_prop [rps]
    lines[200] = ",".join(cells)
    bad = tmp_path / "broken.csv"
    bad.write_text("\n".join(lines) + "\n")
    rc = main(["--params", "efd", "--recordings", str(bad)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "broken.csv" in err and "n_prop" in err and "200" in err


def test_missing_data_root_is_explained(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MMG_DATA_DIR", str(tmp_path / "nowhere"))
    assert main(["--params", "efd", "--set", "test"]) == 2
    assert "python -m sweep.download" in capsys.readouterr().err


def test_command_line_entry_point_has_no_traceback(tmp_path, data_dir):
    shutil.copy(data_dir / "data/berthing/berthing_12-Nov-2020_13_21_03.csv", tmp_path / "a.csv")
    bad = tmp_path / "nonexistent.json"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "sweep.evaluate",
            "--params",
            str(bad),
            "--recordings",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "nonexistent.json" in proc.stderr


def test_a_source_is_required_and_manoeuvre_flags_need_manoeuvres(capsys):
    for argv in (["--params", "efd"], ["--params", "efd", "--set", "test", "--figure", "f.png"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--manoeuvres is required" in err and "go with --manoeuvres" in err


def test_manoeuvre_intervals_from_the_parameters_own_uncertainty(data_dir, tmp_path, capsys):
    """--intervals: the shipped model's intervals on the training set its file names (Train-R,
    J1), drawn with a seed: the same seed gives the same table; EFD and a file that names no
    training set are refused with a message."""
    args = ["--params", str(SHIPPED), "--manoeuvres", "--data-root", str(data_dir), "--draws", "4"]
    out = tmp_path / "m.json"
    assert main([*args, "--intervals", "--seed", "3", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "4 draws (seed 3)" in printed and "on set R with J1" in printed
    report = json.loads(out.read_text())["manoeuvres"]
    advance = next(r for r in report["standard"] if r["key"] == "turning.advance")
    assert 0 < advance["samples"] <= 4 and advance["lo"] <= advance["hi"]
    assert {r["inside"] for r in report["recorded"]} <= {True, False, None}
    again = tmp_path / "again.json"
    assert main([*args, "--intervals", "R", "--objective", "J1", "--seed", "3",
                 "--json", str(again)]) == 0  # fmt: skip
    assert json.loads(again.read_text())["manoeuvres"] == report
    capsys.readouterr()
    assert main(["--params", "efd", "--manoeuvres", "--intervals", "R"]) == 2
    assert "no identification uncertainty" in capsys.readouterr().err
    bare = tmp_path / "p.json"
    efd_parameters().save_json(bare)
    assert main(["--params", str(bare), "--manoeuvres", "--intervals"]) == 2
    assert "names no training set" in capsys.readouterr().err
