"""Where the base model misses, on all training windows: the regimes its trajectory residual
concentrates in, the biases of its equation residuals, and the worst windows."""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from mmg import Parameters
from sweep.diagnose.context import Context
from sweep.diagnose.locate import (
    BiasScore,
    RegimeScore,
    equation_residuals,
    locate,
    locate_bias,
    rank_windows,
    residual_frame,
)


@dataclass(frozen=True)
class Location:
    """The located mismatch: regimes by eta^2, equation biases, the worst windows (8 rows)."""

    regimes: list[RegimeScore]
    biases: list[BiasScore]
    windows: pd.DataFrame


def locate_misfit(ctx: Context, params: Parameters) -> Location:
    """Residuals of the base ``params`` per regime (training windows) and equation biases
    (training recordings), logged."""
    frame = residual_frame(params, ctx.windows)
    regimes = locate(frame)
    biases = locate_bias(equation_residuals(params, ctx.train))
    worst = rank_windows(frame, "velocity", top=8)
    ctx.log(
        "mismatch concentrates in "
        + ", ".join(
            f"{r.variable} {r.worst_bin} ({r.group}, eta2 {r.eta2:.2f})" for r in regimes[:3]
        )
    )
    return Location(regimes, biases, worst)
