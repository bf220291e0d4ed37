"""A linear right-hand side for the RK4 order test (imported by the generated kernel by name).

xdot = A x with A block-diagonal: three damped oscillators, (x0, u), (y0, v_m), (psi, r).
"""

from __future__ import annotations

import numpy as np

from mmg._jit import subfunction

A = np.array(
    [
        [-0.1, 1.0, 0, 0, 0, 0],
        [-1.0, -0.1, 0, 0, 0, 0],
        [0, 0, -0.3, 2.0, 0, 0],
        [0, 0, -2.0, -0.3, 0, 0],
        [0, 0, 0, 0, 0.0, 1.5],
        [0, 0, 0, 0, -1.5, -0.2],
    ]
)


@subfunction
def linear_rhs(x0, u, y0, v_m, psi, r, delta, n_p, U_T, gamma_T, P, i, sh):
    return (
        -0.1 * x0 + 1.0 * u,
        -1.0 * x0 - 0.1 * u,
        -0.3 * y0 + 2.0 * v_m,
        -2.0 * y0 - 0.3 * v_m,
        1.5 * r,
        -1.5 * psi - 0.2 * r,
    )
