"""``rudder_offset``: the logged rudder angle is off by a constant (a zero error of the sensor).

delta_acting = delta_log + delta_0. A rudder angle sensor zeroed a degree off is common in
free-running tests; the ship then needs a steady logged rudder angle to go straight, and the
model, given the log, turns where the ship went straight.
Regime: every motion with water on the rudder, most visible on straight runs (steady yaw).
"""

from __future__ import annotations

from typing import NamedTuple

from mmg._jit import subfunction
from mmg.effect import Effect, EffectParam


class RudderOffsetParams(NamedTuple):
    """The parameters of ``rudder_offset`` in kernel order (unit of each after its field)."""

    delta_0: float  # acting minus logged rudder angle [rad]


@subfunction
def rudder_offset_inputs(
    delta_log: float,
    n_log: float,
    delta_prev: float,
    n_prev: float,
    dt: float,
    e: RudderOffsetParams,
) -> tuple[float, float]:
    """Acting (delta [rad], n_p [rev/s])."""
    return delta_log + e.delta_0, n_log


RUDDER_OFFSET = Effect(
    name="rudder_offset",
    description="the logged rudder angle has a constant zero error",
    regime="all motions with flow at the rudder; a steady yaw tendency on straight runs",
    params=(EffectParam("delta_0", "rad", 0.0, -0.1, 0.1, "acting minus logged angle"),),
    param_type=RudderOffsetParams,
    inputs=rudder_offset_inputs,
)
