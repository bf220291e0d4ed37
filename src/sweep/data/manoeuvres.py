"""Standard manoeuvres measured on trajectories: turning circle, zigzag, crash stop; Froude
scaling to the full ship; the criteria of IMO resolution MSC.137(76).

Every measurement is a pure function of a sampled trajectory: t (N,) [s], states x (N, 6) =
(x0 [m], u [m/s], y0 [m], v_m [m/s], psi [rad, unwrapped], r [rad/s]) at midship, and, for the
zigzag, the rudder angle delta (N,) [rad]. ``k0`` is the sample of the first execute (the rudder
order). Quantities are returned at the scale of the input (the recordings: model scale), lengths
in metres, times in seconds from the execute, angles in degrees, speed loss as a fraction.

Definitions follow MSC.137(76), Annex, section 4.2 (IMO 2002):

- advance: distance along the original course travelled by midship from the execute to a heading
  change of 90 deg; transfer: the distance across it at 90 deg (4.2.3);
- tactical diameter: the distance across the original course at a heading change of 180 deg
  (4.2.4);
- first (second) overshoot angle: the additional heading deviation after the second (third)
  execute of a zigzag, taken from the heading at that execute (4.2.6);
- track reach: the distance along the path of midship from the full-astern order until the ship
  stops dead in the water (4.2.9); here "stops" is the first zero of the ahead speed u.

Not defined there and chosen here: the steady turning diameter is 2 mean(U) / mean(|r|) over a
full revolution of the steady turn (heading change from :data:`STEADY_FROM_DEG` to
:data:`STEADY_TO_DEG`), which is a circle's diameter whatever a steady wind does to the track;
the speed loss is 1 - mean(U) / U_0 over the same revolution, U_0 the speed at the execute.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from mmg.params import ESSO_OSAKA

FloatArray = NDArray[np.float64]

L_FULL = 325.0
"""Length between perpendiculars of the full-scale Esso Osaka [m] (Crane 1979, SNAME Trans. 87,
251-283; its breadth 53.0 m gives the same scale with the model's 0.48925 m)."""
SCALE = L_FULL / ESSO_OSAKA.L_pp
"""Geometric scale lambda of the 3-m model (108.3): lengths x lambda, times and speeds x
sqrt(lambda) (Froude similarity)."""
KNOT = 1852.0 / 3600.0
"""One knot [m/s]."""
APPROACH_KNOTS = 7.7
"""Full-scale approach speed [kn]: the paper's cruising speed, 10 rev/s of the model (Miyauchi
et al. 2022, section 4)."""
APPROACH_SPEED = APPROACH_KNOTS * KNOT / math.sqrt(SCALE)
"""The approach speed at model scale [m/s] (0.381)."""
STEADY_FROM_DEG = 270.0
"""Heading change at which the steady part of a turn starts [deg]."""
STEADY_TO_DEG = 630.0
"""... and ends: one full revolution [deg]."""

Kind = Literal["length", "time", "angle", "ratio"]


@dataclass(frozen=True)
class Quantity:
    """A measured quantity: key, manoeuvre, label and what it is (how it scales)."""

    key: str
    manoeuvre: str
    label: str
    kind: Kind


#: every quantity the standard manoeuvres report, in table order
QUANTITIES: tuple[Quantity, ...] = (
    Quantity("turning.advance", "turning 35 deg", "advance", "length"),
    Quantity("turning.transfer", "turning 35 deg", "transfer", "length"),
    Quantity("turning.tactical_diameter", "turning 35 deg", "tactical diameter", "length"),
    Quantity("turning.steady_diameter", "turning 35 deg", "steady diameter", "length"),
    Quantity("turning.speed_loss", "turning 35 deg", "speed loss", "ratio"),
    Quantity("turning.time_90", "turning 35 deg", "time to 90 deg", "time"),
    Quantity("turning.time_180", "turning 35 deg", "time to 180 deg", "time"),
    Quantity("zigzag10.initial_turning", "zigzag 10/10", "track to the check angle", "length"),
    Quantity("zigzag10.overshoot_1", "zigzag 10/10", "first overshoot", "angle"),
    Quantity("zigzag10.overshoot_2", "zigzag 10/10", "second overshoot", "angle"),
    Quantity("zigzag10.time_1", "zigzag 10/10", "time to first overshoot", "time"),
    Quantity("zigzag10.time_2", "zigzag 10/10", "time to second overshoot", "time"),
    Quantity("zigzag20.overshoot_1", "zigzag 20/20", "first overshoot", "angle"),
    Quantity("zigzag20.overshoot_2", "zigzag 20/20", "second overshoot", "angle"),
    Quantity("zigzag20.time_1", "zigzag 20/20", "time to first overshoot", "time"),
    Quantity("zigzag20.time_2", "zigzag 20/20", "time to second overshoot", "time"),
    Quantity("stopping.track_reach", "crash stop", "track reach", "length"),
    Quantity("stopping.head_reach", "crash stop", "head reach", "length"),
    Quantity("stopping.lateral_deviation", "crash stop", "lateral deviation", "length"),
    Quantity("stopping.time", "crash stop", "time to stop", "time"),
)
QUANTITY = {q.key: q for q in QUANTITIES}
#: the quantities each measurement returns, by kind of manoeuvre
KEYS: dict[str, tuple[str, ...]] = {
    "turning": (
        "advance", "transfer", "tactical_diameter", "steady_diameter", "speed_loss", "time_90",
        "time_180",
    ),
    "zigzag": ("initial_turning", "overshoot_1", "overshoot_2", "time_1", "time_2"),
    "stopping": ("track_reach", "head_reach", "lateral_deviation", "time"),
}  # fmt: skip


def _crossing(values: FloatArray, level: float, start: int = 0) -> float:
    """The fractional index at which ``values`` first reaches ``level`` from below at or after
    ``start`` (linear interpolation between samples); NaN if it never does."""
    above = np.flatnonzero(values[start:] >= level)
    if above.size == 0:
        return math.nan
    k = start + int(above[0])
    if k == start:
        return float(k)
    a, b = values[k - 1], values[k]
    return k - 1 + float((level - a) / (b - a)) if b != a else float(k)


def _at(series: FloatArray, index: float) -> float:
    """``series`` linearly interpolated at a fractional index (NaN for a NaN index)."""
    if math.isnan(index):
        return math.nan
    return float(np.interp(index, np.arange(series.shape[0]), series))


def course_frame(x: FloatArray, k0: int) -> tuple[FloatArray, FloatArray]:
    """Midship positions relative to the execute, along and across (to starboard) the original
    course psi(k0): two arrays (N,) [m]."""
    dx, dy = x[:, 0] - x[k0, 0], x[:, 2] - x[k0, 2]
    c, s = math.cos(x[k0, 4]), math.sin(x[k0, 4])
    return dx * c + dy * s, -dx * s + dy * c


def measure_turning(t: FloatArray, x: FloatArray, k0: int = 0) -> dict[str, float]:
    """Advance, transfer, tactical diameter [m], steady diameter [m], speed loss [-] and the
    times to 90 and 180 deg of heading change [s] of a turn executed at sample ``k0``.

    The turn's side is that of the final heading change; distances across the course are
    counted positive to that side. A quantity the run does not reach is NaN.
    """
    t, x = np.asarray(t, dtype=np.float64), np.asarray(x, dtype=np.float64)
    change = x[:, 4] - x[k0, 4]
    side = 1.0 if change[-1] >= 0 else -1.0
    turned = np.degrees(side * change)
    along, across = course_frame(x, k0)
    across = side * across
    i90, i180 = _crossing(turned, 90.0, k0), _crossing(turned, 180.0, k0)
    speed = np.hypot(x[:, 1], x[:, 3])
    diameter, loss = math.nan, math.nan
    i_from, i_to = _crossing(turned, STEADY_FROM_DEG, k0), _crossing(turned, STEADY_TO_DEG, k0)
    if not math.isnan(i_to):
        window = slice(math.ceil(i_from), math.floor(i_to) + 1)
        mean_u, mean_r = float(np.mean(speed[window])), float(np.mean(np.abs(x[window, 5])))
        diameter = 2.0 * mean_u / mean_r
        loss = 1.0 - mean_u / float(speed[k0])
    return {
        "advance": _at(along, i90),
        "transfer": _at(across, i90),
        "tactical_diameter": _at(across, i180),
        "steady_diameter": diameter,
        "speed_loss": loss,
        "time_90": _at(t, i90) - t[k0],
        "time_180": _at(t, i180) - t[k0],
    }


def rudder_executes(delta: FloatArray, k0: int = 0) -> tuple[list[int], float]:
    """The samples of a zigzag's executes and the side (+1 starboard, -1 port) of the first:
    ``k0``, then each sample at which the rudder starts to move to the other side (found from
    each change of the rudder's sign, back along its monotonic ramp to where it left its held
    angle). The rudder value of sample k is held over the step from sample k to k + 1."""
    d = np.asarray(delta, dtype=np.float64)
    sign = np.sign(d)
    out = [k0]
    nonzero = np.flatnonzero(sign[k0:] != 0)
    if nonzero.size == 0:
        return out, 1.0
    first = side = float(sign[k0 + int(nonzero[0])])
    k = k0 + int(nonzero[0])
    while True:
        flips = np.flatnonzero(sign[k:] == -side)
        if flips.size == 0:
            break
        k += int(flips[0])
        m = k
        while m - 1 > out[-1] + 1 and (d[m - 1] - d[m - 2]) * side < 0:
            m -= 1  # back along the ramp to the sample where the rudder left its angle
        out.append(m)
        side = -side
    return out, first


def _peak(values: FloatArray, start: int, stop: int) -> tuple[float, int]:
    """The maximum of ``values[start:stop]`` and its index, NaN if it is at the window's end
    (the heading still grew: no overshoot peak inside the run)."""
    stop = min(stop, values.shape[0])
    if stop - start < 2:
        return math.nan, -1
    k = start + int(np.argmax(values[start:stop]))
    if k == stop - 1 and stop == values.shape[0]:
        return math.nan, -1
    return float(values[k]), k


def measure_zigzag(
    t: FloatArray, x: FloatArray, delta: FloatArray, k0: int = 0
) -> dict[str, float]:
    """First and second overshoot angles [deg], the times of their heading peaks after the first
    execute [s], and the track travelled until the second execute [m] (the initial turning of
    MSC.137(76) 5.3.2 when the check angle is 10 deg) of a zigzag whose first execute is at
    sample ``k0``.

    Executes are found from the rudder (:func:`rudder_executes`); the n-th overshoot is the
    heading deviation's extremum between execute n + 1 and execute n + 2 (or the end of the
    run) less the deviation at execute n + 1, in the direction the heading was turning.
    """
    t, x = np.asarray(t, dtype=np.float64), np.asarray(x, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64)
    ex, side = rudder_executes(d, k0)
    dev = np.degrees(x[:, 4] - x[k0, 4])
    out = {"overshoot_1": math.nan, "overshoot_2": math.nan, "time_1": math.nan}
    out |= {"time_2": math.nan, "initial_turning": math.nan}
    if len(ex) >= 2:
        speed = np.hypot(x[:, 1], x[:, 3])
        out["initial_turning"] = float(np.trapezoid(speed[k0 : ex[1] + 1], t[k0 : ex[1] + 1]))
    for n in (1, 2):
        if len(ex) < n + 1:
            break
        s = side if n == 1 else -side
        stop = ex[n + 1] + 1 if len(ex) > n + 1 else dev.shape[0]
        peak, k = _peak(s * dev, ex[n], stop)
        if not math.isnan(peak):
            out[f"overshoot_{n}"] = peak - s * dev[ex[n]]
            out[f"time_{n}"] = float(t[k] - t[k0])
    return out


def measure_stopping(t: FloatArray, x: FloatArray, k0: int = 0) -> dict[str, float]:
    """Track reach (path length of midship) [m], head reach (along the original course) [m],
    lateral deviation (across it, signed: + to starboard) [m] and the time [s] from the
    full-astern order at sample ``k0`` to the first zero of the ahead speed u; NaN if u stays
    positive."""
    t, x = np.asarray(t, dtype=np.float64), np.asarray(x, dtype=np.float64)
    i_stop = _crossing(-x[:, 1], 0.0, k0)
    if math.isnan(i_stop):
        return dict.fromkeys(("track_reach", "head_reach", "lateral_deviation", "time"), math.nan)
    speed = np.hypot(x[:, 1], x[:, 3])
    k = math.floor(i_stop)
    frac = i_stop - k
    path = float(np.trapezoid(speed[k0 : k + 1], t[k0 : k + 1]))
    if frac > 0:
        tail_speed = _at(speed, i_stop)
        path += 0.5 * (speed[k] + tail_speed) * frac * (t[k + 1] - t[k])
    along, across = course_frame(x, k0)
    return {
        "track_reach": path,
        "head_reach": _at(along, i_stop),
        "lateral_deviation": _at(across, i_stop),
        "time": _at(t, i_stop) - t[k0],
    }


# ---------------------------------------------------------------------------------------------
# Froude scaling and the IMO criteria


def to_full_scale(key: str, value: float, scale: float = SCALE) -> float:
    """A model-scale value of quantity ``key`` at full scale: lengths x lambda, times x
    sqrt(lambda); angles and ratios unchanged (Froude similarity)."""
    kind = QUANTITY[key].kind
    if kind == "length":
        return value * scale
    if kind == "time":
        return value * math.sqrt(scale)
    return value


def in_ship_lengths(key: str, value: float, L: float = ESSO_OSAKA.L_pp) -> float:
    """A length in ship lengths (the value unchanged for other kinds); L at the value's scale."""
    return value / L if QUANTITY[key].kind == "length" else value


@dataclass(frozen=True)
class Criterion:
    """One limit of MSC.137(76), Annex 5.3: quantity ``key`` must not exceed ``limit`` (in ship
    lengths for lengths, degrees for angles); ``text`` cites the paragraph."""

    key: str
    limit: float
    text: str


def imo_criteria(L_over_V: float) -> tuple[Criterion, ...]:
    """The criteria of MSC.137(76), Annex 5.3 (IMO 2002), for a ship of full-scale L / V [s].

    Turning ability (5.3.1): advance <= 4.5 L, tactical diameter <= 5 L. Initial turning ability
    (5.3.2): with 10 deg rudder, at most 2.5 L travelled by the time the heading has changed by
    10 deg. Yaw checking (5.3.3): 10/10 first overshoot <= 10 deg if L/V < 10 s, 20 deg if L/V >=
    30 s, else 5 + L/V / 2 deg; 10/10 second overshoot <= 25 deg, 40 deg, else 17.5 + 0.75 L/V
    deg; 20/20 first overshoot <= 25 deg. Stopping ability (5.3.4): track reach <= 15 L, which
    the Administration may relax for ships of large displacement, to no more than 20 L.
    """
    if L_over_V < 10.0:
        first, second = 10.0, 25.0
    elif L_over_V >= 30.0:
        first, second = 20.0, 40.0
    else:
        first, second = 5.0 + 0.5 * L_over_V, 17.5 + 0.75 * L_over_V
    LV = f"{L_over_V:.0f} s"
    return (
        Criterion("turning.advance", 4.5, "5.3.1: advance <= 4.5 L"),
        Criterion("turning.tactical_diameter", 5.0, "5.3.1: tactical diameter <= 5 L"),
        Criterion("zigzag10.initial_turning", 2.5, "5.3.2: <= 2.5 L to 10 deg heading change"),
        Criterion("zigzag10.overshoot_1", first, f"5.3.3.1: <= {first:g} deg at L/V {LV}"),
        Criterion("zigzag10.overshoot_2", second, f"5.3.3.2: <= {second:g} deg at L/V {LV}"),
        Criterion("zigzag20.overshoot_1", 25.0, "5.3.3.3: <= 25 deg"),
        Criterion("stopping.track_reach", 15.0, "5.3.4: <= 15 L (large ships: up to 20 L)"),
    )  # fmt: skip


#: the ceiling of the track reach for ships of large displacement (MSC.137(76) 5.3.4) [L]
TRACK_REACH_CEILING = 20.0


def summarise(values: Any, quantiles: tuple[float, float] = (0.05, 0.95)) -> dict[str, float]:
    """Mean, std, the ``quantiles`` and the number of finite values of samples (S,) of one
    quantity (NaN entries, samples that never reached the quantity, are left out and counted)."""
    v = np.asarray(values, dtype=np.float64).ravel()
    ok = v[np.isfinite(v)]
    if ok.size == 0:
        return {"mean": math.nan, "std": math.nan, "lo": math.nan, "hi": math.nan, "n": 0.0}
    lo, hi = np.quantile(ok, quantiles)
    return {
        "mean": float(np.mean(ok)),
        "std": float(np.std(ok)),
        "lo": float(lo),
        "hi": float(hi),
        "n": float(ok.size),
        "missing": float(v.size - ok.size),
    }


def flatten(groups: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """{"turning": {"advance": 1.0}} -> {"turning.advance": 1.0}."""
    return {f"{g}.{k}": float(v) for g, values in groups.items() for k, v in values.items()}


__all__ = [
    "APPROACH_SPEED",
    "L_FULL",
    "QUANTITIES",
    "SCALE",
    "Criterion",
    "Quantity",
    "course_frame",
    "flatten",
    "imo_criteria",
    "in_ship_lengths",
    "measure_stopping",
    "measure_turning",
    "measure_zigzag",
    "rudder_executes",
    "summarise",
    "to_full_scale",
]
