"""``heading_bias``: the measured heading is off by a constant.

A compass (or GNSS-heading antenna baseline) mounted or calibrated off by b_psi logs
psi_log = psi + b_psi. When the logged body velocities are the GNSS velocity resolved along the
logged heading, they are rotated as well (by b_v = b_psi); b_v is a separate parameter because a
log may take its velocities from another sensor (b_v = 0). The simulation starts from the true
state implied by the log and is compared with the logged quantities.
Regime: everywhere; visible as a steady drift angle on straight runs and through the wind angle.
"""

from __future__ import annotations

from typing import NamedTuple

from mmg._jit import subfunction
from mmg.effect import Effect, EffectParam


class HeadingBiasParams(NamedTuple):
    """The parameters of ``heading_bias`` in kernel order (unit of each after its field)."""

    b_psi: float  # logged minus true heading [rad]
    b_v: float  # rotation of the logged body velocities [rad]


@subfunction
def heading_bias_observe(e: HeadingBiasParams) -> tuple[float, float]:
    """(b_psi, b_v) [rad]."""
    return e.b_psi, e.b_v


HEADING_BIAS = Effect(
    name="heading_bias",
    description="the logged heading is off by a constant (and with it the logged velocities)",
    regime="all motions; a steady apparent drift angle on straight runs",
    params=(
        EffectParam("b_psi", "rad", 0.0, -0.1, 0.1, "heading offset"),
        EffectParam("b_v", "rad", 0.0, -0.1, 0.1, "rotation of the logged velocities"),
    ),
    param_type=HeadingBiasParams,
    observe=heading_bias_observe,
)
