"""The acceptance threshold calibrated on the data: linearised fits against real fits, the null."""

from __future__ import annotations

import numpy as np
import pytest

from mmg import get_effect
from mmg.discovered import with_bounds
from mmg.params import N_THETA
from sweep.data.recordings import Recording
from sweep.diagnose.fit import FitSettings, fit
from sweep.diagnose.linearised import Linearised
from sweep.diagnose.scoring import delta_bic, n_effective
from sweep.diagnose.threshold import CEILING, acceptance_null, heldout_parts
from sweep.identification.polish import PolishSettings
from sweep.identification.vector import with_effects
from tests.conftest import kernels, noisy_windows

pytestmark = [
    pytest.mark.integration,  # planted cases; the library's kernels
    pytest.mark.kernels(
        *kernels((), "simulate", "moments"), *kernels(("discovered:Y_one",), "simulate", "moments")
    ),
]

KINDS = ("random", "turning", "zigzag")


@pytest.fixture(scope="module")
def case(small_case):
    """Four 100-s windows of a perturbed ship (no noise yet) and the noise levels."""
    return small_case


def _planted(case, value: float, seed: int = 8):
    """The case's windows with a constant sway force Y = 0.5 rho L d C (C = value) and noise."""
    ship, windows, noise = case
    eff = with_bounds(get_effect("discovered:Y_one"), [2e-3])
    truth = with_effects(ship, (eff,), [value])
    return ship, eff, noisy_windows(truth, windows, noise, seed)


def test_trajectory_discovery_finds_the_planted_term(case):
    """Selection by held-out gain over the whole library on the trajectory
    residuals picks the constant sway force first, with its coefficient within 25 %, and its
    linearised dBIC is far below the null of the same selection on noise-only copies."""
    ship, _, data = _planted(case, 2e-4)
    _, windows, noise = case
    folds = ([0, 2], [1, 3])
    n_eff = n_effective(data, "J2")
    lin = Linearised(ship, data, folds, (), library_terms=2)
    sel = lin.select(lin.residuals(data), n_eff)
    assert sel.terms[0] == "Y_one"
    assert sel.coefficients[0] == pytest.approx(2e-4, rel=0.25)
    assert sel.heldout_gain[0] > 0
    null = acceptance_null(lin, noise, np.random.default_rng(2), n_eff=n_eff, draws=30)
    assert sel.dbic < null.per_candidate["discovered"]["quantile"] - 20.0
    # on the noise-only windows the same selection stays within its null
    clean = Linearised(ship, windows, folds, (), library_terms=2)
    noisy = [
        Recording(
            w.name, None, w.t, w.x + noise.draw(np.random.default_rng(5), w.x.shape[0]), w.u, w.w
        )
        for w in windows
    ]
    quiet = clean.select(clean.residuals(noisy), n_eff)
    assert quiet.dbic > null.per_candidate["discovered"]["quantile"] - 5.0


def test_linearised_fits_predict_the_real_fits(case):
    """A term in no catalog (a constant sway force Y = 0.5 rho L d C) is in the data: the linearised
    control and candidate fits of :class:`Linearised` give the J and the gain that the
    diagnosis' real fits (Levenberg-Marquardt on 57 + 1 parameters with the prior, per fold)
    reach, and so the same dBIC."""
    ship, eff, data = _planted(case, 2e-4)
    folds = ([0, 2], [1, 3])
    n_eff = n_effective(data, "J2")
    lin = Linearised(ship, data, folds, (eff,))
    R = lin.residuals(data)[..., None]
    J0, gains = lin.gains(R)
    gain = float(gains[eff.name][0][0])
    predicted = float(lin.dbic(R, n_eff)[eff.name][0])

    polish = PolishSettings(
        max_iterations=40, rtol=1e-6, max_evaluations=10**6, prior_weight=1.0, prior_dims=N_THETA
    )
    settings = FitSettings(budget=0, effect_only_budget=40, polish=polish)
    J_control = J_effect = 0.0
    for idx in folds:
        recs = [data[i] for i in idx]
        J_control += fit(recs, ship, (), settings, prior_center=ship).f
        J_effect += fit(recs, ship, (eff,), settings, prior_center=ship).f
    real = delta_bic(J_effect, J_control, 1, n_eff)
    assert gain > 0.1 * float(J0[0])  # the term matters: the test is not about noise
    assert J_control == pytest.approx(float(J0[0]), rel=0.10)
    assert J_control - J_effect == pytest.approx(gain, rel=0.15)
    assert real == pytest.approx(predicted, rel=0.15)


def test_null_of_the_best_candidate_on_noise_only_windows(case):
    """Noise only: each catalog candidate's null dBIC sits near its BIC penalty (median above
    0), the library's look-elsewhere makes the discovered candidate's null reach lower than any
    single catalog effect's, and the threshold used is the quantile capped at the ceiling."""
    ship, windows, noise = case
    rng = np.random.default_rng(4)
    cands = tuple(get_effect(n) for n in ("current", "rudder_offset", "propeller_walk"))
    n_eff = n_effective(windows, "J2")
    lin = Linearised(ship, windows, ([0, 2], [1, 3]), cands, library_terms=3)
    null = acceptance_null(lin, noise, rng, n_eff=n_eff, draws=60, alpha=0.05)
    per = null.per_candidate
    for name in ("current", "rudder_offset", "propeller_walk"):
        k = len(get_effect(name).params)
        assert 0.0 < per[name]["median"] < k * np.log(n_eff) + 1e-9, name
    assert per["discovered"]["quantile"] < min(per[n]["quantile"] for n in per if n != "discovered")
    assert null.quantile == pytest.approx(float(np.quantile(null.best, 0.05)))
    assert null.threshold == min(null.quantile, CEILING)
    assert -30.0 < null.quantile < 10.0
    d = null.as_dict()
    assert d["draws"] == 60 and d["best_dbic"]["min"] <= d["best_dbic"]["median"]
    # the refit of the 57 parameters takes part of the noise out: the floor of a fitted model
    assert 0.3 < null.refit_factor < 1.0
    # ... and all of a residual that a change of the parameters explains (up to the prior)
    A = lin.A  # (S, M, 57)
    step = 1e-3 * np.ones(N_THETA)
    R = (A @ step)[..., None]  # (S, M, 1): the residual of the parameters moved by 1e-3
    assert lin.refit_factor(R) < 0.05


def test_the_nulls_copies_side_by_side_give_the_same_figures_on_any_machine(case):
    """The held-out fits of noise-only copies in parts on the threads of the process: the same
    figures, to the last bit, on one thread as on several, and those of all copies at once to
    rounding."""
    ship, windows, _ = case
    cands = tuple(get_effect(n) for n in ("current", "rudder_offset"))
    lin = Linearised(ship, windows, ([0, 2], [1, 3]), cands, library_terms=2)
    S, M = lin.A.shape[:2]
    R = np.random.default_rng(5).normal(size=(S, M, 7))
    n_eff = n_effective(windows, "J2")
    whole = lin.heldout(R, n_eff)
    one, two = (heldout_parts(lin, R, n_eff, threads) for threads in (1, 2))
    assert list(one.dbic) == list(two.dbic) == list(whole.dbic)
    for name, v in whole.dbic.items():
        np.testing.assert_array_equal(one.dbic[name], two.dbic[name])
        np.testing.assert_allclose(two.dbic[name], v, rtol=1e-12, atol=1e-12)
    for field in ("gain", "worst_run"):
        a, b, c = (getattr(h, field) for h in (one, two, whole))
        np.testing.assert_array_equal(a, b)
        np.testing.assert_allclose(b, c, rtol=1e-12, atol=1e-12)


def test_a_fit_with_the_effect_held_refits_the_base_alone(case):
    """The transfer check's fit (``fixed_effects``): the effect stays at the value it starts
    with while the 57 base parameters move; held at the planted value it fits the data better
    than held at zero (the base alone makes up only part of the force)."""
    ship, eff, data = _planted(case, 2e-4)
    polish = PolishSettings(
        max_iterations=15, rtol=1e-6, max_evaluations=10**6, prior_weight=1.0, prior_dims=N_THETA
    )
    settings = FitSettings(budget=0, effect_only_budget=40, polish=polish, fixed_effects=True)
    right = fit(data, with_effects(ship, (eff,), [2e-4]), (eff,), settings, prior_center=ship)
    none = fit(data, with_effects(ship, (eff,), [0.0]), (eff,), settings, prior_center=ship)
    assert dict(dict(right.params.effects)[eff.name])["C_Y_one"] == pytest.approx(2e-4, rel=1e-6)
    assert dict(dict(none.params.effects)[eff.name])["C_Y_one"] == pytest.approx(0.0, abs=1e-10)
    assert right.params.theta != ship.theta  # the base did move
    assert right.f < 0.8 * none.f


def test_the_refit_drift_is_what_the_control_s_fold_fits_make_of_the_other_fold(case):
    """:meth:`Linearised.refit_drift`: the control fitted on one fold's windows (57 parameters,
    the prior) and judged on the other's, both ways round: its held-out J is what the real fold
    fits (Levenberg-Marquardt) give on the held-out windows, its base J the base model's J on
    all windows, and its worst window one of them with its share."""
    from sweep.data.objective import Objective

    ship, _, data = _planted(case, 2e-4)
    folds = ([0, 2], [1, 3])
    lin = Linearised(ship, data, folds, ())
    drift = lin.refit_drift(lin.residuals(data))

    polish = PolishSettings(
        max_iterations=40, rtol=1e-6, max_evaluations=10**6, prior_weight=1.0, prior_dims=N_THETA
    )
    settings = FitSettings(budget=0, effect_only_budget=40, polish=polish)
    held = 0.0
    for fitted, judged in (folds, folds[::-1]):
        refit = fit([data[i] for i in fitted], ship, (), settings, prior_center=ship).params
        held += float(Objective([data[i] for i in judged], "J2").evaluate(refit)[0])
    base = float(Objective(data, "J2").evaluate(ship)[0])
    assert drift.base == pytest.approx(base, rel=1e-6)
    assert drift.heldout == pytest.approx(held, rel=0.10)
    assert drift.ratio == pytest.approx(drift.heldout / base)
    assert drift.window in {w.name for w in data}
    assert 0.25 <= drift.share <= 1.0  # four windows: the worst carries at least a quarter


def test_a_linearisation_with_another_prior_is_the_one_built_with_it(case):
    """:meth:`Linearised.with_prior`: the fold fits with another prior weight are those of a
    linearisation built with that weight, and the one it came from keeps its own."""
    ship, _, data = _planted(case, 2e-4)
    folds = ([0, 2], [1, 3])
    lin = Linearised(ship, data, folds, ())
    r = lin.residuals(data)
    before = lin.refit_drift(r)
    heavy = lin.with_prior(100.0).refit_drift(r)
    built = Linearised(ship, data, folds, (), prior_weight=100.0).refit_drift(r)
    assert heavy.heldout == pytest.approx(built.heldout, rel=1e-9)
    assert heavy.heldout != pytest.approx(before.heldout, rel=1e-6)
    assert lin.refit_drift(r).heldout == before.heldout
