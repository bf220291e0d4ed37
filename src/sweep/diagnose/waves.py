"""Forces that come and go in time, probed by their closed forms, beside the learned shapes.

A shape of the recording's time (``x~t``, ``N~t``: :mod:`mmg.shapes`) is chosen, like every
shape, by its gain on held-out runs: fitted on one half of the training runs, judged on the
other's. A spline of time learnt where one half's runs were recorded says little about the
clock times that only the other half covers (the runs' windows start at a few clock times
each), so a force that changes over minutes is not chosen however much it explains: on a
planted push whose direction turns over the basin once in 300 s, the time shapes of the
basin's two components took 24 % off the training windows' J in sample and lost 12 % held
out, and the selection chose nothing (test J2 26 x the true model's).

A periodic force carries over where a spline cannot: its period and phase, learnt where runs
went, give the times between. The probe has three steps.

1. *Is a wave there?* Each component's wave a + b sin(2 pi t / T + phi) (forces on the ship's
   axes, X, Y, N, and fixed to the basin, x and y), and the basin's two together, over a
   geometric grid of periods (:data:`PERIOD_RATIO`): its trajectory columns are the gate's
   own time shapes' columns (:func:`gate_groups`: knots about 10 s apart over the clock
   below :data:`GATE_CLOCK`, where the selection's span the whole clock) times the wave in
   their basis
   (:func:`~sweep.diagnose.naming.form_transform`, at phases 0 and pi / 2: the phase is then
   linear), the base's 57 parameters refitted beside them (linearised, with the prior, on all
   windows). The best in-sample dBIC (the coefficients and the period counted) is compared
   with the same statistic on noise-only copies of the training windows (the ``alpha``
   quantile, capped at :data:`~sweep.diagnose.threshold.CEILING`).
2. *Its period* (:func:`period_peaks`): the linearised columns are derivatives at the base,
   whose trajectories the missing force has moved, and the gate's knots end where its range
   does; they do not place the period. A periodogram of the equation-level
   residual of every sample does, to one cycle over the span of the clock.
3. *The wave* (:func:`_by_output_error`): the basin's two components (a force of the water or
   the air that comes and goes is fixed to the basin; the two at one period hold a push along
   one direction as well as one that turns) fitted by output error at the periodogram's
   peaks and about the best; the best goes to the candidates, where it is judged on held-out
   runs and on other sessions' runs like every other.

Time is a candidate variable only where the training runs come from several sessions
(:func:`~sweep.diagnose.shaping.default_variables`: a force of the recording's clock must
carry over to another session's runs), and the probe runs only where the misfit test finds
the base beyond the noise floor (as the memories' probe, :mod:`sweep.diagnose.memory`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg import Effect, Parameters
from mmg.shapes import Form, Group, form_scale, shape_effect
from sweep.data.recordings import Recording
from sweep.diagnose.calibration import Calibration
from sweep.diagnose.candidates import candidate_settings
from sweep.diagnose.context import Context
from sweep.diagnose.corners import ITERATIONS as CORNER_ITERATIONS
from sweep.diagnose.discover import DiscoverySettings, equation_data, null_sets
from sweep.diagnose.fit import Fit
from sweep.diagnose.naming import WAVE_KNOTS, form_transform
from sweep.diagnose.proposals import ProbeProposal
from sweep.diagnose.scoring import delta_bic
from sweep.diagnose.shapes import (
    N_BASIS,
    ShapeColumns,
    _block_diag,
    _tmul,
    groups_over,
    range_of,
    sampled,
)
from sweep.diagnose.shaping import default_variables
from sweep.diagnose.threshold import CEILING
from sweep.identification.polish import PolishSettings
from sweep.identification.vector import effect_values, with_effects

FloatArray = NDArray[np.float64]

#: the variable of the waves (a key of :data:`mmg.shapes.VARIABLES`)
TIME = "t"
#: the gate's time shapes span the clock times below this [s] (a session's first runs): a wave
#: enters the gate as the time shapes' columns times the wave in their basis, which holds a 40-s
#: wave only with knots about 10 s apart (:data:`~sweep.diagnose.shapes.TIME_KNOT_SPACING`), as
#: many as a 40-function spline keeps over a few hundred seconds. With the time shapes' knots
#: over a session's hour (95 s apart) the gate's best wave on the strong planted seiche lay at
#: 410 s (dBIC -2.6 against the null's -10) and the 40-s one was missed
GATE_CLOCK = 1e3
#: successive periods of the grid differ by this factor: a wave of period T fitted where one
#: of 1.08 T is, over the 400 s the training runs span, drifts by a quarter of a cycle only
#: after three cycles (T = 130 s and longer: within the range), and the fit by output error
#: moves the period to where the data put it
PERIOD_RATIO = 1.08
#: the longest period, in widths of the time range (a wave of twice the range is half a cycle
#: over it: a slow swing rather than a trend, which the term library's time terms hold)
LONGEST = 2.0
#: steps of the periodogram's frequency grid per cycle over the span of the clock times
PEAK_STEPS = 8
#: the periodogram's shortest period [s] (the equation residual is smoothed over 1-2 s)
SHORTEST = 30.0
#: the periodogram's peaks refitted by output error
PEAKS = 3
#: the most half-steps of the periodogram's grid that the period moves from the best peak while
#: the training J falls: on the planted turning push at the medium magnitude the peak lay at
#: 303.8 s, and a search that stopped three quarters of a step away left it at 301.5 s (planted
#: 300 s, the J still falling), a wave whose phase drifts by 0.4 rad over the hour of the clock
WALK = 6
#: ... then halvings of that step either side of the best (an eighth of the grid's step: 0.02
#: of a cycle over the span)
HALVINGS = 2
#: the library term the periodogram's equation data are built with: any (it uses their residual
#: and the base's regressors alone), one for a small kernel (:func:`sweep.diagnose.run.probes`)
PEAK_TERMS = ("E_x0",)
_TWO_PI = 2.0 * math.pi
#: a quarter of a cycle [rad]: the phase of a cosine
HALF_PI = 0.5 * math.pi
#: the components probed together: a force fixed to the basin, along x0 and y0 (a push that
#: turns over the basin has both at one period, a quarter of a cycle apart)
TOGETHER = ("xy",)
#: the components of the wave fitted by output error: the basin's
BASIN = "xy"


@dataclass
class WaveTrial:
    """The best trial of one set of components: their letters, the period [s] and dBIC."""

    components: str
    period: float
    dbic: float


@dataclass
class WaveProposal(ProbeProposal):
    """The probe's result: the wave (where proposed, the basin's fitted by output error at the
    periodogram's peaks, else the gate's best), the coefficients it starts from, the gate's
    linearised dBIC and the null's quantile it is compared with, whether it is proposed, the
    number of the gate's periods; the gate's best trial of each set of components, the
    training J at each period fitted by output error (``scan``) and the periodogram's peaks
    with the share of the equation residual each explains."""

    periods: int = 0
    trials: list[WaveTrial] = field(default_factory=list)
    scan: list[dict[str, float]] = field(default_factory=list)
    peaks: list[dict[str, float]] = field(default_factory=list)

    what = "wave in time"

    def as_dict(self) -> dict[str, Any]:
        return {
            **super().as_dict(),
            "periods": self.periods,
            "trials": [asdict(t) for t in self.trials],
            "scan": self.scan,
            "peaks": self.peaks,
        }


def periods(lo: float, hi: float, n: int) -> list[float]:
    """The periods probed [s] over a time range [lo, hi] spanned by ``n`` basis functions: a
    geometric grid (:data:`PERIOD_RATIO`) from :data:`~sweep.diagnose.naming.WAVE_KNOTS` knot
    intervals to :data:`LONGEST` widths of the range."""
    width = hi - lo
    if width <= 0.0 or n < 4:
        return []
    shortest = WAVE_KNOTS * width / (n - 3)
    count = math.floor(math.log(LONGEST * width / shortest) / math.log(PERIOD_RATIO)) + 1
    return [shortest * PERIOD_RATIO**k for k in range(count)]


def wave_basis(group: Group, period: float) -> FloatArray | None:
    """(n, 3) the constant, sin(2 pi t / T) and cos(2 pi t / T) in the spline basis of the
    time ``group`` (each wave over its largest |value| on the range, as the closed form's
    coefficient b takes it); None where the range holds too little of a cycle to tell them."""
    s = form_transform(group, Form("wave", (period, 0.0)))
    c = form_transform(group, Form("wave", (period, HALF_PI)))
    if s is None or c is None:
        return None
    return np.column_stack([s, c[:, 1]])


def phase_form(group: Group, period: float, coefficients: FloatArray) -> tuple[Group, list[float]]:
    """The closed-form group a + b sin(2 pi t / T + phi) of one component of the time ``group``
    from the coefficients (a, s, c) of :func:`wave_basis`'s columns, and its coefficients
    (a, b) as the effect takes them."""
    a, s, c = (float(v) for v in coefficients)
    gs = form_scale(_wave_group(group, period, 0.0))
    gc = form_scale(_wave_group(group, period, HALF_PI))
    s, c = s / max(gs, 1e-300), c / max(gc, 1e-300)  # of sin and cos themselves
    phi = math.atan2(c, s)  # b sin(w t + phi) = b cos(phi) sin(w t) + b sin(phi) cos(w t)
    named = _wave_group(group, period, phi)
    return named, [a, math.hypot(s, c) * form_scale(named)]


def _wave_group(group: Group, period: float, phase: float) -> Group:
    """One component's wave group over the time ``group``'s range."""
    form = Form("wave", (period, phase))
    return Group(group.components, group.variable, group.lo, group.hi, 2, form=form.text)


def _unit_sets(units: list[Group]) -> list[tuple[int, ...]]:
    """Each component alone, and the basin's components together (:data:`TOGETHER`)."""
    sets: list[tuple[int, ...]] = [(u,) for u in range(len(units))]
    for letters in TOGETHER:
        both = tuple(u for u, g in enumerate(units) if g.components in letters)
        if len(both) == len(letters):
            sets.append(both)
    return sets


def _scan(
    cols: ShapeColumns, R: FloatArray, n_eff: float, grid: list[float]
) -> tuple[FloatArray, list[tuple[tuple[int, ...], float, FloatArray]]]:
    """(dBIC (n_trials, D), per trial (units, period, W of each unit stacked)) of every set of
    components at every period for the residual vectors R (S, M, D): the base refitted beside
    the wave's columns (linearised, with the prior, on all windows), their coefficients free;
    the coefficients and the period counted."""
    fold = cols.lin.all
    part = cols.all
    Rf = fold.resid(fold.stack(R))
    J0 = np.maximum((Rf * Rf).sum(axis=0), 1e-300)
    C = _tmul(cols.lib, fold.ix, Rf[: len(fold.ix) * R.shape[1]])  # (T, D)
    units = [u.group for u in cols.units]
    out: list[FloatArray] = []
    where: list[tuple[tuple[int, ...], float, FloatArray]] = []
    for period in grid:
        Ws = [wave_basis(g, period) for g in units]
        for members in _unit_sets(units):
            if any(Ws[u] is None for u in members):
                continue
            idx = np.concatenate([cols.units[u].columns for u in members]).astype(int)
            Z = _block_diag([Ws[u] for u in members])  # type: ignore[misc]
            H = Z.T @ part.LL[np.ix_(idx, idx)] @ Z
            H[np.diag_indices_from(H)] += 1e-12 * max(float(np.trace(H)), 1e-300) / len(H)
            cz = Z.T @ C[idx]  # (k, D)
            gain = np.einsum("kd,kd->d", cz, np.linalg.solve(H, cz))
            ratio = np.clip((J0 - gain) / J0, 1e-12, None)
            out.append(n_eff * np.log(ratio) + (Z.shape[1] + 1) * math.log(n_eff))
            where.append((members, period, np.linalg.solve(H, -cz[:, 0])))
    if not out:
        return np.zeros((0, R.shape[-1])), []
    return np.stack(out), where


def _wave_effect(
    units: list[Group], members: tuple[int, ...], period: float, coefficients: FloatArray
) -> tuple[Effect, list[float]]:
    """The shape effect of the waves of the components ``members`` (of ``units``) at
    ``period`` from their coefficients (a, s, c) each (:func:`wave_basis`), and its start."""
    named: list[Group] = []
    start: list[float] = []
    for j, u in enumerate(members):
        g, values = phase_form(units[u], period, coefficients[3 * j : 3 * j + 3])
        named.append(g)
        start += values
    return shape_effect(named), start


def period_peaks(
    params: Parameters, windows: Sequence[Recording], count: int = PEAKS
) -> list[tuple[float, float]]:
    """The ``count`` periods [s] of a force fixed to the basin that explain most of the
    equation-level residual (:func:`~sweep.diagnose.discover.equation_data`: the recorded
    accelerations less the ``params`` model's, the base's 57 regressors projected out), with
    the share each explains: for each frequency of an even grid (:data:`PEAK_STEPS` steps per
    cycle over the span of the windows' clock times, from one cycle in :data:`LONGEST` spans
    to :data:`SHORTEST` s), a force (F_x0, F_y0) = a cos(w t) + b sin(w t) + c, on the ship's
    axes X = F_x0 cos psi + F_y0 sin psi, Y = -F_x0 sin psi + F_y0 cos psi (the surge and
    sway accelerations alike), fitted by least squares; peaks at least two steps apart, the
    largest share first.

    A periodogram of every sample of every window: its resolution is one cycle over the whole
    span of the clock (a 300-s wave over 3,300 s to 2.5 s), which no trajectory column gives:
    on a strong planted push turning over the basin once in 300 s the peak is at 302 s, on the
    medium one at 304 s (the trajectories' linearised dBIC was lowest at 396-407 s)."""
    data = equation_data(params, windows, DiscoverySettings(terms=PEAK_TERMS))
    t, psi, sc = data.t, data.psi, data.scale
    M = t.size
    span = float(t.max() - t.min()) if M else 0.0
    if span <= 0.0:
        return []
    Q, _ = np.linalg.qr(data.B)
    y = data.y - Q @ (Q.T @ data.y)
    yy = max(float(y @ y), 1e-300)
    step = 1.0 / (PEAK_STEPS * span)
    grid = np.arange(1.0 / (LONGEST * span), 1.0 / SHORTEST, step)
    c, s = np.cos(psi), np.sin(psi)
    zero = np.zeros(M)
    share = np.zeros(grid.size)
    for i, f in enumerate(grid):
        cols = []
        for g in (np.cos(_TWO_PI * f * t), np.sin(_TWO_PI * f * t), np.ones(M)):
            cols.append(np.concatenate([c * g * sc[0], -s * g * sc[1], zero]))  # F_x0
            cols.append(np.concatenate([s * g * sc[0], c * g * sc[1], zero]))  # F_y0
        A = np.stack(cols, axis=1)
        A = A - Q @ (Q.T @ A)
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        r = y - A @ coef
        share[i] = 1.0 - float(r @ r) / yy
    peaks: list[tuple[float, float]] = []
    for i in np.argsort(-share):
        if len(peaks) == count:
            break
        if all(abs(grid[i] - 1.0 / p) > 2.5 * step for p, _ in peaks):
            peaks.append((float(1.0 / grid[i]), float(share[i])))
    return peaks


def refined_frequency(
    J: Callable[[float], float], f: float, grid: float, walk: int = WALK, halvings: int = HALVINGS
) -> float:
    """The frequency of the lowest ``J`` near ``f`` [1/s]: from half the periodogram's ``grid``
    step, one step at a time towards the lower side while ``J`` falls (at most ``walk``
    steps: a peak of the equation residual can lie a few steps from the output error's
    minimum), then ``halvings`` times a step half as long either side of the best."""
    step = 0.5 * grid
    below, above = J(f - step), J(f + step)
    if min(below, above) < J(f):
        way = -step if below < above else step
        for _ in range(walk):
            if J(f + way) >= J(f):
                break
            f += way
    for _ in range(halvings):
        step /= 2.0
        f = min((f - step, f, f + step), key=J)
    return f


def _by_output_error(
    ctx: Context, base: Fit, units: list[Group], peaks: list[tuple[float, float]], span: float
) -> tuple[Effect, list[float], list[dict[str, float]]] | None:
    """The waves of the basin's components ``units`` (x and y, each over the clock's whole
    range) at the period of the lowest training J by output error: at each of the
    periodogram's ``peaks`` (:func:`period_peaks`), then where :func:`refined_frequency`
    moves the best (in steps of the grid's, one cycle in :data:`PEAK_STEPS` ``span``), the
    base and each component's sine and cosine fitted from none (a short joint fit, as a closed
    form's numbers are fitted: the phase, linear in them, free); its effect (one wave of its
    phase per component), start and the J of each period tried; None where at no peak the
    waves lower the training J by more than their parameters' BIC allows (nothing to refine,
    no candidate: on the real Train-TZR, 28 windows, the fits at the three peaks left the
    training J at the base's 1524). A wave's period must be right to a few per cent of a
    cycle over the span: on the strong planted turning push (300 s) J was 0.709
    at 300 s, 1.08 at 310 s and 1.22 at 316 s (the planted form's 0.682, the base's 1.55)."""
    settings = replace(
        candidate_settings(ctx),
        budget=0,
        effect_only_budget=0,
        polish=ctx.lm(CORNER_ITERATIONS, PolishSettings.rtol),
    )
    done: dict[float, tuple[float, FloatArray]] = {}

    def fitted(f: float) -> float:
        if f <= 0.0:
            return math.inf
        if f not in done:
            period = 1.0 / f
            groups = [_wave_group(u, period, ph) for u in units for ph in (0.0, HALF_PI)]
            effect = shape_effect(groups)
            p0 = with_effects(base.params, (effect,), [0.0] * len(effect.params))
            fit = ctx.refit(ctx.windows, p0, (effect,), settings, f"period of {effect.name}")
            v = np.asarray(effect_values(fit.params, (effect,))).reshape(len(units), 4)
            # (the cosine's level is the sine's: one of the two is redundant)
            done[f] = (fit.f, np.column_stack([v[:, 0] + v[:, 2], v[:, 1], v[:, 3]]))
        return done[f][0]

    best = min((1.0 / p for p, _ in peaks), key=fitted)
    # (a wave of each component's level, sine and cosine, and the period)
    if delta_bic(done[best][0], base.f, 3 * len(units) + 1, ctx.n_eff) >= 0.0:
        ctx.log(
            "waves in time by output error: at none of the periodogram's peaks do the waves "
            f"lower the training J by more than their parameters' BIC allows (the best "
            f"{done[best][0]:.4g} at {1.0 / best:.1f} s, the base alone {base.f:.4g}): not "
            "proposed"
        )
        return None
    best = refined_frequency(fitted, best, 1.0 / (PEAK_STEPS * span))
    J, coefficients = done[best]
    effect, start = _wave_effect(units, tuple(range(len(units))), 1.0 / best, coefficients.ravel())
    # the coefficients, each component's phase and the period, as fitted numbers
    ctx.dof[effect.name] = float(len(effect.params) + len(units) + 1)
    record = [{"period": 1.0 / f, "J": J_f} for f, (J_f, _) in sorted(done.items())]
    ctx.log(
        f"waves in time by output error: {effect.name}, training J {J:.4g} (of {len(done)} "
        "periods: "
        + ", ".join(f"{r['period']:.1f} s {r['J']:.4g}" for r in record)
        + f"; the base alone {base.f:.4g})"
    )
    return effect, start, record


def gate_groups(windows: Sequence[Recording], params: Parameters) -> list[Group]:
    """The time shapes whose columns carry the gate's waves: on the ship's axes and fixed to
    the basin, their knots over the 0.5-99.5 % range of the clock times below
    :data:`GATE_CLOCK` (none where no window was recorded there, or the clock does not vary)."""
    clock = sampled(windows, params, (TIME,))[TIME]
    r = range_of(clock[clock < GATE_CLOCK])
    return [] if r is None else groups_over({TIME: r}, (TIME,), (), (), (), N_BASIS)


def propose_waves(ctx: Context, base: Fit, cal: Calibration) -> WaveProposal | None:
    """The best wave in time at the ``base`` model, proposed when its dBIC passes the null's
    quantile (None with shapes off, time not among the shapes' variables, or the base within
    the noise floor); logged."""
    s = ctx.settings
    if not s.shapes or TIME not in default_variables(ctx):
        return None
    if not cal.misfit.significant:
        ctx.log("waves in time: not probed (the base is within the noise floor)")
        return None
    t0 = time.perf_counter()
    params = base.params
    groups = gate_groups(ctx.windows, params)
    if not groups:
        return None
    cols = ShapeColumns(cal.lin, groups)
    grid = periods(groups[0].lo, groups[0].hi, groups[0].n)
    r = cal.lin.residuals(ctx.windows)
    dbic, where = _scan(cols, r[..., None], ctx.n_eff, grid)
    if not where:
        return None
    rng = np.random.default_rng(s.seed + 31)
    copies = null_sets(params, ctx.windows, cal.noise, rng, s.shape_null_draws)
    R = np.stack([cal.lin.residuals(c) for c in copies], axis=-1)
    null = _scan(cols, R, ctx.n_eff, grid)[0].min(axis=0)
    threshold = min(float(np.quantile(null, s.alpha)), CEILING)
    units = [u.group for u in cols.units]
    trials: dict[str, WaveTrial] = {}
    for k, (members, period, _) in enumerate(where):
        letters = "".join(units[u].components for u in members)
        if letters not in trials or dbic[k, 0] < trials[letters].dbic:
            trials[letters] = WaveTrial(letters, period, float(dbic[k, 0]))
    i = int(np.argmin(dbic[:, 0]))
    members, period, coefficients = where[i]
    effect, start = _wave_effect(units, members, period, coefficients)
    proposed = float(dbic[i, 0]) <= threshold
    out = WaveProposal(
        effect,
        start,
        float(dbic[i, 0]),
        threshold,
        proposed,
        0.0,
        null=[float(v) for v in null],
        periods=len(grid),
        trials=sorted(trials.values(), key=lambda t: t.dbic),
    )
    ctx.log(
        f"waves in time: {effect.name} (of {len(where)} trials over {len(grid)} periods), "
        f"linearised dBIC {out.dbic:.1f} against the null's {s.alpha:.0%} quantile "
        f"{threshold:.1f} -> {'proposed' if proposed else 'not proposed'}"
    )
    if proposed:
        clock = np.concatenate([np.asarray(w.t, dtype=np.float64) for w in ctx.windows])
        lo, hi = float(clock.min()), float(clock.max())
        peaks = period_peaks(params, ctx.windows)
        out.peaks = [{"period": p, "share": v} for p, v in peaks]
        ctx.log(
            "waves in time, the periodogram's peaks of a force fixed to the basin: "
            + ", ".join(f"{p:.1f} s ({100 * v:.2f} % of the equation residual)" for p, v in peaks)
        )
        basin = [_wave_group(Group(c, TIME, lo, hi, 4), 1.0, 0.0) for c in BASIN]
        wave = _by_output_error(ctx, base, basin, peaks, hi - lo) if peaks else None
        if wave is not None:
            out.effect, out.start, out.scan = wave
            ctx.starts.setdefault(out.proposal.name, out.start)
        else:
            out.proposed = False
    out.seconds = time.perf_counter() - t0
    return out


__all__ = ["LONGEST", "PERIOD_RATIO", "WaveProposal", "periods", "propose_waves", "wave_basis"]
