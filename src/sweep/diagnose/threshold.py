"""The acceptance threshold of candidates, calibrated on the data at hand.

A candidate is accepted when its dBIC over the two folds is below a threshold: the ``alpha``
quantile of the null distribution of the *best* candidate's dBIC, from a parametric bootstrap
(noise-only copies of the training windows simulated by the base model) with the fold fits
linearised (:class:`sweep.diagnose.linearised.Linearised`), never above :data:`CEILING`.

It must also carry over: its fits on one fold must take more off the control's J on the other
fold's whole runs than the best candidate's fits do on the same noise-only copies in all but a
share ``alpha`` of them (the held-out gain's null, :attr:`AcceptanceNull.heldout_threshold`,
never below zero); it must make more held-out runs better than worse; and it must make no
held-out run worse by more than the best candidate's fits make their worst held-out run on the
same copies in all but a share ``alpha`` of them (:attr:`AcceptanceNull.worst_run_limit`; the
best catalog candidate's, as the library's greedy selection on noise is not what a proposal
fits). A catalog effect's worst run is compared relative to the control's J of that run, as the
null is, where the base misses a force (the misfit beyond the noise floor; within it, in units
of the run's noise J like a generated candidate's); a candidate generated from the data
(library terms, learned shapes and their closed forms) was chosen on residuals of all training
windows, the held-out ones included, so its held-out gains are biased in its favour: its worst
run's loss is compared in units of that run's noise J, the null's scale before any model error
inflates the control's J. A run worse by at
most :data:`NEGLIGIBLE` of the control's J of it is not held against any candidate: that is the
harm figure's own tolerance, and a quiet run's noise J can be a small share of its J when the
control misses the effect there.
The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sweep.diagnose.discover import null_sets
from sweep.diagnose.floor import NoiseModel
from sweep.diagnose.linearised import HeldOut, Linearised
from sweep.diagnose.threads import column_parts, map_threads

FloatArray = NDArray[np.float64]

#: the threshold is never above this dBIC (Kass and Raftery: a BIC difference beyond 10 is very
#: strong evidence); it matters only when the null's quantile is closer to zero
CEILING = -10.0

#: a held-out run worse by at most this share of the control's J of it is not a loss that
#: refuses a candidate (the benchmarks count a finding as harmful from 5 % on)
NEGLIGIBLE = 0.05


def more_better(run_changes: dict[str, float]) -> bool:
    """Whether more runs got better than worse (``run_changes``: each run's relative change of
    J, negative: better)."""
    better = sum(v < 0.0 for v in run_changes.values())
    worse = sum(v > 0.0 for v in run_changes.values())
    return better > worse


@dataclass
class AcceptanceNull:
    """The null distribution of the best candidate's dBIC and the threshold it gives."""

    alpha: float
    draws: int
    threshold: float  # the threshold used (quantile, capped at CEILING)
    quantile: float  # the alpha quantile of the best dBIC over the draws
    best: list[float]  # best dBIC of each draw
    per_candidate: dict[str, dict[str, float]] = field(default_factory=dict)  # median, quantile
    seconds: float = 0.0
    #: J of the base refitted on all windows over J before refitting, on the noise-only copies:
    #: what fitting the 57 parameters (with the prior) takes out of pure noise
    refit_factor: float = 1.0
    #: held-out gain of each draw's best candidate (by dBIC) relative to the control's held-out
    #: J (noise alone: the noise's J), and its 1 - alpha quantile
    heldout_best: list[float] = field(default_factory=list)
    heldout_quantile: float = 0.0
    #: the largest loss of one held-out run by each draw's best catalog candidate relative to
    #: the control's held-out J of that run (noise alone: that run's noise J), and its 1 - alpha
    #: quantile
    worst_run: list[float] = field(default_factory=list)
    worst_run_quantile: float = 0.0
    #: the noise's J of a fitted model on all training windows and on each run
    #: (:class:`sweep.diagnose.floor.MisfitTest`): the scale of the two thresholds
    noise_J: float = 0.0
    run_noise: dict[str, float] = field(default_factory=dict)

    @property
    def worst_run_limit(self) -> float:
        """The loss of one held-out run a candidate may not exceed, as a share of that run's
        noise J: the null's quantile, at least 0."""
        return max(self.worst_run_quantile, 0.0)

    @property
    def run_change_limit(self) -> float:
        """The relative change of one run's J a catalog effect (or a candidate judged on
        runs it was not chosen on) may not exceed: :attr:`worst_run_limit`, at least
        :data:`NEGLIGIBLE`."""
        return max(self.worst_run_limit, NEGLIGIBLE)

    @property
    def heldout_threshold(self) -> float:
        """The held-out gain [J] a candidate must exceed: the null's quantile times the noise's
        J on the training windows, at least 0."""
        return max(self.heldout_quantile, 0.0) * self.noise_J

    def run_excess(
        self, run_losses: dict[str, float], run_changes: dict[str, float] | None = None
    ) -> float:
        """The largest loss of a held-out run as a share of that run's noise J (0 without
        runs; infinite for a loss on a run whose noise J is unknown). A run whose relative
        change (``run_changes``) is at most :data:`NEGLIGIBLE` counts as no loss."""
        out = 0.0 if not run_losses else -math.inf
        for run, loss in run_losses.items():
            if run_changes is not None and 0.0 < run_changes.get(run, math.inf) <= NEGLIGIBLE:
                loss = 0.0
            n = self.run_noise.get(run, 0.0)
            out = max(out, loss / n if n > 0 else (math.inf if loss > 0 else 0.0))
        return out

    def carries_over(
        self,
        heldout_gain: float,
        run_losses: dict[str, float],
        run_changes: dict[str, float],
        generated: bool,
    ) -> bool:
        """Whether a candidate's fits carry over to the held-out runs: a held-out gain above
        :attr:`heldout_threshold`, more runs better than worse (``run_changes``), and no run
        worse than :attr:`worst_run_limit` allows: relative to the control's J of the run for a
        catalog effect, in units of the run's noise J (:meth:`run_excess` of ``run_losses``)
        for a ``generated`` one, and for any candidate the caller judges alike
        (:func:`sweep.diagnose.scoring.judged_as_generated`: a catalog effect where the base's
        misfit is within the noise floor)."""
        if not self.heldout_ok(heldout_gain, run_changes):
            return False
        if generated:
            return self.run_excess(run_losses, run_changes) <= self.worst_run_limit
        return max(run_changes.values(), default=0.0) <= self.run_change_limit

    def heldout_ok(self, heldout_gain: float, run_changes: dict[str, float]) -> bool:
        """The first two conditions of :meth:`carries_over`: a held-out gain above
        :attr:`heldout_threshold` and more held-out runs better than worse."""
        return heldout_gain > self.heldout_threshold and more_better(run_changes)

    def transfers(
        self, transfer_gain: float, run_changes: dict[str, float], heldout_gain: float
    ) -> bool:
        """Whether a generated candidate passes the transfer check
        (:mod:`sweep.diagnose.transfer`): the runs' summed J falls, more runs get better than
        worse, no run gets worse, relative to the control's J of it, than
        :attr:`run_change_limit` allows a catalog effect's held-out run, and the gain on runs
        the effect was not fitted on beats :attr:`heldout_threshold` in one of the two checks
        (``heldout_gain`` with the base refitted alongside on the other half, ``transfer_gain``
        with the base alone refitted on the runs it is judged on)."""
        return (
            transfer_gain > 0.0
            and max(transfer_gain, heldout_gain) > self.heldout_threshold
            and more_better(run_changes)
            and max(run_changes.values(), default=0.0) <= self.run_change_limit
        )

    def as_dict(self) -> dict[str, Any]:
        """The null as ``report.json`` shows it (``acceptance``), with a summary of ``best``."""
        b = np.asarray(self.best)
        return {
            "method": "parametric bootstrap, linearised fits (sweep.diagnose.threshold)",
            "alpha": self.alpha,
            "draws": self.draws,
            "threshold": self.threshold,
            "quantile": self.quantile,
            "ceiling": CEILING,
            "best_dbic": {
                "min": float(b.min()),
                "q05": float(np.quantile(b, 0.05)),
                "median": float(np.median(b)),
                "q95": float(np.quantile(b, 0.95)),
                "max": float(b.max()),
            },
            "per_candidate": self.per_candidate,
            "seconds": self.seconds,
            "heldout": {
                "threshold": self.heldout_threshold,
                "quantile": self.heldout_quantile,
                "median": float(np.median(self.heldout_best)) if self.heldout_best else 0.0,
                "q": 1.0 - self.alpha,
                "worst_run_limit": self.worst_run_limit,
                "noise_J": self.noise_J,
                "worst_run_median": float(np.median(self.worst_run)) if self.worst_run else 0.0,
            },
        }


def heldout_parts(
    lin: Linearised, R: FloatArray, n_eff: float, threads: int | None = None
) -> HeldOut:
    """:meth:`Linearised.heldout` of residual vectors R (S, M, D), the columns in
    :data:`PARTS` parts, up to ``threads`` (default: the cores) side by side: the same figures
    on any machine; to rounding those of all columns at once."""
    done = map_threads(
        lambda ix: lin.heldout(R[..., ix], n_eff), column_parts(R.shape[-1]), threads
    )
    if len(done) == 1:
        return done[0]
    return HeldOut(
        dbic={k: np.concatenate([h.dbic[k] for h in done]) for k in done[0].dbic},
        gain=np.concatenate([h.gain for h in done]),
        worst_run=np.concatenate([h.worst_run for h in done]),
    )


def acceptance_null(
    lin: Linearised,
    noise: NoiseModel,
    rng: np.random.Generator,
    *,
    n_eff: float,
    draws: int = 200,
    alpha: float = 0.05,
) -> AcceptanceNull:
    """The null of the best dBIC for the fold fits of the diagnosis, linearised in ``lin``
    (``draws`` noise-only copies of its windows; the threshold is its ``alpha`` quantile)."""
    import time

    t0 = time.perf_counter()
    params, windows = lin.params, lin.windows
    # null residual vectors of the base model on noisy copies of the windows
    # (one after another: the residual rows are a Numba-parallel function, see threads.py)
    cols = [lin.residuals(recs) for recs in null_sets(params, windows, noise, rng, draws)]
    R = np.stack(cols, axis=-1)
    ho = heldout_parts(lin, R, n_eff)
    per, held = ho.dbic, ho.gain
    best = np.min(np.stack(list(per.values())), axis=0)
    q = float(np.quantile(best, alpha))
    return AcceptanceNull(
        alpha=alpha,
        draws=draws,
        threshold=min(q, CEILING),
        quantile=q,
        best=[float(b) for b in best],
        per_candidate={
            name: {"median": float(np.median(v)), "quantile": float(np.quantile(v, alpha))}
            for name, v in per.items()
        },
        seconds=time.perf_counter() - t0,
        refit_factor=lin.refit_factor(R),
        heldout_best=[float(h) for h in held],
        heldout_quantile=float(np.quantile(held, 1.0 - alpha)),
        worst_run=[float(w) for w in ho.worst_run],
        worst_run_quantile=float(np.quantile(ho.worst_run, 1.0 - alpha)),
    )
