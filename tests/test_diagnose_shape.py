"""A form no library term expresses, learned as a shape, end to end (its own file, so that the
test runner can give it a worker of its own beside the other end-to-end diagnoses)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from benchmarks.planted import generate, noise_levels, pick_windows, unforeseen_spec, write_case

from mmg import efd_parameters
from tests.conftest import kernels
from tests.planted_cases import read_runs, run_diagnosis

pytestmark = pytest.mark.kernels(*kernels((), "simulate", "moments", "derivatives"))


@pytest.fixture(scope="module")
def runs(data_dir: Path) -> dict[str, list]:
    return read_runs(data_dir)


@pytest.mark.integration  # a planted case, end to end
@pytest.mark.kernels(*kernels(("rudder_offset",), "simulate", "moments"))
def test_a_form_no_library_term_expresses_is_learned_as_a_shape_end_to_end(runs, tmp_path):
    """Cross-flow drag that sets in beyond a drift angle of 30 deg (a hinge in |sin beta|, of
    the planted set no library term expresses): no catalog candidate and no library term (off
    here) fits it; the learned shape of the side force and yaw moment in the drift angle is
    found, fitted with the 57 parameters, accepted, named or plotted, and the re-identified
    model fits the test recording better."""
    # random runs only: their slow, crabbing stretches pass 30 deg of drift in every window, so
    # that each half of the windows sees the hinge
    rng = np.random.default_rng(3)
    wins = pick_windows(runs, {"random": 5}, rng)
    noise = noise_levels([r for v in runs.values() for r in v])
    spec = unforeseen_spec("drift_hinge", 2.0)
    recs, diverged = generate(wins, efd_parameters(), spec, noise, rng)
    assert not diverged
    case = tmp_path / "case"
    write_case(case, recs[1:], recs[:1], spec, efd_parameters())
    out = tmp_path / "out"
    args = ("--no-tracking", "--no-discovery", "--candidates", "rudder_offset")
    assert run_diagnosis(case, out, *args) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["shapes"]["proposed"]
    # the random runs are of one day: the shapes use the ship's state and controls alone
    assert "beta" in report["shapes"]["variables"]
    assert not {"psi", "x0", "y0", "t"} & set(report["shapes"]["variables"])
    assert report["verdict"] == "shape", report["statement"]
    groups = report["shape"]["groups"]
    assert {g["variable"] for g in groups} & {"beta", "v", "rp"}
    # named afterwards: the closest closed forms were fitted as a candidate of their own; the
    # finding is the formula or the shape, with its confidence band and its closest forms
    form = report["shapes"]["form"]
    assert form and form in {c["effect"] for c in report["candidates"]}
    assert all(g["closest"] or g["closed_form"] or g["variable"] == "1" for g in groups)
    assert all(g["band"] and min(g["band"]) > 0 for g in groups if g["variable"] != "1")
    assert (out / "shapes.png").stat().st_size > 0
    md = (out / "report.md").read_text()
    assert "## Learned shape of the missing force" in md
    assert "(without heading, position and time, which one session's runs cannot check)" in md
    before, after = report["J_before"]["J2"]["Total"], report["J_after"]["J2"]["Total"]
    assert after < before
    # the learned shape is rebuilt from its name: the parameter file evaluates elsewhere
    from sweep.evaluate import run as evaluate_run

    table = evaluate_run(
        ["--params", str(out / "params_after.json"), "--recordings", str(case / "test")]
    )
    assert table["J2"]["Total"] == pytest.approx(after, rel=1e-9)
