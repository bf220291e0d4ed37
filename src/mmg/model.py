"""Equations of motion at midship with the x_G coupling (paper Eqs. (1)-(3)).

State x = (x0, u, y0, v_m, psi, r) [m, m/s, m, m/s, rad, rad/s]; control (delta [rad], n_p [rev/s]);
wind (U_T [m/s], gamma_T [rad], the direction it blows from). These functions sum the sub-models;
they know nothing of integration.
"""

from __future__ import annotations

from typing import NamedTuple

from mmg._jit import subfunction
from mmg.hull import hull_forces
from mmg.params import Ship, Theta
from mmg.propeller import advance_ratio, propeller_forces, wake_factor
from mmg.rudder import rudder_forces, rudder_inflow
from mmg.trig import sincos
from mmg.wind import apparent_wind, wind_forces


@subfunction
def hydrodynamic_forces(
    u: float,
    v_m: float,
    r: float,
    sin_delta: float,
    cos_delta: float,
    n_p: float,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """Hull, propeller and rudder forces (X_H, Y_H, N_H, X_P, Y_P, N_P, X_R, Y_R, N_R).

    u, v_m [m/s] velocity through the water at midship, r [rad/s], rudder angle delta [rad] as
    sin(delta), cos(delta), n_p [rev/s]. Forces in N, moments in N m, at midship.
    """
    X_H, Y_H, N_H = hull_forces(u, v_m, r, th, sh)
    one_minus_w = wake_factor(u, v_m, r, th, sh)
    J_s = advance_ratio(u, n_p, sh)
    X_P, Y_P, N_P, K_T = propeller_forces(u, n_p, J_s, one_minus_w, th, sh)
    u_R, v_R = rudder_inflow(u, v_m, r, n_p, one_minus_w, K_T, th, sh)
    X_R, Y_R, N_R = rudder_forces(u_R, v_R, sin_delta, cos_delta, th, sh)
    return X_H, Y_H, N_H, X_P, Y_P, N_P, X_R, Y_R, N_R


@subfunction
def rudder_inflow_at(
    u: float, v_m: float, r: float, n_p: float, th: Theta, sh: Ship
) -> tuple[float, float]:
    """Rudder inflow u_R, v_R [m/s] at a state: the wake factor, advance ratio and K_T of the
    propeller model (section 2.2) feeding Eqs. (21)-(25), as in :func:`hydrodynamic_forces`.

    For sub-models that change the rudder force (:mod:`mmg.catalog`): u, v_m [m/s], r [rad/s],
    n_p [rev/s].
    """
    one_minus_w = wake_factor(u, v_m, r, th, sh)
    J_s = advance_ratio(u, n_p, sh)
    K_T = propeller_forces(u, n_p, J_s, one_minus_w, th, sh)[3]
    return rudder_inflow(u, v_m, r, n_p, one_minus_w, K_T, th, sh)


@subfunction
def aerodynamic_forces(
    u: float,
    v_m: float,
    sin_psi: float,
    cos_psi: float,
    U_T: float,
    sin_gamma_T: float,
    cos_gamma_T: float,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Wind forces (X_A [N], Y_A [N], N_A [N m]); u, v_m [m/s] velocity over ground; angles as
    sine and cosine (see :func:`mmg.wind.apparent_wind`)."""
    u_A, v_A = apparent_wind(u, v_m, sin_psi, cos_psi, U_T, sin_gamma_T, cos_gamma_T)
    return wind_forces(u_A, v_A, th, sh)


@subfunction
def all_forces(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float, float]:
    """The twelve force components (X_H, Y_H, N_H, X_P, Y_P, N_P, X_R, Y_R, N_R, X_A, Y_A, N_A).

    Still water (velocity through the water = velocity over ground). Angles in rad, forces in N,
    moments in N m. The reference entry point for tests; the kernel calls the parts directly.
    """
    sin_d, cos_d = sincos(delta)
    sin_psi, cos_psi = sincos(psi)
    sin_g, cos_g = sincos(gamma_T)
    X_H, Y_H, N_H, X_P, Y_P, N_P, X_R, Y_R, N_R = hydrodynamic_forces(
        u, v_m, r, sin_d, cos_d, n_p, th, sh
    )
    X_A, Y_A, N_A = aerodynamic_forces(u, v_m, sin_psi, cos_psi, U_T, sin_g, cos_g, th, sh)
    return X_H, Y_H, N_H, X_P, Y_P, N_P, X_R, Y_R, N_R, X_A, Y_A, N_A


class Inertia(NamedTuple):
    """The left-hand side of Eq. (1) for one parameter set: the sway-yaw matrix
    [[m + m_y, x_G m], [x_G m, I_zz + J_zz + x_G^2 m]] and the reciprocals the solve uses.

    It depends on the parameters alone, so the batched kernel computes it once per lane and
    chunk (:func:`inertia`) rather than in every right-hand side: two vector divisions fewer per
    stage."""

    m_m_x: float  # m + m_x, mass plus added mass in surge [kg]
    m_m_y: float  # m + m_y, mass plus added mass in sway [kg]
    x_G_m: float  # x_G m [kg m]
    a22: float  # I_zz + J_zz + x_G^2 m [kg m^2]
    inv_m_m_x: float  # 1 / (m + m_x) [1/kg]
    inv_det: float  # 1 / det of the sway-yaw matrix [1/(kg^2 m^2)]


@subfunction
def inertia(th: Theta, sh: Ship) -> Inertia:
    """The masses and inertias of Eq. (1) from the non-dimensional parameters (m', m'_x, m'_y,
    (I_zz + J_zz)', x'_G): m = m' 0.5 rho L^2 d, I = I' 0.5 rho L^4 d."""
    L = sh.L_pp
    half_rho_L2d = 0.5 * sh.rho * L * L * sh.d
    m = sh.m_nd * half_rho_L2d
    m_x = th.m_x * half_rho_L2d
    m_y = th.m_y * half_rho_L2d
    I_zJ_z = th.I_zz_J_zz * half_rho_L2d * L * L
    x_G = sh.x_G_nd * L
    a11 = m + m_y
    a12 = x_G * m
    a22 = I_zJ_z + x_G * x_G * m
    det = a11 * a22 - a12 * a12
    return Inertia(m + m_x, a11, a12, a22, 1.0 / (m + m_x), 1.0 / det)


@subfunction
def accelerations(
    X: float, Y: float, N: float, u: float, v_m: float, r: float, M: Inertia
) -> tuple[float, float, float]:
    """(u_dot [m/s^2], v_m_dot [m/s^2], r_dot [rad/s^2]) from the total force X, Y, N (Eq. (1)).

    The sway-yaw pair is the 2x2 system
    [[m + m_y, x_G m], [x_G m, I_zz + J_zz + x_G^2 m]] [v_m_dot, r_dot] = [Y - (m + m_x) u r,
    N - x_G m u r], solved by Cramer's rule. M from :func:`inertia`.
    """
    u_dot = (X + M.m_m_y * v_m * r + M.x_G_m * r * r) * M.inv_m_m_x  # Eq. (1), surge
    b1 = Y - M.m_m_x * u * r  # Eq. (1), sway
    b2 = N - M.x_G_m * u * r  # Eq. (1), yaw
    v_dot = (M.a22 * b1 - M.x_G_m * b2) * M.inv_det
    r_dot = (M.m_m_y * b2 - M.x_G_m * b1) * M.inv_det
    return u_dot, v_dot, r_dot


@subfunction
def kinematics(u: float, v_m: float, sin_psi: float, cos_psi: float) -> tuple[float, float]:
    """Earth-fixed velocity of midship (x0_dot, y0_dot) [m/s] from body velocities [m/s] and the
    heading psi as sin(psi), cos(psi)."""
    return u * cos_psi - v_m * sin_psi, u * sin_psi + v_m * cos_psi
