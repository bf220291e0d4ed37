"""``actuator_lag``: the acting rudder angle and propeller speed lag the logged ones.

The logged delta and n_p are commands or readings upstream of the steering gear and the motor;
the acting values follow them after a dead time tau and with a first-order lag of time
constant T ("first order plus dead time", the usual model of an actuator loop):

    d delta / dt = (delta_log(t - tau_delta) - delta) / T_delta,
    d n_p / dt = (n_log(t - tau_n) - n_p) / T_n

the lag integrated exactly over each 0.1-s step with the (delayed) logged value held, the dead
time interpolated between logged samples. T = tau = 0 is no lag (the paper). A dead time alone
(a logging clock offset, a steering gear that starts late) is T = 0, tau > 0.
Regime: fast changes of the controls (zigzag rudder reversals, propeller reversals in berthing).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from mmg._jit import subfunction
from mmg.effect import Effect, EffectParam


class ActuatorLagParams(NamedTuple):
    """The parameters of ``actuator_lag`` in kernel order (unit of each after its field)."""

    T_delta: float  # rudder time constant [s]
    T_n: float  # propeller time constant [s]
    tau_delta: float  # rudder dead time [s]
    tau_n: float  # propeller dead time [s]


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
    """Acting (delta [rad], n_p [rev/s]) of this step from the (delayed) logged ones."""
    delta = delta_prev + lag_gain(e.T_delta, dt) * (delta_log - delta_prev)
    n_p = n_prev + lag_gain(e.T_n, dt) * (n_log - n_prev)
    return delta, n_p


@subfunction
def actuator_dead_times(e: ActuatorLagParams) -> tuple[float, float]:
    """(tau_delta, tau_n) [s]."""
    return e.tau_delta, e.tau_n


ACTUATOR_LAG = Effect(
    name="actuator_lag",
    description=(
        "the acting rudder angle and propeller speed lag the logged values "
        "(first-order lag and dead time)"
    ),
    regime="fast changes of the controls (rudder reversals, propeller reversals)",
    params=(
        EffectParam("T_delta", "s", 0.0, 0.0, 5.0, "rudder time constant"),
        EffectParam("T_n", "s", 0.0, 0.0, 5.0, "propeller time constant"),
        EffectParam("tau_delta", "s", 0.0, 0.0, 3.0, "rudder dead time"),
        EffectParam("tau_n", "s", 0.0, 0.0, 3.0, "propeller dead time"),
    ),
    param_type=ActuatorLagParams,
    inputs=actuator_lag_inputs,
    delay=actuator_dead_times,
)
