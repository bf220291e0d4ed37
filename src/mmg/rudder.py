"""Rudder forces (paper section 2.3, Eqs. (14)-(26)).

Standard MMG rudder model (Yasukawa & Yoshimura 2015) with the inflow angle by atan2, Yoshimura's
low-speed longitudinal inflow for n_p >= 0, Kitagawa's propeller-reversal inflow, and u_R = u when
going astern. Y_R uses (1 + a_H), the standard MMG form of Yasukawa & Yoshimura (2015) and of the
paper's authors' code (the paper's text prints 1 - a_H, a typo).
"""

from __future__ import annotations

import math

from mmg._jit import subfunction
from mmg.params import Ship, Theta

#: 8 / pi of Eqs. (22) and (25), a constant factor rather than a division per call
EIGHT_OVER_PI = 8.0 / math.pi


@subfunction
def rudder_inflow(
    u: float,
    v_m: float,
    r: float,
    n_p: float,
    one_minus_w: float,
    K_T: float,
    th: Theta,
    sh: Ship,
) -> tuple[float, float]:
    """Longitudinal and lateral inflow velocity at the rudder, u_R and v_R [m/s].

    u, v_m [m/s], r [rad/s], n_p [rev/s]; one_minus_w = 1 - w_P [-] and K_T [-] from
    :mod:`mmg.propeller` (for n_p < 0, K_T of the reversal polynomial).
    Branches (authors' implementation): Yoshimura's form whenever n_p >= 0 and K_T > 0 (also
    astern, u < 0); otherwise Kitagawa's form for u >= 0 and u_R = u for u < 0.
    """
    L, D = sh.L_pp, sh.D_p
    x_R = sh.x_R_nd * L
    gamma = th.gamma_P if v_m + x_R * r >= 0.0 else th.gamma_N  # Eq. (21)
    v_R = -gamma * (v_m + th.l_R * L * r)  # Eq. (21)
    H_R = math.sqrt(sh.A_R * sh.lambda_R)  # rudder span [m]
    eta = D / H_R
    u_P = one_minus_w * u
    nD = n_p * D
    yoshimura = n_p >= 0.0 and K_T > 0.0  # else Kitagawa's form (or u_R = u astern)
    # Each form takes two square roots; the compiled kernel evaluates every branch for a vector
    # of lanes, so the forms share them: the first is sqrt(u_P^2 + 8/pi K_T (n_p D_p)^2) in
    # Eq. (22) and |n_p D_p| sqrt(8/pi |K_T|) in Eq. (25); the second is u_R itself. Four square
    # roots become two (a vector root costs about 12 cycles per 4 lanes in the divider).
    thrust = EIGHT_OVER_PI * abs(K_T) * nD * nD
    root_1 = math.sqrt(thrust + (u_P * u_P if yoshimura else 0.0))
    # Eq. (22) times epsilon: epsilon u_P + k_x (root_1 - u_P) is epsilon times the bracket
    # u_P + (k_x / epsilon)(root_1 - u_P), without the division by epsilon
    eps_jet = th.epsilon * u_P + th.k_x * (root_1 - u_P)
    eps_u_P = th.epsilon * u_P
    u_RPR2 = u * th.epsilon * one_minus_w  # Eq. (26)
    u_RPR1 = u_RPR2 + th.k_xPR * math.copysign(root_1, nD)  # Eq. (25)
    u_Rsq = (
        eta * math.copysign(u_RPR1 * u_RPR1, u_RPR1)
        + (1.0 - eta) * math.copysign(u_RPR2 * u_RPR2, u_RPR2)
        + th.C_PR * u * u
    )  # Eq. (24), last term C_PR u^2, dimensionally consistent (the paper prints C_PR u)
    # u_R = sqrt(a) with the sign of sgn; every branch sets (sgn, a) before the one root
    if yoshimura:  # Eq. (22): u_R = epsilon sqrt(eta jet^2 + (1 - eta) u_P^2), epsilon inside
        sgn, a = th.epsilon, eta * eps_jet * eps_jet + (1.0 - eta) * eps_u_P * eps_u_P
    elif u >= 0.0:
        sgn, a = u_Rsq, abs(u_Rsq)  # Eq. (23)
    else:  # astern without positive thrust: u_R = u (Kobayashi 1994); sqrt(u^2) = |u| exactly
        sgn, a = u, u * u
    u_R = math.copysign(math.sqrt(a), sgn)
    return u_R, v_R


@subfunction
def lift_gradient(sh: Ship) -> float:
    """f_alpha [-], the rudder's normal-force gradient coefficient (Eq. (18), Fujii's formula)."""
    return 6.13 * sh.lambda_R / (2.25 + sh.lambda_R)  # Eq. (18)


@subfunction
def rudder_forces(
    u_R: float, v_R: float, sin_delta: float, cos_delta: float, th: Theta, sh: Ship
) -> tuple[float, float, float]:
    """Rudder forces X_R [N], Y_R [N] and yaw moment N_R [N m] at midship.

    u_R, v_R [m/s] rudder inflow; the rudder angle delta [rad] (positive turns to starboard)
    enters through sin(delta) and cos(delta), which the caller computes once per input sample.
    F_N = 0.5 rho A_R U_R^2 f_alpha sin(alpha_R) with alpha_R = delta - atan2(v_R, u_R) is written
    without the angle: U_R^2 sin(alpha_R) = U_R (u_R sin(delta) - v_R cos(delta)).
    """
    L = sh.L_pp
    f_alpha = lift_gradient(sh)  # Eq. (18), Fujii's formula
    U_R = math.sqrt(u_R * u_R + v_R * v_R)  # Eq. (19)
    sin_d = sin_delta
    cos_d = cos_delta
    F_N = 0.5 * sh.rho * sh.A_R * f_alpha * U_R * (u_R * sin_d - v_R * cos_d)  # Eqs. (17), (20)
    X_R = -(1.0 - th.t_R) * F_N * sin_d  # Eq. (14)
    Y_R = -(1.0 + th.a_H) * F_N * cos_d  # Eq. (15), standard MMG sign
    N_R = -(sh.x_R_nd * L + th.a_H * th.x_H * L) * F_N * cos_d  # Eq. (16)
    return X_R, Y_R, N_R
