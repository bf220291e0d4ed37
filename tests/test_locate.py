"""Residuals per run, window and regime (missing-physics groundwork)."""

from __future__ import annotations

import numpy as np
import pytest

from mmg import efd_parameters, simulate
from sweep.data.datasets import load_split
from sweep.data.recordings import Recording
from sweep.diagnose.locate import CHANNELS, locate, rank_windows, residual_frame
from tests.conftest import SHARED_EFFECTS, kernels, shared_effects

#: the planted walk in the shared effects' kernel
pytestmark = pytest.mark.kernels(
    *kernels((), "simulate", "derivatives"), *kernels(SHARED_EFFECTS, "simulate", "derivatives")
)


def _synthetic(rec: Recording, p) -> Recording:
    traj = simulate(rec.x[None, 0], rec.u[None, :-1], rec.w[None, :-1], p)[0]
    return Recording(rec.name, None, rec.t, traj, rec.u, rec.w)


def test_the_true_model_leaves_no_residual_and_a_wrong_one_is_located(data_dir):
    test = load_split("paper").load(data_dir)
    truth = efd_parameters().replace(N_r=-0.09)
    recs = [_synthetic(test["Test-B-P"], truth), _synthetic(test["Test-Z"], truth)]
    same = residual_frame(truth, recs)
    windows = same.groupby("run")["window"].nunique()
    # consecutive windows share their boundary sample
    assert len(same) == sum(r.n_samples + windows[r.name] - 1 for r in recs)
    assert np.nanmax(np.abs(same[[f"res_{c}" for c in CHANNELS]].to_numpy())) < 1e-6
    wrong = residual_frame(efd_parameters(), recs)
    scores = locate(wrong)
    assert scores and all(0.0 <= s.eta2 <= 1.0 for s in scores)
    top = rank_windows(wrong, "velocity", top=3)
    assert list(top["energy"]) == sorted(top["energy"], reverse=True)
    assert top["energy"].iloc[0] > 0.01


def test_equation_residuals_locate_a_planted_propeller_walk(data_dir):
    """Side force of the propeller going ahead, planted and hidden in noise: located at n_p > 0."""
    from mmg import Parameters
    from sweep.diagnose.locate import equation_residuals, locate_bias

    walk = shared_effects()  # propeller_walk, the others neutral
    planted = Parameters(
        efd_parameters().theta, effects=(("propeller_walk", (("C_Yw", 4e-4), ("C_Nw", -2e-4))),)
    )
    test = load_split("paper").load(data_dir)
    rng = np.random.default_rng(0)
    noise = np.array([0.01, 0.002, 0.01, 0.002, 0.002, 0.0005])  # like the recordings' jitter
    recs = []
    for label in ("Test-B-S", "Test-B-P", "Test-Z", "Test-R"):
        rec = test[label]
        traj = simulate(rec.x[None, 0], rec.u[None, :-1], rec.w[None, :-1], planted, effects=walk)
        x = traj[0] + rng.normal(size=traj[0].shape) * noise
        recs.append(Recording(label, None, rec.t, x, rec.u, rec.w))
    scores = locate_bias(equation_residuals(efd_parameters(), recs))
    top = scores[0]
    assert top.variable in ("n_p", "quadrant") and top.channel in ("v_dot", "r_dot")
    assert top.bin in ("[0.5, 5.0)", "[5.0, 10.0)", "[10.0, 25.0)", "[0.5, 1.5)")
    assert abs(top.t) > 4
    # without the planted effect, no bin stands out as strongly
    clean = [Recording(r.name, None, r.t, r.x, r.u, r.w) for r in recs]
    honest = locate_bias(equation_residuals(planted, clean, effects=walk))
    assert abs(honest[0].t) < abs(top.t) / 2


def test_heading_time_and_position_are_regime_variables():
    """A residual that grows with the time in the run (a slow drift of the basin, say) is
    located by ``t_run`` (quintile bins) ahead of every other variable; heading is binned too."""
    import pandas as pd

    rng = np.random.default_rng(0)
    n = 5000
    frame = pd.DataFrame(
        {
            "beta_deg": rng.uniform(0, 180, n),
            "quadrant": rng.integers(1, 5, n),
            "delta_deg": rng.uniform(0, 40, n),
            "gamma_A_deg": rng.uniform(0, 180, n),
            "U": rng.uniform(0, 0.5, n),
            "n_p": rng.uniform(-20, 20, n),
            "psi_deg": rng.uniform(0, 360, n),
            "x0": rng.uniform(-10, 10, n),
            "y0": rng.uniform(-5, 5, n),
            "t_run": rng.uniform(0, 900, n),
            "u_dot": rng.normal(0, 0.01, n),
            "r_dot": rng.normal(0, 0.1, n),
        }
    )
    for c in CHANNELS:
        frame[f"res_{c}"] = rng.normal(0, 1, n) * (1 + 3 * (frame["t_run"] > 700))
    scores = locate(frame)
    assert scores[0].variable == "t_run" and scores[0].eta2 > 0.2
    assert {"psi_deg", "x0", "y0", "u_dot", "r_dot"} <= {s.variable for s in scores}
    assert max(s.eta2 for s in scores if s.variable != "t_run") < 0.05
