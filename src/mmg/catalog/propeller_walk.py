"""``propeller_walk``: side force and yaw moment of a single propeller going ahead.

The paper's model sets Y_P = N_P = 0 for u >= 0 and n_p >= 0. A real single-screw ship feels a
lateral force from the asymmetric blade loading ("propeller walk"), proportional to (n_p D_p)^2.
Regime: n_p > 0, largest at low advance ratio (starting, berthing approach).
"""

from __future__ import annotations

from typing import NamedTuple

from mmg._jit import subfunction
from mmg.effect import Effect, EffectParam
from mmg.params import Ship, Theta


class PropellerWalkParams(NamedTuple):
    """The parameters of ``propeller_walk`` in kernel order (unit of each after its field)."""

    C_Yw: float  # Y = 0.5 rho L d (n_p D_p)^2 C_Yw [-]
    C_Nw: float  # N = 0.5 rho L^2 d (n_p D_p)^2 C_Nw [-]


@subfunction
def propeller_walk_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: PropellerWalkParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Extra (0 [N], Y [N], N [N m]) for n_p > 0, in the form of Hasegawa's reversal terms."""
    if n_p <= 0.0:
        return 0.0, 0.0, 0.0
    nD2 = (n_p * sh.D_p) * (n_p * sh.D_p)
    q = 0.5 * sh.rho * sh.L_pp * sh.d * nD2
    return 0.0, q * e.C_Yw, q * sh.L_pp * e.C_Nw


PROPELLER_WALK = Effect(
    name="propeller_walk",
    description="side force and yaw moment of the propeller when going ahead (n_p > 0)",
    regime="n_p > 0, low advance ratio",
    params=(
        EffectParam("C_Yw", "-", 0.0, -2e-3, 2e-3, "side-force coefficient"),
        EffectParam("C_Nw", "-", 0.0, -2e-3, 2e-3, "yaw-moment coefficient"),
    ),
    param_type=PropellerWalkParams,
    force=propeller_walk_force,
)
