"""What noise alone would give at a base model: the noise of the recordings and the floor of J
it gives, the fold fits linearised with the acceptance null of the best candidate's dBIC, and
the misfit test (is the base above the floor of a *fitted* model?).

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmg import Parameters
from sweep.diagnose.context import Context
from sweep.diagnose.floor import (
    Floor,
    MisfitTest,
    NoiseModel,
    calibrated_noise,
    misfit_test,
    noise_floor,
)
from sweep.diagnose.linearised import Linearised
from sweep.diagnose.threshold import AcceptanceNull, acceptance_null


@dataclass(frozen=True)
class Calibration:
    """The noise, the linearised fold fits, the acceptance null and the misfit at one base."""

    noise: NoiseModel
    lin: Linearised
    null: AcceptanceNull
    misfit: MisfitTest


def noise_and_floor(ctx: Context, params: Parameters) -> tuple[NoiseModel, Floor]:
    """The noise of the training windows around ``params`` and the floor of J it gives."""
    rng = np.random.default_rng(ctx.settings.seed + 7)
    noise = calibrated_noise(ctx.windows, params, rng, ctx.settings.exact_starts)
    if not noise.first.noisy:
        copies = (
            "the noise-only copies begin exactly too"
            if noise.first.copies_exact
            else "the noise-only copies begin noisy all the same (--exact-starts: exactly)"
        )
        ctx.log(
            "noise: the windows begin at exact states, not recorded ones (a simulation's start; "
            f"log-odds {noise.first.log_odds:.0f} over {noise.first.items} windows x channels): "
            + copies
        )
    return noise, noise_floor(params, ctx.windows, noise, rng, ctx.settings.floor_draws)


def linearise(ctx: Context, params: Parameters) -> Linearised:
    """The fold fits of every candidate (and, with discovery, of the library) linearised at
    ``params``."""
    s = ctx.settings
    position = {id(w): i for i, w in enumerate(ctx.windows)}
    return Linearised(
        params,
        ctx.windows,
        ([position[id(w)] for w in ctx.fit_w], [position[id(w)] for w in ctx.held_w]),
        ctx.candidate_effects(),
        objective=s.objective,
        prior_weight=s.prior_weight,
        library_terms=s.discover_terms if s.discover else 0,
    )


def null_of(ctx: Context, lin: Linearised, noise: NoiseModel) -> AcceptanceNull:
    """The null of the best candidate's dBIC on these windows (the acceptance threshold)."""
    s = ctx.settings
    return acceptance_null(
        lin,
        noise,
        np.random.default_rng(s.seed + 11),
        n_eff=ctx.n_eff,
        draws=s.threshold_draws,
        alpha=s.alpha,
    )


def misfit_of(ctx: Context, floor: Floor, null: AcceptanceNull) -> MisfitTest:
    """The base's misfit against the floor of a fitted model (its 57 parameters also fit part
    of the noise: the null's refit factor), logged."""
    s = ctx.settings
    misfit = misfit_test(floor, s.objective, margin=s.floor_margin, refit_factor=null.refit_factor)
    ctx.log(
        f"misfit: {s.objective} {misfit.J:.3g} on the training windows, {misfit.ratio:.2f} x "
        f"the noise floor of a fitted model, {misfit.floor:.3g} (the refit keeps "
        f"{100 * null.refit_factor:.0f} % of the noise's J; z = {misfit.z:.1f}): "
        + ("significant" if misfit.significant else "within the floor")
    )
    return misfit


def calibrate(ctx: Context, params: Parameters) -> Calibration:
    """The floor, the acceptance null and the misfit test at the base ``params``."""
    noise, floor = noise_and_floor(ctx, params)
    lin = linearise(ctx, params)
    null = null_of(ctx, lin, noise)
    misfit = misfit_of(ctx, floor, null)
    # the scale of the carrying-over thresholds: the noise's J of a fitted model
    null.noise_J = misfit.floor
    null.run_noise = {str(r["run"]): float(r["floor"]) for r in misfit.per_run}
    return Calibration(noise, lin, null, misfit)
