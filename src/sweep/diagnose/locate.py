"""Locate a model-data mismatch: residuals per run, window and regime.

The objectives standardise each 100-s subsequence, so this module does the same: for every
subsequence the simulation (started from the recorded state, driven by the recorded controls and
wind) is compared with the recording sample by sample, residuals are divided by the recording's
own standard deviation in that subsequence (with the objective's floors), and each sample carries
the regime it was in:

- ``beta_deg``: drift angle atan2(-v_m, u) [deg], folded to [0, 180];
- ``quadrant``: propeller quadrant 1 (u >= 0, n >= 0), 2 (u < 0, n >= 0), 3 (u >= 0, n < 0),
  4 (u < 0, n < 0);
- ``delta_deg``: |rudder angle| [deg];
- ``gamma_A_deg``: apparent wind direction from the bow [deg], folded to [0, 180];
- ``U``: speed over ground [m/s]; ``n_p`` [rev/s];
- ``psi_deg``: heading in the basin [deg], 0 to 360;
- ``x0``, ``y0`` [m]: position in the basin; ``t_run`` [s]: time since the run's start;
  ``u_dot`` [m/s^2], ``r_dot`` [deg/s^2]: the recorded accelerations (central differences),
  binned at their quintiles (a force tied to the basin, to the run's history or to
  accelerations, such as a mis-estimated added mass, concentrates in one of these).

:func:`locate` bins each regime variable and measures how much of the residual energy the bins
explain (the between-bin share of the sum of squares, eta^2, and the worst bin's mean square
relative to the average), per channel group (velocities = J1's channels, track = J3's). A high
eta^2 for one variable says where the mismatch concentrates; runs and windows are ranked too.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mmg import Effect, Parameters, simulate_batch
from sweep.data.objective import DEFAULT_FLOORS, observables, split_recording
from sweep.data.recordings import Recording

#: the standardised residual channels (the J2 observables)
CHANNELS = ("x0", "u", "y0", "v_m", "sin_psi", "cos_psi", "r")
#: channel groups: velocities (J1's channels) and track (J3's)
GROUPS = {"velocity": ("u", "v_m", "r"), "track": ("x0", "y0", "sin_psi", "cos_psi")}
#: regime variables and their bin edges
BINS: dict[str, np.ndarray] = {
    "beta_deg": np.array([0, 5, 10, 20, 45, 90, 135, 180.0001]),
    "quadrant": np.array([0.5, 1.5, 2.5, 3.5, 4.5]),
    "delta_deg": np.array([0, 5, 10, 20, 30, 45]),
    "gamma_A_deg": np.array([0, 30, 60, 90, 120, 150, 180.0001]),
    "U": np.array([0, 0.05, 0.1, 0.2, 0.3, 1.0]),
    "n_p": np.array([-25, -10, -0.5, 0.5, 5, 10, 25]),
    "psi_deg": np.arange(0.0, 361.0, 45.0),
}
#: regime variables binned at their quintiles in the data at hand
QUANTILE_VARS = ("x0", "y0", "t_run", "u_dot", "r_dot")


def bin_edges(frame: pd.DataFrame) -> dict[str, list[float]]:
    """Bin edges of every regime variable present in ``frame``."""
    out = {v: list(e) for v, e in BINS.items() if v in frame}
    for v in QUANTILE_VARS:
        if v not in frame:
            continue
        edges = np.unique(np.nanquantile(frame[v], np.linspace(0.0, 1.0, 6)))
        if edges.size >= 3:
            edges[-1] = np.nextafter(edges[-1], np.inf)
            out[v] = [float(e) for e in edges]
    return out


def regimes(
    x: np.ndarray, u: np.ndarray, w: np.ndarray, dt: float | None = None
) -> dict[str, np.ndarray]:
    """The regime variables of samples: states x (N, 6), controls u (N, 2), wind w (N, 2);
    with the sample interval ``dt`` [s] also the recorded accelerations."""
    uA = w[:, 0] * np.cos(w[:, 1] - x[:, 4]) + x[:, 1]  # apparent wind, see mmg.wind
    vA = w[:, 0] * np.sin(w[:, 1] - x[:, 4]) + x[:, 3]
    ahead = u[:, 1] >= 0
    forward = x[:, 1] >= 0
    return {
        "beta_deg": np.abs(np.degrees(np.arctan2(-x[:, 3], x[:, 1]))),
        "quadrant": np.where(ahead, np.where(forward, 1, 2), np.where(forward, 3, 4)),
        "delta_deg": np.abs(np.degrees(u[:, 0])),
        "gamma_A_deg": np.abs(np.degrees(np.arctan2(vA, uA))),
        "U": np.hypot(x[:, 1], x[:, 3]),
        "n_p": u[:, 1],
        "x0": x[:, 0],
        "y0": x[:, 2],
        "psi_deg": np.mod(np.degrees(x[:, 4]), 360.0),
        **(
            {
                "u_dot": np.gradient(x[:, 1], dt),
                "r_dot": np.degrees(np.gradient(x[:, 5], dt)),
            }
            if dt is not None and x.shape[0] > 1
            else {}
        ),
    }


def residual_frame(
    params: Parameters,
    recordings: Sequence[Recording],
    effects: tuple[Effect, ...] = (),
    floors: Mapping[str, float] = DEFAULT_FLOORS,
) -> pd.DataFrame:
    """One row per sample: run, window, time, regime variables, standardised residuals.

    Residual columns ``res_<channel>`` are (simulated - recorded) / sigma_recorded of the window.
    """
    frames = []
    floor = np.array([floors[c] for c in CHANNELS])
    for rec in recordings:
        for w, seg in enumerate(split_recording(rec)):
            sl = slice(seg.start, seg.start + seg.n_steps + 1)
            x = np.asarray(rec.x[sl])
            u = np.asarray(rec.u[sl])
            wind = np.asarray(rec.w[sl])
            sim = simulate_batch(
                x[None, 0],
                u[None, :-1],
                wind[None, :-1],
                params,
                effects=effects,
                t0=float(rec.t[seg.start]),
            )
            z_rec = observables(x)
            z_sim = observables(sim.states[0])
            sigma = np.maximum(z_rec.std(axis=0), floor)
            res = (z_sim - z_rec) / sigma
            if sim.diverged[0]:
                res[:] = np.nan
            t = np.asarray(rec.t[sl])
            data = {"run": rec.name, "window": w, "t": t, "t_run": t - float(rec.t[0])}
            data.update(regimes(x, u, wind, rec.dt))
            for j, c in enumerate(CHANNELS):
                data[f"res_{c}"] = res[:, j]
            frames.append(pd.DataFrame(data))
    return pd.concat(frames, ignore_index=True)


@dataclass(frozen=True)
class RegimeScore:
    """How strongly the residual energy of a channel group depends on one regime variable."""

    variable: str
    group: str
    eta2: float  # between-bin share of the residual sum of squares, 0..1
    worst_bin: str  # label of the bin with the largest mean square
    worst_ratio: float  # its mean square / the overall mean square
    samples: int


def _energy(frame: pd.DataFrame, group: str) -> pd.Series:
    cols = [f"res_{c}" for c in GROUPS[group]]
    return (frame[cols] ** 2).sum(axis=1)


def locate(frame: pd.DataFrame, min_share: float = 0.02) -> list[RegimeScore]:
    """Score every (regime variable, channel group), most concentrated first.

    Bins holding less than ``min_share`` of the samples are pooled out (no verdict from a handful
    of samples).
    """
    clean = frame.dropna(subset=[f"res_{c}" for c in CHANNELS])
    scores: list[RegimeScore] = []
    for group in GROUPS:
        e = _energy(clean, group)
        total_mean = float(e.mean())
        for var, edges in bin_edges(clean).items():
            labels = pd.cut(clean[var], edges, right=False)
            counts = labels.value_counts()
            keep = counts[counts >= min_share * len(clean)].index
            mask = labels.isin(keep)
            if mask.sum() < 10 or len(keep) < 2:
                continue
            ek, lk = e[mask], labels[mask]
            means = ek.groupby(lk, observed=True).mean()
            sizes = ek.groupby(lk, observed=True).size()
            grand = float(ek.mean())
            between = float((sizes * (means - grand) ** 2).sum())
            total = float(((ek - grand) ** 2).sum())
            worst = means.idxmax()
            scores.append(
                RegimeScore(
                    variable=var,
                    group=group,
                    eta2=between / total if total > 0 else 0.0,
                    worst_bin=str(worst),
                    worst_ratio=float(means.max() / total_mean) if total_mean > 0 else 0.0,
                    samples=int(mask.sum()),
                )
            )
    return sorted(scores, key=lambda s: s.eta2, reverse=True)


def rank_windows(frame: pd.DataFrame, group: str = "velocity", top: int = 10) -> pd.DataFrame:
    """The windows (run, window) with the largest mean residual energy of a channel group."""
    e = _energy(frame, group)
    table = (
        frame.assign(energy=e)
        .groupby(["run", "window"], observed=True)
        .agg(t0=("t", "min"), energy=("energy", "mean"), samples=("t", "size"))
        .sort_values("energy", ascending=False)
    )
    return table.head(top).reset_index()


#: the recorded accelerations used as regime variables (u_dot [m/s^2], v_dot, r_dot)
ACCELERATIONS = ("u_dot", "v_dot", "r_dot")


def equation_residuals(
    params: Parameters,
    recordings: Sequence[Recording],
    effects: tuple[Effect, ...] = (),
    smooth_s: float = 1.0,
) -> pd.DataFrame:
    """One row per sample: regime variables and equation residuals (recorded - model).

    The recorded accelerations (central differences of the recorded u, v_m, r) are compared with
    the model's at the recorded state, controls and wind (paper Eq. (1)-(3)); unlike trajectory
    residuals these do not accumulate along a window, so a missing force shows up in the regime
    where it acts. Both are averaged over ``smooth_s`` seconds against differentiation noise.
    Columns ``eq_u_dot``, ``eq_v_dot`` [m/s^2], ``eq_r_dot`` [rad/s^2].
    """
    from mmg import derivatives

    frames = []
    for rec in recordings:
        x = np.asarray(rec.x)
        u = np.asarray(rec.u)
        w = np.asarray(rec.w)
        acc_rec = np.gradient(x[:, [1, 3, 5]], rec.dt, axis=0)
        acc_mod = derivatives(x, u, w, params, effects, t=np.asarray(rec.t))[:, [1, 3, 5]]
        width = max(1, round(smooth_s / rec.dt))
        kernel = np.ones(width) / width
        res = np.stack(
            [np.convolve(acc_rec[:, j] - acc_mod[:, j], kernel, mode="same") for j in range(3)],
            axis=1,
        )
        t = np.asarray(rec.t)
        data = {"run": rec.name, "t": t, "t_run": t - float(t[0])}
        data.update(regimes(x, u, w, rec.dt))
        for j, name in enumerate(ACCELERATIONS):
            data[f"eq_{name}"] = res[:, j]
        frames.append(pd.DataFrame(data))
    return pd.concat(frames, ignore_index=True)


@dataclass(frozen=True)
class BiasScore:
    """A regime bin in which an equation residual has a mean far from zero."""

    variable: str
    channel: str
    bin: str
    mean: float  # mean residual in the bin [m/s^2 or rad/s^2]
    t: float  # mean / standard error (samples 1 s apart treated as independent)
    samples: int


def locate_bias(frame: pd.DataFrame, min_share: float = 0.02) -> list[BiasScore]:
    """Rank (regime bin, acceleration) pairs by how far the mean residual is from zero.

    A missing force acts in a regime: inside it the equation residual has a non-zero mean,
    elsewhere it averages out. Standard errors count one independent sample per second (the
    residuals are smoothed and the recordings filtered), so |t| > 4 is a strong signal.
    """
    scores: list[BiasScore] = []
    per_second = max(1, round(1.0 / float(np.median(np.diff(frame["t"][:100])))))
    for var, edges in bin_edges(frame).items():
        labels = pd.cut(frame[var], edges, right=False)
        for channel in ACCELERATIONS:
            col = frame[f"eq_{channel}"]
            grouped = col.groupby(labels, observed=True)
            for label, values in grouped:
                n = len(values)
                if n < min_share * len(frame) or n < 2 * per_second:
                    continue
                se = float(values.std()) / np.sqrt(n / per_second)
                mean = float(values.mean())
                scores.append(
                    BiasScore(var, channel, str(label), mean, mean / se if se > 0 else 0.0, n)
                )
    return sorted(scores, key=lambda s: abs(s.t), reverse=True)
