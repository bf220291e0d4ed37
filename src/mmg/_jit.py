"""The one place that decides how sub-model functions are compiled.

Sub-models are scalar functions of floats. ``subfunction`` compiles them with Numba so that the
batched kernel inlines them (and LLVM vectorises across trajectories); they stay callable from
Python. They are inlined in Numba's IR (``inline="always"``), so that each kernel compiles them with
its own options: the objective's kernel contracts their multiply-adds, the simulator's keeps them
strict. *Rejected*: inlining them by LLVM (``forceinline``), which compiled a kernel entry point in
about half the time but compiled each sub-model once per process, strict for every kernel: the
objective's kernel was 12-15 % slower. With ``NUMBA_DISABLE_JIT=1`` the very same source runs as
plain Python, which is the reference path of the benchmark.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import numba

F = TypeVar("F", bound=Callable[..., Any])

#: options shared by every compiled function of the model: numpy error model (no zero-division
#: checks, which block vectorisation) and strict IEEE arithmetic (no fastmath) for reproducibility.
JIT_OPTIONS: dict[str, Any] = {"error_model": "numpy", "nogil": True}
#: ... and for the objective's kernel (:func:`mmg.integrate.segment_moments`): the same, with a * b
#: + c contracted into fused multiply-adds (one rounding instead of two; about a seventh faster,
#: measured against the same kernel with strict sub-models). Its J agrees with J of the simulated
#: trajectories to rounding, not bit for bit; the simulator, the pointwise right-hand side and the
#: reference path keep strict IEEE arithmetic.
FUSED_OPTIONS: dict[str, Any] = {**JIT_OPTIONS, "fastmath": {"contract"}}


def subfunction(func: F) -> F:
    """Compile a scalar sub-model function for inlining into the batched kernel.

    Strict arithmetic is set explicitly: Numba lets a callee inherit ``fastmath`` from the
    function that compiles it first, so the objective's fused kernel would otherwise leave
    contracted multiply-adds in the sub-models for every later kernel of the process, and the
    simulator's results would depend on which kernel a process compiled first."""
    return numba.njit(inline="always", **JIT_OPTIONS)(func)
