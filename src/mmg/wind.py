"""Wind forces: Fujiwara's (1998) regression with the apparent wind computed inside the model
(paper section 2.4, Eqs. (27)-(28)).

Conventions: the true wind (U_T [m/s], gamma_T [rad]) blows FROM gamma_T, earth-fixed, clockwise
from x0, so gamma_T = psi is a head wind. The apparent wind angle gamma_A is measured the same way
from the bow (gamma_A = 0: head wind, pi/2: from starboard).
"""

from __future__ import annotations

import math

from mmg._jit import subfunction
from mmg.params import Ship, Theta


@subfunction
def apparent_wind(
    u: float,
    v_m: float,
    sin_psi: float,
    cos_psi: float,
    U_T: float,
    sin_gamma_T: float,
    cos_gamma_T: float,
) -> tuple[float, float]:
    """Body-frame components (u_A, v_A) [m/s] of the apparent wind, pointing where it comes FROM.

    U_A = hypot(u_A, v_A), gamma_A = atan2(v_A, u_A). u, v_m [m/s] ship velocity over ground at
    midship; heading psi and true wind direction gamma_T [rad] enter through their sine and
    cosine; the relative angle gamma_T - psi follows by the angle-difference identities.
    """
    c = cos_gamma_T * cos_psi + sin_gamma_T * sin_psi  # cos(gamma_T - psi)
    s = sin_gamma_T * cos_psi - cos_gamma_T * sin_psi  # sin(gamma_T - psi)
    u_A = U_T * c + u
    v_A = U_T * s + v_m
    return u_A, v_A


@subfunction
def wind_forces(u_A: float, v_A: float, th: Theta, sh: Ship) -> tuple[float, float, float]:
    """Wind forces X_A [N], Y_A [N] and yaw moment N_A [N m] from the apparent wind (u_A, v_A).

    The harmonics of (2 pi - gamma_A) follow from cos(gamma_A), sin(gamma_A) by multiple-angle
    identities: cos k(2 pi - g) = cos kg and sin k(2 pi - g) = -sin kg.
    """
    U_A2 = u_A * u_A + v_A * v_A
    U_A = math.sqrt(U_A2)
    if U_A > 0.0:
        inv_U_A = 1.0 / U_A  # one division for both
        c = u_A * inv_U_A  # cos(gamma_A)
        s = v_A * inv_U_A  # sin(gamma_A)
    else:
        c = 1.0
        s = 0.0
    c2 = c * c
    s2 = s * s
    cos3 = c * (4.0 * c2 - 3.0)
    cos5 = c * (16.0 * c2 * c2 - 20.0 * c2 + 5.0)
    sin2 = 2.0 * s * c
    sin3 = s * (3.0 - 4.0 * s2)
    sin5 = s * (16.0 * s2 * s2 - 20.0 * s2 + 5.0)
    C_X = th.X0 + th.X1 * c + th.X3 * cos3 + th.X5 * cos5  # Eq. (28)
    C_Y = -(th.Y1 * s + th.Y3 * sin3 + th.Y5 * sin5)  # Eq. (28)
    C_N = -(th.N1 * s + th.N2 * sin2 + th.N3 * sin3)  # Eq. (28)
    q = 0.5 * sh.rho_A * U_A2
    X_A = q * sh.A_T * C_X  # Eq. (27)
    Y_A = q * sh.A_L * C_Y  # Eq. (27)
    N_A = q * sh.A_L * sh.L_pp * C_N  # Eq. (27), L_pp as in the authors' code (text: L_OA)
    return X_A, Y_A, N_A
