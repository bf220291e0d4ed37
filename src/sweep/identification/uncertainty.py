"""How well the data determine an identified model: intervals, statuses and flat directions.

The objectives are sums of squares of residuals
(:func:`~sweep.identification.polish.residual_vectors`: per subsequence w, sample k and channel
j, r_wkj = sqrt(w_k dt) (z_hat_in - z_hat_sim)). Near an
optimum z_hat (normalised box coordinates, [0, 1] per parameter) the output-error estimate
responds to a perturbation e of the residuals (measurement noise, or what the model cannot
follow) as

    dz = -A^-1 sum_w G_w' e_w,     A = sum_w G_w' G_w,     G_w = dr_w / dz

(G: central differences of ``fd_step`` in the normalised box). The 100-s subsequences are
independent initial-value problems, but within one the residuals are strongly correlated: the
recorded channels are coloured, the simulation starts from a noisy recorded state and every
channel is standardised by its own mean and spread. So the covariance is the cluster-robust
sandwich with one cluster per subsequence,

    C = A^-1 (sum_w g_w g_w') A^-1,   g_w = G_w' (I - H_ww)^-1/2 r_w,   H_ww = G_w A^-1 G_w'

with the residuals r_w at the optimum; (I - H_ww)^-1/2 undoes the share of a subsequence's
residual that the fit itself absorbed (the CR2 correction of Bell and McCaffrey), without which
the intervals come out too narrow. It needs no noise model and covers residuals that are model
error as well as noise. Directions the data leave flat (eigenvalues of A below ``rcond`` of the
largest) get the spread of a uniform distribution over the box, 1/sqrt(12) per normalised
coordinate, and no direction gets more (eigenvalues of C clipped there).

Intervals: estimate +- t sd, t the Student quantile of ``level`` with (subsequences - 1)
degrees of freedom, clipped to the box, in parameter units. Statuses (:func:`classify`):

- ``at a bound``: the estimate lies within ``bound_margin`` (share of the box width) of a bound
  of the search domain (the optimiser is held there; the local picture does not apply);
- ``determined``: otherwise, when the interval's half-width is at most ``determined_width`` of
  the box width;
- ``weakly determined``: the rest.

Flat directions (which parameters trade off) are the eigenvectors of the information matrix A
with its columns scaled to unit diagonal (so that the answer depends neither on units nor on
how well each parameter is determined alone), smallest eigenvalue lambda first. The collinearity
index 1 / sqrt(lambda) says by how much the combination is less determined than its parameters
would be if the others were known (Brun, Reichert and Kuensch 2001, Water Resour. Res. 37(4),
1015-1030; an index of 10 or more is reported). Each is named by its dominant parameters, those
that carry ``dominant_share`` of its squared loading (2 to ``max_named`` of them).

Calibration (``benchmarks/interval_coverage.py``): on data simulated from known parameters with
the recordings' coloured noise, the 90 % intervals of the parameters called determined cover the
truth in 85-95 % of cases (docs/guide/uncertainty.md has the figures).
"""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import t as student_t
from threadpoolctl import threadpool_limits

from mmg import Effect, Parameters
from mmg.params import PARAMETER_NAMES
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.identification.cmaes import Box
from sweep.identification.polish import residual_vectors
from sweep.identification.vector import from_full_vector, full_vector, joint_box

FloatArray = NDArray[np.float64]

DETERMINED = "determined"
WEAK = "weakly determined"
AT_BOUND = "at a bound"
#: the statuses, in table order
STATUSES = (DETERMINED, WEAK, AT_BOUND)
#: a Gauss-Newton step of more than this many standard deviations (median over the determined
#: parameters) says the parameters are not an optimum of the objective on the recordings (the
#: model's piecewise right-hand side leaves converged fits at 0.3-1.2, EFD on Train-R at 4)
NOT_OPTIMUM = 3.0
#: Jacobian columns simulated per batch (memory: two residual arrays per column)
JACOBIAN_CHUNK = 16
#: standard deviation of a uniform distribution over the normalised box: the most any
#: parameter's spread is allowed to be
BOX_SD = 1.0 / math.sqrt(12.0)


@dataclass(frozen=True)
class UncertaintySettings:
    """How the intervals are computed and judged (see the module docstring)."""

    level: float = 0.90  # coverage of the intervals
    fd_step: float = 1e-3  # central-difference step in the normalised box
    rcond: float = 1e-10  # eigenvalues of A below this share of the largest: flat
    leverage_cap: float = 0.99  # largest leverage the CR2 correction undoes
    determined_width: float = 0.05  # largest half-width (share of the box) of "determined"
    bound_margin: float = 0.01  # an estimate this close to a bound (share of the box) is on it
    flat_directions: int = 5  # most flat directions reported
    min_collinearity: float = 10.0  # smallest collinearity index of a reported direction
    dominant_share: float = 0.8  # the named parameters carry this share of a direction
    max_named: int = 4  # parameters named per direction at most


@dataclass(frozen=True)
class FlatDirection:
    """One direction (normalised coordinates) the data leave flat."""

    #: collinearity index 1 / sqrt(lambda) (infinite for a parameter the data do not see)
    collinearity: float
    loadings: dict[str, float]  # dominant parameters -> component of the unit direction

    @property
    def names(self) -> list[str]:
        """The dominant parameters, largest loading first."""
        return list(self.loadings)

    def sentence(self) -> str:
        """``"Y_v, C_D and C_rY trade off"`` (one name: ``"X is not seen by the data"``)."""
        names = self.names
        if len(names) == 1:
            return f"{names[0]} is not seen by the data"
        return f"{', '.join(names[:-1])} and {names[-1]} trade off"


@dataclass
class Uncertainty:
    """Intervals of every parameter of an identified model.

    ``names`` (n,): the 57 base parameters, then the effects' as ``effect.param``;
    ``estimate``, ``sd``, ``lower``, ``upper`` (n,) in each parameter's unit; ``status`` (n,)
    one of :data:`STATUSES`; ``cov`` (n, n) the covariance in normalised box coordinates;
    ``box_lower``, ``box_upper`` (n,) the search box; ``f`` the objective at the estimate.
    """

    names: list[str]
    estimate: FloatArray
    sd: FloatArray
    lower: FloatArray
    upper: FloatArray
    status: list[str]
    cov: FloatArray
    box_lower: FloatArray
    box_upper: FloatArray
    flat: list[FlatDirection]
    objective: str
    f: float
    level: float
    quantile: float  # interval half-width in standard deviations
    dof: int  # degrees of freedom of the Student t behind the intervals (subsequences - 1)
    seconds: float = 0.0
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def fraction_determined(self) -> float:
        """The share of the parameters called determined."""
        return sum(s == DETERMINED for s in self.status) / max(len(self.status), 1)

    @property
    def counts(self) -> dict[str, int]:
        """Number of parameters per status."""
        return {s: sum(x == s for x in self.status) for s in STATUSES}

    def half_width_share(self) -> FloatArray:
        """(n,) half-width of each interval as a share of its box width (before clipping)."""
        return np.asarray(self.quantile * self.sd / (self.box_upper - self.box_lower))

    def covers(self, truth: Any) -> FloatArray:
        """(n,) booleans: whether each interval holds the value of ``truth`` (n,)."""
        v = np.asarray(truth, dtype=np.float64)
        return np.asarray((v >= self.lower) & (v <= self.upper))

    def sample(self, n: int, rng: np.random.Generator) -> FloatArray:
        """(n, len(names)) parameter vectors drawn from the interval model (a multivariate
        Student t with ``dof`` degrees of freedom around the estimate, scale ``cov`` in
        normalised coordinates: each parameter's draws fall in its interval at the interval's
        level), clipped to the search box, in parameter units, laid out as
        :func:`sweep.identification.vector.full_vector`. Quantities computed from the draws
        (a manoeuvre's overshoot, ...) get their intervals from the draws' quantiles.

        A parameter at a bound stays at its estimate, and the others are drawn from their
        distribution given it (the conditional covariance): drawn freely, half of its draws
        were clipped onto the bound and the rest could only move inward, which pushed the
        manoeuvres of every draw one way (the shipped model's crash stop fell outside its own
        interval)."""
        width = self.box_upper - self.box_lower
        z0 = (self.estimate - self.box_lower) / width
        held = np.array([st == AT_BOUND for st in self.status])
        cov = np.array(self.cov, dtype=np.float64)
        free = ~held
        if held.any() and free.any():
            S_fb = cov[np.ix_(free, held)]
            S_bb = cov[np.ix_(held, held)]
            cond = cov[np.ix_(free, free)] - S_fb @ np.linalg.pinv(S_bb) @ S_fb.T
            cov = np.zeros_like(cov)
            cov[np.ix_(free, free)] = 0.5 * (cond + cond.T)
        elif held.all():
            cov = np.zeros_like(cov)
        w, V = np.linalg.eigh(cov)
        root = V * np.sqrt(np.clip(w, 0.0, None))
        scale = np.sqrt(self.dof / rng.chisquare(self.dof, n))
        z = z0[None, :] + scale[:, None] * (rng.standard_normal((n, z0.size)) @ root.T)
        out = np.asarray(self.box_lower + np.clip(z, 0.0, 1.0) * width)
        # a held parameter is its estimate itself: the round trip through the normalised box
        # ((x - lower) / width * width + lower) can differ from it in the last digit
        out[:, held] = self.estimate[held]
        return out

    def sample_parameters(
        self, n: int, rng: np.random.Generator, template: Parameters, effects: Sequence[Effect]
    ) -> list[Parameters]:
        """:meth:`sample` as Parameters with the ship of ``template``, carrying ``effects`` (the
        effects the intervals were computed with, in that order)."""
        return [from_full_vector(v, template, effects) for v in self.sample(n, rng)]

    def rows(self) -> list[dict[str, Any]]:
        """One dict per parameter: name, estimate, sd, lower, upper, half_width_share, status."""
        share = self.half_width_share()
        return [
            {
                "name": name,
                "estimate": float(self.estimate[i]),
                "sd": float(self.sd[i]),
                "lower": float(self.lower[i]),
                "upper": float(self.upper[i]),
                "half_width_share": float(share[i]),
                "status": self.status[i],
            }
            for i, name in enumerate(self.names)
        ]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: objective, f, level, counts, fraction determined, the rows, the flat
        directions (sentence, collinearity index, loadings), how they were computed (``meta``),
        the search box and the covariance (normalised coordinates, n x n): enough for
        :meth:`from_dict` to draw the same samples."""
        return {
            "objective": self.objective,
            "f": self.f,
            "level": self.level,
            "quantile": self.quantile,
            "dof": self.dof,
            "seconds": self.seconds,
            "fraction_determined": self.fraction_determined,
            "counts": self.counts,
            "parameters": self.rows(),
            "flat_directions": [
                {
                    "sentence": d.sentence(),
                    "collinearity": d.collinearity if math.isfinite(d.collinearity) else None,
                    "loadings": d.loadings,
                }
                for d in self.flat
            ],
            "meta": self.meta,
            "box_lower": self.box_lower.tolist(),
            "box_upper": self.box_upper.tolist(),
            "cov": self.cov.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Uncertainty:
        """Inverse of :meth:`as_dict` (e.g. a sweep job's ``uncertainty.json``)."""
        rows = data["parameters"]
        column = lambda key: np.array([float(r[key]) for r in rows])  # noqa: E731
        flat = [
            FlatDirection(
                math.inf if d["collinearity"] is None else float(d["collinearity"]),
                {str(k): float(v) for k, v in d["loadings"].items()},
            )
            for d in data["flat_directions"]
        ]
        return cls(
            names=[str(r["name"]) for r in rows],
            estimate=column("estimate"),
            sd=column("sd"),
            lower=column("lower"),
            upper=column("upper"),
            status=[str(r["status"]) for r in rows],
            cov=np.asarray(data["cov"], dtype=np.float64),
            box_lower=np.asarray(data["box_lower"], dtype=np.float64),
            box_upper=np.asarray(data["box_upper"], dtype=np.float64),
            flat=flat,
            objective=str(data["objective"]),
            f=float(data["f"]),
            level=float(data["level"]),
            quantile=float(data["quantile"]),
            dof=int(data["dof"]),
            seconds=float(data["seconds"]),
            meta=dict(data["meta"]),
        )

    def to_csv(self) -> str:
        """The interval table as CSV text (the columns of :meth:`rows`, floats exact)."""
        buf = io.StringIO()
        rows = self.rows()
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: repr(v) if isinstance(v, float) else v for k, v in row.items()})
        return buf.getvalue()

    def to_markdown(self) -> str:
        """The interval table and the flat directions as Markdown."""
        pct = round(100 * self.level)
        c = self.counts
        lines = [
            f"{pct} % intervals of the {len(self.names)} parameters ({self.objective} = "
            f"{self.f:.4g} on {self.meta.get('subsequences', '?')} subsequences): "
            f"{c[DETERMINED]} determined, {c[WEAK]} weakly determined, {c[AT_BOUND]} at a bound.",
            "",
            f"| parameter | estimate | sd | {pct} % interval | half-width / box | status |",
            "|---|---:|---:|---|---:|---|",
        ]
        for row in self.rows():
            lines.append(
                f"| {row['name']} | {row['estimate']:.4g} | {row['sd']:.2g} | "
                f"[{row['lower']:.4g}, {row['upper']:.4g}] | {row['half_width_share']:.3f} | "
                f"{row['status']} |"
            )
        step = float(self.meta.get("newton_step_sd", 0.0))
        if step > NOT_OPTIMUM:
            lines += [
                "",
                f"Warning: a Gauss-Newton step from these parameters moves the determined ones by "
                f"{step:.1f} standard deviations (median): they are probably not an optimum of "
                f"{self.objective} on these recordings, and the intervals describe the curvature "
                "here, not where the optimum lies.",
            ]
        lines += ["", "Parameters that trade off (flat directions of the information):", ""]
        if not self.flat:
            lines.append("- none: no combination has a collinearity index of 10 or more")
        for d in self.flat:
            parts = ", ".join(f"{k} {v:+.2f}" for k, v in d.loadings.items())
            gamma = f"{d.collinearity:.0f}" if math.isfinite(d.collinearity) else "infinite"
            lines.append(f"- {d.sentence()} (collinearity index {gamma}; loadings {parts})")
        return "\n".join(lines) + "\n"


def jacobian(
    obj: Objective, box: Box, theta: FloatArray, step: float
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """Residuals r (S, M) at ``theta`` (n,), their Jacobian G (n, S, M) with respect to the
    normalised coordinates (central differences of ``step``, one-sided within ``step`` of a
    bound) and the flags (S,) of the subsequences that diverge at ``theta``. Rows of a
    diverged subsequence are zero; so is a column whose probe diverges elsewhere (a direction
    the data cannot judge)."""
    width = box.upper - box.lower
    z = np.clip((theta - box.lower) / width, 0.0, 1.0)
    n = z.size
    up = np.minimum(z + step, 1.0)
    down = np.maximum(z - step, 0.0)
    r, bad = residual_vectors(obj, box.to_theta(z)[None])
    G = np.empty((n, *r.shape[1:]))
    frozen = np.zeros(n, dtype=bool)
    for lo in range(0, n, JACOBIAN_CHUNK):  # a chunk of columns at a time: bounded memory
        i = np.arange(lo, min(lo + JACOBIAN_CHUNK, n))
        probes = np.repeat(z[None, :], 2 * i.size, axis=0)
        probes[np.arange(i.size), i] = up[i]
        probes[i.size + np.arange(i.size), i] = down[i]
        rp, badp = residual_vectors(obj, box.to_theta(probes))
        G[i] = (rp[: i.size] - rp[i.size :]) / (up - down)[i, None, None]
        frozen[i] = (badp[: i.size] | badp[i.size :])[:, ~bad[0]].any(axis=1)
    G[:, bad[0]] = 0.0
    G[frozen] = 0.0
    return r[0], G, bad[0]


def cluster_covariance(
    G: FloatArray, r: FloatArray, A: FloatArray, rcond: float = 1e-10, leverage_cap: float = 0.99
) -> tuple[FloatArray, FloatArray]:
    """The CR2 cluster-robust covariance (n, n) of the estimate, one cluster per subsequence,
    in normalised coordinates (module docstring), and the directions (n, d) the data leave
    flat: the eigenvectors of A = sum_w G_w G_w' with eigenvalues below ``rcond`` of the
    largest, flattest first, on which the covariance is zero. G (n, S, M) the Jacobian,
    r (S, M) the residuals at the optimum, A (n, n) = sum_w G_w G_w' (:func:`information`)."""
    n, S, _ = G.shape
    a, V = np.linalg.eigh(0.5 * (A + A.T))
    live = a > rcond * max(float(a[-1]), 1e-300)
    Vl = V[:, live]
    root_inv = (Vl / np.sqrt(a[live])) @ Vl.T  # A^-1/2 on the live directions
    meat = np.zeros((n, n))
    for w in range(S):
        B = root_inv @ G[:, w]  # (n, M): H_ww = B' B
        _, sig, Qt = np.linalg.svd(B, full_matrices=False)
        h = np.minimum(sig * sig, leverage_cap)
        rw = r[w] + Qt.T @ ((1.0 / np.sqrt(1.0 - h) - 1.0) * (Qt @ r[w]))
        g = root_inv @ (G[:, w] @ rw)  # A^-1/2 g_w
        meat += np.outer(g, g)
    C = root_inv @ meat @ root_inv
    return np.asarray(0.5 * (C + C.T)), np.asarray(V[:, ~live])


def information(G: FloatArray) -> FloatArray:
    """A = sum over subsequences and samples of G G' (n, n): the Gauss-Newton information of
    the Jacobian G (n, S, M), up to the scale of the residuals."""
    return np.asarray(np.einsum("isk,jsk->ij", G, G))


def capped(C: FloatArray, null: FloatArray) -> FloatArray:
    """The covariance ``C`` (n, n) with variance :data:`BOX_SD` ** 2 along the flat directions
    ``null`` (n, d) and no eigenvalue above that (the spread of a uniform distribution over the
    box: the data cannot make a parameter less certain than the search domain does)."""
    full = C + BOX_SD**2 * (null @ null.T)
    c, U = np.linalg.eigh(0.5 * (full + full.T))
    return np.asarray((U * np.clip(c, 0.0, BOX_SD**2)) @ U.T)


def newton_step(A: FloatArray, g: FloatArray, free: np.ndarray, rcond: float) -> FloatArray:
    """The Gauss-Newton step (n,) -A^-1 g over the ``free`` coordinates (n,) (the others held),
    normalised coordinates; directions of A below ``rcond`` of its largest eigenvalue left out.
    At an optimum it is a small fraction of the standard deviations."""
    step = np.zeros(g.size)
    if free.any():
        Af = A[np.ix_(free, free)]
        a, V = np.linalg.eigh(0.5 * (Af + Af.T))
        live = a > rcond * max(float(a[-1]), 1e-300)
        step[free] = -(V[:, live] / a[live]) @ (V[:, live].T @ g[free])
    return step


def classify(z: FloatArray, half_width: FloatArray, s: UncertaintySettings) -> list[str]:
    """Status of each parameter from its normalised estimate z (n,) and its interval's
    half-width as a share of the box (n,) (rules in the module docstring)."""
    out = []
    for zi, hw in zip(z, half_width, strict=True):
        if zi <= s.bound_margin or zi >= 1.0 - s.bound_margin:
            out.append(AT_BOUND)
        elif hw <= s.determined_width:
            out.append(DETERMINED)
        else:
            out.append(WEAK)
    return out


def flat_directions(
    A: FloatArray, names: Sequence[str], s: UncertaintySettings
) -> list[FlatDirection]:
    """Up to ``s.flat_directions`` combinations of parameters that trade off (module
    docstring): eigenvectors of the information matrix ``A`` (n, n) with its columns scaled to
    unit diagonal, smallest eigenvalue lambda first, while the collinearity index
    1 / sqrt(lambda) is at least ``s.min_collinearity``. A parameter the data do not see at all
    (a zero diagonal) comes first, alone, with an infinite index."""
    d = np.sqrt(np.clip(np.diag(A), 0.0, None))
    seen = d > 1e-12 * max(float(d.max()), 1e-300)
    out = [FlatDirection(math.inf, {names[int(j)]: 1.0}) for j in np.flatnonzero(~seen)]
    idx = np.flatnonzero(seen)
    scaled = A[np.ix_(idx, idx)] / np.outer(d[idx], d[idx])
    lam, V = np.linalg.eigh(0.5 * (scaled + scaled.T))
    for i in range(lam.size):
        gamma = 1.0 / math.sqrt(max(float(lam[i]), 1e-300))
        if len(out) >= s.flat_directions or gamma < s.min_collinearity:
            break
        v = V[:, i]
        rank = np.argsort(-np.abs(v))
        share = np.cumsum(v[rank] ** 2)
        k = max(2, min(int(np.searchsorted(share, s.dominant_share)) + 1, s.max_named))
        sign = 1.0 if v[rank[0]] >= 0 else -1.0
        out.append(FlatDirection(gamma, {names[int(idx[j])]: float(sign * v[j]) for j in rank[:k]}))
    return out


def model_names(effects: Sequence[Effect]) -> list[str]:
    """Names of the full vector: the 57 base parameters, then ``effect.param`` of each effect."""
    return list(PARAMETER_NAMES) + [f"{e.name}.{q}" for e in effects for q in e.param_names]


def uncertainty_at(
    obj: Objective,
    box: Box,
    theta: Any,
    names: Sequence[str],
    settings: UncertaintySettings | None = None,
) -> Uncertainty:
    """The intervals of ``theta`` (n,), an optimum of ``obj`` within ``box`` (module docstring);
    ``names`` (n,) label the parameters. Raises ValueError when fewer than two subsequences
    are left to judge it (the rest diverged)."""
    s = settings or UncertaintySettings()
    theta = np.asarray(theta, dtype=np.float64)
    t0 = time.perf_counter()
    # one BLAS thread: the products are small and the simulator's threads need the cores
    with threadpool_limits(limits=1, user_api="blas"):
        r, G, bad = jacobian(obj, box, theta, s.fd_step)
        keep = ~bad
        S = int(keep.sum())
        if S < 2:
            raise ValueError(
                f"{S} of {bad.size} subsequences left (the rest diverge at these parameters): "
                "too few to judge the parameters"
            )
        A = information(G[:, keep])
        raw, null = cluster_covariance(G[:, keep], r[keep], A, s.rcond, s.leverage_cap)
        cov = capped(raw, null)
        gradient = np.einsum("isk,sk->i", G[:, keep], r[keep])
    width = box.upper - box.lower
    sd_z = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    q = float(student_t.ppf(0.5 + s.level / 2, S - 1))
    z = np.clip((theta - box.lower) / width, 0.0, 1.0)
    status = classify(z, q * sd_z, s)
    step = newton_step(A, gradient, np.array([x != AT_BOUND for x in status]), s.rcond)
    determined = np.array([x == DETERMINED for x in status])
    step_sd = float(np.median(np.abs(step / sd_z)[determined])) if determined.any() else 0.0
    return Uncertainty(
        names=list(names),
        estimate=theta.copy(),
        sd=sd_z * width,
        lower=box.to_theta(np.clip(z - q * sd_z, 0.0, 1.0)),
        upper=box.to_theta(np.clip(z + q * sd_z, 0.0, 1.0)),
        status=status,
        cov=cov,
        box_lower=box.lower.copy(),
        box_upper=box.upper.copy(),
        flat=flat_directions(A, names, s),
        objective=obj.name,
        f=float((r[keep] ** 2).sum()),
        level=s.level,
        quantile=q,
        dof=S - 1,
        seconds=time.perf_counter() - t0,
        meta={
            "method": "CR2 cluster-robust sandwich, one cluster per subsequence",
            "subsequences": S,
            "diverged": int(bad.sum()),
            "fd_step": s.fd_step,
            "determined_width": s.determined_width,
            "bound_margin": s.bound_margin,
            "newton_step_sd": step_sd,
        },
    )


def parameter_uncertainty(
    params: Parameters,
    recordings: Sequence[Recording],
    objective: str = "J2",
    effects: Sequence[Effect] = (),
    settings: UncertaintySettings | None = None,
) -> Uncertainty:
    """Intervals of ``params`` (an optimum of ``objective`` on ``recordings``, e.g. a job's
    best parameters) carrying ``effects`` (their parameters are judged too, within their
    search intervals, :func:`sweep.identification.vector.joint_box`)."""
    effects = tuple(effects)
    obj = Objective(recordings, objective, effects=effects, ship=params.ship)
    theta = full_vector(params, effects)
    return uncertainty_at(obj, joint_box(effects), theta, model_names(effects), settings)


__all__ = [
    "AT_BOUND",
    "BOX_SD",
    "DETERMINED",
    "NOT_OPTIMUM",
    "STATUSES",
    "WEAK",
    "FlatDirection",
    "Uncertainty",
    "UncertaintySettings",
    "capped",
    "classify",
    "cluster_covariance",
    "flat_directions",
    "information",
    "jacobian",
    "model_names",
    "newton_step",
    "parameter_uncertainty",
    "uncertainty_at",
]
