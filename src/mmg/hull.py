"""Hull forces: the unified model of Yoshimura et al. (2009) with cross-flow drag (paper Eq. (4)).

The added-mass terms of Yoshimura's original expression sit on the left-hand side of the equations
of motion (:mod:`mmg.model`). The cross-flow integrals are evaluated in closed form.
"""

from __future__ import annotations

import math

from mmg._jit import subfunction
from mmg.params import Ship, Theta
from mmg.trig import atan2

# Divisions by constants are written as products with their reciprocals, and a quantity divided
# twice shares one reciprocal: a vector division costs about 8 cycles per 4 lanes and a long
# latency in the batched kernel, a multiply 0.5. Results move by an ulp, nothing else.
#: 1/3, 1/6, 1/12 and 1/pi as factors (see above)
ONE_3RD = 1.0 / 3.0
ONE_6TH = 1.0 / 6.0
ONE_12TH = 1.0 / 12.0
INV_PI = 1.0 / math.pi


@subfunction
def cross_flow_integrals(v_m: float, b: float, L: float) -> tuple[float, float]:
    """Closed forms of the cross-flow drag integrals over x in [-L/2, L/2].

    With s(x) = v_m + b x (b = C r [1/s]):
    I_0 = int |s| s dx [m^3/s^2] and I_1 = int |s| s x dx [m^4/s^2].

    Where s keeps its sign on the hull (|v_m| >= |b| L / 2), |s| s = sign(v_m) s^2 and both
    integrals are polynomials, exact and free of cancellation; otherwise s changes sign,
    |b| L > 2 |v_m|, and the antiderivatives divided by b are well conditioned:
    I_0 = (s2^2 |s2| - s1^2 |s1|) / (3 b), I_1 = [s^3 |s| / 4 - v_m s^2 |s| / 3]_{s1}^{s2} / b^2
    with s1, s2 = v_m -/+ b L / 2.
    """
    half = 0.5 * L
    if abs(v_m) >= abs(b) * half:
        sgn = 1.0 if v_m >= 0.0 else -1.0
        I_0 = sgn * (v_m * v_m * L + b * b * L * L * L * ONE_12TH)  # int s^2 dx
        I_1 = abs(v_m) * b * L * L * L * ONE_6TH  # sign(v_m) int s^2 x dx
    else:
        inv_b = 1.0 / b  # one division for both integrals
        s1 = v_m - b * half  # s at the stern, x = -L/2
        s2 = v_m + b * half  # s at the bow, x = L/2
        q1 = s1 * s1 * abs(s1)  # |s| s^2 at the ends
        q2 = s2 * s2 * abs(s2)
        I_0 = (q2 - q1) * ONE_3RD * inv_b  # Eq. (4), closed form (s^2 |s| / (3 b))
        F2 = q2 * (0.25 * s2 - ONE_3RD * v_m)  # antiderivative of I_1 (times b^2)
        F1 = q1 * (0.25 * s1 - ONE_3RD * v_m)
        I_1 = (F2 - F1) * inv_b * inv_b  # Eq. (4), closed form
    return I_0, I_1


@subfunction
def hull_forces(u: float, v_m: float, r: float, th: Theta, sh: Ship) -> tuple[float, float, float]:
    """Hull surge force X_H [N], sway force Y_H [N] and yaw moment N_H [N m] at midship.

    u, v_m [m/s] surge and sway velocity at midship, r [rad/s] yaw rate (paper Eq. (4)).
    """
    L = sh.L_pp
    inv_L = 1.0 / L  # the same for every trajectory: computed once per step, not per lane
    U = math.sqrt(u * u + v_m * v_m)  # speed over the water [m/s]
    beta = atan2(v_m, u)  # drift angle; only |beta| / pi enters X_H
    half_rho_Ld = 0.5 * sh.rho * L * sh.d
    X_0 = sh.X_0F + (th.X_0A - sh.X_0F) * abs(beta) * INV_PI  # Eq. (4), X_H resistance term
    X_H = half_rho_Ld * (X_0 * u * U + th.X_vr * L * v_m * r)  # Eq. (4)
    I_Y, _ = cross_flow_integrals(v_m, th.C_rY * r, L)
    _, I_N = cross_flow_integrals(v_m, th.C_rN * r, L)
    C_D_L = th.C_D * inv_L  # C_D / L
    Y_H = half_rho_Ld * (th.Y_v * v_m * abs(u) + th.Y_r * L * r * u - C_D_L * I_Y)  # Eq. (4)
    # Eq. (4), N_H (C_D / L^2 = C_D_L / L):
    N_H = half_rho_Ld * L * (th.N_v * v_m * u + th.N_r * L * r * abs(u) - C_D_L * inv_L * I_N)
    return X_H, Y_H, N_H
