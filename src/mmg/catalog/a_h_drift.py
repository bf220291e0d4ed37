"""``a_h_drift``: the rudder-hull interaction factor a_H varies with the drift angle.

The paper takes a_H constant (Eqs. (15)-(16)); its section 6 notes that a_H changes sign at drift
angles beyond about 45 deg (Yasukawa's captive tests at large drift). Here

    a_H(beta) = a_H + k_aH sin^2(beta),   beta = atan2(-v_m, u) (through the water)

which for k_aH = -2 a_H is a_H cos(2 beta): a sign change at 45 deg. The extra hull force induced
by the rudder is distributed as in Eqs. (15)-(16): dY = -dA F_N cos(delta),
dN = -dA x_H L F_N cos(delta), dA = k_aH sin^2(beta).
Regime: large drift angles (berthing, low speed, turning), with a loaded rudder.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from mmg._jit import subfunction
from mmg.effect import Effect, EffectParam
from mmg.model import rudder_inflow_at
from mmg.params import Ship, Theta
from mmg.rudder import lift_gradient
from mmg.trig import sincos


class AHDriftParams(NamedTuple):
    """The parameters of ``a_h_drift`` in kernel order (unit of each after its field)."""

    k_aH: float  # change of a_H at 90 deg drift [-]


@subfunction
def a_h_drift_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: AHDriftParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Change (0, dY [N], dN [N m]) of the rudder-induced hull force from a_H(beta)."""
    U2 = u * u + v_m * v_m
    if U2 <= 0.0:
        return 0.0, 0.0, 0.0
    sin2_beta = v_m * v_m / U2  # sin^2(beta), beta = atan2(-v_m, u)
    u_R, v_R = rudder_inflow_at(u, v_m, r, n_p, th, sh)  # as in hydrodynamic_forces
    sin_d, cos_d = sincos(delta)
    f_alpha = lift_gradient(sh)  # Eq. (18)
    U_R = math.sqrt(u_R * u_R + v_R * v_R)  # Eq. (19)
    F_N = 0.5 * sh.rho * sh.A_R * f_alpha * U_R * (u_R * sin_d - v_R * cos_d)  # Eqs. (17), (20)
    dA = e.k_aH * sin2_beta
    dY = -dA * F_N * cos_d  # Eq. (15), the a_H part
    dN = -dA * th.x_H * sh.L_pp * F_N * cos_d  # Eq. (16), the a_H part
    return 0.0, dY, dN


A_H_DRIFT = Effect(
    name="a_h_drift",
    description="the rudder-hull interaction a_H changes with the drift angle",
    regime="large drift angle |beta| (>= 20-45 deg) with the rudder loaded",
    params=(EffectParam("k_aH", "-", 0.0, -2.0, 2.0, "change of a_H at 90 deg drift"),),
    param_type=AHDriftParams,
    force=a_h_drift_force,
)
