"""Memory shapes: the share of a control's gap that the acting control leaves open in a step,
learnt as a spline of the gap (:mod:`mmg.shapes`, groups ``D~ed`` and ``P~en``)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from scipy.optimize import least_squares

from mmg import Effect, efd_parameters, get_effect
from mmg.shapes import (
    CONTROLS,
    Group,
    basis,
    groups_of,
    probe_effect,
    probe_rows,
    shape_effect,
    variable_values,
)
from sweep.data.recordings import Recording

#: a force group and both memories: the hooks of both kinds in one effect
SPEC = "shape:N~beta[-0.5:0.5]/5+D~ed[-4:4]/10+P~en[-4:4]/6"
DT = 0.1


def _acting(log: np.ndarray, step: Callable[[float, float], float]) -> np.ndarray:
    """The acting sequence of a logged one through step(log_k, acting_(k-1))."""
    out = np.empty(len(log))
    out[0] = log[0]
    for k in range(1, len(log)):
        out[k] = step(log[k], out[k - 1])
    return out


def test_a_memory_group_leaves_its_share_of_the_gap_open() -> None:
    """delta = delta_log - e_delta f_D(z_delta), z = asinh(e / 1 deg); n_p likewise with
    0.5 rev/s; the force group stays in the force hook; neutral coefficients change nothing."""
    eff = get_effect(SPEC)
    assert eff.force_at is not None and eff.inputs is not None
    assert "memory of the controls" in eff.description
    gD, gP = Group("D", "ed", -4.0, 4.0, 10), Group("P", "en", -4.0, 4.0, 6)
    rng = np.random.default_rng(3)
    values = rng.normal(0.0, 0.3, len(eff.params))
    e = eff.param_type(*values)
    for d_log, d_prev, n_log, n_prev in ((0.3, 0.0, 10.0, 9.0), (-0.02, 0.01, -5.0, 10.0)):
        gap_d, gap_n = d_log - d_prev, n_log - n_prev
        want_d = d_log - gap_d * float(
            basis(gD, [math.asinh(gap_d / math.radians(1))])[0] @ values[5:15]
        )
        want_n = n_log - gap_n * float(basis(gP, [math.asinh(gap_n / 0.5)])[0] @ values[15:])
        got = eff.inputs(d_log, n_log, d_prev, n_prev, DT, e)
        assert got == pytest.approx((want_d, want_n), rel=1e-12)
        assert eff.inputs(d_log, n_log, d_prev, n_prev, DT, eff.param_type(*eff.neutral())) == (
            d_log,
            n_log,
        )
    assert eff.params[5].name == "s1_D0"
    assert "delta = delta_log - e_delta f_D1(z_delta)  [rad]" in eff.params[5].description
    assert CONTROLS["P"].quantum == 0.5


def test_the_probe_gives_the_acting_control_of_each_coefficient() -> None:
    """The probe's inputs hook (G, C = 3 or 4, J, A) is the memory with that one coefficient at
    A; its force hook gives nothing for a memory's row, and the force rows move no control."""
    p = efd_parameters()
    eff, probe = get_effect(SPEC), probe_effect(SPEC)
    rows = probe_rows(eff, 0.4)
    assert rows.shape == (21, 7) and rows[5].tolist()[:4] == [1.0, 3.0, 0.0, 0.4]
    assert rows[15].tolist()[:4] == [2.0, 4.0, 0.0, 0.4]
    assert rows[5].tolist()[4:6] == [groups_of(eff)[1].lo, groups_of(eff)[1].hi]
    assert probe.inputs is not None and probe.force_at is not None and eff.inputs is not None
    for d_log, d_prev, n_log, n_prev in ((0.3, 0.05, 10.0, 9.0), (-0.1, 0.01, -5.0, 8.0)):
        for i, row in enumerate(rows):
            values = np.zeros(21)
            values[i] = 0.4
            want = eff.inputs(d_log, n_log, d_prev, n_prev, DT, eff.param_type(*values))
            got = probe.inputs(d_log, n_log, d_prev, n_prev, DT, probe.param_type(*row))
            assert got == pytest.approx(want, rel=1e-12), i
            if i >= 5:
                force = probe.force_at(
                    1.0, 0.0, 0.0, 0.5, 0.05, 0.01, 0.0, 0.1, 10.0, 0.0, 0.0,
                    probe.param_type(*row), p.theta, p.ship,
                )  # fmt: skip
                assert force == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    ("kind", "size"), [("rate", 0.8727), ("rate", 0.2), ("play", 0.03), ("lag", 0.5)]
)
def test_a_memory_shape_expresses_rate_limits_play_and_lags(kind: str, size: float) -> None:
    """Fitted to the acting rudder of a rate-limited gear (50 and 11 deg/s), of a gear with
    1.7 deg of play and of a first-order lag (0.5 s), through the hook itself, 16 basis
    functions over a 40 deg command's gap leave an error in the acting angle of less than a
    fifth of a degree (rms), 10 to 60 x less than the log's."""
    rng = np.random.default_rng(1)
    holds: list[float] = []
    while len(holds) < 1500:
        holds += [rng.uniform(-0.61, 0.61)] * int(rng.integers(30, 150))
    log = np.round(np.array(holds[:1500]) / 0.0098) * 0.0098  # the log's 0.56-deg steps
    planted = {
        "rate": lambda lg, pv: pv + np.clip(lg - pv, -size * DT, size * DT),
        "play": lambda lg, pv: max(lg - size, min(lg + size, pv)),
        "lag": lambda lg, pv: pv + (1.0 - math.exp(-DT / size)) * (lg - pv),
    }[kind]
    truth = _acting(log, planted)
    z_max = math.asinh(0.7 / math.radians(1.0))
    eff = shape_effect([Group("D", "ed", -z_max, z_max, 16)])
    assert eff.inputs is not None
    hook = eff.inputs

    def residual(c: np.ndarray) -> np.ndarray:
        e = eff.param_type(*c)
        return _acting(log, lambda lg, pv: hook(lg, 10.0, pv, 10.0, DT, e)[0]) - truth

    assert eff.bounds == ((0.0,) * 16, (1.0,) * 16)  # the share lies in [0, 1]
    fit = least_squares(residual, np.full(16, 0.5), bounds=eff.bounds, max_nfev=100)
    rms = math.degrees(float(np.sqrt(np.mean(fit.fun**2))))
    before = math.degrees(float(np.sqrt(np.mean((log - truth) ** 2))))
    assert rms < 0.2 and rms < before / 8.0, (rms, before)


def _planted_log(kind: str, size: float) -> tuple[np.ndarray, np.ndarray]:
    """A logged rudder (holds of 3-15 s at angles within +-35 deg, in the log's 0.56-deg steps)
    and the acting rudder of a gear of ``kind`` (rate [rad/s], play [rad], lag [s])."""
    rng = np.random.default_rng(1)
    holds: list[float] = []
    while len(holds) < 1500:
        holds += [rng.uniform(-0.61, 0.61)] * int(rng.integers(30, 150))
    log = np.round(np.array(holds[:1500]) / 0.0098) * 0.0098
    planted = {
        "rate": lambda lg, pv: pv + np.clip(lg - pv, -size * DT, size * DT),
        "play": lambda lg, pv: max(lg - size, min(lg + size, pv)),
        "lag": lambda lg, pv: pv + (1.0 - math.exp(-DT / size)) * (lg - pv),
    }[kind]
    return log, _acting(log, planted)


@pytest.mark.parametrize(
    ("kind", "size"), [("rate", 0.8727), ("rate", 0.2), ("play", 0.03), ("lag", 0.5)]
)
def test_a_memory_spline_is_named_by_its_closed_form(kind: str, size: float) -> None:
    """A memory spline fitted to a rate-limited gear, to a gear with play and to a lag is closest
    to that family (:func:`sweep.diagnose.naming.memory_forms`), with its size; the closed form
    fitted through its own hook then reproduces the acting rudder to a hundredth of a degree,
    and its report states the gear in the control's terms."""
    from sweep.diagnose.naming import memory_forms

    log, truth = _planted_log(kind, size)
    z_max = math.asinh(0.7 / math.radians(1.0))
    spline = Group("D", "ed", -z_max, z_max, 16)

    def residual(c: np.ndarray, effect: Effect) -> np.ndarray:
        hook, p = effect.inputs, effect.param_type(*c)
        assert hook is not None
        return _acting(log, lambda lg, pv: hook(lg, 10.0, pv, 10.0, DT, p)[0]) - truth

    eff = shape_effect([spline])
    fit = least_squares(residual, np.full(16, 0.5), bounds=eff.bounds, args=(eff,), max_nfev=100)
    forms = memory_forms(spline, list(fit.x))
    assert forms[0].form == kind, forms
    assert forms[0].r2 > 0.9 and all(0.0 < f.r2 < forms[0].r2 for f in forms[1:])
    assert memory_forms(spline, [0.0] * 16) == []  # no memory: nothing to name
    named = Group("D", "ed", -z_max, z_max, 1, form=kind)
    assert named.text == f"D~ed[{named.lo:g}:{named.hi:g}]:{kind}"
    closed = shape_effect([named])
    assert closed.bounds == ((0.0,), (1.0,)) and closed.inputs is not None
    e_max = CONTROLS["D"].quantum * math.sinh(z_max)
    want = {"rate": 1.0 - size * DT / e_max, "play": size / e_max, "lag": math.exp(-DT / size)}
    assert forms[0].a == pytest.approx(want[kind], abs=0.05)
    refit = least_squares(residual, [forms[0].a], bounds=closed.bounds, args=(closed,), max_nfev=50)
    assert refit.x[0] == pytest.approx(want[kind], rel=1e-3)
    assert math.degrees(float(np.sqrt(np.mean(refit.fun**2)))) < 0.01
    text = named.memory_closed(float(refit.x[0]), DT)
    shown = {
        "rate": f"a rate limit of the rudder angle: {math.degrees(size):.3g} deg/s",
        "play": f"play of the rudder angle: {math.degrees(size):.3g} deg",
        "lag": f"a first-order lag of the rudder angle: T = {size:.3g} s",
    }
    assert text.startswith(shown[kind]), text


def test_a_memory_closed_form_takes_the_steps_of_its_family() -> None:
    """Through the hook: a lag closes (1 - c) of the gap, a rate limit at most (1 - c) e_max,
    play nothing below c e_max and the rest beyond; c = 0 is the paper's model."""
    from mmg.shapes import memory_steps

    e_max = math.radians(1.0) * math.sinh(4.0)
    for kind, c, gap, step in (
        ("lag", 0.25, 0.2, 0.15),
        ("rate", 0.9, 0.2, 0.1 * e_max),
        ("rate", 0.9, -0.01, -0.01),
        ("play", 0.02, 0.2, 0.2 - 0.02 * e_max),
        ("play", 0.02, -0.005, 0.0),
    ):
        g = Group("D", "ed", -4.0, 4.0, 1, form=kind)
        eff = shape_effect([g])
        assert eff.inputs is not None
        for c_ in (c, 0.0):
            want = step if c_ else gap
            got = eff.inputs(0.1 + gap, 10.0, 0.1, 10.0, DT, eff.param_type(c_))[0]
            assert got == pytest.approx(0.1 + want, abs=1e-12), (kind, c_)
            assert memory_steps(g, [c_], [gap])[1][0] == pytest.approx(want, abs=1e-12)
    assert get_effect("shape:D~ed[-4:4]:play").params[0].description == (
        "delta = delta_prev + sign(e_delta) max(|e_delta| - b, 0),  b = s0_D0 e_max,  "
        f"e_max = {e_max:.6g} rad  [rad]"
    )


def test_memory_groups_are_written_one_way() -> None:
    """The gap of the rudder is a memory of the rudder alone, without multiplier, scaling or
    closed form; a force group cannot take a control's letter."""
    for bad, why in (
        ("shape:Y~ed[-4:4]/8", "its shape's component is D"),
        ("shape:DP~ed[-4:4]/8", "its shape's component is D"),
        ("shape:P~ed[-4:4]/8", "its shape's component is D"),
        ("shape:D~beta[0:1]/6", "one or more of X, Y, N"),
        ("shape:D~ed[-4:4]/8*v", "no multiplier"),
        ("shape:D~ed[-4:4]:odd", "a memory's closed form is one of lag, rate, play"),
        ("shape:D~ed[-4:4]/8@U2", "no multiplier or scale"),
        ("shape:Y~beta[-1:1]:rate", "unknown closed form 'rate'"),
    ):
        with pytest.raises(KeyError, match=why):
            get_effect(bad)
    assert Group("D", "ed", -4.0, 4.0, 8).formula("D", 2) == (
        "delta = delta_log - e_delta f_D2(z_delta)  [rad]"
    )
    assert Group("P", "en", -4.0, 4.0, 8).formula("P", 0) == (
        "n_p = n_log - e_n f_P0(z_n)  [rev/s]"
    )


def test_the_gaps_of_the_log_give_the_memory_candidates() -> None:
    """A gap is the log's change from the sample before (0 at the first), on the asinh scale;
    the candidates hold a memory of the rudder spanning [-m, m] of its largest gap and none of
    a propeller whose log does not change."""
    from sweep.diagnose.shapes import N_MEMORY_BASIS, candidate_groups

    p = efd_parameters()
    k = np.arange(300)
    x = np.zeros((300, 6))
    x[:, 1] = 0.5
    x[:, 3] = 0.02 * np.sin(k / 20.0)
    delta = np.where(k < 100, 0.0, np.where(k < 200, 0.35, -0.1))
    c = np.column_stack([delta, np.full(300, 10.0)])
    w = np.zeros((300, 2))
    t = np.asarray(0.1 * k, dtype=np.float64)
    z = variable_values("ed", t, x, c, w, p.theta, p.ship)
    assert z[0] == 0.0 and z[100] == pytest.approx(math.asinh(0.35 / math.radians(1.0)))
    assert z[200] == pytest.approx(-math.asinh(0.45 / math.radians(1.0)))
    assert np.count_nonzero(z) == 2
    assert not variable_values("en", t, x, c, w, p.theta, p.ship).any()
    wins = [Recording("w", None, t, x, c, w)]
    groups = {g.variable: g for g in candidate_groups(wins, p, products=(), quadrants=())}
    assert "en" not in groups
    assert groups["ed"] == Group("D", "ed", z[200], -z[200], N_MEMORY_BASIS)


def test_the_report_states_a_memory_as_the_steps_it_lets_the_control_take() -> None:
    """A constant share of 0.5 (a lag halving the gap each step): the table gives, at gaps of
    both signs in degrees, the share, the step (half the gap) and that step per second."""
    from sweep.diagnose.report import _memory_entry, _memory_md

    g = Group("D", "ed", -4.0, 4.0, 8)
    m = _memory_entry(g, [0.5] * 8, 0.1)
    gaps = np.asarray(m["gap"])
    assert m["unit"] == "deg" and len(gaps) == 12 and gaps[0] < 0 < gaps[-1]
    assert gaps[-1] == pytest.approx(math.degrees(math.sinh(4.0) * math.radians(1.0)))
    np.testing.assert_allclose(m["share"], 0.5, rtol=1e-12)
    np.testing.assert_allclose(m["step"], 0.5 * gaps, rtol=1e-12)
    np.testing.assert_allclose(m["rate"], 5.0 * gaps, rtol=1e-12)
    md = "\n".join(_memory_md(m))
    assert "| gap [deg] | share left open f | step in 0.1 s [deg] | as a rate [deg/s] |" in md
    assert "A constant share is a first-order lag" in md
    # a rate limit named: no step beyond a tenth of the range's largest gap (2.73 deg, 27.3 deg/s)
    rate = _memory_entry(Group("D", "ed", -4.0, 4.0, 1, form="rate"), [0.9], 0.1)
    assert rate["gap"] == m["gap"]
    np.testing.assert_allclose(np.abs(rate["rate"]), np.minimum(np.abs(gaps), 0.1 * gaps[-1]) / 0.1)
    assert not m["away"] and "signed away" not in md
    # of the gap signed away from midships: two rate limits, a tenth moving away, a fifth back
    two = _memory_entry(Group("D", "eda", -4.0, 4.0, 2, form="rate"), [0.9, 0.8], 0.1)
    limit = np.where(gaps > 0, 0.1, 0.2) * gaps[-1]
    np.testing.assert_allclose(np.abs(two["step"]), np.minimum(np.abs(gaps), limit))
    assert two["away"] and "+ where the delta moves away from 0" in "\n".join(_memory_md(two))


def test_a_learned_memory_becomes_its_closed_form_candidate() -> None:
    """A selection of a memory alone (a share of 1 below 2 deg, falling beyond: play) is named
    play, started at the coefficient fitted to the spline, both as the name on the trajectories
    and as the closest form (then one candidate)."""
    from types import SimpleNamespace

    from sweep.diagnose.shapes import ShapeSelection
    from sweep.diagnose.shaping import closest_form, named_form

    g = Group("D", "ed", -4.0, 4.0, 16)
    e = np.sinh(np.linspace(-4.0, 4.0, 400)) * math.radians(1.0)
    share = np.minimum(1.0, math.radians(2.0) / np.abs(e))
    z = np.arcsinh(e / math.radians(1.0))
    coef = [float(c) for c in np.linalg.lstsq(basis(g, z), share, rcond=None)[0]]
    sel = ShapeSelection([g], [coef], [np.zeros((16, 16))], [0.5], [6.0], -100.0)
    columns = SimpleNamespace(groups=[g])  # no force group: the naming needs no columns
    named, form, start = named_form(columns, sel, np.zeros((1, 1)))  # type: ignore[arg-type]
    assert form is not None and form.name == "shape:D~ed[-4:4]:play"
    assert named[0] is not None and named[0].family.startswith("play")
    e_max = math.radians(1.0) * math.sinh(4.0)
    assert start[0] * e_max == pytest.approx(math.radians(2.0), rel=0.02)
    closest, closest_start = closest_form(sel)
    assert closest is not None and closest.name == form.name and closest_start == start


def test_the_probe_s_sizes_are_powers_of_two_of_the_control_s_quantum() -> None:
    """Play b = c e_max and a rate limit's largest step (1 - c) e_max run over the quantum times
    2^-4 ... 2^4 (1 deg of rudder, 0.5 rev/s of propeller), those within the range's largest
    gap; the groups are the two forms of each gap (plain, and signed away from the control's
    zero) of a control whose log moves."""
    from sweep.diagnose.memory import FORMS, GRID_EXPONENTS, by_form, grid_values, memory_groups

    g = Group("D", "ed", -4.0, 4.0, 1, form="play")
    e_max = math.radians(1.0) * math.sinh(4.0)
    b = [c * e_max for c in grid_values(g)]
    assert b == pytest.approx([math.radians(1.0) * 2.0**k for k in GRID_EXPONENTS], rel=1e-12)
    r = Group("P", "en", -2.0, 2.0, 1, form="rate")
    steps = [(1.0 - c) * 0.5 * math.sinh(2.0) for c in grid_values(r)]
    assert steps == pytest.approx([0.5 * 2.0**k for k in GRID_EXPONENTS if 2.0**k < math.sinh(2)])
    p = efd_parameters()
    k = np.arange(300)
    x = np.zeros((300, 6))
    x[:, 1] = 0.5
    c = np.column_stack([np.where(k < 150, 0.0, 0.2), np.full(300, 10.0)])
    t = np.asarray(0.1 * k, dtype=np.float64)
    wins = [Recording("w", None, t, x, c, np.zeros((300, 2)))]
    groups = memory_groups(wins, p)
    assert [(g.components, g.variable, g.form) for g in groups] == [
        ("D", v, f) for v in ("ed", "eda") for f in FORMS
    ]  # the plain gap's forms, and those acting away from midships alone
    assert groups[0].hi == pytest.approx(math.asinh(0.2 / math.radians(1.0)), rel=1e-5)
    # one effect per form and kind of gap: never two groups of one control in one probe (a form
    # at 0 acts on gaps beyond its range, and a memory probed beside it makes such gaps)
    for _, members in by_form(groups):
        assert len({g.control for g in members}) == len(members)
    assert len(by_form(groups)) == 2 * len(FORMS)


def test_the_probe_counts_only_a_change_that_takes_the_residual_away() -> None:
    """A direction g and a residual r: the base refitted beside g (here nothing to refit), its
    scale free but positive. r = -2 g: scale 2, all of r's J gained; r = +g: the form would make
    the fit worse at any positive size, so no gain, and the dBIC is the price of a coefficient."""
    from types import SimpleNamespace

    from sweep.diagnose.memory import best_direction

    class Fold:  # the base's Jacobian projected out: none in this test double
        @staticmethod
        def stack(X: np.ndarray) -> np.ndarray:
            return X.reshape(X.shape[0] * X.shape[1], -1)

        @staticmethod
        def resid(X: np.ndarray) -> np.ndarray:
            return X

    cal = SimpleNamespace(lin=SimpleNamespace(all=Fold()))
    rng = np.random.default_rng(5)
    g = rng.normal(size=(3, 40, 1))
    noise = 0.01 * rng.normal(size=(3, 40, 1))
    R = np.concatenate([-2.0 * g + noise, g + noise], axis=-1)
    dbic, scale, J0 = best_direction(cal, g, R, 100.0)  # type: ignore[arg-type]
    assert scale[0, 0] == pytest.approx(2.0, rel=0.01) and scale[0, 1] < 0
    assert dbic[0, 0] < -300.0
    assert dbic[0, 1] == pytest.approx(math.log(100.0))
    np.testing.assert_allclose(J0, (R * R).sum(axis=(0, 1)), rtol=1e-12)


def test_the_probe_runs_only_where_the_base_misses_beyond_the_noise_floor() -> None:
    """Within the floor there is no misfit whose cause the probe could look for: nothing is
    probed or proposed, and the log says why."""
    from types import SimpleNamespace

    from sweep.diagnose.memory import propose_memory
    from sweep.diagnose.settings import DiagnoseSettings

    lines: list[str] = []
    ctx = SimpleNamespace(settings=DiagnoseSettings(), log=lines.append, windows=[])
    cal = SimpleNamespace(misfit=SimpleNamespace(significant=False))
    assert propose_memory(ctx, None, cal) is None  # type: ignore[arg-type]
    assert lines == ["memories of the controls: not probed (the base is within the noise floor)"]
    off = SimpleNamespace(settings=DiagnoseSettings(shapes=False), log=lines.append)
    assert propose_memory(off, None, cal) is None  # type: ignore[arg-type]
    assert len(lines) == 1


def test_a_gap_signed_away_from_midships_tells_the_moves_away_from_those_back() -> None:
    """``eda``: +|e| where the rudder moves away from midships (or leaves it), -|e| where it
    moves back, in the log's gaps and in the hook; a spline of it leaves its own share open
    each way, and a closed form takes one coefficient moving away and another moving back
    (0: as logged)."""
    from mmg.shapes import away_sign, memory_steps

    gaps, prev = [0.1, -0.1, 0.1, -0.1, 0.2, -0.2], [0.2, 0.2, -0.2, -0.2, 0.0, 0.0]
    assert away_sign(gaps, prev).tolist() == [0.1, -0.1, -0.1, 0.1, 0.2, 0.2]
    p = efd_parameters()
    delta = np.array([0.0, 0.1, 0.3, 0.2, -0.1, -0.2, -0.1])
    c = np.column_stack([delta, np.full(7, 10.0)])
    z = variable_values(
        "eda", np.arange(7.0), np.zeros((7, 6)), c, np.zeros((7, 2)), p.theta, p.ship
    )
    q = math.radians(1.0)
    want = [0.0, 0.1, 0.2, -0.1, -0.3, 0.1, -0.1]
    assert z == pytest.approx(np.arcsinh(np.array(want) / q), rel=1e-12)
    g = Group("D", "eda", -4.0, 4.0, 8)
    eff = shape_effect([g])
    assert eff.inputs is not None
    values = np.random.default_rng(5).uniform(0.0, 1.0, 8)
    e = eff.param_type(*values)
    for d_log, d_prev in (
        (0.3, 0.1),
        (0.05, 0.1),
        (-0.2, 0.1),
        (-0.3, -0.1),
        (0.2, 0.0),
        (-0.1, 0.0),
    ):
        gap = d_log - d_prev
        z_a = math.asinh(float(away_sign([gap], [d_prev])[0]) / q)
        want_d = d_log - gap * float(basis(g, [z_a])[0] @ values)
        assert eff.inputs(d_log, 10.0, d_prev, 10.0, DT, e)[0] == pytest.approx(want_d, rel=1e-12)
    rate = Group("D", "eda", -4.0, 4.0, 2, form="rate")
    closed = shape_effect([rate])
    assert closed.inputs is not None and len(closed.params) == 2
    e_max = q * math.sinh(4.0)
    for away, back in ((0.95, 0.0), (0.95, 0.8)):
        for d_log, d_prev in ((0.3, 0.1), (-0.2, 0.1), (0.4, 0.0), (-0.4, -0.35), (-0.1, -0.35)):
            gap = d_log - d_prev
            got = closed.inputs(d_log, 10.0, d_prev, 10.0, DT, closed.param_type(away, back))[0]
            e_a = float(away_sign([gap], [d_prev])[0])
            m = (1.0 - (away if e_a > 0 else back)) * e_max
            step = math.copysign(min(abs(gap), m), gap)
            assert got == pytest.approx(d_prev + step, abs=1e-12), (d_log, d_prev)
            steps = memory_steps(rate, [away, back], [e_a])[1]
            assert abs(steps[0]) == pytest.approx(abs(step), abs=1e-12)
    said = rate.memory_closed(0.95, DT)
    assert said.endswith("moving away from midships (as logged moving back)")
    assert "; moving back, a rate limit of the rudder angle" in rate.memory_closed(0.95, DT, 0.8)
    assert "moves delta away from 0" in closed.params[0].description
    with pytest.raises(ValueError, match="2 coefficient"):
        Group("D", "eda", -4.0, 4.0, 1, form="rate")
    assert get_effect("shape:D~eda[-4:4]:rate").params[1].name == "s0_D1"


def test_a_steering_gear_slower_away_from_midships_is_learnt_by_the_signed_gap() -> None:
    """A gear turning the rudder away from midships at 15 deg/s and back, helped by its load, at
    45 deg/s: a spline of the gap signed away from midships learns it to a tenth of the error
    that one of the plain gap leaves, and is named a rate limit of 15 deg/s away from midships
    and 45 deg/s back (:func:`sweep.diagnose.naming.memory_forms`); refitted through its own
    hook, both rates come out within a thousandth of their coefficient."""
    from sweep.diagnose.naming import memory_forms

    rng = np.random.default_rng(1)
    holds: list[float] = []
    while len(holds) < 1500:
        holds += [rng.uniform(-0.61, 0.61)] * int(rng.integers(30, 150))
    log = np.round(np.array(holds[:1500]) / 0.0098) * 0.0098
    away, back = math.radians(15.0) * DT, math.radians(45.0) * DT

    def gear(lg: float, pv: float) -> float:
        d = lg - pv
        m = away if d * (pv if pv != 0.0 else d) > 0.0 else back
        return pv + float(np.clip(d, -m, m))

    truth = _acting(log, gear)
    z_max = math.asinh(0.7 / math.radians(1.0))

    def through_hook(g: Group, start: list[float], nfev: int) -> tuple[np.ndarray, float]:
        """The group's coefficients fitted through its own hook to the acting rudder, and the
        error left [deg rms]."""
        eff = shape_effect([g])
        hook = eff.inputs
        assert hook is not None

        def residual(c: np.ndarray) -> np.ndarray:
            e = eff.param_type(*c)
            return _acting(log, lambda lg, pv: hook(lg, 10.0, pv, 10.0, DT, e)[0]) - truth

        fit = least_squares(residual, start, bounds=eff.bounds, max_nfev=nfev)
        return fit.x, math.degrees(float(np.sqrt(np.mean(fit.fun**2))))

    def fitted(variable: str) -> tuple[Group, np.ndarray, float]:
        g = Group("D", variable, -z_max, z_max, 16)
        return (g, *through_hook(g, [0.5] * 16, 100))

    _, _, rms_plain = fitted("ed")
    g, coef, rms_away = fitted("eda")
    assert rms_away < 0.1 * rms_plain and rms_away < 0.2, (rms_away, rms_plain)
    forms = memory_forms(g, list(coef))
    assert forms[0].form == "rate", forms
    e_max = 0.7
    assert forms[0].a == pytest.approx(1.0 - away / e_max, abs=0.03)
    assert forms[0].b == pytest.approx(1.0 - back / e_max, abs=0.05)
    named = Group("D", "eda", -z_max, z_max, 2, form="rate")
    refit, rms = through_hook(named, [forms[0].a, forms[0].b], 50)
    assert refit == pytest.approx([1.0 - away / e_max, 1.0 - back / e_max], abs=1e-3)
    before = math.degrees(float(np.sqrt(np.mean((log - truth) ** 2))))
    assert rms < min(0.2, before / 8.0)
    said = named.memory_closed(float(refit[0]), DT, float(refit[1]))
    assert said.startswith("a rate limit of the rudder angle: 15 deg/s"), said
    assert "moving away from midships; moving back, a rate limit of the rudder angle: 4" in said
