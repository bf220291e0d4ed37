"""Where a finding holds: the box of states an effect acts in (mmg.domain) and the ranges
recordings cover (sweep.data.ranges)."""

from __future__ import annotations

import math
import pickle
import re
from typing import Any

import numpy as np
import pytest

from mmg import efd_parameters, get_effect
from mmg.domain import Domain, DomainEffect, parse_spec, split_name, within
from sweep.data.ranges import departures, ranges_of
from sweep.data.recordings import Recording

BOX = Domain({"u": 0.2, "n_p": 3.0}, {"u": 1.3, "n_p": 5.0})


def _walk_force(effect, u, n_p):
    p = efd_parameters()
    e = effect.param_type(C_Yw=0.01, C_Nw=-0.004)
    return np.array(effect.force(u, 0.05, 0.01, 0.0, 0.1, n_p, 0.0, 0.0, e, p.theta, p.ship))


def test_a_domain_reads_back_from_its_spec_and_bad_specs_are_clear():
    d = Domain({"u": 0.21234567, "r": -0.03}, {"u": 1.30001, "r": 0.0412}, "off")
    spec = d.spec
    assert spec == "off(u=0.2123:1.301,r=-0.03:0.0412)"  # rounded outward: the box still holds
    back = parse_spec(spec)
    assert back.mode == "off" and back.lower["u"] <= 0.21234567 and back.upper["u"] >= 1.30001
    assert parse_spec(back.spec) == back
    for bad, message in (
        ("held(u=1:0)", "lower 1.0 above upper 0.0"),
        ("held(w=0:1)", "domain variable 'w'"),
        ("maybe(u=0:1)", "domain mode 'maybe'"),
        ("held(u=a:1)", "not a number"),
        ("held u=0:1", "expected mode(var=lo:hi,...)"),
    ):
        with pytest.raises(ValueError, match=re.escape(message)):
            parse_spec(bad)


def test_a_box_read_back_from_its_spec_rounds_to_the_same_spec():
    """A bound rounded outward to 4 digits is a fixed point: the box rebuilt from a wrapped
    effect's name is the box it was made with, one effect and one kernel in every process (in
    binary, 0.02521 / 1e-5 is 2520.9999...: the name said 0.0252 while the hook held 0.02521)."""
    d = Domain({"u": 0.025215, "r": -0.0412345}, {"u": 0.42005, "r": 0.0312})
    assert d.spec == "held(u=0.02521:0.4201,r=-0.04124:0.0312)"
    rng = np.random.default_rng(7)
    for x in rng.uniform(-1.0, 1.0, 2000) * 10.0 ** rng.uniform(-5.0, 3.0, 2000):
        box = Domain({"v_m": float(x)}, {"v_m": abs(float(x)) + 1.0})
        back = parse_spec(box.spec)
        assert back.spec == box.spec and back.lower["v_m"] <= x
    held = within(get_effect("propeller_walk"), d)
    assert isinstance(held, DomainEffect)
    assert split_name(held.name)[1] == held.domain == d.rounded()


def test_a_wrapped_effect_is_rebuilt_by_name_and_pickles_by_name():
    walk = get_effect("propeller_walk")
    held = within(walk, BOX)
    assert held.name == "propeller_walk@held(u=0.2:1.3,n_p=3:5)"
    assert split_name(held.name) == ("propeller_walk", BOX.rounded())
    assert get_effect(held.name) is held
    assert pickle.loads(pickle.dumps(held)).name == held.name
    assert held.params == walk.params and held.param_type is walk.param_type
    assert hash(held) == hash(pickle.loads(pickle.dumps(held)))  # (kernels are kept by effects)
    # wrapping a wrapped effect replaces its box
    off = within(held, BOX.with_mode("off"))
    assert off.name == "propeller_walk@off(u=0.2:1.3,n_p=3:5)"
    with pytest.raises(KeyError, match=r"effect 'warp@held.*unknown effect 'warp'"):
        get_effect("warp@held(u=0:1)")


def test_inside_its_box_the_effect_is_unchanged_outside_it_is_held_or_off():
    walk = get_effect("propeller_walk")
    held, off = within(walk, BOX), within(walk, BOX.with_mode("off"))
    inside = _walk_force(walk, 0.8, 4.0)
    assert np.abs(inside).max() > 0
    np.testing.assert_array_equal(_walk_force(held, 0.8, 4.0), inside)
    np.testing.assert_array_equal(_walk_force(off, 0.8, 4.0), inside)
    # beyond the box in n_p (and u): held at the boundary's force, or nothing
    np.testing.assert_array_equal(_walk_force(held, 0.8, 9.0), _walk_force(walk, 0.8, 5.0))
    np.testing.assert_array_equal(_walk_force(held, 2.0, 1.0), _walk_force(walk, 1.3, 3.0))
    np.testing.assert_array_equal(_walk_force(off, 0.8, 9.0), np.zeros(3))
    assert np.abs(_walk_force(walk, 0.8, 9.0)).max() > np.abs(inside).max()


def _force(effect: Any, state: tuple[float, ...], e: Any) -> np.ndarray:
    """(dX, dY, dN) of ``effect``'s force hook at ``state`` (u v_m r psi delta n_p U_T gamma_T)."""
    p = efd_parameters()
    assert effect.force is not None
    return np.asarray(effect.force(*state, e, p.theta, p.ship), dtype=np.float64)


def test_above_the_top_speed_a_held_effect_keeps_its_non_dimensional_force():
    """Beyond U_max the state is brought to U_max by similarity (u, v_m, r, n_p and the wind
    speed scaled by U_max / U) and the force found there divided by (U_max / U)^2; a box that
    also clamps n_p clamps the scaled rate."""
    walk = get_effect("propeller_walk")
    box = Domain({"U": 0.0, "n_p": 3.0}, {"U": 1.0, "n_p": 12.0})
    held, off = within(walk, box), within(walk, box.with_mode("off"))
    assert held.name == "propeller_walk@held(U=0:1,n_p=3:12)"
    e = walk.param_type(C_Yw=0.01, C_Nw=-0.004)
    state = (1.6, 0.12, 0.02, 0.3, 0.1, 8.0, 2.0, 0.7)  # u v_m r psi delta n_p U_T gamma_T
    s = 1.0 / math.hypot(1.6, 0.12)
    similar = (1.6 * s, 0.12 * s, 0.02 * s, 0.3, 0.1, 8.0 * s, 2.0 * s, 0.7)
    got = _force(held, state, e)
    np.testing.assert_allclose(got, _force(walk, similar, e) / s**2, rtol=1e-12)
    assert np.abs(got).max() > 0
    np.testing.assert_array_equal(_force(off, state, e), np.zeros(3))
    # below the top speed nothing is scaled
    slow = (0.8, 0.05, 0.01, 0.3, 0.1, 8.0, 2.0, 0.7)
    np.testing.assert_array_equal(_force(held, slow, e), _force(walk, slow, e))
    # the scaled rate is clamped too: at 2 U_max and 30 rev/s, n_p s = 15 is held at 12
    fast = (2.0, 0.0, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0)
    at_box = _force(walk, (1.0, 0.0, 0.0, 0.0, 0.0, 12.0, 0.0, 0.0), e)
    np.testing.assert_allclose(_force(held, fast, e), 4.0 * at_box, rtol=1e-12)


def _recording(name: str, u: np.ndarray, n_p: np.ndarray, r: float = 0.0) -> Recording:
    k = len(u)
    x = np.zeros((k, 6))
    x[:, 1] = u
    x[:, 5] = r
    c = np.zeros((k, 2))
    c[:, 1] = n_p
    t = 0.1 * np.arange(k, dtype=np.float64)
    return Recording(name=name, path=None, t=t, x=x, u=c, w=np.zeros((k, 2)))


def test_ranges_and_the_recordings_that_leave_them():
    train = [
        _recording("a", np.linspace(0.3, 1.0, 100), np.full(100, 8.0)),
        _recording("b", np.linspace(0.5, 1.2, 100), np.linspace(6.0, 10.0, 100)),
    ]
    rng = ranges_of(train)
    assert rng.intervals["u"] == (0.3, 1.2)
    assert rng.intervals["n_p"] == (6.0, 10.0)
    assert rng.quadrants["Q1"] == 1.0 and rng.quadrants["Q3"] == 0.0
    assert math.isclose(rng.intervals["beta"][1], 0.0, abs_tol=1e-12)
    box = rng.domain()
    assert box.mode == "held" and box.upper["n_p"] == 10.0
    assert box.upper["U"] == rng.intervals["U"][1] and box.lower["U"] == 0.0
    assert box.lower["r"] == 0.0 == box.upper["r"]
    # a berthing-like recording: slower, propeller reversed half the time
    berth = _recording(
        "berth",
        np.concatenate([np.linspace(0.4, 0.0, 50), np.linspace(0.0, -0.2, 50)]),
        np.concatenate([np.full(50, 7.0), np.full(50, -12.0)]),
    )
    inside = _recording("inside", np.linspace(0.4, 1.1, 100), np.full(100, 9.0))
    found = departures(rng, [berth, inside], ["Test-B-S", "Test-R"])
    assert {d.recording for d in found} == {"Test-B-S"}
    by_var = {d.variable: d for d in found}
    assert by_var["n_p"].extreme == -12.0 and by_var["n_p"].beyond == 18.0
    assert by_var["n_p"].time_share == 0.5
    assert "n_p to -12 rev/s, 18 rev/s beyond 6" in by_var["n_p"].text()
    assert by_var["quadrant"].quadrant == "Q3"
    assert "never in the fitted runs" in by_var["quadrant"].text()
    # faster than the training runs: named once, by the speed (u says the same)
    fast = _recording("fast", np.linspace(0.5, 1.5, 100), np.full(100, 8.0))
    named = [d.variable for d in departures(rng, [fast])]
    assert "U" in named and "u" not in named  # (and J, the advance ratio, at the same rate)
    # a short excursion (at most 1 % of the samples) is not named
    blip = _recording("blip", np.full(200, 0.8), np.r_[np.full(198, 8.0), 11.0, 11.0])
    assert departures(rng, [blip]) == []


def test_boxes_of_the_same_bounds_run_one_kernel_with_the_bounds_in_its_rows():
    """The kernel's code holds no bound: the boxes of one effect that bound the same variables
    share one compiled kernel, the bounds being parameter rows after the effect's own. Each box
    acts through those rows: a state inside box a and outside box b (n_p 4.5) gets the
    effect's force with a, and none with b switched off outside it."""
    from mmg.fixed import kernel_effects
    from mmg.integrate import derivatives_rows
    from mmg.kernel import load_kernel

    walk = get_effect("propeller_walk")
    a = within(walk, BOX.with_mode("off"))
    b = within(walk, Domain({"u": 0.1, "n_p": 2.0}, {"u": 0.9, "n_p": 4.0}, "off"))
    assert kernel_effects((a,)) == kernel_effects((b,)) != (walk,)
    assert load_kernel(kernel_effects((a,))) is load_kernel(kernel_effects((b,)))
    p = efd_parameters()
    rows = np.concatenate([p.vector(), [0.01, -0.004]])[None, :]  # (1, 57 + C_Yw, C_Nw)
    x = np.array([0.0, 0.8, 0.0, 0.05, 0.0, 0.01])
    w = np.zeros(2)

    def xdot(effects: tuple, n_p: float) -> np.ndarray:
        u = np.array([0.1, n_p])
        return derivatives_rows(x, u, w, rows[:, : 57 + 2 * len(effects)], effects)[0]

    inside_both, outside_b = 3.5, 4.5
    for n_p in (inside_both, outside_b):
        np.testing.assert_allclose(xdot((a,), n_p), xdot((walk,), n_p), rtol=1e-13, atol=0)
    np.testing.assert_allclose(xdot((b,), inside_both), xdot((walk,), inside_both), rtol=1e-13)
    np.testing.assert_allclose(xdot((b,), outside_b), xdot((), outside_b), rtol=1e-13, atol=0)
    assert np.abs(xdot((walk,), outside_b) - xdot((), outside_b)).max() > 1e-6
