"""``current``: a uniform, steady water current.

The recorded velocities are over ground (GNSS); with a current the hull, propeller and rudder feel
the velocity through the water. Regime: everywhere, most visible at low speed (berthing, coasting)
as a steady drift of the track.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from mmg._jit import subfunction
from mmg.effect import Effect, EffectParam
from mmg.trig import sincos


class CurrentParams(NamedTuple):
    """The parameters of ``current`` in kernel order (unit of each after its field)."""

    V_c: float  # current speed [m/s]
    beta_c: float  # direction the current flows TOWARDS, earth-fixed, clockwise from x0 [rad]


@subfunction
def current_velocity(x0: float, y0: float, psi: float, e: CurrentParams) -> tuple[float, float]:
    """Body-frame current (u_c, v_c) [m/s] at heading psi [rad]."""
    s, c = sincos(e.beta_c - psi)
    return e.V_c * c, e.V_c * s


CURRENT = Effect(
    name="current",
    description="a uniform water current: forces act on the velocity through the water",
    regime="all motions; dominant at low speed, as a steady drift of position",
    params=(
        EffectParam("V_c", "m/s", 0.0, 0.0, 0.1, "current speed"),
        EffectParam("beta_c", "rad", 0.0, -math.pi, math.pi, "direction it flows towards"),
    ),
    param_type=CurrentParams,
    current=current_velocity,
)
