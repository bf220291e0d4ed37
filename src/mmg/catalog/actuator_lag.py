"""``actuator_lag``: the acting rudder angle and propeller speed lag the logged ones.

The logged delta and n_p are commands or readings upstream of the steering gear and the motor;
the acting values follow with first-order lags of time constants T_delta and T_n:

    d delta / dt = (delta_log - delta) / T_delta,   d n_p / dt = (n_log - n_p) / T_n

integrated exactly over each 0.1-s step with the logged value held. T = 0 is no lag (the paper).
Regime: fast control changes (zigzag rudder reversals, propeller reversals in berthing).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from mmg._jit import subfunction
from mmg.effects import Effect, EffectParam, register


class ActuatorLagParams(NamedTuple):
    T_delta: float  # rudder time constant [s]
    T_n: float  # propeller time constant [s]


@subfunction
def lag_gain(T: float, dt: float) -> float:
    """Share of the step to the new input reached in one step of dt [s] with time constant T [s]."""
    return 1.0 if T <= 1e-6 else 1.0 - math.exp(-dt / T)


@subfunction
def actuator_lag_inputs(
    delta_log: float,
    n_log: float,
    delta_prev: float,
    n_prev: float,
    dt: float,
    e: ActuatorLagParams,
) -> tuple[float, float]:
    """Acting (delta [rad], n_p [rev/s]) of this step."""
    delta = delta_prev + lag_gain(e.T_delta, dt) * (delta_log - delta_prev)
    n_p = n_prev + lag_gain(e.T_n, dt) * (n_log - n_prev)
    return delta, n_p


ACTUATOR_LAG = register(
    Effect(
        name="actuator_lag",
        description="the acting rudder angle and propeller speed lag the logged values",
        regime="fast changes of the controls (rudder reversals, propeller reversals)",
        params=(
            EffectParam("T_delta", "s", 0.0, 0.0, 5.0, "rudder time constant"),
            EffectParam("T_n", "s", 0.0, 0.0, 5.0, "propeller time constant"),
        ),
        param_type=ActuatorLagParams,
        inputs=actuator_lag_inputs,
    )
)
