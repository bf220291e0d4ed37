"""Hull forces: the unified model of Yoshimura et al. (2009) with cross-flow drag (paper Eq. (4)).

The added-mass terms of Yoshimura's original expression sit on the left-hand side of the equations
of motion (:mod:`mmg.model`). The cross-flow integrals are evaluated in closed form.
"""

from __future__ import annotations

import math

from mmg._jit import subfunction
from mmg.params import Ship, Theta
from mmg.trig import atan2


@subfunction
def cross_flow_integrals(v_m: float, b: float, L: float) -> tuple[float, float]:
    """Closed forms of the cross-flow drag integrals over x in [-L/2, L/2].

    With s(x) = v_m + b x (b = C r [1/s]):
    I_0 = int |s| s dx [m^3/s^2] and I_1 = int |s| s x dx [m^4/s^2].

    Where s keeps its sign on the hull (|v_m| >= |b| L / 2), |s| s = sign(v_m) s^2 and both
    integrals are polynomials, exact and free of cancellation; otherwise s changes sign,
    |b| L > 2 |v_m|, and the antiderivatives divided by b (reference "Numerical details") are well
    conditioned.
    """
    half = 0.5 * L
    if abs(v_m) >= abs(b) * half:
        sgn = 1.0 if v_m >= 0.0 else -1.0
        I_0 = sgn * (v_m * v_m * L + b * b * L * L * L / 12.0)  # int s^2 dx
        I_1 = abs(v_m) * b * L * L * L / 6.0  # sign(v_m) int s^2 x dx
    else:
        s1 = v_m - b * half  # s at the stern, x = -L/2
        s2 = v_m + b * half  # s at the bow, x = L/2
        I_0 = (s2 * s2 * abs(s2) - s1 * s1 * abs(s1)) / (3.0 * b)  # Eq. (4), reference closed form
        F2 = s2 * s2 * s2 * abs(s2) / 4.0 - v_m * s2 * s2 * abs(s2) / 3.0  # antiderivative of I_1
        F1 = s1 * s1 * s1 * abs(s1) / 4.0 - v_m * s1 * s1 * abs(s1) / 3.0
        I_1 = (F2 - F1) / (b * b)  # Eq. (4), reference closed form
    return I_0, I_1


@subfunction
def hull_forces(u: float, v_m: float, r: float, th: Theta, sh: Ship) -> tuple[float, float, float]:
    """Hull surge force X_H [N], sway force Y_H [N] and yaw moment N_H [N m] at midship.

    u, v_m [m/s] surge and sway velocity at midship, r [rad/s] yaw rate (paper Eq. (4)).
    """
    L = sh.L_pp
    U = math.sqrt(u * u + v_m * v_m)  # speed over the water [m/s]
    beta = atan2(v_m, u)  # drift angle; only |beta| / pi enters X_H
    half_rho_Ld = 0.5 * sh.rho * L * sh.d
    X_0 = sh.X_0F + (th.X_0A - sh.X_0F) * abs(beta) / math.pi  # Eq. (4), X_H resistance term
    X_H = half_rho_Ld * (X_0 * u * U + th.X_vr * L * v_m * r)  # Eq. (4)
    I_Y, _ = cross_flow_integrals(v_m, th.C_rY * r, L)
    _, I_N = cross_flow_integrals(v_m, th.C_rN * r, L)
    Y_H = half_rho_Ld * (th.Y_v * v_m * abs(u) + th.Y_r * L * r * u - th.C_D / L * I_Y)  # Eq. (4)
    N_H = (
        half_rho_Ld * L * (th.N_v * v_m * u + th.N_r * L * r * abs(u) - th.C_D / (L * L) * I_N)
    )  # Eq. (4)
    return X_H, Y_H, N_H
