"""Residuals per run, window and regime (missing-physics groundwork)."""

from __future__ import annotations

import numpy as np

from mmg import efd_parameters, simulate
from sweep.datasets import load_split
from sweep.diagnose.locate import CHANNELS, locate, rank_windows, residual_frame
from sweep.recordings import Recording


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
