"""Vectorisable double-precision sin, cos and atan2 for the batched kernel.

The C library's sin and atan2 are opaque calls (about 15 and 25 ns here) that LLVM cannot vectorise;
with seven of them per RK4 stage they cost 80 % of the simulator's time. These are the classic
algorithms of the C libraries themselves, written as straight-line arithmetic so that LLVM
vectorises them across trajectories:

- ``sincos``: Cody-Waite reduction by pi/2 in three parts and the fdlibm minimax kernels
  (``__kernel_sin``, ``__kernel_cos``) on [-pi/4, pi/4]; within 1 ulp of ``math.sin``/``math.cos``
  for |x| < 1e5 (accuracy degrades gracefully beyond); NaN for |x| >= 2^50, which only a diverged
  trajectory reaches (and which the kernel then flags).
- ``atan2``: reduction to [0, 1] by min/max, then Cephes' rational atan (reduction at tan(pi/8)
  style threshold 0.66); within 2 ulp of ``math.atan2``.
- ``sin``, ``cos``: one half of ``sincos`` each (for an angle whose sine or cosine alone is
  needed; where both are, call ``sincos`` once).

The generated effects (:mod:`mmg.discovered`) write their terms' sines and cosines with these in
place of :mod:`math`'s, so that a term with the heading or the rudder angle vectorises like the
model itself. Tests compare all of them against :mod:`math` over wide ranges.
"""

from __future__ import annotations

import math

import numpy as np

from mmg._jit import subfunction

# pi / 2 in three parts (fdlibm): pio2_1 has 33 significant bits, so k * pio2_1 is exact
_PIO2_1 = 1.57079632673412561417e00
_PIO2_2 = 6.07710050630396597660e-11
_PIO2_3 = 2.02226624871116645580e-21
_TWO_OVER_PI = 6.36619772367581382433e-01

# fdlibm __kernel_sin coefficients
_S1 = -1.66666666666666324348e-01
_S2 = 8.33333333332248946124e-03
_S3 = -1.98412698298579493134e-04
_S4 = 2.75573137070700676789e-06
_S5 = -2.50507602534068634195e-08
_S6 = 1.58969099521155010221e-10
# fdlibm __kernel_cos coefficients
_C1 = 4.16666666666666019037e-02
_C2 = -1.38888888888741095749e-03
_C3 = 2.48015872894767294178e-05
_C4 = -2.75573143513906633035e-07
_C5 = 2.08757232129817482790e-09
_C6 = -1.13596475577881948265e-11

# Cephes atan: P / Q rational approximation on [-0.66, 0.66]
_P0 = -8.750608600031904122785e-01
_P1 = -1.615753718733365076637e01
_P2 = -7.500855792314704667340e01
_P3 = -1.228866684490136173410e02
_P4 = -6.485021904942025371773e01
_Q0 = 2.485846490142306297962e01
_Q1 = 1.650270098316988542046e02
_Q2 = 4.328810604912902668951e02
_Q3 = 4.853903996359136964868e02
_Q4 = 1.945506571482613964425e02
_MOREBITS = 6.123233995736765886130e-17  # pi/2 - float(pi/2)
_PIO4 = 7.85398163397448309616e-01
_PIO2 = 1.57079632679489661923e00


@subfunction
def sincos(x: float) -> tuple[float, float]:
    """(sin x, cos x) for x [rad]; NaN for |x| >= 2^50 (no digit of the reduction would be right)
    and for non-finite x."""
    if not abs(x) < 1.125899906842624e15:
        return math.nan, math.nan
    # np.floor, not math.floor: Numba's math.floor returns an integer, a float-int-float round
    # trip on the kernel's critical path (the same numbers, about 3 % faster)
    k = np.floor(x * _TWO_OVER_PI + 0.5)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3  # Cody-Waite, |r| <= pi/4
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (
        ((1.0 - w) - hz) + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    )
    q = k - 4.0 * np.floor(k * 0.25)  # quadrant 0..3 (as a float, exact)
    if q == 0.0:
        return s, c
    if q == 1.0:
        return c, -s
    if q == 2.0:
        return -s, -c
    return -c, s


@subfunction
def _atan_ratio(small: float, big: float) -> float:
    """atan(small / big) for 0 <= small <= big, big > 0 (Cephes atan, one reduction step).

    The reduced argument (t - 1) / (t + 1) with t = small / big is formed as
    (small - big) / (small + big): one division for the argument instead of two (a vector
    division costs about 8 cycles per 4 lanes and lengthens the dependency chain)."""
    reduce = small > 0.66 * big  # t > 0.66
    p = small - big if reduce else small
    q = small + big if reduce else big
    x = p / q
    y0 = _PIO4 if reduce else 0.0
    extra = 0.5 * _MOREBITS if reduce else 0.0
    z = x * x
    num = z * ((((_P0 * z + _P1) * z + _P2) * z + _P3) * z + _P4)
    den = ((((z + _Q0) * z + _Q1) * z + _Q2) * z + _Q3) * z + _Q4
    return y0 + (x + x * (num / den) + extra)


@subfunction
def atan2(y: float, x: float) -> float:
    """atan2(y, x) [rad] in [-pi, pi]; atan2(+-0, x >= 0) = +-0, atan2(0, 0) = 0."""
    ax = abs(x)
    ay = abs(y)
    big = ax if ax >= ay else ay
    small = ay if ax >= ay else ax
    a = _atan_ratio(small, big) if big > 0.0 else 0.0
    if ay > ax:
        a = (_PIO2 - a) + _MOREBITS
    if x < 0.0:
        a = (2.0 * _PIO2 - a) + 2.0 * _MOREBITS
    return math.copysign(a, y)


@subfunction
def sin(x: float) -> float:
    """sin x [x in rad] (see :func:`sincos`)."""
    return sincos(x)[0]


@subfunction
def cos(x: float) -> float:
    """cos x [x in rad] (see :func:`sincos`)."""
    return sincos(x)[1]
