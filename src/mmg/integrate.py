"""Public entry points: state derivatives and batched RK4 simulation.

Shapes: state x (..., 6) = (x0 [m], u [m/s], y0 [m], v_m [m/s], psi [rad], r [rad/s]);
control (..., 2) = (delta [rad], n_p [rev/s]); wind (..., 2) = (U_T [m/s], gamma_T [rad], the
direction the true wind blows from, earth-fixed, clockwise from x0).

Parameters ``p`` are a :class:`~mmg.params.Parameters` (one set for every trajectory), a float
array (n,) or (B, n) of flat vectors (57 explored values, then the effects' values in the order of
``effects``), or a sequence of :class:`~mmg.params.Parameters`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from mmg.effect import Effect
from mmg.fixed import kernel_effects
from mmg.kernel import LANE_BLOCK, LIMIT_A, load_kernel
from mmg.params import ESSO_OSAKA, N_THETA, FloatArray, Parameters, Ship

#: what the entry points accept as parameters (see the module docstring)
ParamsLike = Parameters | Sequence[Parameters] | FloatArray

#: lanes per work item of the kernel; 8 x an odd number (rows of 2^k doubles alias in L1 cache)
DEFAULT_CHUNK = 120


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
        """(B,) bool: True for a lane that hit the xdot limiter or became non-finite."""
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


def kernel_array(a: Any, dtype: type = np.float64) -> np.ndarray:
    """A writable, C-contiguous array: the one memory layout the compiled kernel is built for
    (a read-only or strided array would be a different Numba signature and compile again)."""
    return np.require(a, dtype=dtype, requirements=["C", "W", "A"])


def parameter_matrix(p: ParamsLike, B: int, effects: tuple[Effect, ...] = ()) -> FloatArray:
    """Per-lane parameters as a contiguous, writable (rows, B) float64 matrix: the kernel's
    rows for ``effects`` (:func:`kernel_rows`; n_params rows unless an effect is held)."""
    return kernel_rows(_parameter_matrix(p, B, effects), effects)


def kernel_rows(P: FloatArray, effects: tuple[Effect, ...]) -> FloatArray:
    """The (n_params, B) parameter matrix ``P`` of ``effects`` as the rows of their kernel
    (:func:`mmg.fixed.kernel_effects`): a held effect, which has no parameters, runs the kernel
    of the effect it holds, so its held values are put in as that effect's rows; the numbers of
    an effect's kernel form (a box's bounds) follow its rows."""
    forms = [e.kernel_form() for e in effects]
    if all(held is None and not numbers for _, held, numbers in forms):
        return P
    B = P.shape[1]
    blocks, k = [P[:N_THETA]], N_THETA
    for e, (_, held, numbers) in zip(effects, forms, strict=True):
        if held is None:
            blocks.append(P[k : k + len(e.params)])
            k += len(e.params)
        else:
            blocks.append(np.repeat(np.asarray(held, dtype=np.float64)[:, None], B, 1))
        if numbers:
            blocks.append(np.repeat(np.asarray(numbers, dtype=np.float64)[:, None], B, 1))
    return kernel_array(np.concatenate(blocks, axis=0))


def _parameter_matrix(p: ParamsLike, B: int, effects: tuple[Effect, ...]) -> FloatArray:
    """Per-lane parameters as a contiguous, writable (n_params, B) float64 matrix."""
    n = N_THETA + sum(len(e.params) for e in effects)
    if isinstance(p, Parameters):
        vec = np.concatenate([p.vector(), effect_vector(p, effects)])
        return np.repeat(vec[:, None], B, axis=1)
    if isinstance(p, np.ndarray):
        arr = np.asarray(p, dtype=np.float64)
        if arr.ndim == 1:
            arr = np.broadcast_to(arr, (B, arr.shape[0]))
        if arr.shape[-1] != n or math.prod(arr.shape[:-1]) != B:
            raise ValueError(f"parameter array must have shape ({n},) or ({B}, {n}); got {p.shape}")
        # written straight into the kernel's layout, whatever the leading shape (reshaping a
        # broadcast (..., n) view to (B, n) and then transposing it copied the matrix twice;
        # equation-level discovery passes hundreds of parameter rows per sample)
        P = np.empty((n, B))
        P.reshape(n, *arr.shape[:-1])[...] = np.moveaxis(arr, -1, 0)
        return P
    rows = [np.concatenate([q.vector(), effect_vector(q, effects)]) for q in p]
    if len(rows) != B:
        raise ValueError(f"{len(rows)} parameter sets for {B} trajectories")
    return kernel_array(np.array(rows).T)


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


def _points(
    x: Any, u: Any, w: Any, t: Any
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, tuple[int, ...]]:
    """x, u, w, t as float arrays and the broadcast shape of their points."""
    x_arr = np.asarray(x, dtype=np.float64)
    u_arr = np.asarray(u, dtype=np.float64)
    w_arr = np.asarray(w, dtype=np.float64)
    t_arr = np.asarray(t, dtype=np.float64)
    shape = np.broadcast_shapes(x_arr.shape[:-1], u_arr.shape[:-1], w_arr.shape[:-1], t_arr.shape)
    return x_arr, u_arr, w_arr, t_arr, shape


def derivatives(
    x: Any,
    u: Any,
    w: Any,
    p: ParamsLike,
    effects: tuple[Effect, ...] = (),
    ship: Ship | None = None,
    t: Any = 0.0,
) -> FloatArray:
    """State derivatives xdot (..., 6) of paper Eq. (3), without the limiter.

    x (..., 6), u (..., 2) = (delta, n_p), w (..., 2) = (U_T, gamma_T); ``p`` one parameter set or
    one per point (array (..., n) or sequence); t (...) [s] the time on the recording's clock
    (used only by effects whose forces depend on time). Leading shapes broadcast.
    """
    x_arr, u_arr, w_arr, t_arr, shape = _points(x, u, w, t)
    M = int(np.prod(shape))
    T = kernel_array(np.broadcast_to(t_arr, shape).reshape(M))
    X = kernel_array(np.broadcast_to(x_arr, (*shape, 6)).reshape(M, 6).T)
    U = np.broadcast_to(u_arr, (*shape, 2)).reshape(M, 2)
    Wd = np.broadcast_to(w_arr, (*shape, 2)).reshape(M, 2)
    if isinstance(p, np.ndarray) and p.ndim > 1:
        p = np.broadcast_to(p, (*shape, p.shape[-1]))  # one parameter set per point
    P = parameter_matrix(p, M, effects)
    kern = load_kernel(kernel_effects(effects))
    out = np.empty((6, M))
    kern.rhs_rows(
        T,
        X,
        kernel_array(U[:, 0]),
        kernel_array(U[:, 1]),
        kernel_array(Wd[:, 0]),
        kernel_array(Wd[:, 1]),
        kernel_array(P),
        np.arange(M, dtype=np.int64),  # point i reads column i
        _ship_of(p, ship),
        out,
    )
    return out.T.reshape(*shape, 6)


def derivatives_rows(
    x: Any,
    u: Any,
    w: Any,
    rows: Any,
    effects: tuple[Effect, ...] = (),
    ship: Ship | None = None,
    t: Any = 0.0,
) -> FloatArray:
    """State derivatives xdot (R, ..., 6) of each of R parameter sets ``rows`` (R, n) at every
    point of x (..., 6), u (..., 2), w (..., 2), t (...) (leading shapes broadcast).

    The same numbers as :func:`derivatives` with the parameters broadcast to every point, but
    the kernel reads each point's set from the R columns: no (n, R x points) copy of them (with
    hundreds of sets, as equation-level discovery has, that copy cost more than the physics).
    """
    return _rows("rhs_rows", 6, x, u, w, rows, effects, ship, t)


def effect_accelerations_rows(
    x: Any,
    u: Any,
    w: Any,
    rows: Any,
    effects: tuple[Effect, ...],
    ship: Ship | None = None,
    t: Any = 0.0,
) -> FloatArray:
    """(R, ..., 3) the accelerations (u_dot, v_m_dot, r_dot) that the forces of the last of
    ``effects`` add to the right-hand side, for each of R parameter sets ``rows`` (R, n) at every
    point (arguments as :func:`derivatives_rows`).

    Eq. (1) is linear in the forces: this is :func:`derivatives_rows` of the rows less that of
    the rows with the last effect's forces left out (up to rounding, and free of the
    cancellation of that difference), at the cost of the effect's forces alone.
    """
    if not effects:
        raise ValueError("effect_accelerations_rows needs at least one effect")
    if effects[-1].force is None and effects[-1].force_at is None:
        raise ValueError(f"effect {effects[-1].name!r} adds no force (no force hook)")
    return _rows("effect_rows", 3, x, u, w, rows, effects, ship, t)


def _rows(
    entry: str,
    k_out: int,
    x: Any,
    u: Any,
    w: Any,
    rows: Any,
    effects: tuple[Effect, ...],
    ship: Ship | None,
    t: Any,
) -> FloatArray:
    P_rows = np.asarray(rows, dtype=np.float64)
    n = N_THETA + sum(len(e.params) for e in effects)
    if P_rows.ndim != 2 or P_rows.shape[1] != n:
        raise ValueError(f"rows must have shape (R, {n}); got {P_rows.shape}")
    x_arr, u_arr, w_arr, t_arr, shape = _points(x, u, w, t)
    M = int(np.prod(shape))
    R = P_rows.shape[0]

    def lanes(a: FloatArray, k: int) -> FloatArray:
        """Points (..., k) broadcast to ``shape`` -> kernel lanes (k, R * M); lane r M + m is
        parameter row r at point m."""
        pts = np.broadcast_to(a, (*shape, k)).reshape(M, k).T
        return kernel_array(np.broadcast_to(pts[:, None, :], (k, R, M)).reshape(k, R * M))

    X = lanes(x_arr, 6)
    U = lanes(u_arr, 2)
    Wd = lanes(w_arr, 2)
    T = lanes(t_arr[..., None], 1)[0]
    out = np.empty((k_out, R * M))
    getattr(load_kernel(kernel_effects(effects)), entry)(
        kernel_array(T),
        X,
        kernel_array(U[0]),
        kernel_array(U[1]),
        kernel_array(Wd[0]),
        kernel_array(Wd[1]),
        kernel_rows(kernel_array(P_rows.T), effects),
        kernel_array(np.repeat(np.arange(R, dtype=np.int64), M), np.int64),
        _ship_of(P_rows, ship),
        out,
    )
    return np.moveaxis(out.reshape(k_out, R, *shape), 0, -1)


def chunk_width(B: int, chunk: int = DEFAULT_CHUNK) -> int:
    """Lanes per chunk: at most about ``chunk``, in whole vector blocks (:data:`LANE_BLOCK`), with a
    number of chunks that the threads share evenly (the last chunk may be shorter; the kernels
    pad it to whole blocks)."""
    threads = numba.get_num_threads()
    n_chunks = max(1, -(-B // chunk))
    n_chunks = -(-n_chunks // threads) * threads if threads <= B else n_chunks
    width = -(-B // n_chunks)
    return max(1, -(-width // LANE_BLOCK) * LANE_BLOCK)


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
    t0: Any = 0.0,
    out: FloatArray | None = None,
) -> SimulationResult:
    """RK4 simulation of B trajectories with the xdot limiter of paper Algorithm 1.

    x0 (B, 6) initial states; u_seq (B, K, 2) controls and w_seq (B, K, 2) true wind, held over
    each step of dt [s]; n_steps (B,) optional lengths <= K for segments of unequal length
    (default K for all); t0 (B,) or a scalar: the start times [s] on the recordings' clocks (for
    effects whose forces depend on time). Returns states (B, K + 1, 6) and the per-trajectory
    divergence flags.
    out: an optional C-contiguous float64 (B, K + 1, 6) array the states are written into (and
    returned): a caller that simulates batch after batch reuses it, where a fresh array of tens
    of MB is page-faulted in again every time (it is mapped anew by the allocator).
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
    kern = load_kernel(kernel_effects(effects))
    order = np.argsort(-steps, kind="stable")  # similar lengths share a chunk
    if out is None:
        out = np.empty((B, K + 1, 6))
    elif out.shape != (B, K + 1, 6) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(
            f"out must be a C-contiguous float64 array of shape {(B, K + 1, 6)}; got "
            f"{out.dtype} {out.shape}"
        )
    bad = np.empty(B, dtype=np.int64)
    t_start = np.broadcast_to(np.asarray(t0, dtype=np.float64), (B,))
    kern.simulate_lanes(
        kernel_array(X0),
        kernel_array(t_start),
        kernel_array(U),
        kernel_array(Wd),
        kernel_array(P),
        kernel_array(steps, np.int64),
        kernel_array(order, np.int64),
        sh,
        float(dt),
        LIMIT_A,
        LIMIT_A / (0.5 * sh.L_pp),
        chunk_width(B, chunk),
        numba.get_num_threads(),
        out,
        bad,
    )
    return SimulationResult(states=out, bad_step=bad)


def simulate(
    x0: Any,
    u_seq: Any,
    w_seq: Any,
    p: ParamsLike,
    dt: float = 0.1,
    n_steps: Any = None,
    effects: tuple[Effect, ...] = (),
    ship: Ship | None = None,
    t0: Any = 0.0,
) -> FloatArray:
    """Trajectories (B, K + 1, 6); see :func:`simulate_batch` for flags and arguments."""
    return simulate_batch(x0, u_seq, w_seq, p, dt, n_steps, effects, ship, t0=t0).states


def rk4_reference(
    x0: Any,
    u_seq: Any,
    w_seq: Any,
    p: Parameters,
    dt: float = 0.1,
    effects: tuple[Effect, ...] = (),
    t0: float = 0.0,
) -> FloatArray:
    """One trajectory by a plain NumPy RK4 loop with the limiter of Algorithm 1: (K + 1, 6).

    The slow, obvious path that the batched kernel is tested against. x0 (6,), u_seq (K, 2),
    w_seq (K, 2); uses :func:`derivatives` for the right-hand side.
    """
    x = np.asarray(x0, dtype=np.float64).copy()
    U = np.asarray(u_seq, dtype=np.float64)
    Wd = np.asarray(w_seq, dtype=np.float64)
    K = U.shape[0]
    t_f = K * dt
    lim = np.array([LIMIT_A] * 4 + [LIMIT_A / (0.5 * p.ship.L_pp)] * 2)
    position_rows = np.array([True, False, True, False, True, False])
    out = np.empty((K + 1, 6))
    out[0] = x
    for k in range(K):
        ks: list[FloatArray] = []
        for c, prev in ((0.0, None), (0.5, 0), (0.5, 1), (1.0, 2)):
            xs = x if prev is None else x + c * dt * ks[prev]
            d = derivatives(xs, U[k], Wd[k], p, effects, t=t0 + (k * dt + c * dt))
            scale = np.where(position_rows, 2.0 - (k * dt + c * dt) / t_f, 1.0)
            d = np.where(np.abs(d) > lim, np.sign(d) * scale * lim, d)
            ks.append(d)
        x = x + dt / 6.0 * (ks[0] + 2.0 * ks[1] + 2.0 * ks[2] + ks[3])
        out[k + 1] = x
    return out


#: the observables whose moments :func:`segment_moments` accumulates (the J2 state of the paper)
OBSERVABLES = ("x0", "u", "y0", "v_m", "sin_psi", "cos_psi", "r")


@dataclass(frozen=True)
class Segments:
    """Initial-value problems shared by every candidate of a population.

    x0 (S, 6) recorded first states; u (S, K, 2) controls and w (S, K, 2) true wind (zero-order
    hold); n_steps (S,) lengths <= K; ref (S, K + 1, 7) a reference series per observable (e.g. the
    standardised recording); shift (S, 7) subtracted from the simulated observables before the
    moments are formed (numerical conditioning: use the recorded first values); t0 (S,) the
    segments' start times [s] on the recordings' clocks (default zeros), for effects whose forces
    depend on time.
    """

    x0: FloatArray
    u: FloatArray
    w: FloatArray
    n_steps: np.ndarray
    ref: FloatArray
    shift: FloatArray
    t0: FloatArray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        S, K = self.u.shape[:2]
        if self.t0.size == 0 and S > 0:  # not given: every segment starts at t = 0
            object.__setattr__(self, "t0", np.zeros(S))
        shapes = {
            "x0": (self.x0.shape, (S, 6)),
            "u": (self.u.shape, (S, K, 2)),
            "w": (self.w.shape, (S, K, 2)),
            "n_steps": (self.n_steps.shape, (S,)),
            "ref": (self.ref.shape, (S, K + 1, 7)),
            "shift": (self.shift.shape, (S, 7)),
            "t0": (np.shape(self.t0), (S,)),
        }
        for name, (got, want) in shapes.items():
            if got != want:
                raise ValueError(f"Segments.{name} must have shape {want}; got {got}")


def segment_moments(
    segments: Segments,
    p: ParamsLike,
    dt: float = 0.1,
    effects: tuple[Effect, ...] = (),
    ship: Ship | None = None,
    chunk: int = DEFAULT_CHUNK,
) -> tuple[FloatArray, np.ndarray]:
    """Simulate every (candidate, segment) pair, streaming moments instead of trajectories.

    ``p``: C candidates (array (C, n) or a sequence), or one :class:`Parameters`. Returns
    mom (C, S, 7, 5): per observable of :data:`OBSERVABLES`, over the samples k = 0..n_steps of the
    segment, with trapezoid weights w_k (1/2 at both ends): (sum z, sum z^2, sum w z, sum w z^2,
    sum w z ref), z shifted by ``segments.shift``; and bad_step (C, S), -1 where the simulation
    stayed finite and within the limiter. Memory is O(C S), not O(C S K).
    """
    S = segments.x0.shape[0]
    C = 1 if isinstance(p, Parameters) else len(p)
    sh = _ship_of(p, ship)
    P = parameter_matrix(p, C, effects)
    kern = load_kernel(kernel_effects(effects))
    seg_order = np.argsort(-segments.n_steps, kind="stable")  # long segments first
    lane_seg = np.repeat(seg_order, C)
    lane_cand = np.tile(np.arange(C), S)
    L = C * S
    mom = np.empty((L, 7, 5))
    bad = np.empty(L, dtype=np.int64)
    kern.moments_lanes(
        kernel_array(segments.x0),
        kernel_array(segments.t0),
        kernel_array(segments.u),
        kernel_array(segments.w),
        kernel_array(segments.ref),
        kernel_array(segments.shift),
        kernel_array(segments.n_steps, np.int64),
        kernel_array(P),
        kernel_array(lane_cand, np.int64),
        kernel_array(lane_seg, np.int64),
        sh,
        float(dt),
        LIMIT_A,
        LIMIT_A / (0.5 * sh.L_pp),
        chunk_width(L, chunk),
        numba.get_num_threads(),
        mom,
        bad,
    )
    out = np.empty((C, S, 7, 5))
    out[lane_cand, lane_seg] = mom
    bad_cs = np.empty((C, S), dtype=np.int64)
    bad_cs[lane_cand, lane_seg] = bad
    return out, bad_cs
