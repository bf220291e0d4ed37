"""Public entry points: state derivatives and batched RK4 simulation.

Shapes: state x (..., 6) = (x0 [m], u [m/s], y0 [m], v_m [m/s], psi [rad], r [rad/s]);
control (..., 2) = (delta [rad], n_p [rev/s]); wind (..., 2) = (U_T [m/s], gamma_T [rad], the
direction the true wind blows from, earth-fixed, clockwise from x0).

Parameters ``p`` are a :class:`~mmg.params.Parameters` (one set for every trajectory), a float
array (n,) or (B, n) of flat vectors (57 explored values, then the effects' values in the order of
``effects``), or a sequence of :class:`~mmg.params.Parameters`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mmg.effects import Effect
from mmg.kernel import LIMIT_A, load_kernel
from mmg.params import ESSO_OSAKA, N_THETA, FloatArray, Parameters, Ship

ParamsLike = Parameters | Sequence[Parameters] | FloatArray

#: default lane-chunk width of the kernel (lanes per thread work item); 8 x odd avoids L1 aliasing
DEFAULT_CHUNK = 40


@dataclass(frozen=True)
class SimulationResult:
    """Output of :func:`simulate_batch`.

    states (B, K + 1, 6): trajectories; entries after a lane's own length are NaN.
    bad_step (B,): first step at which the lane hit the xdot limiter or became non-finite, -1 if
    never. diverged (B,) bool: bad_step >= 0.
    """

    states: FloatArray
    bad_step: np.ndarray

    @property
    def diverged(self) -> np.ndarray:
        return np.asarray(self.bad_step >= 0)


def effect_vector(p: Parameters, effects: tuple[Effect, ...]) -> FloatArray:
    """The effects' parameter values of ``p`` in kernel order (neutral where absent)."""
    values: list[float] = []
    for eff in effects:
        given = p.effect_values(eff.name)
        unknown = set(given) - set(eff.param_names)
        if unknown:
            raise ValueError(f"effect {eff.name}: unknown parameter(s) {sorted(unknown)}")
        values += [given.get(q.name, q.neutral) for q in eff.params]
    return np.asarray(values, dtype=np.float64)


def parameter_matrix(p: ParamsLike, B: int, effects: tuple[Effect, ...] = ()) -> FloatArray:
    """Per-lane parameters as a contiguous (n_params, B) float64 matrix."""
    n = N_THETA + sum(len(e.params) for e in effects)
    if isinstance(p, Parameters):
        vec = np.concatenate([p.vector(), effect_vector(p, effects)])
        return np.ascontiguousarray(np.broadcast_to(vec[:, None], (n, B)))
    if isinstance(p, np.ndarray):
        arr = np.asarray(p, dtype=np.float64)
        if arr.ndim == 1:
            arr = np.broadcast_to(arr, (B, arr.shape[0]))
        if arr.shape != (B, n):
            raise ValueError(f"parameter array must have shape ({n},) or ({B}, {n}); got {p.shape}")
        return np.ascontiguousarray(arr.T)
    rows = [np.concatenate([q.vector(), effect_vector(q, effects)]) for q in p]
    if len(rows) != B:
        raise ValueError(f"{len(rows)} parameter sets for {B} trajectories")
    return np.ascontiguousarray(np.array(rows).T)


def _ship_of(p: ParamsLike, ship: Ship | None) -> Ship:
    if ship is not None:
        return ship
    if isinstance(p, Parameters):
        return p.ship
    if not isinstance(p, np.ndarray) and len(p) > 0:
        ships = {q.ship for q in p}
        if len(ships) > 1:
            raise ValueError("all parameter sets of one call must share the ship particulars")
        return next(iter(ships))
    return ESSO_OSAKA


def derivatives(
    x: Any,
    u: Any,
    w: Any,
    p: ParamsLike,
    effects: tuple[Effect, ...] = (),
    ship: Ship | None = None,
) -> FloatArray:
    """State derivatives xdot (..., 6) of paper Eq. (3), without the limiter.

    x (..., 6), u (..., 2) = (delta, n_p), w (..., 2) = (U_T, gamma_T); ``p`` one parameter set or
    one per point (array (..., n) or sequence). Leading shapes broadcast.
    """
    x_arr = np.asarray(x, dtype=np.float64)
    u_arr = np.asarray(u, dtype=np.float64)
    w_arr = np.asarray(w, dtype=np.float64)
    shape = np.broadcast_shapes(x_arr.shape[:-1], u_arr.shape[:-1], w_arr.shape[:-1])
    M = int(np.prod(shape))
    X = np.ascontiguousarray(np.broadcast_to(x_arr, (*shape, 6)).reshape(M, 6).T)
    U = np.broadcast_to(u_arr, (*shape, 2)).reshape(M, 2)
    Wd = np.broadcast_to(w_arr, (*shape, 2)).reshape(M, 2)
    if isinstance(p, np.ndarray) and p.ndim > 1:
        p = np.broadcast_to(p, (*shape, p.shape[-1])).reshape(M, p.shape[-1])
    P = parameter_matrix(p, M, effects)
    kern = load_kernel(effects)
    out = np.empty((6, M))
    kern.rhs_lanes(
        X,
        np.ascontiguousarray(U[:, 0]),
        np.ascontiguousarray(U[:, 1]),
        np.ascontiguousarray(Wd[:, 0]),
        np.ascontiguousarray(Wd[:, 1]),
        P,
        _ship_of(p, ship),
        out,
    )
    return out.T.reshape(*shape, 6)


def _padded(B: int) -> int:
    """Lane count rounded up to 8 x an odd number (rows of 2^k doubles alias in L1)."""
    b = max(8, -(-B // 8) * 8)
    return b if (b // 8) % 2 == 1 else b + 8


def simulate_batch(
    x0: Any,
    u_seq: Any,
    w_seq: Any,
    p: ParamsLike,
    dt: float = 0.1,
    n_steps: Any = None,
    effects: tuple[Effect, ...] = (),
    ship: Ship | None = None,
    chunk: int = DEFAULT_CHUNK,
) -> SimulationResult:
    """RK4 simulation of B trajectories with the xdot limiter of paper Algorithm 1.

    x0 (B, 6) initial states; u_seq (B, K, 2) controls and w_seq (B, K, 2) true wind, held over
    each step of dt [s]; n_steps (B,) optional lengths <= K for segments of unequal length
    (default K for all). Returns states (B, K + 1, 6) and the per-trajectory divergence flags.
    A diverging trajectory never raises: it is flagged (and its states may be huge or NaN).
    """
    X0 = np.asarray(x0, dtype=np.float64)
    U = np.asarray(u_seq, dtype=np.float64)
    Wd = np.asarray(w_seq, dtype=np.float64)
    if X0.ndim != 2 or X0.shape[1] != 6:
        raise ValueError(f"x0 must have shape (B, 6); got {X0.shape}")
    B = X0.shape[0]
    if U.ndim != 3 or U.shape[0] != B or U.shape[2] != 2:
        raise ValueError(f"u_seq must have shape ({B}, K, 2); got {U.shape}")
    K = U.shape[1]
    if Wd.shape != U.shape:
        raise ValueError(f"w_seq must have shape {U.shape}; got {Wd.shape}")
    steps = np.full(B, K, dtype=np.int64) if n_steps is None else np.asarray(n_steps, np.int64)
    if steps.shape != (B,) or np.any(steps < 0) or np.any(steps > K):
        raise ValueError(f"n_steps must have shape ({B},) with values in [0, {K}]")
    sh = _ship_of(p, ship)
    P = parameter_matrix(p, B, effects)
    kern = load_kernel(effects)

    order = np.argsort(-steps, kind="stable")  # similar lengths share a chunk
    Bp = _padded(B)

    def lanes(a: FloatArray) -> FloatArray:
        """(B, ...) -> (..., Bp) contiguous, lanes in ``order``, padding repeats the last lane."""
        idx = np.concatenate([order, np.full(Bp - B, order[-1] if B else 0)])
        return np.ascontiguousarray(np.moveaxis(a[idx], 0, -1))

    Pl = lanes(P.T)
    stl = np.concatenate([steps[order], np.zeros(Bp - B, np.int64)])
    out = np.empty((K + 1, 6, Bp))
    bad = np.empty(Bp, dtype=np.int64)
    lim_lin = LIMIT_A
    lim_ang = LIMIT_A / (0.5 * sh.L_pp)
    kern.simulate_lanes(
        lanes(X0),
        lanes(U[:, :, 0]),
        lanes(U[:, :, 1]),
        lanes(Wd[:, :, 0]),
        lanes(Wd[:, :, 1]),
        Pl,
        stl,
        sh,
        float(dt),
        lim_lin,
        lim_ang,
        int(chunk),
        out,
        bad,
    )
    if np.array_equal(order, np.arange(B)):
        inverse = order
        states = out[:, :, :B].transpose(2, 0, 1)  # (B, K + 1, 6), a view
    else:
        inverse = np.empty(B, dtype=np.int64)
        inverse[order] = np.arange(B)
        states = out[:, :, inverse].transpose(2, 0, 1)
    short = steps < K
    if np.any(short):
        mask = np.arange(K + 1)[None, :] > steps[:, None]
        states[mask] = np.nan
    return SimulationResult(states=states, bad_step=bad[inverse])


def simulate(
    x0: Any,
    u_seq: Any,
    w_seq: Any,
    p: ParamsLike,
    dt: float = 0.1,
    n_steps: Any = None,
    effects: tuple[Effect, ...] = (),
    ship: Ship | None = None,
) -> FloatArray:
    """Trajectories (B, K + 1, 6); see :func:`simulate_batch` for flags and arguments."""
    return simulate_batch(x0, u_seq, w_seq, p, dt, n_steps, effects, ship).states
