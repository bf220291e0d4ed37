"""The identification job end to end (small budgets): outputs, resume, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmg import Parameters, efd_parameters, simulate
from sweep.data.objective import Objective
from sweep.data.recordings import Recording, read_recording
from sweep.identification.cmaes import Settings
from sweep.identify import identify, main
from tests.conftest import kernels

pytestmark = pytest.mark.kernels(*kernels((), "simulate", "moments"))


@pytest.fixture(scope="module")
def berthing(data_dir):
    return read_recording(data_dir / "data/berthing/berthing_12-Nov-2020_13_21_03.csv")


def test_identification_recovers_a_planted_change(berthing):
    """Synthetic berthing run with four hull/rudder parameters changed: J2 must fall by 80 %.

    Measured: J2 of EFD 64.5, identified 4.1 after 2,000 evaluations (seed 0)."""
    truth = efd_parameters().replace(N_r=-0.12, Y_v=-0.9, C_D=2.0, a_H=0.8)
    n = 601
    traj = simulate(
        berthing.x[None, 0], berthing.u[None, : n - 1], berthing.w[None, : n - 1], truth
    )
    rec = Recording("synthetic", None, berthing.t[:n], traj[0], berthing.u[:n], berthing.w[:n])
    J_efd = Objective([rec], "J2").evaluate(efd_parameters())[0]
    result, best = identify([rec], "J2", Settings(seed=0, max_evaluations=2000, sigma0=0.05))
    assert J_efd > 50.0
    assert result.f < 0.2 * J_efd
    assert Objective([rec], "J2").evaluate(best)[0] == pytest.approx(result.f, rel=1e-9)


def test_command_writes_outputs_and_resumes(data_dir, tmp_path, capsys):
    rec_path = data_dir / "data/berthing/berthing_12-Nov-2020_13_21_03.csv"
    out = tmp_path / "job"
    args = ["--train", str(rec_path), "--objective", "J1", "--budget", "200", "--out", str(out)]
    assert main(args) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["evaluations"] == 200 and result["stop_reason"] == "budget"
    assert result["restarts"][0]["popsize"] == 20
    best = Parameters.load_json(out / "best_params.json")
    assert np.all(np.isfinite(best.vector()))
    history = (out / "history.csv").read_text().splitlines()
    assert history[0].startswith("restart,popsize,generation,evaluations,best_f")
    assert len(history) == 1 + 10
    # how well the recording determines each parameter, beside the parameters
    intervals = json.loads((out / "uncertainty.json").read_text())
    assert len(intervals["parameters"]) == 57 and 0.0 <= intervals["fraction_determined"] <= 1.0
    assert "determined" in (out / "uncertainty.md").read_text()
    assert "intervals:" in capsys.readouterr().out
    # a second run finds the finished checkpoint and returns the same result at once
    assert main(args) == 0
    again = json.loads((out / "result.json").read_text())
    assert again["f"] == result["f"]


def test_bad_training_input_is_reported(tmp_path, capsys):
    bad = tmp_path / "x.csv"
    bad.write_text("t [s],foo\n0,1\n")
    assert main(["--train", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "x.csv" in capsys.readouterr().err
