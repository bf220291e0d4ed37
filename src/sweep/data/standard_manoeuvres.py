"""The standard manoeuvres predicted by a parameter set and by samples of it, and the recorded
turning and zigzag runs replayed under their own controls.

Both take the identified parameters and, optionally, parameter samples (an array (S, n) of flat
vectors: the 57 explored values, then the effects' values; or a sequence of
:class:`~mmg.params.Parameters`), e.g. drawn from the identification's uncertainty. Every lane
(the estimate, then each sample) is simulated in one batched call per manoeuvre; the quantities
of :mod:`sweep.data.manoeuvres` are measured on each lane, so each quantity has a point value
and, with samples, an interval.

The standard manoeuvres (MSC.137(76), 4.2) start from a steady straight approach at
:data:`~sweep.data.manoeuvres.APPROACH_SPEED` in calm air, with the propeller at the revolution
that holds that speed (found per lane from the model's surge equation): a turning circle with
35 deg of starboard rudder, the 10/10 and 20/20 zigzags (starboard first; the rudder is reversed
at the first sample at which the heading deviation passes the check angle: a closed loop, run as
one batched simulation per execute), and a crash stop (rudder amidships, the propeller reversed
to :data:`N_ASTERN`). The rudder moves at :data:`RUDDER_RATE`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from mmg.effect import Effect
from mmg.integrate import derivatives, effect_vector, simulate_batch
from mmg.params import Parameters, Ship
from sweep.data.manoeuvres import (
    APPROACH_SPEED,
    KEYS,
    SCALE,
    FloatArray,
    measure_stopping,
    measure_turning,
    measure_zigzag,
    rudder_executes,
)
from sweep.data.recordings import DT, Recording
from sweep.errors import UserError

RUDDER_RATE = math.radians(65.0 / 28.0) * math.sqrt(SCALE)
"""Rudder rate at model scale [rad/s] (24.2 deg/s): SOLAS II-1 regulation 29.3.2, 35 deg on one
side to 30 deg on the other in 28 s at full scale, Froude-scaled. The recordings' logged rudder
angle steps within one 0.1-s sample (it is the order), so they bound no slower rate."""
N_ASTERN = -10.0
"""Propeller revolution of the crash stop [rev/s]: full astern of the random runs the models are
identified on (the berthing runs go to -20 rev/s, outside the training range)."""
REVERSAL_SECONDS = 0.3
"""Time for the propeller to go from the approach revolution to :data:`N_ASTERN` at model scale
[s]: the recordings' random runs reverse 10 to -10 rev/s within 0.3 s."""
N_MAX = 40.0
"""Largest approach revolution searched [rev/s]."""


@dataclass(frozen=True)
class Settings:
    """How the standard manoeuvres are run (model scale, SI units, angles in radians)."""

    approach_speed: float = APPROACH_SPEED
    rudder_rate: float = RUDDER_RATE
    turning_rudder: float = math.radians(35.0)
    zigzags: tuple[float, ...] = (math.radians(10.0), math.radians(20.0))
    n_astern: float = N_ASTERN
    reversal_seconds: float = REVERSAL_SECONDS
    turning_seconds: float = 600.0
    zigzag_seconds: float = 300.0
    stopping_seconds: float = 300.0
    dt: float = DT


@dataclass(frozen=True)
class Runs:
    """Simulated runs of one manoeuvre: t (K + 1,) [s], states (R, K + 1, 6), rudder (R, K + 1)
    [rad] (NaN-padded after a lane's end), lane 0 the estimate, lanes 1.. the samples; ``bad``
    (R,) bool the lanes that diverged or found no approach revolution (None: not known), which
    have no quantities and are not drawn."""

    t: FloatArray
    states: FloatArray
    delta: FloatArray
    bad: np.ndarray | None = None


@dataclass(frozen=True)
class Prediction:
    """Quantities of the standard manoeuvres, per lane: ``values[key]`` (R,) at model scale
    (keys of :data:`~sweep.data.manoeuvres.QUANTITIES`), lane 0 the estimate. ``n_approach`` (R,)
    the propeller revolution holding the approach speed (NaN: none up to :data:`N_MAX`; such a
    lane, and one that diverged, has NaN quantities). ``runs`` the trajectories by manoeuvre."""

    settings: Settings
    values: dict[str, FloatArray]
    n_approach: FloatArray
    runs: dict[str, Runs] = field(repr=False)

    @property
    def n_samples(self) -> int:
        """Number of parameter samples (lanes after the estimate)."""
        return int(self.n_approach.shape[0] - 1)


def parameter_rows(
    params: Parameters, samples: Any = None, effects: tuple[Effect, ...] = ()
) -> FloatArray:
    """(1 + S, n) flat parameter vectors: ``params``, then the S ``samples`` (an array (S, n) or
    (n,), or a sequence of :class:`Parameters`; None for none)."""
    base = np.concatenate([params.vector(), effect_vector(params, effects)])
    if samples is None:
        return base[None, :]
    if isinstance(samples, np.ndarray) or (
        len(samples) > 0 and not isinstance(samples[0], Parameters)
    ):
        rows = np.atleast_2d(np.asarray(samples, dtype=np.float64))
    else:
        rows = np.array([np.concatenate([q.vector(), effect_vector(q, effects)]) for q in samples])
    if rows.size == 0:
        return base[None, :]
    if rows.ndim != 2 or rows.shape[1] != base.size:
        raise UserError(
            f"parameter samples must have shape (S, {base.size}) (the 57 explored values, then "
            f"{base.size - 57} effect values); got {rows.shape}"
        )
    if not np.all(np.isfinite(rows)):
        raise UserError("parameter samples contain non-finite values")
    return np.concatenate([base[None, :], rows])


def approach_revolutions(
    rows: FloatArray, speed: float, effects: tuple[Effect, ...], ship: Ship, iterations: int = 60
) -> FloatArray:
    """(R,) the propeller revolution [rev/s] at which each parameter row's surge acceleration
    vanishes at ``speed`` [m/s], straight ahead, rudder amidships, calm air (bisection on
    [0, :data:`N_MAX`]); NaN where u_dot does not change sign there."""
    R = rows.shape[0]
    x = np.zeros((R, 6))
    x[:, 1] = speed
    wind = np.zeros((R, 2))

    def u_dot(n: FloatArray) -> FloatArray:
        u = np.stack([np.zeros(R), n], axis=1)
        return derivatives(x, u, wind, rows, effects, ship)[:, 1]

    lo, hi = np.zeros(R), np.full(R, N_MAX)
    f_lo, f_hi = u_dot(lo), u_dot(hi)
    bracket = (f_lo <= 0.0) & (f_hi >= 0.0)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        below = u_dot(mid) < 0.0
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return np.where(bracket, 0.5 * (lo + hi), np.nan)


def rudder_ramp(
    start: FloatArray, target: FloatArray, rate: float, dt: float, K: int
) -> FloatArray:
    """(B, K) rudder angles [rad] moving from ``start`` (B,) to ``target`` (B,) at ``rate``
    [rad/s], one value per step (the first already one step's travel from ``start``)."""
    travel = np.arange(1, K + 1) * rate * dt
    gap = target - start
    return start[:, None] + np.sign(gap)[:, None] * np.minimum(
        travel[None, :], np.abs(gap)[:, None]
    )


def _approach_states(n_lanes: int, speed: float) -> FloatArray:
    x0 = np.zeros((n_lanes, 6))
    x0[:, 1] = speed
    return x0


def _open_loop(
    rows: FloatArray,
    n_app: FloatArray,
    s: Settings,
    effects: tuple[Effect, ...],
    ship: Ship,
) -> tuple[Runs, Runs, np.ndarray, np.ndarray]:
    """The turning circle and the crash stop of every lane in one batch, and the lanes (R,)
    bool of each that diverged."""
    R = rows.shape[0]
    K_turn, K_stop = round(s.turning_seconds / s.dt), round(s.stopping_seconds / s.dt)
    K = max(K_turn, K_stop)
    n = np.nan_to_num(n_app)
    U = np.zeros((2 * R, K, 2))
    U[:R, :, 0] = rudder_ramp(np.zeros(R), np.full(R, s.turning_rudder), s.rudder_rate, s.dt, K)
    U[:R, :, 1] = n[:, None]
    steps = np.arange(1, K + 1) * s.dt / s.reversal_seconds
    U[R:, :, 1] = n[:, None] + (s.n_astern - n)[:, None] * np.minimum(steps, 1.0)[None, :]
    lengths = np.r_[np.full(R, K_turn), np.full(R, K_stop)]
    res = simulate_batch(
        _approach_states(2 * R, s.approach_speed),
        U,
        np.zeros_like(U),
        np.concatenate([rows, rows]),
        s.dt,
        n_steps=lengths,
        effects=effects,
        ship=ship,
    )
    t = np.arange(K + 1, dtype=np.float64) * s.dt
    delta = np.concatenate([U[:, :, 0], U[:, -1:, 0]], axis=1)
    turn = Runs(t[: K_turn + 1], res.states[:R, : K_turn + 1], delta[:R, : K_turn + 1])
    stop = Runs(t[: K_stop + 1], res.states[R:, : K_stop + 1], delta[R:, : K_stop + 1])
    return turn, stop, res.diverged[:R], res.diverged[R:]


def simulate_zigzag(
    rows: FloatArray,
    x0: FloatArray,
    n_p: FloatArray,
    wind: FloatArray,
    check: float,
    rate: float,
    effects: tuple[Effect, ...],
    ship: Ship,
    first_side: float = 1.0,
    t0: float = 0.0,
    max_executes: int = 40,
    dt: float = DT,
) -> tuple[Runs, np.ndarray]:
    """A check/check zigzag (rudder angle = check angle ``check`` [rad], first to
    ``first_side``, +1 starboard) of every lane from x0 (R, 6) under the propeller n_p (R, K)
    [rev/s] and true wind (R, K, 2); the rudder moves at ``rate`` [rad/s]. Returns the runs and
    the lanes (R,) bool that diverged.

    Closed loop by restarts: all lanes are simulated to the end with the rudder held at its
    current side; at the first sample at which a lane's heading deviation from x0 passes the
    check angle on that side the rudder order reverses (at most ``max_executes`` executes), and
    the lane is simulated again from that sample's state. One batched call per execute."""
    R, K = n_p.shape
    states = np.full((R, K + 1, 6), np.nan)
    delta = np.zeros((R, K + 1))
    start = np.zeros(R, dtype=np.int64)
    side = np.full(R, first_side)
    rudder0 = np.zeros(R)
    diverged = np.zeros(R, dtype=bool)
    states[:, 0] = x0
    lanes = np.arange(R)
    for _ in range(max_executes):
        if lanes.size == 0:
            break
        Kr = K - start[lanes]
        width = int(Kr.max())
        ramp = rudder_ramp(rudder0[lanes], side[lanes] * check, rate, dt, width)
        U = np.zeros((lanes.size, width, 2))
        W = np.zeros_like(U)
        U[:, :, 0] = ramp
        for i, lane in enumerate(lanes):
            U[i, : Kr[i], 1] = n_p[lane, start[lane] :]
            W[i, : Kr[i]] = wind[lane, start[lane] :]
        res = simulate_batch(
            states[lanes, start[lanes]], U, W, rows[lanes], dt, n_steps=Kr, effects=effects,
            ship=ship, t0=t0 + start[lanes] * dt,
        )  # fmt: skip
        diverged[lanes] |= res.diverged
        following = []
        for i, lane in enumerate(lanes):
            k0, n = int(start[lane]), int(Kr[i])
            states[lane, k0:] = res.states[i, : n + 1]
            delta[lane, k0:K] = ramp[i, :n]
            turned = side[lane] * (states[lane, k0 + 1 :, 4] - x0[lane, 4])
            passed = np.flatnonzero(turned >= check)
            if passed.size and not res.diverged[i]:
                start[lane] = k0 + 1 + int(passed[0])
                rudder0[lane] = delta[lane, start[lane] - 1]
                side[lane] = -side[lane]
                following.append(lane)
        lanes = np.array(following, dtype=np.int64)
    delta[:, K] = delta[:, K - 1]
    return Runs(np.arange(K + 1, dtype=np.float64) * dt, states, delta), diverged


def _measure_lanes(kind: str, runs: Runs, bad: np.ndarray, k0: int = 0) -> dict[str, FloatArray]:
    """{quantity: (R,)} of one manoeuvre ("turning", "stopping" or "zigzag") measured on every
    lane (NaN for a bad lane)."""
    R = runs.states.shape[0]
    out = {key: np.full(R, np.nan) for key in KEYS[kind]}
    for lane in range(R):
        x = runs.states[lane]
        if bad[lane] or not np.all(np.isfinite(x)):
            continue
        if kind == "turning":
            m = measure_turning(runs.t, x, k0)
        elif kind == "stopping":
            m = measure_stopping(runs.t, x, k0)
        else:
            m = measure_zigzag(runs.t, x, runs.delta[lane], k0)
        for key, value in m.items():
            out[key][lane] = value
    return out


def predict_standard(
    params: Parameters,
    samples: Any = None,
    effects: tuple[Effect, ...] = (),
    settings: Settings | None = None,
) -> Prediction:
    """The standard manoeuvres of ``params`` and of its ``samples`` (see
    :func:`parameter_rows`); quantities at model scale (see :func:`to_full_scale
    <sweep.data.manoeuvres.to_full_scale>`)."""
    s = settings or Settings()
    rows = parameter_rows(params, samples, effects)
    n_app = approach_revolutions(rows, s.approach_speed, effects, params.ship)
    no_approach = ~np.isfinite(n_app)
    turn, stop, bad_turn, bad_stop = _open_loop(rows, n_app, s, effects, params.ship)
    runs = {
        "turning": replace(turn, bad=bad_turn | no_approach),
        "stopping": replace(stop, bad=bad_stop | no_approach),
    }
    groups = {
        "turning": _measure_lanes("turning", turn, bad_turn | no_approach),
        "stopping": _measure_lanes("stopping", stop, bad_stop | no_approach),
    }
    for check in s.zigzags:
        name = f"zigzag{round(math.degrees(check))}"
        K = round(s.zigzag_seconds / s.dt)
        n_p = np.broadcast_to(np.nan_to_num(n_app)[:, None], (n_app.size, K))
        x0 = _approach_states(n_app.size, s.approach_speed)
        wind = np.zeros((n_app.size, K, 2))
        zz, bad_z = simulate_zigzag(
            rows, x0, n_p, wind, check, s.rudder_rate, effects, params.ship, dt=s.dt
        )
        runs[name] = replace(zz, bad=bad_z | no_approach)
        groups[name] = _measure_lanes("zigzag", zz, bad_z | no_approach)
    values = {f"{g}.{k}": v for g, measured in groups.items() for k, v in measured.items()}
    return Prediction(settings=s, values=values, n_approach=n_app, runs=runs)


# ---------------------------------------------------------------------------------------------
# recorded turning and zigzag runs

RunKind = Literal["turning", "zigzag"]

MIN_HOLD_SECONDS = 3.0
"""Shortest rudder hold that counts as part of a manoeuvre [s]."""
MIN_HOLD_DEG = 5.0
"""Smallest rudder angle of a manoeuvre's hold [deg]."""
MIN_TURN_SECONDS = 60.0
"""Shortest hold of a turning run [s]."""
MAX_RAMP_SAMPLES = 30
"""Longest rudder movement between two holds of a zigzag [samples]."""


@dataclass(frozen=True)
class RecordedRun:
    """The manoeuvre part of a recording: samples ``k0`` (the first execute) to ``end``
    (exclusive), its kind and rudder angle [deg]; ``label`` names it in tables."""

    recording: Recording
    kind: RunKind
    k0: int
    end: int
    angle_deg: float
    label: str

    @property
    def title(self) -> str:
        """``"turning 35 deg"`` or ``"zigzag 20/20"``."""
        a = round(self.angle_deg)
        return f"turning {a} deg" if self.kind == "turning" else f"zigzag {a}/{a}"


def _holds(delta: FloatArray) -> list[tuple[int, int]]:
    """(start, end) of the rudder's constant stretches of at least :data:`MIN_HOLD_SECONDS` at
    :data:`MIN_HOLD_DEG` or more."""
    change = np.flatnonzero(np.abs(np.diff(delta)) > 1e-6) + 1
    starts, ends = np.r_[0, change], np.r_[change, delta.size]
    return [
        (int(a), int(b))
        for a, b in zip(starts, ends, strict=True)
        if (b - a) * DT >= MIN_HOLD_SECONDS and abs(math.degrees(delta[a])) >= MIN_HOLD_DEG
    ]


def _ramp_start(delta: FloatArray, k: int) -> int:
    """The first sample of the rudder's monotonic movement that ends in the hold starting at
    ``k``."""
    step = np.sign(delta[k] - delta[k - 1]) if k > 0 else 0.0
    while k - 1 > 0 and step != 0 and (delta[k - 1] - delta[k - 2]) * step > 0:
        k -= 1
    return k


def find_manoeuvre(rec: Recording, label: str = "") -> RecordedRun | None:
    """The turning or zigzag manoeuvre of a recording, from its rudder: a zigzag is the longest
    chain of at least three holds of alternating side and like angle (within 20 %), each
    reached within :data:`MAX_RAMP_SAMPLES` of the last; a turn is a hold of at least
    :data:`MIN_TURN_SECONDS` with 180 deg of heading change. None if neither is found."""
    d = rec.u[:, 0]
    holds = _holds(d)
    best: list[tuple[int, int]] = []
    chain: list[tuple[int, int]] = []
    for a, b in holds:
        if chain:
            pa, pb = chain[-1]
            alike = abs(abs(d[a]) - abs(d[pa])) <= 0.2 * abs(d[pa])
            if not (a - pb <= MAX_RAMP_SAMPLES and d[a] * d[pa] < 0 and alike):
                chain = []
        chain.append((a, b))
        best = list(chain) if len(chain) > len(best) else best
    name = label or rec.name
    if len(best) >= 3:
        angle = float(np.median([abs(math.degrees(d[a])) for a, _ in best]))
        return RecordedRun(rec, "zigzag", _ramp_start(d, best[0][0]), best[-1][1], angle, name)
    for a, b in sorted(holds, key=lambda h: h[0] - h[1]):
        turned = abs(math.degrees(rec.x[b - 1, 4] - rec.x[a, 4]))
        if (b - a) * DT >= MIN_TURN_SECONDS and turned >= 180.0:
            angle = abs(math.degrees(d[a]))
            return RecordedRun(rec, "turning", _ramp_start(d, a), b, angle, name)
    return None


@dataclass(frozen=True)
class Comparison:
    """A recorded run against the model under its recorded controls and wind: ``measured``
    {quantity: value} from the recording, ``predicted`` {quantity: (R,)} (lane 0 the estimate),
    ``runs`` the simulated lanes (from the recorded state at the first execute)."""

    run: RecordedRun
    measured: dict[str, float]
    predicted: dict[str, FloatArray]
    runs: Runs


def _measure(kind: RunKind, t: FloatArray, x: FloatArray, delta: FloatArray) -> dict[str, float]:
    if kind == "turning":
        return measure_turning(t, x, 0)
    return measure_zigzag(t, x, delta, 0)


def _replay_turns(
    rows: FloatArray, runs: Sequence[RecordedRun], effects: tuple[Effect, ...], ship: Ship
) -> list[tuple[Runs, np.ndarray]]:
    """The turning runs under their recorded rudder, propeller and wind, in one batch: per run
    the simulated lanes and those that diverged."""
    if not runs:
        return []
    R = rows.shape[0]
    lengths = np.array([r.end - r.k0 - 1 for r in runs])
    U = np.zeros((len(runs) * R, int(lengths.max()), 2))
    W = np.zeros_like(U)
    x0 = np.empty((len(runs) * R, 6))
    t0 = np.empty(len(runs) * R)
    for j, r in enumerate(runs):
        lanes = slice(j * R, (j + 1) * R)
        U[lanes, : lengths[j]] = r.recording.u[r.k0 : r.end - 1]
        W[lanes, : lengths[j]] = r.recording.w[r.k0 : r.end - 1]
        x0[lanes], t0[lanes] = r.recording.x[r.k0], r.recording.t[r.k0]
    res = simulate_batch(
        x0, U, W, np.tile(rows, (len(runs), 1)), DT, n_steps=np.repeat(lengths, R),
        effects=effects, ship=ship, t0=t0,
    )  # fmt: skip
    out = []
    for j, r in enumerate(runs):
        n = int(lengths[j]) + 1
        t = r.recording.t[r.k0 : r.end] - r.recording.t[r.k0]
        delta = np.broadcast_to(r.recording.u[r.k0 : r.end, 0], (R, n))
        out.append(
            (Runs(t, res.states[j * R : (j + 1) * R, :n], delta), res.diverged[j * R : (j + 1) * R])
        )
    return out


def _replay_zigzag(
    rows: FloatArray, run: RecordedRun, effects: tuple[Effect, ...], ship: Ship
) -> tuple[Runs, np.ndarray]:
    """A zigzag run as the model steers it: from the recorded state at the first execute,
    under the recorded propeller and wind, the rudder reversed by the zigzag's rule at the
    model's own heading (check angle = rudder angle = the run's nominal angle), moving within
    one sample as the recorded rudder does."""
    R = rows.shape[0]
    rec = run.recording
    d = rec.u[run.k0 : run.end, 0]
    _, first_side = rudder_executes(d, 0)
    check = math.radians(round(run.angle_deg))
    return simulate_zigzag(
        rows, np.tile(rec.x[run.k0], (R, 1)), np.tile(rec.u[run.k0 : run.end - 1, 1], (R, 1)),
        np.tile(rec.w[run.k0 : run.end - 1], (R, 1, 1)), check, 2.0 * check / DT, effects, ship,
        first_side=first_side, t0=float(rec.t[run.k0]),
    )  # fmt: skip


def compare_recorded(
    params: Parameters,
    runs: Sequence[RecordedRun],
    samples: Any = None,
    effects: tuple[Effect, ...] = (),
) -> list[Comparison]:
    """Each recorded run measured, and the model (``params`` and ``samples``, see
    :func:`parameter_rows`) simulated from the recorded state at the run's first execute under
    the recorded propeller and true wind, measured the same way. A turn keeps its recorded
    rudder (one batched call for all turns); a zigzag's rudder follows the zigzag's rule at the
    model's own heading (:func:`simulate_zigzag`), so that its overshoots are those of a zigzag
    test of the model."""
    rows = parameter_rows(params, samples, effects)
    turns = [r for r in runs if r.kind == "turning"]
    replayed = dict(
        zip((id(r) for r in turns), _replay_turns(rows, turns, effects, params.ship), strict=True)
    )
    out = []
    for r in runs:
        rec = r.recording
        t, delta = rec.t[r.k0 : r.end] - rec.t[r.k0], rec.u[r.k0 : r.end, 0]
        sim, bad = (
            replayed[id(r)]
            if r.kind == "turning"
            else _replay_zigzag(rows, r, effects, params.ship)
        )
        predicted = _measure_lanes(r.kind, sim, bad)
        measured = _measure(r.kind, t, rec.x[r.k0 : r.end], delta)
        out.append(Comparison(r, measured, predicted, replace(sim, bad=bad)))
    return out


__all__ = [
    "N_ASTERN",
    "RUDDER_RATE",
    "Comparison",
    "Prediction",
    "RecordedRun",
    "Runs",
    "Settings",
    "approach_revolutions",
    "compare_recorded",
    "find_manoeuvre",
    "parameter_rows",
    "predict_standard",
    "rudder_ramp",
    "simulate_zigzag",
]
