"""Standard manoeuvres: the measurements on trajectories whose answers are known (a circle, a
zigzag, a stop), the IMO criteria, the simulated manoeuvres and the command line."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sweep.data.manoeuvres import (
    SCALE,
    imo_criteria,
    measure_stopping,
    measure_turning,
    measure_zigzag,
    rudder_executes,
    summarise,
    to_full_scale,
)

DT = 0.1


def circle(R: float, V: float, psi0: float, approach: float = 20.0, turns: float = 2.2):
    """A straight approach at speed V along heading psi0 from (5, -3), then a starboard turn on a
    circle of radius R at the same speed: t (N,), states (N, 6), the execute's sample."""
    r = V / R
    t = np.arange(0.0, approach + turns * 2 * math.pi / r, DT)
    k0 = round(approach / DT)
    s = np.clip(t - t[k0], 0.0, None)  # time into the turn
    psi = psi0 + r * s
    # in the original course's frame: along = V (t - t0) before, R sin(r s) after; across = R(1-cos)
    along = np.where(t < t[k0], V * (t - t[k0]), R * np.sin(r * s))
    across = np.where(t < t[k0], 0.0, R * (1.0 - np.cos(r * s)))
    x0 = 5.0 + along * math.cos(psi0) - across * math.sin(psi0)
    y0 = -3.0 + along * math.sin(psi0) + across * math.cos(psi0)
    yaw = np.where(t < t[k0], 0.0, r)
    x = np.stack([x0, np.full_like(t, V), y0, np.zeros_like(t), psi, yaw], axis=1)
    return t, x, k0


@pytest.mark.parametrize("psi0", [0.0, 2.0, -2.9])
def test_a_circle_of_known_diameter(psi0):
    R, V = 7.5, 0.3
    t, x, k0 = circle(R, V, psi0)
    m = measure_turning(t, x, k0)
    # a turn that starts on its circle: advance = transfer = R, tactical = steady diameter = 2 R
    assert m["advance"] == pytest.approx(R, rel=1e-3)
    assert m["transfer"] == pytest.approx(R, rel=1e-3)
    assert m["tactical_diameter"] == pytest.approx(2 * R, rel=1e-4)
    assert m["steady_diameter"] == pytest.approx(2 * R, rel=1e-9)
    assert m["speed_loss"] == pytest.approx(0.0, abs=1e-12)
    assert m["time_90"] == pytest.approx(0.5 * math.pi * R / V, abs=1e-6)
    assert m["time_180"] == pytest.approx(math.pi * R / V, abs=1e-6)


def test_a_port_turn_is_measured_like_a_starboard_one():
    t, x, k0 = circle(6.0, 0.25, 0.4)
    mirrored = x.copy()
    mirrored[:, 2] = -x[:, 2]  # reflect y0, heading, sway and yaw: the same turn to port
    mirrored[:, 3:6] *= [-1.0, -1.0, -1.0]
    a, b = measure_turning(t, x, k0), measure_turning(t, mirrored, k0)
    for key in a:
        assert b[key] == pytest.approx(a[key], rel=1e-9, abs=1e-12)


def test_a_turn_that_stops_short_has_no_steady_diameter():
    t, x, k0 = circle(5.0, 0.3, 0.0, turns=0.6)  # 216 deg of turn: past 180, short of 630
    m = measure_turning(t, x, k0)
    assert m["tactical_diameter"] == pytest.approx(10.0, rel=1e-4)
    assert math.isnan(m["steady_diameter"]) and math.isnan(m["speed_loss"])


def zigzag(amplitudes=(15.0, 22.0, 18.0, 20.0), check=10.0, period=40.0, V=0.3):
    """A heading psi = a_j sin(w t) [deg] whose amplitude a_j changes at each zero (so psi stays
    continuous) and a rudder of +-check deg that a zigzag controller gives it: reversed where the
    heading deviation passes +-check. Overshoot j is a_j - check at t = (j - 1/2) pi / w."""
    w = 2 * math.pi / period
    t = np.arange(0.0, period * len(amplitudes) / 2 + 5.0, DT)
    half = np.minimum((w * t // math.pi).astype(int), len(amplitudes) - 1)
    psi = np.radians(np.asarray(amplitudes)[half] * np.sin(w * t))
    delta = np.empty_like(t)
    side = 1.0
    for k, p in enumerate(np.degrees(psi)):
        if side * p >= check:
            side = -side
        delta[k] = side * math.radians(check)
    x = np.zeros((t.size, 6))
    x[:, 1], x[:, 4], x[:, 5] = V, psi, np.gradient(psi, t)
    x[:, 0] = V * t
    return t, x, delta, w


def test_a_zigzag_of_known_overshoots_and_times():
    t, x, delta, w = zigzag()
    m = measure_zigzag(t, x, delta, 0)
    # the heading at the second execute is the first sample past 10 deg, not exactly 10 deg
    ex, side = rudder_executes(delta, 0)
    assert side == 1.0 and len(ex) == 6
    dev_at = np.degrees(x[ex, 4])
    assert m["overshoot_1"] == pytest.approx(15.0 - dev_at[1], abs=1e-3)
    assert m["overshoot_2"] == pytest.approx(22.0 + dev_at[2], abs=1e-3)
    # ... which is within one step of heading change (at most 3.5 deg/s here) of 10 deg
    assert abs(m["overshoot_1"] - 5.0) < 0.35 and abs(m["overshoot_2"] - 12.0) < 0.35
    assert m["time_1"] == pytest.approx(0.5 * math.pi / w, abs=DT)
    assert m["time_2"] == pytest.approx(1.5 * math.pi / w, abs=DT)
    assert m["initial_turning"] == pytest.approx(0.3 * t[ex[1]], rel=1e-9)


def test_zigzag_executes_follow_a_rate_limited_rudder():
    delta = np.radians([0, 4, 8, 10, 10, 10, 6, 2, -2, -6, -10, -10, -10, -6, -2, 2, 6, 10, 10])
    ex, side = rudder_executes(delta, 0)
    assert ex == [0, 6, 13] and side == 1.0
    ex, side = rudder_executes(-delta, 0)
    assert ex == [0, 6, 13] and side == -1.0


def test_a_zigzag_that_ends_before_its_second_peak():
    t, x, delta, _ = zigzag()
    cut = int(np.flatnonzero(np.degrees(x[:, 4]) < -12.0)[0])  # still turning to port
    m = measure_zigzag(t[:cut], x[:cut], delta[:cut], 0)
    assert abs(m["overshoot_1"] - 5.0) < 0.1 and math.isnan(m["overshoot_2"])


def test_a_stop_of_known_reach_and_time():
    V, T, psi0 = 0.38, 50.0, 0.7
    t = np.arange(0.0, 80.0, DT)
    u = V * (1.0 - t / T)  # uniform deceleration: reach V T / 2, then astern
    s = V * t - V * t**2 / (2 * T)
    x = np.zeros((t.size, 6))
    x[:, 0], x[:, 1], x[:, 2], x[:, 4] = s * math.cos(psi0), u, s * math.sin(psi0), psi0
    m = measure_stopping(t, x, 0)
    assert m["time"] == pytest.approx(T, abs=1e-9)
    assert m["track_reach"] == pytest.approx(V * T / 2, rel=1e-4)
    assert m["head_reach"] == pytest.approx(V * T / 2, rel=1e-6)
    assert m["lateral_deviation"] == pytest.approx(0.0, abs=1e-9)
    # a sideways drift adds path but not head reach
    x[:, 3] = 0.05
    x[:, 0] -= 0.05 * t * math.sin(psi0)
    x[:, 2] += 0.05 * t * math.cos(psi0)
    m = measure_stopping(t, x, 0)
    assert m["head_reach"] == pytest.approx(V * T / 2, rel=1e-6)
    assert m["lateral_deviation"] == pytest.approx(0.05 * T, rel=1e-6)
    a, c = V / T, 0.05  # the path: the integral of sqrt((a tau)^2 + c^2) over tau in [0, T]
    path = (a * T * math.hypot(a * T, c) + c**2 * math.asinh(a * T / c)) / (2 * a)
    assert m["track_reach"] == pytest.approx(path, rel=1e-4)
    x[:, 1] = V  # never stops
    assert all(math.isnan(v) for v in measure_stopping(t, x, 0).values())


def test_imo_limits_of_the_yaw_checking_criteria_follow_l_over_v():
    def limits(LV):
        return {c.key: c.limit for c in imo_criteria(LV)}

    assert limits(5.0)["zigzag10.overshoot_1"] == 10.0
    assert limits(20.0)["zigzag10.overshoot_1"] == 15.0
    assert limits(20.0)["zigzag10.overshoot_2"] == 32.5
    assert limits(30.0)["zigzag10.overshoot_2"] == 40.0
    assert limits(82.0)["turning.advance"] == 4.5
    assert limits(82.0)["stopping.track_reach"] == 15.0


def test_froude_scaling_and_summaries():
    assert to_full_scale("turning.advance", 3.0) == pytest.approx(325.0)
    assert to_full_scale("stopping.time", 10.0) == pytest.approx(10.0 * math.sqrt(SCALE))
    assert to_full_scale("zigzag20.overshoot_1", 7.0) == 7.0
    s = summarise([1.0, 2.0, np.nan, 3.0], (0.0, 1.0))
    assert (s["lo"], s["hi"], s["n"], s["missing"]) == (1.0, 3.0, 3.0, 1.0)
