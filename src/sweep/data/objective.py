"""The objectives J1, J2, J3 of the paper (section 3.1, Eqs. (29)-(37)) over a whole population.

Each recording is split into contiguous subsequences of t_f = 100 s (the last one shorter; a
sample is shared by the end of one subsequence and the start of the next). Each subsequence is an
initial-value problem: the simulation starts from the recorded first state and is driven by the
recorded controls and true wind (zero-order hold). Per subsequence i and observable j,

    z_hat = (z - mu_j^i) / sigma_j^i   (recorded and simulated series each with their own mean
                                        and standard deviation over the subsequence's samples)
    J = sum_i sum_j int_0^{t_f} (z_hat_input - z_hat_sim)^2 dt   (trapezoid rule, dt = 0.1 s)

with z = (u, v_m, r) for J1, (x0, u, y0, v_m, sin psi, cos psi, r) for J2 and
(x0, y0, sin psi, cos psi) for J3, so that J2 = J1 + J3 exactly (the per-channel integrals are
computed once and summed).

Standardisation floor: sigma is replaced by max(sigma, floor_j) for both series, so that a channel
that barely moves in a subsequence (heading during a straight run-in, v_m on a straight course)
does not turn measurement noise into a huge J. The floors (:data:`DEFAULT_FLOORS`) are about the
noise level of the recordings: 5 cm for positions, 5 mm/s for velocities, 0.01 for sin and cos
of the heading (0.6 deg), 2e-3 rad/s for r.

Failure is a value: a simulation that diverges (limiter of Algorithm 1 hit, or non-finite) costs
:data:`PENALTY_FACTOR` x (duration of the subsequence) per channel. A standardised series has a
mean square of at most 1, so a finite simulation can cost at most about 4 x duration per channel:
the penalty is larger than any finite result, finite, and never NaN.

The population is simulated with :func:`mmg.integrate.segment_moments`, which streams the moments
J needs instead of storing trajectories.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg.effect import Effect
from mmg.integrate import OBSERVABLES, Segments, segment_moments
from mmg.params import ESSO_OSAKA, Parameters, Ship
from sweep.data.recordings import Recording

FloatArray = NDArray[np.float64]

#: channels (indices into :data:`mmg.integrate.OBSERVABLES`) of each objective
CHANNELS: dict[str, tuple[int, ...]] = {
    "J1": (1, 3, 6),  # u, v_m, r
    "J2": (0, 1, 2, 3, 4, 5, 6),  # x0, u, y0, v_m, sin psi, cos psi, r
    "J3": (0, 2, 4, 5),  # x0, y0, sin psi, cos psi
}
#: the objectives' names, ("J1", "J2", "J3")
OBJECTIVES = tuple(CHANNELS)

#: standardisation floors per observable (units of the observable)
DEFAULT_FLOORS: dict[str, float] = {
    "x0": 0.05,
    "u": 0.005,
    "y0": 0.05,
    "v_m": 0.005,
    "sin_psi": 0.01,
    "cos_psi": 0.01,
    "r": 0.002,
}
#: cost per channel of a diverged subsequence, in units of its duration
PENALTY_FACTOR = 10.0
#: subsequence duration of the paper [s]
T_F = 100.0


def observables(x: FloatArray) -> FloatArray:
    """The seven observables (x0, u, y0, v_m, sin psi, cos psi, r) of states x (..., 6)."""
    return np.stack(
        [
            x[..., 0],
            x[..., 1],
            x[..., 2],
            x[..., 3],
            np.sin(x[..., 4]),
            np.cos(x[..., 4]),
            x[..., 5],
        ],
        axis=-1,
    )


@dataclass(frozen=True)
class SegmentIndex:
    """Where a subsequence comes from: recording name, first sample, number of steps."""

    recording: str
    start: int
    n_steps: int


def split_recording(rec: Recording, t_f: float = T_F) -> list[SegmentIndex]:
    """Contiguous subsequences of t_f seconds (the last one shorter, at least one step)."""
    steps = round(t_f / rec.dt)
    total = rec.n_samples - 1
    return [
        SegmentIndex(rec.name, start, min(steps, total - start)) for start in range(0, total, steps)
    ]


@dataclass
class SegmentSet:
    """The subsequences of a list of recordings, ready for population evaluation.

    ``groups`` maps a label (a recording's name, or a subset name such as "Test-R") to the indices
    of its subsequences, for per-subset reporting.
    """

    recordings: Sequence[Recording]
    t_f: float = T_F
    floors: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_FLOORS))
    labels: Sequence[str] | None = None

    def __post_init__(self) -> None:
        if not self.recordings:
            raise ValueError("no recordings to evaluate")
        dts = {round(r.dt, 9) for r in self.recordings}
        if len(dts) != 1:
            raise ValueError(f"recordings have different time steps: {sorted(dts)}")
        self.dt = float(next(iter(dts)))
        labels = list(self.labels) if self.labels is not None else [r.name for r in self.recordings]
        self.index: list[SegmentIndex] = []
        self.groups: dict[str, list[int]] = {}
        for label, rec in zip(labels, self.recordings, strict=True):
            for seg in split_recording(rec, self.t_f):
                self.groups.setdefault(label, []).append(len(self.index))
                self.index.append(seg)
        by_name = {r.name: r for r in self.recordings}
        S = len(self.index)
        K = max(s.n_steps for s in self.index)
        floor = np.array([self.floors[name] for name in OBSERVABLES])
        x0 = np.zeros((S, 6))
        t0 = np.zeros(S)  # start times on the recordings' clocks
        u = np.zeros((S, K, 2))
        w = np.zeros((S, K, 2))
        ref = np.zeros((S, K + 1, 7))
        shift = np.zeros((S, 7))
        self.ref_square = np.zeros((S, 7))  # sum_k w_k z_hat_in^2
        self.ref_sum = np.zeros((S, 7))  # sum_k w_k z_hat_in
        self.weight_sum = np.zeros(S)  # sum_k w_k = n_steps
        self.n_samples = np.zeros(S)
        for s, seg in enumerate(self.index):
            rec = by_name[seg.recording]
            n = seg.n_steps
            sl = slice(seg.start, seg.start + n + 1)
            z = observables(rec.x[sl])
            sigma = np.maximum(z.std(axis=0), floor)
            z_hat = (z - z.mean(axis=0)) / sigma  # paper Eq. (33)
            wt = np.ones(n + 1)
            wt[0] = wt[-1] = 0.5
            x0[s] = rec.x[seg.start]
            t0[s] = rec.t[seg.start]
            u[s, :n] = rec.u[seg.start : seg.start + n]
            w[s, :n] = rec.w[seg.start : seg.start + n]
            ref[s, : n + 1] = z_hat
            shift[s] = z[0]
            self.ref_square[s] = wt @ (z_hat * z_hat)
            self.ref_sum[s] = wt @ z_hat
            self.weight_sum[s] = wt.sum()
            self.n_samples[s] = n + 1
        self.floor = floor
        steps = np.array([s.n_steps for s in self.index])
        self.segments = Segments(x0, u, w, steps, ref, shift, t0)

    @property
    def durations(self) -> FloatArray:
        """Duration of each subsequence [s], shape (S,)."""
        return self.weight_sum * self.dt

    def channel_costs(self, mom: FloatArray, bad: np.ndarray) -> FloatArray:
        """Per-channel integrals (C, S, 7) from streamed moments (C, S, 7, 5) and flags (C, S)."""
        m0, m1, m2, m3, m4 = (mom[..., i] for i in range(5))
        n = self.n_samples[None, :, None]
        mu = m0 / n
        var = np.maximum(m1 / n - mu * mu, 0.0)
        sigma = np.maximum(np.sqrt(var), self.floor)
        sw = self.weight_sum[None, :, None]
        cross = (m4 - mu * self.ref_sum[None]) / sigma  # sum w z_hat_in z_hat_sim
        sim2 = (m3 - 2.0 * mu * m2 + mu * mu * sw) / (sigma * sigma)  # sum w z_hat_sim^2
        cost = self.dt * np.maximum(self.ref_square[None] - 2.0 * cross + sim2, 0.0)  # Eq. (32)
        penalty = PENALTY_FACTOR * self.durations[None, :, None]
        failed = (bad >= 0)[..., None] | ~np.isfinite(cost)
        return np.where(failed, penalty, cost)


class Objective:
    """J1, J2 and J3 of a population over a set of recordings.

    ``evaluate(thetas)`` returns the chosen objective per candidate; ``costs(thetas)`` the
    per-subsequence, per-channel integrals for any breakdown (see :meth:`table`).
    """

    def __init__(
        self,
        recordings: Sequence[Recording],
        name: str = "J2",
        labels: Sequence[str] | None = None,
        t_f: float = T_F,
        floors: Mapping[str, float] | None = None,
        effects: tuple[Effect, ...] = (),
        ship: Ship = ESSO_OSAKA,
    ) -> None:
        if name not in CHANNELS:
            raise ValueError(f"unknown objective {name!r}; choose one of {', '.join(OBJECTIVES)}")
        self.name = name
        self.effects = effects
        self.ship = ship
        self.data = SegmentSet(recordings, t_f, dict(floors or DEFAULT_FLOORS), labels)
        self.seconds = 0.0  # time spent simulating (the kernel and the moments-to-J algebra)
        #: CPU time of this process in the same calls (all its threads): on a CPU shared with
        #: other jobs' workers the wall time above also counts the time spent waiting
        self.cpu_seconds = 0.0

    @property
    def n_segments(self) -> int:
        """Number of subsequences (initial-value problems) over all recordings."""
        return len(self.data.index)

    @property
    def max_penalty(self) -> float:
        """The value of a candidate whose every subsequence diverged (the worst finite value)."""
        n_channels = len(CHANNELS[self.name])
        return float(PENALTY_FACTOR * self.data.durations.sum() * n_channels)

    def costs(self, thetas: Any) -> tuple[FloatArray, np.ndarray]:
        """(C, S, 7) per-channel integrals and (C, S) divergence flags for C candidates.

        ``thetas``: array (C, n) of flat vectors (57 + effect parameters), or a Parameters.
        """
        p: Any = thetas
        if not isinstance(thetas, Parameters):
            p = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
        t0 = time.perf_counter()
        c0 = time.process_time()
        mom, bad = segment_moments(
            self.data.segments, p, self.data.dt, effects=self.effects, ship=self.ship
        )
        cost = self.data.channel_costs(mom, bad)
        self.seconds += time.perf_counter() - t0
        self.cpu_seconds += time.process_time() - c0
        return cost, bad >= 0

    def evaluate(self, thetas: Any, name: str | None = None) -> FloatArray:
        """Objective values (C,) of C candidates (``name`` overrides the objective)."""
        cost, _ = self.costs(thetas)
        return objective_values(cost, name or self.name)

    def table(self, thetas: Any) -> dict[str, dict[str, FloatArray]]:
        """{J: {group label: (C,) values}} for J1, J2, J3 and each group of subsequences."""
        return self.table_of(self.costs(thetas)[0])

    def table_of(self, cost: FloatArray) -> dict[str, dict[str, FloatArray]]:
        """:meth:`table` of per-channel integrals ``cost`` (C, S, 7) from :meth:`costs`."""
        out: dict[str, dict[str, FloatArray]] = {}
        for J in OBJECTIVES:
            per_seg = objective_per_segment(cost, J)
            out[J] = {g: per_seg[:, idx].sum(axis=1) for g, idx in self.data.groups.items()}
        return out


def objective_per_segment(cost: FloatArray, name: str) -> FloatArray:
    """(C, S) values of objective ``name`` per subsequence. J2 is J1 + J3 by construction."""
    if name == "J2":
        return objective_per_segment(cost, "J1") + objective_per_segment(cost, "J3")
    return cost[..., list(CHANNELS[name])].sum(axis=-1)


def objective_values(cost: FloatArray, name: str) -> FloatArray:
    """(C,) totals of objective ``name`` from per-channel costs (C, S, 7)."""
    return objective_per_segment(cost, name).sum(axis=-1)
