"""Standard manoeuvres: the measurements on trajectories whose answers are known (a circle, a
zigzag, a stop), the IMO criteria, the simulated manoeuvres and the command line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mmg import efd_parameters
from mmg.integrate import derivatives
from sweep.data.datasets import load_split
from sweep.data.manoeuvre_tables import manoeuvre_metrics, recorded_table, standard_table
from sweep.data.manoeuvres import (
    APPROACH_SPEED,
    SCALE,
    imo_criteria,
    measure_stopping,
    measure_turning,
    measure_zigzag,
    rudder_executes,
    summarise,
    to_full_scale,
)
from sweep.data.standard_manoeuvres import (
    RUDDER_RATE,
    approach_revolutions,
    compare_recorded,
    find_manoeuvre,
    parameter_rows,
    predict_standard,
)
from sweep.evaluate import main
from tests.conftest import kernels

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


# ---------------------------------------------------------------------------------------------
# the model's manoeuvres (compiled kernels: the base model's simulate and derivatives)

kernel_marks = pytest.mark.kernels(*kernels((), "simulate", "derivatives"))


def stand_in_samples(params, n, seed=0):
    """A STAND-IN for the identification's parameter uncertainty, for these tests only: a
    diagonal Gaussian of 3 % of each value around the estimate."""
    v = params.vector()
    return v + 0.03 * np.abs(v) * np.random.default_rng(seed).standard_normal((n, v.size))


@kernel_marks
def test_the_approach_revolution_holds_the_approach_speed():
    p = efd_parameters()
    rows = parameter_rows(p, stand_in_samples(p, 3))
    n = approach_revolutions(rows, APPROACH_SPEED, (), p.ship)
    assert np.all((n > 5.0) & (n < 15.0))
    x = np.tile([0.0, APPROACH_SPEED, 0.0, 0.0, 0.0, 0.0], (4, 1))
    u = np.stack([np.zeros(4), n], axis=1)
    u_dot = derivatives(x, u, np.zeros((4, 2)), rows)[:, 1]
    assert np.all(np.abs(u_dot) < 1e-9)


@kernel_marks
def test_standard_zigzag_reverses_at_the_first_sample_past_the_check_angle():
    p = efd_parameters()
    pred = predict_standard(p, stand_in_samples(p, 4))
    for name, check in (("zigzag10", 10.0), ("zigzag20", 20.0)):
        runs = pred.runs[name]
        for lane in range(5):
            ex, side = rudder_executes(runs.delta[lane], 0)
            assert side == 1.0 and len(ex) >= 4
            dev = np.degrees(runs.states[lane, :, 4])
            for j, e in enumerate(ex[1:]):
                s = 1.0 if j % 2 == 0 else -1.0  # the side the heading was turning to
                assert s * dev[e] >= check > s * dev[e - 1]
            # the rudder moves at the rate limit, never faster
            rate = np.abs(np.diff(runs.delta[lane])) / DT
            assert rate.max() <= RUDDER_RATE * (1 + 1e-9)
    rows = standard_table(pred)
    verdicts = {r["key"]: r["verdict"] for r in rows if "verdict" in r}
    assert len(verdicts) == 7
    for r in rows:
        assert r["samples"] == 4 and r["lo"] <= r["hi"]
    metrics = manoeuvre_metrics(pred)
    advance = next(r for r in rows if r["key"] == "turning.advance")
    assert metrics["manoeuvre.turning.advance"] == advance["value"]
    assert metrics["manoeuvre.turning.advance_hi"] == advance["hi"]
    assert metrics["manoeuvre.turning.advance_margin"] == pytest.approx(4.5 - advance["value"])


@kernel_marks
def test_recorded_turning_and_zigzag_runs(data_dir):
    test = load_split("paper").load(data_dir)
    found = [find_manoeuvre(test[k], k) for k in ("Test-T", "Test-Z")]
    runs = [r for r in found if r is not None]
    assert [r.kind for r in runs] == ["turning", "zigzag"]
    assert [round(r.angle_deg) for r in runs] == [35, 20]
    assert test["Test-T"].t[runs[0].k0] == pytest.approx(159.9, abs=0.15)
    assert find_manoeuvre(test["Test-R"]) is None and find_manoeuvre(test["Test-B-S"]) is None
    p = efd_parameters()
    # identical samples: the interval shrinks to the estimate's value
    comparisons = compare_recorded(p, runs, [p, p])
    turn = comparisons[0]
    rec = test["Test-T"]
    direct = measure_turning(rec.t[runs[0].k0 : runs[0].end], rec.x[runs[0].k0 : runs[0].end])
    assert turn.measured == pytest.approx(direct, rel=1e-12)
    for row in recorded_table(comparisons):
        if not math.isnan(row["predicted"]):
            assert row["lo"] == pytest.approx(row["predicted"], rel=1e-9)


@kernel_marks
def test_command_prints_the_manoeuvres_of_efd(data_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MMG_DATA_DIR", str(data_dir))
    out = tmp_path / "m.json"
    assert main(["--params", "efd", "--manoeuvres", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "Standard manoeuvres of efd" in printed and "tactical diameter" in printed
    assert "intervals need parameter samples" in printed and "Test-Z" in printed
    report = json.loads(out.read_text())["manoeuvres"]
    assert {r["run"] for r in report["recorded"]} == {"Test-T", "Test-Z"}
    advance = next(r for r in report["standard"] if r["key"] == "turning.advance")
    assert advance["limit"] == 4.5 and advance["margin"] == pytest.approx(4.5 - advance["value"])
    assert advance["value_m"] == pytest.approx(325.0 * advance["value"])
    samples = tmp_path / "s.npy"
    np.save(samples, stand_in_samples(efd_parameters(), 3))
    fig = tmp_path / "m.png"
    args = ["--params", "efd", "--manoeuvres", "--samples", str(samples), "--figure", str(fig)]
    assert main(args) == 0
    assert "over 3 parameter samples" in capsys.readouterr().out and fig.stat().st_size > 0


def test_command_user_errors(data_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MMG_DATA_DIR", str(data_dir))  # the recorded runs load before the samples
    bad = tmp_path / "bad.npy"
    np.save(bad, np.zeros((2, 5)))
    assert main(["--params", "efd", "--manoeuvres", "--samples", str(bad)]) == 2
    assert "shape (S, 57)" in capsys.readouterr().err
    assert main(["--params", "efd", "--manoeuvres", "--samples", str(tmp_path / "no.npy")]) == 2
    assert "no such samples file" in capsys.readouterr().err
    (tmp_path / "text.npy").write_text("not an array")
    assert main(["--params", "efd", "--manoeuvres", "--samples", str(tmp_path / "text.npy")]) == 2
    assert "text.npy" in capsys.readouterr().err
