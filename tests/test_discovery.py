"""Missing physics beyond the catalog: generated effects, the noise floor, discovery end to end."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from benchmarks.planted import (
    PlantedSpec,
    generate,
    noise_levels,
    perturbed_ship,
    pick_windows,
    write_case,
)

from mmg import derivatives, efd_parameters, get_effect
from mmg.discovered import discovered_effect, effect_name
from sweep.data.recordings import Recording, read_recordings
from sweep.diagnose.__main__ import main
from sweep.diagnose.floor import NoiseModel, calibrated_noise, misfit_test, noise_floor
from sweep.diagnose.windows import cut_windows
from sweep.identification.vector import with_effects
from tests.conftest import kernels, noisy_windows, planted_case_args, probe_kernels

pytestmark = pytest.mark.kernels(
    *kernels((), "simulate", "moments", "derivatives"), *probe_kernels()
)

KINDS = ("random", "turning", "zigzag")
#: the library terms of the tests that compare forces point by point
POINT_TERMS = ("Y_vav", "E_x0", "E_y0", "N_scdnn", "Y_Usy", "N_Usy", "N_b300", "N_bt")


def point_effects() -> tuple:
    """The effects of the tests that compare derivatives point by point, in one kernel: planted
    forms and library terms side by side, each test setting its own and leaving the others at
    their neutral values, which add exactly nothing (a kernel each cost 20-30 s to compile)."""
    from benchmarks.planted import UNLISTED

    planted = tuple(UNLISTED[k] for k in ("earth_force", "wash_yaw", "reverse_sway", "bank"))
    return (*planted, discovered_effect(list(POINT_TERMS)))


#: values of the others than their neutral ones: the planted bank's neutral width, 0, would make
#: its force 0 x tanh(0 / 0) (its strength C_b = 0 still makes it vanish)
POINT_OTHERS = {"W_b": 1.0}


def point_params(p, **values: float):
    """``p`` carrying :func:`point_effects`, ``values`` by parameter name, the rest neutral."""
    effects = point_effects()
    table = [q for e in effects for q in e.params]
    unknown = set(values) - {q.name for q in table}
    assert not unknown, unknown
    given = {**POINT_OTHERS, **values}
    return with_effects(p, effects, [given.get(q.name, q.neutral) for q in table])


def point_derivatives(x, u, w, p, t: float = 0.0, **values: float) -> np.ndarray:
    """The state derivatives at one point (time ``t``) with :func:`point_params` (finite: two
    NaN in the same place would compare equal)."""
    d = derivatives(x, u, w, point_params(p, **values), point_effects(), t=np.array(t))
    assert np.all(np.isfinite(d)), d
    return d


@pytest.fixture(scope="module")
def runs(data_dir: Path) -> dict[str, list]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {k: read_recordings(data_dir / "data" / k) for k in KINDS}


@pytest.mark.integration  # compiles kernels of its own terms and forms
def test_generated_effect_adds_its_term_through_the_mass_matrix():
    """Y += 0.5 rho L d C v_m|v_m|: the sway and yaw accelerations change exactly as a force Y
    through the model's own mass matrix (x_G couples sway and yaw), surge not at all."""
    eff = get_effect(effect_name(["Y_vav"]))
    assert eff is discovered_effect(["Y_vav"]) or eff.name == "discovered:Y_vav"
    assert eff.param_names == ("C_Y_vav",)
    p = efd_parameters()
    x = np.array([0.0, 0.4, 0.0, -0.06, 0.2, 0.01])
    u = np.array([0.1, 10.0])
    w = np.array([1.0, 0.3])
    d0 = point_derivatives(x, u, w, p)
    d1 = point_derivatives(x, u, w, p, C_Y_vav=0.5)
    d2 = point_derivatives(x, u, w, p, C_Y_vav=1.0)
    assert d1[1] == pytest.approx(d0[1], abs=1e-15)
    assert d1[3] != pytest.approx(d0[3], abs=1e-9)
    np.testing.assert_allclose(d2 - d0, 2.0 * (d1 - d0), rtol=1e-9, atol=1e-15)  # linear in C
    with pytest.raises(KeyError, match="unknown library term"):
        get_effect("discovered:Y_warp")


@pytest.mark.integration  # compiles kernels of its own terms and forms
def test_a_terms_column_is_its_force_through_eq_1_without_the_rest_of_the_model():
    """effect_accelerations_rows (the last effect's forces alone through Eq. (1)) equals the
    difference of whole right-hand sides with and without them: with a current acting (the
    term sees the velocity through the water), another effect's force beside it (not counted)
    and a term that depends on time and position, each row with its own masses."""
    from mmg.integrate import derivatives_rows, effect_accelerations_rows
    from mmg.params import N_THETA, PARAMETER_NAMES

    lib = discovered_effect(["Y_vav", "N_bt", "X_x"])
    effects = (get_effect("current"), get_effect("propeller_walk"), lib)
    rng = np.random.default_rng(3)
    n = 40
    x = np.column_stack(
        [
            rng.uniform(-50, 50, n),
            rng.uniform(-0.5, 1.0, n),
            rng.uniform(-30, 30, n),
            rng.uniform(-0.2, 0.2, n),
            rng.uniform(-3, 3, n),
            rng.uniform(-0.02, 0.02, n),
        ]
    )
    u = np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-10, 15, n)])
    w = np.column_stack([rng.uniform(0, 3, n), rng.uniform(-3, 3, n)])
    t = rng.uniform(0, 900, n)
    # V_c, beta_c of the current; C_Yw, C_Nw of the propeller walk (forces of its own)
    base = np.concatenate([efd_parameters().vector(), [0.05, 0.8], [0.001, -0.0015]])
    k = base.size
    rows = np.repeat(np.concatenate([base, lib.neutral()])[None, :], 6, axis=0)
    rows[1, k] = 0.02  # C_Y_vav
    rows[2, k + 1] = -0.003  # C_N_bt (tau at its neutral value)
    rows[3, k:] = [0.01, 0.002, lib.neutral()[2], 1e-4]  # all three
    m_y = PARAMETER_NAMES.index("m_y")
    rows[4:, m_y] *= 1.25  # other masses: rows 4 (no term) and 5 (C_Y_vav) against 0 and 1
    rows[5, k] = 0.02
    got = effect_accelerations_rows(x, u, w, rows, effects, t=t)  # (6, n, 3)
    d = derivatives_rows(x, u, w, rows, effects, t=t)[..., [1, 3, 5]]
    want = d.copy()
    want[:4] -= d[0]
    want[4:] -= d[4]
    assert got.shape == (6, n, 3)
    np.testing.assert_array_equal(got[0], 0.0)  # the walk's forces are not the term's
    np.testing.assert_array_equal(got[4], 0.0)
    scale = np.abs(want).max(axis=(0, 1))
    assert np.all(scale > 0)
    for c in range(3):
        np.testing.assert_allclose(got[..., c], want[..., c], rtol=0, atol=1e-9 * scale[c])
    # (the rows of one term: surge untouched by Y_vav, yaw by it only through x_G)
    assert np.all(got[1, :, 0] == 0.0) and np.any(got[1, :, 1] != 0.0)
    assert np.abs(got[5, :, 1] - got[1, :, 1]).max() > 1e-3 * scale[1]  # the masses count
    with pytest.raises(ValueError, match="at least one effect"):
        effect_accelerations_rows(x, u, w, rows[:, :N_THETA], ())
    with pytest.raises(ValueError, match="adds no force"):
        effect_accelerations_rows(x, u, w, rows[:, : N_THETA + 2], (effects[0],))


@pytest.mark.integration  # compiles kernels of its own terms and forms
def test_earth_fixed_force_terms_are_a_basin_force_resolved_through_the_heading():
    """E_x0 and E_y0 (one coefficient each, entering X and Y) reproduce a steady force of any
    direction fixed to the basin (the planted earth_force form) at every heading."""
    from benchmarks.planted import UNLISTED

    from mmg import ESSO_OSAKA

    eff = get_effect(effect_name(["E_x0", "E_y0"]))
    assert eff.param_names == ("C_E_x0", "C_E_y0")
    assert "X += 0.5 rho L_pp d C_E_x0 U_ref^2 cos(psi)" in eff.description
    planted = UNLISTED["earth_force"]
    assert [q.name for q in planted.params] == ["F_e", "chi_e"]
    F, chi = 0.05, 2.2
    q = 0.5 * ESSO_OSAKA.rho * ESSO_OSAKA.L_pp * ESSO_OSAKA.d  # the terms' U_ref^2 is 1 m^2/s^2
    p = efd_parameters()
    u = np.array([0.1, 10.0])
    w = np.array([1.0, 0.3])
    terms = {"C_E_x0": F * np.cos(chi) / q, "C_E_y0": F * np.sin(chi) / q}
    for psi in (0.0, 0.7, -2.5, 4.0):
        x = np.array([0.0, 0.4, 0.0, -0.06, psi, 0.01])
        d0 = point_derivatives(x, u, w, p)
        d_terms = point_derivatives(x, u, w, p, **terms)
        d_true = point_derivatives(x, u, w, p, F_e=F, chi_e=chi)
        assert d_true[1] != pytest.approx(d0[1], abs=1e-9)
        np.testing.assert_allclose(d_terms, d_true, rtol=1e-9, atol=1e-14)


def test_generated_terms_take_each_angles_sine_once_and_the_wind_only_where_used():
    """The generated hook calls no C library sine (it would keep the kernel's lane loop from
    vectorising), takes the heading's and the rudder angle's sine and cosine once, builds the
    apparent wind only for a wind term, and its wind forces are those written with math's."""
    import math

    from mmg import ESSO_OSAKA
    from mmg.discovered import _source
    from mmg.library import term

    src = _source("x", [term(i) for i in ("X_wuu", "N_spsi", "E_x0", "Y_scdnn")], "K")
    assert "math.sin" not in src and "math.cos" not in src
    assert src.count("_sincos(psi)") == 1 and src.count("_sincos(delta)") == 1
    assert "apparent_wind(" in src
    lean = _source("x", [term("Y_vav")], "K")
    assert "_sincos(" not in lean and "apparent_wind(" not in lean

    eff = get_effect(effect_name(["X_wuu", "Y_wvv", "N_spsi"]))
    assert eff.force_at is not None
    sh = ESSO_OSAKA
    C = (0.3, -0.2, 0.01)
    e = eff.param_type(*C)
    q = 0.5 * sh.rho * sh.L_pp * sh.d
    wT = sh.rho_A * sh.A_T / (sh.rho * sh.L_pp * sh.d)
    wL = sh.rho_A * sh.A_L / (sh.rho * sh.L_pp * sh.d)
    for psi, gamma_T, U_T in ((0.0, 1.0, 8.0), (2.5, -0.4, 12.0), (-7.0, 3.1, 3.0)):
        u, v_m = 0.4, -0.05
        rel = gamma_T - psi
        uA = U_T * math.cos(rel) + u
        vA = U_T * math.sin(rel) + v_m
        f_X, f_Y, f_N = eff.force_at(
            0.0, 1.0, 2.0, u, v_m, 0.001, psi, 0.1, 5.0, U_T, gamma_T, e, None, sh
        )
        assert f_X == pytest.approx(q * C[0] * wT * uA * abs(uA), rel=1e-12)
        assert f_Y == pytest.approx(q * C[1] * wL * vA * abs(vA), rel=1e-12)
        assert f_N == pytest.approx(q * sh.L_pp * C[2] * math.sin(psi), rel=1e-13)


@pytest.mark.integration  # compiles kernels of its own terms and forms
def test_the_rudder_normal_force_term_is_the_planted_wash_moment_at_every_angle():
    """N_scdnn, sin(delta) cos(delta) (n_p D_p)^2, is the planted propeller-wash yaw moment
    (C_d sin(2 delta) (n_p D_p)^2, written by the planted form's own code) with C = 2 C_d at
    every rudder angle, where delta (n_p D_p)^2 and its cube only approximate it."""
    from benchmarks.planted import UNLISTED

    eff = get_effect(effect_name(["N_scdnn"]))
    assert "sin(delta) cos(delta) (n_p D_p)^2" in eff.description
    planted = UNLISTED["wash_yaw"]
    assert [q.name for q in planted.params] == ["C_d"]
    C_d = 2e-4
    p = efd_parameters()
    x = np.array([0.0, 0.4, 0.0, -0.06, 0.3, 0.01])
    w = np.array([1.0, 0.3])
    for delta in (-0.6, -0.1, 0.25, 0.61):
        u = np.array([delta, 8.0])
        d0 = point_derivatives(x, u, w, p)
        d_term = point_derivatives(x, u, w, p, C_N_scdnn=2.0 * C_d)
        d_true = point_derivatives(x, u, w, p, C_d=C_d)
        assert d_true[5] != pytest.approx(d0[5], abs=1e-9)
        np.testing.assert_allclose(d_term, d_true, rtol=1e-9, atol=1e-14)


@pytest.mark.integration  # compiles kernels of its own terms and forms
def test_the_planted_reverse_sway_is_in_the_papers_own_form():
    """The reversed propeller's side force of the planted benchmark is Eqs. (12)-(13) with their
    constant coefficients shifted (planted.IN_FORM): derivatives equal in every advance-ratio
    regime of the reversed propeller, and ahead (n_p > 0) the planted form adds nothing."""
    from benchmarks.planted import FAMILY, IN_FORM, UNLISTED, PlantedSpec

    assert FAMILY["reverse_sway"] == "in_form"
    assert PlantedSpec("reverse_sway", {"C_r": 1e-4}).expected == "none"
    planted = UNLISTED["reverse_sway"]
    assert [q.name for q in planted.params] == ["C_r"]
    C_r = 3e-4
    p = efd_parameters()
    shifted = p.replace(
        **{name: getattr(p.theta, name) + k * C_r for name, k in IN_FORM["reverse_sway"]["C_r"]}
    )
    w = np.array([0.5, 1.0])
    # J_s = u / (n_p D_p) below J_SYN, between J_SYN and J_SYN0, above J_SYN0, and astern
    for u_ship, n_p in ((0.5, -10.0), (0.15, -10.0), (0.02, -10.0), (-0.2, -8.0), (0.5, 10.0)):
        x = np.array([0.0, u_ship, 0.0, 0.03, 0.4, 0.005])
        ctl = np.array([0.1, n_p])
        d_true = point_derivatives(x, ctl, w, p, C_r=C_r)
        d_base = derivatives(x, ctl, w, p)
        d_form = derivatives(x, ctl, w, shifted if n_p < 0 else p)
        np.testing.assert_allclose(d_form, d_true, rtol=1e-10, atol=1e-14)
        assert (n_p < 0) == (abs(d_true[3] - d_base[3]) > 1e-9)


def test_noise_model_recovers_coloured_noise_and_the_floor_of_a_true_model(runs):
    """AR(1) noise (phi 0.7) on a simulated ship: sigma within 10 % on the channels that set J,
    and the floor within 15 % of the J the true model reaches; the misfit test calls the true
    model within the floor and the EFD model on a perturbed ship significant."""
    rng = np.random.default_rng(1)
    ship = perturbed_ship(rng, 0.15)
    wins = pick_windows(runs, {"random": 3, "turning": 2, "zigzag": 1}, rng)
    levels = noise_levels([r for v in runs.values() for r in v])
    clean, _ = generate(wins, ship, PlantedSpec("none"), {k: 0.0 for k in levels}, rng)
    true = NoiseModel(
        {k: 5 * levels[k] for k in levels}, dict.fromkeys(levels, 0.7)
    )  # 5 x: the floor is well above the model's own rounding
    noisy = [
        Recording(r.name, None, r.t, r.x + true.draw(rng, r.x.shape[0]), r.u, r.w) for r in clean
    ]
    windows = cut_windows(noisy)
    est = calibrated_noise(windows, ship, rng)
    for c in ("x0", "y0", "u", "v_m", "psi"):
        assert est.sigma[c] == pytest.approx(true.sigma[c], rel=0.10), c
        assert est.phi[c] == pytest.approx(0.7, abs=0.08), c
    test = misfit_test(noise_floor(ship, windows, est, rng, 8))
    assert test.ratio == pytest.approx(1.0, abs=0.15)
    assert not test.significant
    off = misfit_test(noise_floor(efd_parameters(), windows, est, rng, 8))
    assert off.significant and off.ratio > 3.0


def test_windows_that_begin_at_the_exact_state_are_told_from_recorded_ones(small_case):
    """Windows simulated from their first state, noise on every later sample: the first samples
    are found exact, and the noise copies, asked to begin as the windows do, begin exactly (the
    same numbers but the first row), by default noisy all the same; the same windows with noise
    on the first sample too, or simulated by a model off the truth, keep noisy starts (a misfit
    leans that way)."""
    from dataclasses import replace

    from sweep.diagnose.floor import FIRST_LOG_ODDS, calibrated_noise, first_sample_noise

    ship, windows, levels = small_case
    noise = NoiseModel(dict(levels.sigma), dict.fromkeys(levels.sigma, 0.6))
    noisy = noisy_windows(ship, windows, noise, 5)
    exact = [
        Recording(w.name, None, w.t, np.vstack([c.x[:1], w.x[1:]]), w.u, w.w)
        for w, c in zip(noisy, windows, strict=True)
    ]
    found = first_sample_noise(exact, ship, noise)
    assert not found.noisy and found.log_odds >= FIRST_LOG_ODDS and found.items == 3 * len(windows)
    assert first_sample_noise(noisy, ship, noise).noisy
    assert first_sample_noise(exact, efd_parameters(), noise).noisy
    assert not found.copies_exact
    a = noise.draw_many(np.random.default_rng(9), [50, 7])
    same = replace(noise, first=found).draw_many(np.random.default_rng(9), [50, 7])
    b = replace(noise, first=replace(found, copies_exact=True)).draw_many(
        np.random.default_rng(9), [50, 7]
    )
    for x, y, z in zip(a, b, same, strict=True):
        np.testing.assert_array_equal(y[0], 0.0)
        np.testing.assert_array_equal(x[1:], y[1:])
        np.testing.assert_array_equal(x, z)
    asked = calibrated_noise(exact, ship, np.random.default_rng(3), exact_starts=True).first
    assert not asked.noisy and asked.copies_exact
    default = calibrated_noise(exact, ship, np.random.default_rng(3)).first
    assert not default.noisy and not default.copies_exact
    recorded = calibrated_noise(noisy, ship, np.random.default_rng(3), exact_starts=True).first
    assert recorded.noisy and not recorded.copies_exact


def test_noise_draws_for_many_windows_are_the_sequential_draws_and_scipys_filter():
    """NoiseModel.draw_many gives the numbers of draw() called window after window, and the
    AR(1) recursion is scipy's first-order filter bit for bit (the nulls' numbers are unchanged)."""
    from scipy.signal import lfilter

    from sweep.diagnose.floor import STATES, ar1

    e = np.random.default_rng(2).normal(size=(700, 3))
    for phi in (0.0, 0.35, 0.97):
        c = np.sqrt(1.0 - phi * phi)
        ref = np.empty_like(e)
        ref[0] = e[0]
        ref[1:] = lfilter([c], [1.0, -phi], e[1:], axis=0, zi=phi * e[:1])[0]
        np.testing.assert_array_equal(ar1(e, phi), ref)
        np.testing.assert_array_equal(ar1(e[:, 1], phi), ref[:, 1])
    noise = NoiseModel(
        {c: 0.1 * (j + 1) for j, c in enumerate(STATES)},
        {c: (0.0, 0.5, 0.9)[j % 3] for j, c in enumerate(STATES)},
    )
    lengths = [1001, 37, 501, 2]
    rng = np.random.default_rng(4)
    reference = []  # one generator call per channel and window, filtered by scipy
    for n in lengths:
        x = np.empty((n, 6))
        for j, c in enumerate(STATES):
            w = rng.normal(0.0, 1.0, n)
            phi = noise.phi[c]
            if phi > 0.0 and n > 1:
                zi = phi * w[:1]
                w[1:] = lfilter([np.sqrt(1.0 - phi * phi)], [1.0, -phi], w[1:], zi=zi)[0]
            x[:, j] = noise.sigma[c] * w
        reference.append(x)
    many = noise.draw_many(np.random.default_rng(4), lengths)
    rng = np.random.default_rng(4)
    each = [noise.draw(rng, n) for n in lengths]
    for a, b, c in zip(reference, many, each, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    assert [m.shape for m in many] == [(n, 6) for n in lengths]
    assert np.std(many[0][:, 5]) == pytest.approx(0.6, rel=0.15)  # sigma of channel r


def _case(runs: dict, spec: PlantedSpec, directory: Path) -> None:
    rng = np.random.default_rng(3)
    wins = pick_windows(runs, {"random": 3, "turning": 1, "zigzag": 1}, rng)
    noise = noise_levels([r for v in runs.values() for r in v])
    recs, diverged = generate(wins, efd_parameters(), spec, noise, rng, phi=0.5)
    assert not diverged
    write_case(directory, recs[1:], recs[:1], spec, efd_parameters())


def _diagnose(case: Path, out: Path) -> dict:
    code = main(
        [
            *planted_case_args(case, out),
            "--no-tracking",
            "--no-shapes",  # (the library's terms are tested here; the shapes in test_diagnose)
        ]
    )  # fmt: skip
    assert code == 0
    return json.loads((out / "report.json").read_text())


@pytest.mark.integration  # a planted case, end to end
def test_unlisted_wave_resistance_is_discovered_reidentified_and_improves_the_test(runs, tmp_path):
    """A resistance growing with u^4 is in no catalog entry: the misfit is significantly above
    the floor, discovery proposes library terms, their joint trajectory fit passes the
    acceptance threshold calibrated on these windows, and the re-identified model with the
    discovered terms lowers J2 on the test recording; the terms are written so that the
    parameter file can be used again."""
    _case(runs, PlantedSpec("wave_resistance", {"C_w": 0.3}), tmp_path / "case")
    report = _diagnose(tmp_path / "case", tmp_path / "out")
    assert report["misfit"]["significant"] and report["misfit"]["ratio"] > 1.3
    assert report["discovery"]["proposed"]
    assert report["discovery"]["heldout_r2"] > report["discovery"]["threshold"]
    acc = report["acceptance"]
    assert acc["used"] == min(acc["quantile"], acc["ceiling"]) and acc["draws"] > 50
    assert report["verdict"] == "discovered"
    chosen = report["candidates"][0]
    assert chosen["effect"] == report["discovered"]["effect"]
    assert chosen["accepted"] and chosen["delta_bic"] <= acc["used"]
    assert chosen["improvement"] > 0.1
    before, after = report["J_before"]["J2"]["Total"], report["J_after"]["J2"]["Total"]
    assert after < 0.8 * before
    params = json.loads((tmp_path / "out" / "params_after.json").read_text())
    assert report["discovered"]["effect"] in json.dumps(params)
    assert all(t["formula"] and np.isfinite(t["value"]) for t in report["discovered"]["terms"])
    md = (tmp_path / "out" / "report.md").read_text()
    assert "noise floor" in md and "Discovery" in md and "Acceptance threshold" in md
    # the regression view: the surge residual is what the proposed terms explain
    view = report["discovery"]["regression"]
    assert view["terms"] == report["discovery"]["terms"]
    r2 = {c["channel"]: c["r2"] for c in view["channels"]}
    # (the differentiated recordings are noisy: a few per cent of the residual is signal)
    assert r2["surge (X)"] > 0.02 and r2["surge (X)"] > 3 * max(r2["sway (Y)"], r2["yaw (N)"]), r2
    assert (tmp_path / "out" / "equation_residuals.png").stat().st_size > 10_000
    assert "Regression view" in md


@pytest.mark.integration  # a planted case, end to end
def test_no_effect_with_coloured_noise_gives_none_and_no_accepted_term(runs, tmp_path):
    _case(runs, PlantedSpec("none"), tmp_path / "case")
    report = _diagnose(tmp_path / "case", tmp_path / "out")
    assert report["verdict"] == "none"
    assert not report["misfit"]["significant"]
    assert report["misfit"]["ratio"] < 1.15
    # the proposal's null is calibrated at alpha = 0.05: a proposal may pass it by chance, but
    # then the trajectory fits must reject it (the statistic is at most at the null's edge)
    disc = report["discovery"]
    assert not disc["proposed"] or disc["heldout_r2"] < 1.25 * disc["threshold"], disc
    traj = report["trajectory_discovery"]
    assert not traj["terms"] or traj["dbic"] > report["acceptance"]["used"]
    assert all(not c["accepted"] for c in report["candidates"])


def _equation_data(columns: dict[str, np.ndarray], y: np.ndarray, windows: int, rng):
    from sweep.diagnose.discover import EquationData

    n = y.size
    return EquationData(
        y=y,
        C=np.stack(list(columns.values()), axis=1),
        B=rng.normal(size=(n, 3)),
        groups=np.repeat(np.arange(windows), n // windows),
        term_ids=list(columns),
        scale=np.ones(3),
    )


def test_a_time_term_that_fits_nearly_as_well_as_a_position_term_is_proposed_beside_it():
    """Position and the time in the run drift together over a run: when the residual is a
    time term's and a position term correlated with it explains it about as well, the
    selection keeps its best set and proposes the set without position terms beside it; an
    unrelated term that explains far less is not proposed."""
    from sweep.diagnose.discover import DiscoverySettings, select

    rng = np.random.default_rng(5)
    n, windows = 1200, 12
    drift = np.repeat(rng.normal(size=windows), n // windows)  # a per-window level
    time_col = drift + 0.05 * rng.normal(size=n)
    position = drift + 0.05 * rng.normal(size=n)  # the same drift, other wiggles
    hull = rng.normal(size=n)
    y = 0.4 * time_col + 0.2 * hull + rng.normal(size=n)
    data = _equation_data({"Y_x": position, "Y_t": time_col, "Y_vv": hull}, y, windows, rng)
    sel = select(data, DiscoverySettings(max_terms=2))
    assert set(sel.terms) >= {"Y_vv"}
    assert len(sel.alternatives) == 1
    alt = sel.alternatives[0]
    other = "Y_t" if "Y_x" in sel.terms else "Y_x"
    assert other in alt.terms and alt.without in ("position", "time")
    assert alt.cv_r2 >= 0.8 * sel.cv_r2
    # without the alternatives (as in the null draws): the same selection, none beside it
    bare = select(data, DiscoverySettings(max_terms=2), with_alternatives=False)
    assert bare.terms == sel.terms and bare.alternatives == []
    # a position term unrelated to the residual's time term: nothing near as good, no alternative
    data2 = _equation_data(
        {"Y_x": rng.normal(size=n), "Y_t": time_col, "Y_vv": hull}, y, windows, rng
    )
    sel2 = select(data2, DiscoverySettings(max_terms=2))
    assert "Y_t" in sel2.terms and sel2.alternatives == []


@pytest.mark.integration  # compiles kernels of its own terms and forms
def test_a_step_across_the_basin_is_a_library_term_with_a_centre_and_a_width():
    """The position steps U^2 tanh((y0 - c) / W) (Y_Usy, N_Usy) carry their centre and width as
    named parameters: at the planted bank's values they reproduce its force exactly (Y = q C_b
    U^2 tanh((y0 - y_b) / W_b), N = -0.2 L Y), at every position; the proposal's grid lays the
    centres at quantiles of the positions and the widths at shares of their range, and the
    trajectory fits search within a box around the chosen grid point."""
    from benchmarks.planted import UNLISTED

    from mmg.discovered import with_bounds
    from mmg.library import CENTRE_QUANTILES, library_columns, shape_box, term

    eff = get_effect(effect_name(["Y_Usy", "N_Usy"]))
    assert eff.param_names == ("C_Y_Usy", "c_Y_Usy", "W_Y_Usy", "C_N_Usy", "c_N_Usy", "W_N_Usy")
    assert "U^2 tanh((y0 - c_Y_Usy) / W_Y_Usy)" in eff.description
    planted = UNLISTED["bank"]
    assert [q.name for q in planted.params] == ["C_b", "y_b", "W_b"]
    C_b, y_b, W_b = 0.003, 1.5, 2.5
    p = efd_parameters()
    u = np.array([0.1, 10.0])
    w = np.array([1.0, 0.3])
    terms = dict(zip(eff.param_names, [C_b, y_b, W_b, -0.2 * C_b, y_b, W_b], strict=True))
    for y0 in (-6.0, 0.5, 1.5, 2.0, 9.0):
        x = np.array([3.0, 0.4, y0, -0.06, 0.3, 0.01])
        d_terms = point_derivatives(x, u, w, p, 50.0, **terms)
        d_true = point_derivatives(x, u, w, p, 50.0, C_b=C_b, y_b=y_b, W_b=W_b)
        d0 = point_derivatives(x, u, w, p, 50.0)
        if y0 != y_b:
            assert abs(d_true[3] - d0[3]) > 1e-6
        np.testing.assert_allclose(d_terms, d_true, rtol=1e-9, atol=1e-14)
    # the grid: five centres at quantiles of y0, two widths each; tau on its own grid
    y0s = np.linspace(-10.0, 30.0, 401)
    cols = library_columns(["Y_Usy", "N_bt", "Y_vav"], {"x0": y0s * 0.0, "y0": y0s})
    usy = [dict(c.shape) for c in cols if c.term == "Y_Usy"]
    assert len(usy) == 10
    np.testing.assert_allclose(
        sorted({s["c"] for s in usy}), np.quantile(y0s, CENTRE_QUANTILES), rtol=1e-12
    )
    assert sorted({s["W"] for s in usy}) == pytest.approx([0.1 * 36.0, 0.3 * 36.0])
    assert [dict(c.shape)["tau"] for c in cols if c.term == "N_bt"] == [100.0, 300.0, 1000.0]
    assert [c.label for c in cols if c.term == "Y_vav"] == ["Y_vav"]
    box = shape_box(term("Y_Usy"), {"c": 2.0, "W": 1.0})
    assert box == {"c": (-1.0, 5.0), "W": (0.25, 4.0)}
    boxed = with_bounds(eff, [0.01, 0.002], {"Y_Usy": {"c": 2.0, "W": 1.0}})
    by = {q.name: q for q in boxed.params}
    assert (by["c_Y_Usy"].neutral, by["c_Y_Usy"].lower, by["c_Y_Usy"].upper) == (2.0, -1.0, 5.0)
    assert (by["C_N_Usy"].lower, by["C_N_Usy"].upper) == (-0.002, 0.002)
    assert by["W_N_Usy"] == next(q for q in eff.params if q.name == "W_N_Usy")  # untouched


def test_the_selection_takes_a_shaped_term_once_at_its_best_grid_point():
    """A term with a shape enters the regression as one column per grid point; the selection
    picks the grid point that explains the residual, never two points of the same term, and
    reports the shape it chose."""
    from mmg.library import Column
    from sweep.diagnose.discover import DiscoverySettings, EquationData, select

    rng = np.random.default_rng(3)
    n, windows = 1200, 12
    t = np.tile(np.linspace(0.0, 1500.0, n // windows), windows) + np.repeat(
        rng.uniform(0.0, 2000.0, windows), n // windows
    )
    hull = rng.normal(size=n)
    y = 2.0 * (1.0 - np.exp(-t / 300.0)) + 0.3 * hull + 0.5 * rng.normal(size=n)
    cols = [Column("Y_bt", (("tau", tau),)) for tau in (100.0, 300.0, 1000.0)]
    cols.append(Column("Y_vv"))
    C = np.stack([1.0 - np.exp(-t / tau) for tau in (100.0, 300.0, 1000.0)] + [hull], axis=1)
    data = EquationData(
        y=y,
        C=C,
        B=rng.normal(size=(n, 3)),
        groups=np.repeat(np.arange(windows), n // windows),
        term_ids=[c.term for c in cols],
        scale=np.ones(3),
        columns=cols,
    )
    sel = select(data, DiscoverySettings(max_terms=3, min_gain=0.0))
    assert sorted(sel.terms) == ["Y_bt", "Y_vv"]  # Y_bt once, although its columns correlate
    assert sel.shapes == {"Y_bt": {"tau": 300.0}}
    assert "Y_bt(tau=300 s)" in sel.labels
    alone = {str(r["term"]): float(r["cv_r2"]) for r in sel.single}
    assert alone["Y_bt(tau=300 s)"] > max(alone["Y_bt(tau=100 s)"], alone["Y_bt(tau=1000 s)"])


@pytest.mark.integration  # compiles kernels of its own terms and forms
def test_former_fixed_time_constant_terms_still_load_and_equal_the_shaped_term():
    """Parameter files of earlier versions name transients at fixed time constants
    (``discovered:N_b300``): they still load, are no longer searched, and give the force of the
    shaped term at that time constant."""
    from mmg.library import SEARCHED, TERMS

    assert "N_b300" in TERMS and "N_b300" not in SEARCHED and "N_bt" in SEARCHED
    old = get_effect(effect_name(["N_b300"]))
    new = get_effect(effect_name(["N_bt"]))
    assert old.param_names == ("C_N_b300",) and new.param_names == ("C_N_bt", "tau_N_bt")
    p = efd_parameters()
    x = np.array([3.0, 0.4, 1.0, -0.06, 0.3, 0.01])
    u = np.array([0.1, 10.0])
    w = np.array([1.0, 0.3])
    for t in (0.0, 120.0, 900.0):
        d_old = point_derivatives(x, u, w, p, t, C_N_b300=0.01)
        d_new = point_derivatives(x, u, w, p, t, C_N_bt=0.01, tau_N_bt=300.0)
        np.testing.assert_allclose(d_old, d_new, rtol=1e-12, atol=1e-15)


def test_forward_selections_batched_subsets_are_numpys_least_squares_one_at_a_time():
    """_HeldOut.r2_many solves the subsets of a step as one batch: the same held-out R^2 as
    numpy's lstsq per subset (a repeated column included), and of equal scores the last column
    enters, as max() over (r2, column) had it."""
    from sweep.diagnose.discover import _HeldOut

    rng = np.random.default_rng(4)
    m = 600
    C = rng.normal(size=(m, 6))
    C[:, 5] = C[:, 2]  # a repeated column: rank-deficient subsets
    y = C[:, 1] - 0.5 * C[:, 3] + rng.normal(size=m)
    folds = [np.arange(m) % 3 == f for f in range(3)]
    held = _HeldOut(y, C, folds)

    def loop(cols: list[int]) -> float:
        sse = 0.0
        for f in folds:
            beta = np.linalg.lstsq(C[~f][:, cols], y[~f], rcond=None)[0]
            e = y[f] - C[f][:, cols] @ beta
            sse += float(e @ e)
        return 1.0 - sse / float(y @ y)

    for chosen in ([], [1], [1, 2]):
        cands = [k for k in range(6) if k not in chosen]
        got = held.r2_many(chosen, cands)
        want = [loop([*chosen, k]) for k in cands]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)
    r2 = held.r2_many([1], [2, 5])
    assert r2[0] == r2[1]  # the repeated column scores alike
    from sweep.diagnose.discover import DiscoverySettings, _forward

    ids = ["a", "b", "c", "d", "e", "f"]
    chosen, _, _ = _forward(held, list(range(6)), DiscoverySettings(max_terms=2, min_gain=0.0), ids)
    assert chosen == [1, 3]
    dup = np.column_stack([C[:, 1], C[:, 1]])
    first, _, _ = _forward(
        _HeldOut(y, dup, folds), [0, 1], DiscoverySettings(max_terms=1), ["p", "q"]
    )
    assert first == [1]  # a tie: the last column
