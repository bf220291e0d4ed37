"""Local refinement of an identified model: Levenberg-Marquardt on the objective's residuals.

J1, J2 and J3 (:mod:`sweep.data.objective`) are sums of squares: per subsequence s, observable j and
sample k, with trapezoid weights w_k,

    J = sum_s sum_j sum_k r_sjk^2,   r_sjk = sqrt(w_k dt) (z_hat_in - z_hat_sim)_sjk

(:func:`residual_vectors`; the sum of squares equals :meth:`Objective.evaluate` to rounding).
Near a minimum this converges in a few tens of iterations and is deterministic, which is what
the diagnosis needs to compare models with and without a candidate effect.

The Jacobian is a forward difference in the normalised box ([0, 1] per coordinate), all n + 1
simulations in one batch; each iteration tries several damping factors lambda in one more batch
(Marquardt scaling by diag(J^T J)) and keeps the best, so a step is never worse than the current
point; when none is better, the same Jacobian is tried with 1000 x stronger damping (until the
damping exceeds :data:`MAX_LAMBDA`: a local minimum). Coordinates on a bound that the gradient
pushes outward are held there (:func:`damped_step`); the other steps are clipped to the box.
Subsequences that diverge at the current point keep their penalty and are left out of the
Jacobian; a trial that makes another one diverge pays its penalty.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from mmg.integrate import Segments, SimulationResult, simulate_batch
from mmg.trig import sincos
from sweep.data.objective import CHANNELS, PENALTY_FACTOR, Objective
from sweep.identification.cmaes import Box

FloatArray = NDArray[np.float64]

#: damping factors tried at each iteration, relative to the current lambda
LAMBDA_TRIALS = (1e-2, 1e-1, 1.0, 10.0, 100.0)
#: damping beyond which a point counts as a (local) minimum: steps are then negligible
MAX_LAMBDA = 1e8
#: simulations per batch (candidates x subsequences), bounding the memory of the trajectories
MAX_LANES = 1200


@dataclass(frozen=True)
class PolishSettings:
    """Iteration limits of a Levenberg-Marquardt refinement."""

    max_iterations: int = 25
    fd_step: float = 2e-4  # forward-difference step in the normalised box
    lambda0: float = 1e-3
    rtol: float = 1e-3  # stop after two iterations that each gain less than this (relative)
    max_evaluations: int = 4000
    #: weight mu of a prior mu * |z - z_start|^2 on the first ``prior_dims`` coordinates
    #: (normalised box): keeps a refit on part of the data near a model fitted on all of it
    prior_weight: float = 0.0
    prior_dims: int = 0


@dataclass
class Polished:
    """Outcome of a refinement: the point (parameter units), its objective and the cost."""

    theta: FloatArray
    f: float
    f_start: float
    evaluations: int
    iterations: int
    seconds: float
    history: list[dict[str, float]] = field(default_factory=list)


@numba.njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def _standardised_residuals(
    states: FloatArray,
    n_steps: np.ndarray,
    channels: np.ndarray,
    ref: FloatArray,
    floor: FloatArray,
    sqrt_w: FloatArray,
    out: FloatArray,
    bad: np.ndarray,
) -> None:
    """Residual rows of B simulated subsequences in one pass per lane (parallel over lanes).

    states (B, K + 1, 6) with lane b simulating subsequence b % S; n_steps (S,); channels (m,)
    indices into the observables (x0, u, y0, v_m, sin psi, cos psi, r); ref (S, K + 1, m) the
    standardised recording; floor (m,); sqrt_w (S, K + 1) = sqrt(w_k dt), 0 past the end.
    out (B, (K + 1) m) receives sqrt(w_k dt) (z_hat_in - z_hat_sim) at [k m + j] (paper Eqs. (32),
    (33)), 0 past the end and for a lane that is ``bad`` (diverged) or has a non-finite residual,
    which is then flagged in ``bad`` (B,).
    The heading's sine and cosine are those of the objective's kernel (:func:`mmg.trig.sincos`,
    straight-line arithmetic: the C library's pair cost two opaque calls per sample, about half
    of a Jacobian's time beside the simulation).
    """
    B = states.shape[0]
    S = n_steps.shape[0]
    m = channels.shape[0]
    heading = False
    for j in range(m):
        heading = heading or channels[j] == 4 or channels[j] == 5
    for b in numba.prange(B):
        s = b % S
        n = n_steps[s]
        row = out[b]
        if bad[b]:
            row[:] = 0.0
            continue
        trig = np.empty((2, n + 1))
        if heading:
            for k in range(n + 1):
                trig[0, k], trig[1, k] = sincos(states[b, k, 4])
        finite = True
        for j in range(m):
            q = channels[j]
            total = 0.0  # sums of z - z_0: the variance without cancellation (x0 is tens of m)
            square = 0.0
            z_0 = 0.0
            for k in range(n + 1):
                if q == 4:
                    z = trig[0, k]
                elif q == 5:
                    z = trig[1, k]
                elif q == 6:
                    z = states[b, k, 5]
                else:
                    z = states[b, k, q]
                row[k * m + j] = z  # the observable, standardised below
                if k == 0:
                    z_0 = z
                total += z - z_0
                square += (z - z_0) * (z - z_0)
            d = total / (n + 1)
            mu = z_0 + d
            sigma = max(math.sqrt(max(square / (n + 1) - d * d, 0.0)), floor[j])
            check = 0.0  # stays 0 while every v is finite (inf * 0 and NaN * 0 are NaN)
            for k in range(n + 1):
                v = sqrt_w[s, k] * (ref[s, k, j] - (row[k * m + j] - mu) / sigma)  # Eqs. (32), (33)
                row[k * m + j] = v
                check += v * 0.0
            if check != 0.0:
                finite = False
                break
        if not finite:
            bad[b] = True
            row[:] = 0.0
        else:
            row[(n + 1) * m :] = 0.0


#: per thread, a states buffer that :func:`residual_vectors` reuses from call to call (a fresh
#: (lanes, K + 1, 6) array, up to 58 MB, was mapped and page-faulted in anew every time: about a
#: fifth of a Jacobian's time)
_scratch = threading.local()


def _states_buffer(shape: tuple[int, int, int]) -> FloatArray:
    """A C-contiguous (B, K + 1, 6) view of this thread's buffer, grown when too small."""
    need = shape[0] * shape[1] * shape[2]
    buf: FloatArray | None = getattr(_scratch, "states", None)
    if buf is None or buf.size < need:
        buf = np.empty(need)
        _scratch.states = buf
    return buf[:need].reshape(shape)


def _tiled_segments(seg: Segments, c: int) -> tuple[FloatArray, ...]:
    """(x0, u, w, n_steps, t0) of the subsequences ``seg`` repeated for c candidates.

    Kept per thread for the last subsequence set, one copy per c: a refinement simulates the
    same subsequences for n + 1 probes, then for a few trial points, iteration after iteration
    (tiling the controls anew, tens of MB each time, took about 2 % of a diagnosis). The kernel
    only reads them.
    """
    cache: tuple[Segments, dict[int, tuple[FloatArray, ...]]] | None = getattr(
        _scratch, "tiled", None
    )
    if cache is None or cache[0] is not seg:
        cache = (seg, {})
        _scratch.tiled = cache
    got = cache[1].get(c)
    if got is None:
        got = (
            np.tile(seg.x0, (c, 1)),
            np.tile(seg.u, (c, 1, 1)),
            np.tile(seg.w, (c, 1, 1)),
            np.tile(seg.n_steps, c),
            np.tile(seg.t0, c),
        )
        cache[1][c] = got
    return got


def simulate_subsequences(
    obj: Objective, thetas: FloatArray, out: FloatArray | None = None
) -> SimulationResult:
    """Trajectories of c candidates (c, n) on every subsequence of ``obj`` (S of them), lanes
    candidate-major (lane b: candidate b // S, subsequence b % S); states (c S, K + 1, 6),
    written into ``out`` when given (see :func:`mmg.integrate.simulate_batch`)."""
    seg = obj.data.segments
    S = seg.u.shape[0]
    x0, u, w, n_steps, t0 = _tiled_segments(seg, thetas.shape[0])
    return simulate_batch(
        x0,
        u,
        w,
        np.repeat(thetas, S, axis=0),
        obj.data.dt,
        n_steps,
        effects=obj.effects,
        ship=obj.ship,
        t0=t0,
        out=out,
    )


def residual_vectors(
    obj: Objective, thetas: FloatArray, out: FloatArray | None = None
) -> tuple[FloatArray, np.ndarray]:
    """Residuals (C, S, M) and per-subsequence divergence flags (C, S) of C candidates.

    M = (K + 1) x channels of the objective; entries after a subsequence's end are 0; the
    residuals of a diverged subsequence are 0 (its cost is the penalty, see :func:`totals`).
    ``out``: an optional C-contiguous float64 (C, S, M) array to write them into (a caller that
    computes Jacobian after Jacobian reuses one).
    """
    thetas = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
    data = obj.data
    seg = data.segments
    S, K = seg.u.shape[:2]
    ch = np.asarray(CHANNELS[obj.name], dtype=np.int64)
    k = np.arange(K + 1)
    valid = k[None, :] <= seg.n_steps[:, None]  # (S, K + 1)
    wt = valid.astype(np.float64)
    wt[np.arange(S), 0] = 0.5
    wt[np.arange(S), seg.n_steps] = 0.5
    sqrt_w = np.sqrt(wt * data.dt)  # (S, K + 1)
    floor = np.ascontiguousarray(data.floor[ch])
    ref = np.ascontiguousarray(seg.ref[..., ch])
    steps = np.asarray(seg.n_steps, dtype=np.int64)
    C = thetas.shape[0]
    shape = (C, S, (K + 1) * len(ch))
    if out is None:
        out = np.empty(shape)
    elif out.shape != shape or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float64 array of shape {shape}")
    bad = np.zeros((C, S), dtype=bool)
    per = max(1, MAX_LANES // S)
    for lo in range(0, C, per):
        c = min(per, C - lo)
        states = _states_buffer((c * S, K + 1, 6))
        sim = simulate_subsequences(obj, thetas[lo : lo + c], out=states)
        b = sim.bad_step >= 0  # (c S,)
        rows = out[lo : lo + c].reshape(c * S, -1)  # a view: filled in place
        _standardised_residuals(sim.states, steps, ch, ref, floor, sqrt_w, rows, b)
        bad[lo : lo + c] = b.reshape(c, S)
    return out, bad


def totals(obj: Objective, r: FloatArray, bad: np.ndarray) -> FloatArray:
    """Objective values (C,) from residuals and flags: what :meth:`Objective.evaluate` gives."""
    penalty = PENALTY_FACTOR * obj.data.durations * len(CHANNELS[obj.name])  # (S,)
    return np.asarray((r * r).sum(axis=2).sum(axis=1) + (bad * penalty[None]).sum(axis=1))


def damped_step(
    A: FloatArray, g: FloatArray, d: FloatArray, z: FloatArray, lam: float
) -> FloatArray:
    """The point z + step of one Levenberg-Marquardt trial in the unit box.

    ``step`` solves (A + lam diag(d)) step = -g over the *free* coordinates; a coordinate on a
    bound whose gradient pushes it further out is held there (active set). Solving for it too
    and clipping afterwards would bend the step of every coordinate coupled to it: with the
    fitted base at a bound of the search domain, such clipped steps crept along at a few 1e-4 of
    J per iteration where the active-set steps converged in tens of iterations.
    """
    n = z.size
    free = ~(((z <= 0.0) & (g > 0.0)) | ((z >= 1.0) & (g < 0.0)))
    step = np.zeros(n)
    Af = A[np.ix_(free, free)] + lam * np.diag(d[free]) + 1e-12 * np.eye(int(free.sum()))
    step[free] = np.linalg.solve(Af, -g[free])
    return np.asarray(np.clip(z + step, 0.0, 1.0))


def polish(
    obj: Objective,
    box: Box,
    theta0: FloatArray,
    settings: PolishSettings | None = None,
    progress: Callable[[dict[str, float]], None] | None = None,
    prior_center: FloatArray | None = None,
    penalty: FloatArray | None = None,
) -> Polished:
    """Levenberg-Marquardt from ``theta0`` (parameter units, shape (n,)) within ``box``.

    The prior of ``settings`` (if any) pulls toward ``prior_center`` (parameter units, shape (n,);
    default ``theta0``). ``penalty`` (n, n), symmetric positive semi-definite, adds
    theta' P theta (parameter units) to what is minimised: the smoothness penalty of a shape's
    coefficients, in the normal equations with the Jacobian's. ``Polished.f`` is J alone.
    """
    # One BLAS thread: with two, OpenBLAS's threads spin on after each J J' and take a core from
    # the simulator's threads (8 iterations on Train-R's 14 fit windows, 2 cores: simulations
    # 4.3 -> 3.3 s, residual passes 1.2 -> 0.6 s); the products also no longer depend on the
    # machine's core count
    with threadpool_limits(limits=1, user_api="blas"):
        s = settings or PolishSettings()
        return _polish(obj, box, theta0, s, progress, prior_center, penalty)


def _polish(
    obj: Objective,
    box: Box,
    theta0: FloatArray,
    s: PolishSettings,
    progress: Callable[[dict[str, float]], None] | None,
    prior_center: FloatArray | None,
    penalty: FloatArray | None = None,
) -> Polished:
    t0 = time.perf_counter()
    width = box.upper - box.lower
    n = width.size

    def to_theta(z: FloatArray) -> FloatArray:
        """Box coordinates z (..., n) in [0, 1] -> parameters theta (..., n)."""
        return np.asarray(box.lower + z * width)

    def to_z(theta: FloatArray) -> FloatArray:
        """Parameters theta (..., n) -> box coordinates z (..., n), clipped to [0, 1]."""
        return np.clip((np.asarray(theta, dtype=np.float64) - box.lower) / width, 0.0, 1.0)

    z = to_z(theta0)
    z_prior = z.copy() if prior_center is None else to_z(prior_center)
    pm = np.zeros(n)
    pm[: s.prior_dims] = s.prior_weight

    P = np.zeros((n, n)) if penalty is None else np.asarray(penalty, dtype=np.float64)
    Pz = width[:, None] * P * width[None, :]  # the penalty in box coordinates

    def prior(zs: FloatArray) -> FloatArray:
        """Prior penalty (...,) of box points zs (..., n): weighted squared distance from the
        prior centre over the first ``prior_dims`` coordinates, plus theta' P theta."""
        th = to_theta(zs)
        return np.asarray((pm * (zs - z_prior) ** 2).sum(axis=-1) + ((th @ P) * th).sum(axis=-1))

    r, bad = residual_vectors(obj, to_theta(z)[None])
    f = float(totals(obj, r, bad)[0])
    f_start = f
    evaluations = 1
    lam = s.lambda0
    history: list[dict[str, float]] = [{"iteration": 0, "evaluations": 1, "f": f}]
    small = 0
    it = 0
    Jac: FloatArray = np.zeros((0, 0))
    A: FloatArray = np.zeros((0, 0))
    g: FloatArray = np.zeros(0)
    d: FloatArray = np.zeros(0)
    fresh = False  # whether Jac, A, g belong to the current point
    jac_buffer: FloatArray | None = None
    while it < s.max_iterations and evaluations + n + 1 + len(LAMBDA_TRIALS) <= s.max_evaluations:
        it += 1
        if not fresh:
            keep = ~bad[0]  # subsequences in the Jacobian
            r0 = r[0][keep].ravel()
            h = np.where(z + s.fd_step <= 1.0, s.fd_step, -s.fd_step)
            probes = z[None, :] + np.diag(h)
            if jac_buffer is None:
                jac_buffer = np.empty((n, *r.shape[1:]))
            # the previous Jacobian is no longer needed: its buffer takes the new probes
            rp, badp = residual_vectors(obj, to_theta(probes), out=jac_buffer)
            evaluations += n
            # (n, M), formed in place: a copy of the probes' residuals only when some
            # subsequences are left out (tens of MB per Jacobian otherwise)
            Jac = rp.reshape(n, -1) if keep.all() else rp[:, keep].reshape(n, -1)
            Jac -= r0[None, :]
            Jac /= h[:, None]
            Jac[badp[:, keep].any(axis=1)] = 0.0  # a probe that diverges: coordinate frozen
            A = Jac @ Jac.T + np.diag(pm) + Pz
            g = Jac @ r0 + pm * (z - z_prior) + width * (P @ to_theta(z))
            d = np.diag(A).copy()
            d[d <= 0] = 1.0
            fresh = True
        lams = [lam * t for t in LAMBDA_TRIALS]
        zt = np.array([damped_step(A, g, d, z, lt) for lt in lams])
        rt, badt = residual_vectors(obj, to_theta(zt))
        evaluations += len(zt)
        ft = totals(obj, rt, badt)
        gt = ft + prior(zt)
        g_cur = f + float(prior(z))
        i = int(np.argmin(gt))
        if gt[i] < g_cur:
            gain = (g_cur - float(gt[i])) / g_cur if g_cur > 0 else 0.0
            z, f, r, bad = zt[i], float(ft[i]), rt[i : i + 1], badt[i : i + 1]
            lam = max(lams[i], 1e-9)
            fresh = False
            small = small + 1 if gain < s.rtol else 0
        else:
            # no damping helped: stronger damping on the same Jacobian (shorter, steeper steps)
            lam = lams[-1] * 10.0
        row = {"iteration": float(it), "evaluations": float(evaluations), "f": f, "lambda": lam}
        history.append(row)
        if progress is not None:
            progress(row)
        if small >= 2 or f == 0.0 or lam > MAX_LAMBDA:
            break
    return Polished(
        theta=to_theta(z),
        f=f,
        f_start=f_start,
        evaluations=evaluations,
        iterations=it,
        seconds=time.perf_counter() - t0,
        history=history,
    )


__all__ = [
    "PolishSettings",
    "Polished",
    "damped_step",
    "polish",
    "residual_vectors",
    "simulate_subsequences",
    "totals",
]
