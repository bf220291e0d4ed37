"""Candidates beyond the catalog: terms of the library proposed from the base's equation-level
residuals (:mod:`sweep.diagnose.discover`) and from its trajectory residuals
(:meth:`sweep.diagnose.linearised.Linearised.select`), each only beyond its own null.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mmg import Effect, Parameters
from mmg.discovered import discovered_effect, with_bounds
from mmg.precompile import precompile, tasks
from sweep.diagnose.calibration import Calibration
from sweep.diagnose.context import Context
from sweep.diagnose.discover import DiscoverySettings, Proposal, discover
from sweep.diagnose.linearised import TrajectorySelection
from sweep.diagnose.threshold import CEILING


@dataclass(frozen=True)
class Proposals:
    """The equation-level proposal, the trajectory selection (None with discovery off) and the
    generated effects they add to the candidates, in order, without repeats."""

    proposal: Proposal | None
    trajectory: TrajectorySelection | None
    effects: tuple[Effect, ...]


@dataclass
class ProbeProposal:
    """What a probe beside the learned shapes proposes (the memories' closed forms,
    :mod:`sweep.diagnose.memory`; the waves in time, :mod:`sweep.diagnose.waves`): its best
    effect (None where nothing was probed) and the coefficients it starts from, its linearised
    dBIC, the null's quantile it is compared with, whether it is proposed, the seconds it took
    and the null's draws."""

    effect: Effect | None
    start: list[float]
    dbic: float
    threshold: float
    proposed: bool
    seconds: float
    null: list[float] = field(default_factory=list)

    #: what the probe looks for, in "no ... was probed"
    what = "effect"

    @property
    def name(self) -> str:
        return self.effect.name if self.effect is not None else ""

    @property
    def proposal(self) -> Effect:
        """The proposed effect (ValueError when there is none)."""
        if self.effect is None:
            raise ValueError(f"no {self.what} was probed")
        return self.effect

    def as_dict(self) -> dict[str, Any]:
        return {
            "effect": self.name or None,
            "start": self.start,
            "dbic": self.dbic,
            "threshold": self.threshold,
            "proposed": self.proposed,
            "seconds": self.seconds,
            "null": self.null,
        }


def _add(effects: list[Effect], eff: Effect) -> None:
    if all(e.name != eff.name for e in effects):
        effects.append(eff)


def equation_proposal(ctx: Context, params: Parameters, cal: Calibration) -> Proposal:
    """The library terms proposed from the equation-level residuals of the base ``params``."""
    s = ctx.settings
    return discover(
        params,
        ctx.windows,
        cal.noise,
        np.random.default_rng(s.seed + 13),
        DiscoverySettings(
            max_terms=s.discover_terms,
            null_draws=s.null_draws,
            alpha=s.alpha,
            alternatives=s.discover_alternatives,
        ),
        log=ctx.log,
    )


def trajectory_proposal(ctx: Context, cal: Calibration) -> tuple[TrajectorySelection, bool]:
    """The library terms that explain most of the base's trajectory residual (linearised), and
    whether they pass the null of the same selection (logged)."""
    s = ctx.settings
    selection = cal.lin.select(cal.lin.residuals(ctx.windows), ctx.n_eff)
    limit = min(cal.null.per_candidate["discovered"]["quantile"], CEILING)
    proposed = bool(selection.terms) and selection.dbic <= limit
    ctx.log(
        f"discovery (trajectories): {' + '.join(selection.terms) or 'no term'}, linearised "
        f"dBIC {selection.dbic:.1f} against the null's {s.alpha:.0%} quantile {limit:.1f} "
        f"-> {'proposed' if proposed else 'not proposed'}"
    )
    return selection, proposed


def propose(ctx: Context, params: Parameters, cal: Calibration) -> Proposals:
    """Both proposals (with discovery on) as effects, their kernels compiled."""
    proposal: Proposal | None = None
    trajectory: TrajectorySelection | None = None
    effects: list[Effect] = []
    if ctx.settings.discover:
        proposal = equation_proposal(ctx, params, cal)
        for eff in proposal.effects():  # the proposal and its alternatives
            _add(effects, eff)
        trajectory, proposed = trajectory_proposal(ctx, cal)
        if proposed:
            half = [max(4.0 * abs(c), 1e-6) for c in trajectory.coefficients]
            _add(effects, with_bounds(discovered_effect(trajectory.terms), half, trajectory.shapes))
    precompile(tasks(ctx.with_base((e,)) for e in effects), log=ctx.log)
    return Proposals(proposal, trajectory, tuple(effects))
