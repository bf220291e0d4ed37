"""Is anything missing at all? The measurement-noise floor of J, estimated from the recordings.

1. **Noise model** (:func:`estimate_noise`): per state channel (x0, u, y0, v_m, psi, r) an AR(1)
   process (standard deviation sigma, lag-1 correlation phi; phi > 0 is coloured noise), fitted to
   the variogram of the recordings against the model's short simulations from their own samples
   (lags up to ``window_s``): the noise's sigma^2 (1 - phi^k) plus what the model misses, which
   grows with the lag; :func:`calibrated_noise` removes the estimator's bias.
   Whether the windows' first samples carry that noise too (:func:`first_sample_noise`): a
   recorded state does, a simulation's exact start does not; the noise-only copies behind the
   floor and the acceptance nulls begin noisy unless asked to begin as the windows do
   (``exact_starts``); those of the test recordings' null always do
   (:mod:`sweep.diagnose.generalise`).
2. **Floor of J** (:func:`noise_floor`): J, computed as the objective does, of the identified
   model against synthetic recordings (its own simulation of each training window plus one of
   ``draws`` noise series): what a model exact in form and values would reach, with its spread.
3. **Test** (:func:`misfit_test`): the base model's J against the floor of a *fitted* model (the
   floor times ``refit_factor``, the share of the noise's J a refit of the 57 parameters keeps,
   from :mod:`sweep.diagnose.linearised`); significant when the total exceeds it by more than
   ``margin`` and by more than ``z`` standard deviations of its spread.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from mmg import Parameters, get_effect, simulate_batch
from mmg.integrate import OBSERVABLES as OBSERVABLES_J
from sweep.data.objective import CHANNELS, Objective
from sweep.data.recordings import Recording

FloatArray = NDArray[np.float64]

#: state channels of the recordings (columns of Recording.x)
STATES = ("x0", "u", "y0", "v_m", "psi", "r")
#: allowance for the noise model's approximation: the misfit must exceed the floor by this share
MARGIN = 0.10
#: ... and by this many standard deviations of the floor over noise draws
Z_CRIT = 3.0


@numba.njit(cache=True, nogil=True)
def _ar1_columns(e: FloatArray, phi: float, c: float) -> FloatArray:
    """x_0 = e_0, x_k = c e_k + phi x_{k-1} down each column of e (n, m): the arithmetic of a
    first-order recursive filter (scipy's lfilter), bit for bit, at one pass per column."""
    x = np.empty_like(e)
    n, m = e.shape
    for j in range(m):
        x[0, j] = e[0, j]
        for k in range(1, n):
            x[k, j] = c * e[k, j] + phi * x[k - 1, j]
    return x


def ar1(e: FloatArray, phi: float) -> FloatArray:
    """Unit-variance white noise e (n, ...) turned into stationary AR(1) noise of unit variance
    along axis 0: x_0 = e_0, x_k = phi x_{k-1} + sqrt(1 - phi^2) e_k (a first-order low-pass)."""
    if phi == 0.0:
        return e
    e = np.asarray(e, dtype=np.float64)
    flat = np.ascontiguousarray(e.reshape(e.shape[0], -1))
    return _ar1_columns(flat, float(phi), float(np.sqrt(1.0 - phi * phi))).reshape(e.shape)


@dataclass(frozen=True)
class FirstSample:
    """Whether the windows' first samples carry the measurement noise, with the evidence
    (:func:`first_sample_noise`)."""

    noisy: bool = True
    log_odds: float = 0.0  # ln p(residuals | exact first samples) - ln p(... | noisy ones)
    items: int = 0  # windows x persisting channels compared
    #: whether the noise-only copies begin exactly too (only where the windows do, and only
    #: when asked: ``DiagnoseSettings.exact_starts``)
    copies_exact: bool = False

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready {"noisy", "log_odds_exact", "items", "copies_exact"}."""
        return {
            "noisy": self.noisy,
            "log_odds_exact": self.log_odds,
            "items": self.items,
            "copies_exact": self.copies_exact,
        }


@dataclass(frozen=True)
class NoiseModel:
    """AR(1) measurement noise per state channel: standard deviation and lag-1 correlation."""

    sigma: dict[str, float]
    phi: dict[str, float]
    window_s: float = 3.0
    model_based: bool = False
    #: whether the windows' first samples carry the noise (recorded states) or not (a
    #: simulation's exact start), with the evidence (:func:`first_sample_noise`), and whether
    #: the draws' first samples are 0 (:attr:`FirstSample.copies_exact`)
    first: FirstSample = FirstSample()

    def draw(self, rng: np.random.Generator, n: int) -> FloatArray:
        """(n, 6) noise samples of the six state channels (stationary AR(1) each)."""
        return self.draw_many(rng, [n])[0]

    def draw_many(self, rng: np.random.Generator, lengths: Sequence[int]) -> list[FloatArray]:
        """(n, 6) noise samples for each n of ``lengths``: the same numbers as ``draw`` called
        for each in turn (channel after channel, series after series, from one normal draw of
        the generator, which gives its numbers in the same order), at one generator call for
        all (a null of 200 copies of 28 windows made 34,000 calls). Where the copies begin
        exactly (:attr:`first`, :attr:`FirstSample.copies_exact`), their first sample is 0."""
        m = len(STATES)
        e = rng.normal(0.0, 1.0, m * int(sum(lengths)))
        out = []
        at = 0
        for n in lengths:
            x = np.empty((n, m))
            for j, c in enumerate(STATES):
                x[:, j] = self.sigma[c] * ar1(e[at : at + n], self.phi[c])
                at += n
            if self.first.copies_exact and n:
                x[0] = 0.0
            out.append(x)
        return out

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready {channel: {"sigma", "phi", "corr_time_s"}} (sigma in the channel's unit)."""
        return {
            c: {"sigma": self.sigma[c], "phi": self.phi[c], "corr_time_s": self.corr_time(c)}
            for c in STATES
        }

    def corr_time(self, c: str, dt: float = 0.1) -> float:
        """Correlation time -dt / ln(phi) [s] of channel c (0 for white noise)."""
        phi = self.phi[c]
        return 0.0 if phi <= 0.0 else float(-dt / np.log(phi))


def estimate_noise(
    recordings: Sequence[Recording],
    params: Parameters | None = None,
    window_s: float = 3.0,
    max_corr_time: float = 2.0,
    stride: int = 3,
) -> NoiseModel:
    """The AR(1) noise model of each state channel (see the module docstring).

    Per channel, the variogram V(k) = E[(x_{t+k} - xhat_{t+k})^2] / 2, lags
    k = 1 .. ``window_s`` / dt, is fitted by sigma^2 (1 - phi^k) (AR(1) noise) + a k^2 + b k^4
    (what the prediction misses: it grows with the lag); phi is searched on a grid up to a
    correlation time of ``max_corr_time`` [s], the rest by non-negative least squares. The
    prediction xhat_{t+k} is the recorded x_t (a plain variogram) or, with ``params``, the
    model's simulation from the recorded x_t (every ``stride`` samples) with the recorded controls
    and wind: the ship's motion then cancels up to the model's error over a few seconds, and
    the increments hold the noise (the controls' own jitter drives both alike).
    """
    from scipy.optimize import nnls

    if not recordings:
        raise ValueError("no recordings to estimate the noise from")
    dt = recordings[0].dt
    K = max(5, round(window_s / dt))
    lags = np.arange(1, K + 1)
    sums = np.zeros((K, len(STATES)))
    counts = np.zeros(K)
    effects = tuple(get_effect(n) for n, _ in params.effects) if params is not None else ()
    for rec in recordings:
        x = np.asarray(rec.x, dtype=np.float64).copy()
        if x.shape[0] < 3 * K:
            continue
        x[:, 4] = np.unwrap(x[:, 4])
        if params is None:
            for i, k in enumerate(lags):
                d = x[k:] - x[:-k]
                sums[i] += 0.5 * np.sum(d * d, axis=0)
                counts[i] += d.shape[0]
            continue
        starts = np.arange(0, x.shape[0] - K - 1, stride)
        idx = starts[:, None] + np.arange(K)[None, :]
        uu = np.asarray(rec.u)[idx]
        ww = np.asarray(rec.w)[idx]
        t0 = np.asarray(rec.t)[starts]
        sim = simulate_batch(x[starts], uu, ww, params, effects=effects, t0=t0).states
        truth = x[starts[:, None] + np.arange(K + 1)[None, :]]
        d = truth[:, 1:] - sim[:, 1:]
        d[..., 4] = (d[..., 4] + np.pi) % (2 * np.pi) - np.pi
        ok = np.all(np.isfinite(d), axis=(1, 2))
        sums += 0.5 * np.sum(d[ok] ** 2, axis=0)
        counts += ok.sum()
    if counts[0] == 0:
        raise ValueError("the recordings are too short to estimate their noise")
    V = sums / counts[:, None]
    phi_max = float(np.exp(-dt / max_corr_time))
    phis = np.concatenate([[0.0], np.linspace(0.05, phi_max, 60)])
    sigma: dict[str, float] = {}
    phi: dict[str, float] = {}
    for j, c in enumerate(STATES):
        v = V[:, j]
        if not np.all(np.isfinite(v)) or v[0] <= 0:
            sigma[c], phi[c] = 0.0, 0.0
            continue
        w = 1.0 / v  # relative errors: every lag counts alike
        best = (np.inf, 0.0, 0.0)
        for p in phis:
            A = np.stack([1.0 - p**lags, lags**2.0, lags**4.0], axis=1) * w[:, None]
            coef, res = nnls(A, v * w)
            if res < best[0]:
                best = (res, float(p), float(coef[0]))
        phi[c] = best[1]
        sigma[c] = float(np.sqrt(best[2]))
    return NoiseModel(sigma, phi, window_s, params is not None)


def calibrated_noise(
    recordings: Sequence[Recording],
    params: Parameters,
    rng: np.random.Generator,
    exact_starts: bool = False,
) -> NoiseModel:
    """:func:`estimate_noise` with its bias removed: the estimator is run once more on the
    model's own simulation of the recordings plus noise of the first estimate, and each sigma is
    scaled by first estimate / re-estimate (the variogram fit trades a little noise for motion).
    Whether the recordings begin at exact states is read (:func:`first_sample_noise`) and
    reported; the noise-only copies begin exactly too only with ``exact_starts`` (otherwise
    noisy, as recorded windows begin: the rules of the diagnosis were set with those copies,
    and with exact ones the planted strong and medium rows lost two explained cases and gained
    a harmful finding and a false alarm)."""
    first = estimate_noise(recordings, params)
    sims = simulate_windows(params, recordings)
    synthetic = [
        Recording(r.name, None, r.t, x + first.draw(rng, x.shape[0]), r.u, r.w)
        for r, x in zip(recordings, sims, strict=True)
    ]
    second = estimate_noise(synthetic, params)
    sigma = {
        c: first.sigma[c] * (first.sigma[c] / second.sigma[c] if second.sigma[c] > 0 else 1.0)
        for c in STATES
    }
    noise = NoiseModel(sigma, dict(first.phi), first.window_s, True)
    return begun_as(noise, first_sample_noise(recordings, params, noise, sims), exact_starts)


def begun_as(noise: NoiseModel, start: FirstSample, exact: bool = True) -> NoiseModel:
    """``noise`` with the windows' first samples ``start``, its copies beginning exactly where
    the windows do when ``exact`` (noisy otherwise)."""
    return replace(noise, first=replace(start, copies_exact=exact and not start.noisy))


#: channels whose error at a window's first sample persists along the simulation (positions and
#: heading: the simulation carries an offset of its start to the end), for
#: :func:`first_sample_noise`
PERSISTING = ("x0", "y0", "psi")
#: the first samples are taken as exact only when the recordings favour that by at least these
#: odds (natural log): a model's misfit raises the early residual as noise at the start does, so
#: the test errs towards noisy starts, the nulls of recorded data
FIRST_LOG_ODDS = float(np.log(1e4))
#: the early residual is averaged over this long [s], from where the channel's noise has
#: forgotten the first sample (its AR(1) correlation below :data:`FIRST_FORGOTTEN`)
FIRST_SPAN_S = 5.0
FIRST_FORGOTTEN = 0.05


def first_sample_noise(
    windows: Sequence[Recording],
    params: Parameters,
    noise: NoiseModel,
    sims: Sequence[FloatArray] | None = None,
) -> FirstSample:
    """Do the windows begin at a recorded state (noisy, as the other samples) or at an exact one
    (a simulation's start)?

    The model simulates each window from its first sample, so an error e_0 there stays in the
    positions and the heading (:data:`PERSISTING`) as an offset. Per window and channel the
    residual (recording - simulation) averaged over :data:`FIRST_SPAN_S` from where the
    channel's AR(1) noise has forgotten the first sample, over its sigma, is normal with variance
    v (the average's own noise; exact start) or about v + 1 (a noisy start). The recordings are
    taken to begin exactly when that likelihood ratio favours it by :data:`FIRST_LOG_ODDS`;
    otherwise (and when no window is long enough) as recorded, with noise: a misfit of the model
    adds to the early residual and leans the same way. Copies of recorded windows with a noisy
    first sample, against recordings that begin exactly, make every null wider than the data's:
    on a planted case without an effect (every window the exact start of a simulation) the test
    recordings' null median was 2.5 x what it was with exact starts, the no-effect model's own
    test J 0.5 x that median. ``sims``: the model's states on the windows
    (:func:`simulate_windows`), when the caller has them."""
    if not windows:
        return FirstSample()
    if sims is None:
        sims = simulate_windows(params, windows)
    log_odds = 0.0
    items = 0
    for w, sim in zip(windows, sims, strict=True):
        x = np.asarray(w.x, dtype=np.float64)
        for c in PERSISTING:
            j = STATES.index(c)
            sig, phi = noise.sigma[c], noise.phi[c]
            if sig <= 0.0:
                continue
            k0 = 1 if phi <= 0.0 else max(1, int(np.ceil(np.log(FIRST_FORGOTTEN) / np.log(phi))))
            k = np.arange(k0, k0 + max(1, round(FIRST_SPAN_S / w.dt)) + 1)
            if k[-1] >= x.shape[0]:
                continue
            r = x[k, j] - sim[k, j]
            if c == "psi":
                r = (r + np.pi) % (2 * np.pi) - np.pi
            if not np.all(np.isfinite(r)):
                continue
            y2 = float(r.mean() / sig) ** 2
            v = float(np.mean(phi ** np.abs(k[:, None] - k[None, :]))) if phi > 0 else 1 / k.size
            # normal log-densities of the average under an exact and a noisy first sample
            log_odds += -0.5 * (np.log(v) + y2 / v) + 0.5 * (np.log(v + 1.0) + y2 / (v + 1.0))
            items += 1
    return FirstSample(not (items and log_odds >= FIRST_LOG_ODDS), float(log_odds), items)


def simulate_windows(params: Parameters, windows: Sequence[Recording]) -> list[FloatArray]:
    """The model's states (n_i, 6) [m, m/s, m, m/s, rad, rad/s] on each recording, from its first
    recorded state with its controls and wind; a diverged simulation is replaced by the recording.
    """
    effects = tuple(get_effect(n) for n, _ in params.effects)
    x0 = np.stack([np.asarray(w.x[0]) for w in windows])
    K = max(w.n_samples for w in windows) - 1
    u = np.zeros((len(windows), K, 2))
    wind = np.zeros((len(windows), K, 2))
    n_steps = np.array([w.n_samples - 1 for w in windows])
    for i, w in enumerate(windows):
        u[i, : n_steps[i]] = np.asarray(w.u)[:-1]
        wind[i, : n_steps[i]] = np.asarray(w.w)[:-1]
        u[i, n_steps[i] :] = u[i, n_steps[i] - 1]
        wind[i, n_steps[i] :] = wind[i, n_steps[i] - 1]
    t0 = np.array([float(w.t[0]) for w in windows])
    sim = simulate_batch(x0, u, wind, params, effects=effects, t0=t0)
    out = []
    for i, w in enumerate(windows):
        clean = np.array(sim.states[i, : n_steps[i] + 1])
        out.append(clean if np.all(np.isfinite(clean)) else np.array(w.x, dtype=np.float64))
    return out


@dataclass
class Floor:
    """J of the model against its own simulation plus noise, per window and channel."""

    mean: FloatArray  # (S, 7) mean over draws
    draws: FloatArray  # (D, S, 7)
    actual: FloatArray  # (S, 7) J of the model against the recordings
    runs: list[str]  # (S,) run of each window
    noise: NoiseModel


def run_of(window: Recording) -> str:
    """The run a window was cut from (``run@t0``: :func:`~sweep.diagnose.windows.cut_windows`)."""
    return window.name.rsplit("@", 1)[0]


def _windows_of(windows: Sequence[Recording]) -> list[str]:
    return [run_of(w) for w in windows]


def noise_floor(
    params: Parameters,
    windows: Sequence[Recording],
    noise: NoiseModel,
    rng: np.random.Generator,
    draws: int = 12,
) -> Floor:
    """Floor of J on ``windows`` (each one subsequence of the objective) for ``params``."""
    effects = tuple(get_effect(n) for n, _ in params.effects)
    sims = simulate_windows(params, windows)
    actual, _ = Objective(windows, effects=effects, ship=params.ship).costs(params)
    out = []
    for _ in range(draws):
        noisy = []
        series = noise.draw_many(rng, [clean.shape[0] for clean in sims])
        for w, clean, e in zip(windows, sims, series, strict=True):
            noisy.append(Recording(name=w.name, path=None, t=w.t, x=clean + e, u=w.u, w=w.w))
        cost, _ = Objective(noisy, effects=effects, ship=params.ship).costs(params)
        out.append(cost[0])
    d = np.stack(out)
    return Floor(d.mean(axis=0), d, actual[0], _windows_of(windows), noise)


@dataclass
class MisfitTest:
    """The base model's misfit against the noise floor."""

    objective: str
    J: float  # base model's J on the training windows
    floor: float  # mean floor
    floor_sd: float  # spread of the floor's total over noise draws
    ratio: float  # J / floor
    z: float  # (J - floor) / floor_sd
    significant: bool
    margin: float
    z_crit: float
    per_run: list[dict[str, Any]] = field(default_factory=list)
    per_channel: dict[str, float] = field(default_factory=dict)  # ratio per channel
    refit_factor: float = 1.0  # share of the plain floor a model fitted to the windows keeps


def above_floor(J: float, floor: float, z: float, margin: float, z_crit: float) -> bool:
    """The misfit test's rule: ``J`` is significantly above ``floor`` when it exceeds (1 +
    ``margin``) times the floor and its z (J - floor) / sd exceeds ``z_crit``."""
    return bool((1.0 + margin) * floor < J and z > z_crit)


def misfit_test(
    f: Floor,
    objective: str = "J2",
    margin: float = MARGIN,
    z_crit: float = Z_CRIT,
    refit_factor: float = 1.0,
) -> MisfitTest:
    """Total and per run and channel ratio of J to the floor; significance (module docstring).

    ``refit_factor``: the share of the floor a model *fitted* to the windows keeps (its fit
    takes part of the noise out; :meth:`sweep.diagnose.linearised.Linearised.refit_factor`);
    the base model's J is compared with the floor times this factor."""
    ch = list(CHANNELS[objective])
    draws, mean = refit_factor * f.draws, refit_factor * f.mean  # the floor of a fitted model
    J = float(f.actual[:, ch].sum())
    totals = draws[:, :, ch].sum(axis=(1, 2))
    floor = float(totals.mean())
    sd = float(totals.std(ddof=1)) if totals.size > 1 else 0.0
    sd = max(sd, 1e-12)
    z = (J - floor) / sd
    significant = above_floor(J, floor, z, margin, z_crit)
    per_channel = {
        OBSERVABLES_J[c]: float(f.actual[:, c].sum() / max(mean[:, c].sum(), 1e-300)) for c in ch
    }
    per_run: list[dict[str, Any]] = []
    for run in dict.fromkeys(f.runs):
        idx = [i for i, r in enumerate(f.runs) if r == run]
        a = f.actual[np.ix_(idx, ch)].sum(axis=0)
        b = mean[np.ix_(idx, ch)].sum(axis=0)
        tot_d = draws[:, idx][:, :, ch].sum(axis=(1, 2))
        sd_r = max(float(tot_d.std(ddof=1)) if tot_d.size > 1 else 0.0, 1e-12)
        per_run.append(
            {
                "run": run,
                "J": float(a.sum()),
                "floor": float(b.sum()),
                "ratio": float(a.sum() / max(b.sum(), 1e-300)),
                "z": float((a.sum() - b.sum()) / sd_r),
                "channels": {
                    OBSERVABLES_J[c]: float(a[k] / max(b[k], 1e-300)) for k, c in enumerate(ch)
                },
            }
        )
    per_run.sort(key=lambda r: r["ratio"], reverse=True)
    return MisfitTest(
        objective=objective,
        J=J,
        floor=floor,
        floor_sd=sd,
        ratio=J / floor if floor > 0 else float("inf"),
        z=z,
        significant=significant,
        margin=margin,
        z_crit=z_crit,
        per_run=per_run,
        refit_factor=refit_factor,
        per_channel=per_channel,
    )
