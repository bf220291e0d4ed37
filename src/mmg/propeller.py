"""Propeller forces in four quadrants of (u, n_p) (paper section 2.2, Eqs. (5)-(12)).

First and second quadrant (n_p >= 0): standard MMG thrust with the wake model of ITTC (2002);
second quadrant (u < 0, n_p >= 0): side force and yaw moment of Ueno (2001); third and fourth
quadrant (n_p < 0): Hasegawa (1994) reversal polynomials. Branch choices at exact zeros (u = 0,
n_p = 0) follow the paper's authors' implementation.
"""

from __future__ import annotations

import math

from mmg._jit import subfunction
from mmg.params import Ship, Theta

#: J_s where n_p = 0 (sign of u), avoiding the division by zero (authors' code)
J_S_AT_ZERO_N = 1.0e4
#: J_s where u = 0, and the floor of 1 - w_P: the float64 machine epsilon (authors' code)
EPS = 2.220446049250313e-16
#: speed below which v' and r' are replaced by a small constant (1e-7) [m/s]
U_MIN = 1.0e-5
#: breakpoints of Hasegawa's side-force and yaw-moment polynomials in J_s (paper Eq. (11)-(12))
J_SYN = -0.35  # below: A3 + A4 J_s, B3 + B4 J_s
J_SYN0 = -0.06  # above: A5, B5; between: A1 + A2 J_s, B1 + B2 J_s


@subfunction
def wake_factor(u: float, v_m: float, r: float, th: Theta, sh: Ship) -> float:
    """Effective wake factor 1 - w_P [-] (paper Eq. (6)-(8)).

    1 - w_P = 1 - w_P0 + tau |v' + x'_P r'| + C'_P (v' + x'_P r')^2 for u > 0, clipped to (eps, 1];
    1 - w_P = 1 for u <= 0 (w_P = 0 astern, Eq. (8)). u, v_m [m/s], r [rad/s].
    """
    if u <= 0.0:
        return 1.0
    U = math.sqrt(u * u + v_m * v_m)
    if U < U_MIN:  # guard at zero speed: v' = r' = 1e-7
        v_nd = 1.0e-7
        r_nd = 1.0e-7
    else:
        inv_U = 1.0 / U  # one division for both
        v_nd = v_m * inv_U  # v'
        r_nd = r * sh.L_pp * inv_U  # r'
    beta_P = v_nd + th.x_P * r_nd  # v' + x'_P r', Eq. (6)
    one_minus_w = 1.0 - th.w_P0 + th.tau * abs(beta_P) + th.C_P * beta_P * beta_P  # Eq. (6)
    if one_minus_w > 1.0:
        one_minus_w = 1.0
    if one_minus_w <= 0.0:
        one_minus_w = EPS
    return one_minus_w


@subfunction
def advance_ratio(u: float, n_p: float, sh: Ship) -> float:
    """Apparent advance coefficient J_s = u / (n_p D_p) [-], guarded at n_p = 0 and u = 0."""
    if abs(n_p) < EPS:
        return J_S_AT_ZERO_N if u >= 0.0 else -J_S_AT_ZERO_N
    if abs(u) < EPS:
        return EPS
    return u / (n_p * sh.D_p)


@subfunction
def thrust_coefficient(J_P: float, sh: Ship) -> float:
    """Open-water thrust coefficient K_T(J_P) = k_0 + k_1 J_P + k_2 J_P^2 [-] (paper Eq. (5))."""
    return sh.k_0 + sh.k_1 * J_P + sh.k_2 * J_P * J_P


@subfunction
def propeller_forces(
    u: float, n_p: float, J_s: float, one_minus_w: float, th: Theta, sh: Ship
) -> tuple[float, float, float, float]:
    """Propeller forces X_P [N], Y_P [N], yaw moment N_P [N m], and K_T [-] as seen by the rudder.

    u [m/s], n_p [rev/s], J_s from :func:`advance_ratio`, one_minus_w from :func:`wake_factor`.
    For n_p < 0 the returned K_T is X_P / (rho n_p^2 D_p^4) of the reversal polynomial, as in the
    paper's authors' code.
    """
    rho, D, L, d = sh.rho, sh.D_p, sh.L_pp, sh.d
    nD2 = (n_p * D) * (n_p * D)
    rho_n2_D4 = rho * nD2 * D * D
    if n_p >= 0.0:
        J_P = J_s * one_minus_w if u >= 0.0 else J_s  # J_P = (1 - w_P) u / (n_p D_p)
        K_T = thrust_coefficient(J_P, sh)
        X_P = rho_n2_D4 * (1.0 - th.t_P) * K_T  # Eq. (5)
        if u >= 0.0:
            Y_P = 0.0
            N_P = 0.0
        else:
            nP2 = (n_p * D * sh.pitch_ratio) * (n_p * D * sh.pitch_ratio)
            Y_P = 0.5 * rho * L * d * nP2 * (th.A6 * J_s * J_s + th.A7 * J_s + th.A8)  # Eq. (9)
            N_P = (
                0.5 * rho * L * L * d * nP2 * (th.B6 * J_s * J_s + th.B7 * J_s + th.B8)
            )  # Eq. (10)
    else:
        K_T = th.C6 + th.C7 * J_s if J_s >= th.C10 else th.C3  # Eq. (11), t_P = 0 for n_p < 0
        X_P = rho_n2_D4 * K_T  # Eq. (11)
        if J_s < J_SYN:
            C_Y = th.A3 + th.A4 * J_s  # Eq. (12)
            C_N = th.B3 + th.B4 * J_s  # Eq. (13)
        elif J_s > J_SYN0:
            C_Y = th.A5
            C_N = th.B5
        else:
            C_Y = th.A1 + th.A2 * J_s
            C_N = th.B1 + th.B2 * J_s
        Y_P = 0.5 * rho * L * d * nD2 * C_Y  # Eq. (12)
        N_P = 0.5 * rho * L * L * d * nD2 * C_N  # Eq. (13)
    return X_P, Y_P, N_P, K_T
