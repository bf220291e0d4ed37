"""The one place that decides how sub-model functions are compiled.

Sub-models are scalar functions of floats. ``subfunction`` compiles them with Numba so that the
batched kernel inlines them (and LLVM vectorises across trajectories); they stay callable from
Python. With ``NUMBA_DISABLE_JIT=1`` the very same source runs as plain Python, which is the
reference path of the benchmark.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import numba

F = TypeVar("F", bound=Callable[..., Any])

#: options shared by every compiled function of the model: numpy error model (no zero-division
#: checks, which block vectorisation) and strict IEEE arithmetic (no fastmath) for reproducibility.
JIT_OPTIONS: dict[str, Any] = {"error_model": "numpy", "nogil": True}
#: ... and for the objective's kernel (:func:`mmg.integrate.segment_moments`): the same, with
#: a * b + c contracted into fused multiply-adds (one rounding instead of two; about a fifth
#: faster). Its J agrees with J of the simulated trajectories to rounding, not bit for bit; the
#: simulator, the pointwise right-hand side and the reference path keep strict IEEE arithmetic.
FUSED_OPTIONS: dict[str, Any] = {**JIT_OPTIONS, "fastmath": {"contract"}}


def subfunction(func: F) -> F:
    """Compile a scalar sub-model function for inlining into the batched kernel."""
    return numba.njit(inline="always", **JIT_OPTIONS)(func)
