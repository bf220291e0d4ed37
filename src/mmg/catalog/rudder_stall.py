"""``rudder_stall``: the rudder normal force saturates beyond a stall angle of attack.

The paper's rudder model (Eq. (17)) takes F_N = 0.5 rho A_R U_R^2 f_alpha sin(alpha_R) for every
effective angle of attack alpha_R, i.e. a rudder that never stalls; section 6 of the paper notes
that f_alpha is not constant in deep stall. Here, in ahead flow (u_R > 0) and beyond the stall
angle alpha_s, the growth of sin(alpha_R) is cut by the fraction k_s:

    sin_eff = sin(alpha_s) + (1 - k_s) (sin|alpha_R| - sin(alpha_s))   for |alpha_R| > alpha_s

k_s = 0: no stall (the paper); k_s = 1: the force stays at its stall value; k_s > 1: it drops.
The change of F_N is distributed to X_R, Y_R, N_R as in Eqs. (14)-(16). It scales with u_R^2
instead of U_R^2 = u_R^2 + v_R^2: identical in ahead flow along the rudder (v_R = 0), and it fades
out as the inflow turns sideways (u_R -> 0), so that the force is continuous in the state (a jump
at u_R = 0 would make trajectories through it depend on the last digit of the initial state).
Regime: large rudder angles at low rudder inflow angles, |delta| >= 20-30 deg (berthing, turning).
"""

from __future__ import annotations

from typing import NamedTuple

from mmg._jit import subfunction
from mmg.effect import Effect, EffectParam
from mmg.model import rudder_inflow_at
from mmg.params import Ship, Theta
from mmg.rudder import lift_gradient
from mmg.trig import atan2, sincos


class RudderStallParams(NamedTuple):
    """The parameters of ``rudder_stall`` in kernel order (unit of each after its field)."""

    alpha_s: float  # stall angle of attack [rad]
    k_s: float  # fraction of the growth of sin(alpha_R) lost beyond stall [-]


@subfunction
def rudder_stall_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: RudderStallParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Change (dX_R [N], dY_R [N], dN_R [N m]) of the rudder forces from stall."""
    u_R, v_R = rudder_inflow_at(u, v_m, r, n_p, th, sh)  # as in hydrodynamic_forces
    if u_R <= 0.0:
        return 0.0, 0.0, 0.0
    alpha_R = delta - atan2(v_R, u_R)  # Eq. (20)
    a = abs(alpha_R)
    if a <= e.alpha_s:
        return 0.0, 0.0, 0.0
    s_a = sincos(a)[0]
    s_s = sincos(e.alpha_s)[0]
    sign = 1.0 if alpha_R > 0.0 else -1.0
    d_sin = -sign * e.k_s * (s_a - s_s)  # sin_eff - sin(alpha_R)
    f_alpha = lift_gradient(sh)  # Eq. (18)
    dF_N = 0.5 * sh.rho * sh.A_R * f_alpha * u_R * u_R * d_sin  # Eq. (17), changed part
    sin_d, cos_d = sincos(delta)
    L = sh.L_pp
    dX = -(1.0 - th.t_R) * dF_N * sin_d  # Eq. (14)
    dY = -(1.0 + th.a_H) * dF_N * cos_d  # Eq. (15)
    dN = -(sh.x_R_nd * L + th.a_H * th.x_H * L) * dF_N * cos_d  # Eq. (16)
    return dX, dY, dN


RUDDER_STALL = Effect(
    name="rudder_stall",
    description="the rudder stalls: its normal force stops growing beyond a stall angle",
    regime="|delta| large (>= 20-30 deg), ahead inflow at the rudder",
    params=(
        EffectParam("alpha_s", "rad", 0.35, 0.1, 0.7, "stall angle of attack"),
        EffectParam("k_s", "-", 0.0, 0.0, 2.0, "share of the lift growth lost beyond stall"),
    ),
    param_type=RudderStallParams,
    force=rudder_stall_force,
)
