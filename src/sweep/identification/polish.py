"""Local refinement of an identified model: Levenberg-Marquardt on the objective's residuals.

J1, J2 and J3 (:mod:`sweep.data.objective`) are sums of squares: per subsequence s, observable j and
sample k, with trapezoid weights w_k,

    J = sum_s sum_j sum_k r_sjk^2,   r_sjk = sqrt(w_k dt) (z_hat_in - z_hat_sim)_sjk

(:func:`residual_vectors`; the sum of squares equals :meth:`Objective.evaluate` to rounding).
Near a minimum, Gauss-Newton steps on r converge in a few tens of iterations where CMA-ES needs
thousands of evaluations, and they are deterministic: two refinements from the same start differ
only by what their models can explain. That is what the diagnosis needs to compare a base model
with and without a candidate effect (:mod:`sweep.diagnose.run`), and what a CMA-ES result gains
from a final polish.

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

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mmg.integrate import simulate_batch
from sweep.data.objective import CHANNELS, PENALTY_FACTOR, Objective, observables
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


def residual_vectors(obj: Objective, thetas: FloatArray) -> tuple[FloatArray, np.ndarray]:
    """Residuals (C, S, M) and per-subsequence divergence flags (C, S) of C candidates.

    M = (K + 1) x channels of the objective; entries after a subsequence's end are 0; the
    residuals of a diverged subsequence are 0 (its cost is the penalty, see :func:`totals`).
    """
    thetas = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
    data = obj.data
    seg = data.segments
    S, K = seg.u.shape[:2]
    ch = list(CHANNELS[obj.name])
    k = np.arange(K + 1)
    valid = k[None, :] <= seg.n_steps[:, None]  # (S, K + 1)
    wt = valid.astype(np.float64)
    wt[np.arange(S), 0] = 0.5
    wt[np.arange(S), seg.n_steps] = 0.5
    sqrt_w = np.sqrt(wt * data.dt)[..., None]  # (S, K + 1, 1)
    n = (seg.n_steps + 1.0)[:, None]
    floor = data.floor[ch]
    ref = seg.ref[..., ch]
    C = thetas.shape[0]
    out = np.zeros((C, S, (K + 1) * len(ch)))
    bad = np.zeros((C, S), dtype=bool)
    per = max(1, MAX_LANES // S)
    for lo in range(0, C, per):
        block = thetas[lo : lo + per]
        c = block.shape[0]
        sim = simulate_batch(
            np.tile(seg.x0, (c, 1)),
            np.tile(seg.u, (c, 1, 1)),
            np.tile(seg.w, (c, 1, 1)),
            np.repeat(block, S, axis=0),
            data.dt,
            np.tile(seg.n_steps, c),
            effects=obj.effects,
            ship=obj.ship,
            t0=np.tile(seg.t0, c),
        )
        z = observables(sim.states).reshape(c, S, K + 1, 7)[..., ch]
        z = np.where(valid[None, :, :, None], z, 0.0)
        mu = z.sum(axis=2) / n[None]
        var = np.maximum((z * z).sum(axis=2) / n[None] - mu * mu, 0.0)
        sigma = np.maximum(np.sqrt(var), floor)
        z_hat = (z - mu[:, :, None, :]) / sigma[:, :, None, :]  # paper Eq. (33)
        r = sqrt_w[None] * (ref[None] - z_hat)  # Eq. (32), as a residual
        b = sim.bad_step.reshape(c, S) >= 0
        b |= ~np.isfinite(r).all(axis=(2, 3))
        r = np.where(b[:, :, None, None], 0.0, r)
        out[lo : lo + c] = r.reshape(c, S, -1)
        bad[lo : lo + c] = b
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
) -> Polished:
    """Levenberg-Marquardt from ``theta0`` (parameter units, shape (n,)) within ``box``.

    The prior of ``settings`` (if any) pulls toward ``prior_center`` (parameter units, shape (n,);
    default ``theta0``).
    """
    s = settings or PolishSettings()
    t0 = time.perf_counter()
    width = box.upper - box.lower
    n = width.size

    def to_theta(z: FloatArray) -> FloatArray:
        return np.asarray(box.lower + z * width)

    def to_z(theta: FloatArray) -> FloatArray:
        return np.clip((np.asarray(theta, dtype=np.float64) - box.lower) / width, 0.0, 1.0)

    z = to_z(theta0)
    z_prior = z.copy() if prior_center is None else to_z(prior_center)
    pm = np.zeros(n)
    pm[: s.prior_dims] = s.prior_weight

    def prior(zs: FloatArray) -> FloatArray:
        return np.asarray((pm * (zs - z_prior) ** 2).sum(axis=-1))

    r, bad = residual_vectors(obj, to_theta(z)[None])
    f = float(totals(obj, r, bad)[0])
    f_start = f
    evaluations = 1
    lam = s.lambda0
    history: list[dict[str, float]] = [{"iteration": 0, "evaluations": 1, "f": f}]
    small = 0
    it = 0
    Jac = np.zeros((0, 0))
    A = g = d = np.zeros(0)
    fresh = False  # whether Jac, A, g belong to the current point
    while it < s.max_iterations and evaluations + n + 1 + len(LAMBDA_TRIALS) <= s.max_evaluations:
        it += 1
        if not fresh:
            keep = ~bad[0]  # subsequences in the Jacobian
            r0 = r[0][keep].ravel()
            h = np.where(z + s.fd_step <= 1.0, s.fd_step, -s.fd_step)
            probes = z[None, :] + np.diag(h)
            rp, badp = residual_vectors(obj, to_theta(probes))
            evaluations += n
            Jac = (rp[:, keep].reshape(n, -1) - r0[None, :]) / h[:, None]  # (n, M)
            Jac[badp[:, keep].any(axis=1)] = 0.0  # a probe that diverges: coordinate frozen
            A = Jac @ Jac.T + np.diag(pm)
            g = Jac @ r0 + pm * (z - z_prior)
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


__all__ = ["PolishSettings", "Polished", "damped_step", "polish", "residual_vectors", "totals"]
