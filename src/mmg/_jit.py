"""The one place that decides how sub-model functions are compiled.

Sub-models are scalar functions of floats. ``subfunction`` compiles them with Numba so that the
batched kernel inlines them (and LLVM vectorises across trajectories); they stay callable from
Python. LLVM inlines them (``forceinline``), so each is typed and compiled once per process, not
once per call site in every entry point of every kernel (Numba's IR inlining, used before,
deep-copied and retyped the whole model at each site: 7.5 s of the base model's 25 s
``simulate``).

Each sub-model has two compiled forms: the strict one (:func:`subfunction`, IEEE arithmetic, the
simulator's) and its fused twin (:func:`fused`, multiply-adds contracted, the objective's), in
which every sub-model it calls is the fused twin too. Numba would otherwise compile a callee
once per process with the arithmetic of whichever kernel reached it first. With
``NUMBA_DISABLE_JIT=1`` the very same source runs as plain Python, which is the reference path of
the benchmark.
"""

from __future__ import annotations

import types
from collections.abc import Callable, Iterator
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
    """Compile a scalar sub-model function for inlining into the batched kernel, with strict
    arithmetic (set explicitly: Numba lets a callee inherit ``fastmath`` from the function that
    compiles it first). The objective's kernel calls its :func:`fused` twin instead."""
    return numba.njit(forceinline=True, fastmath=False, **JIT_OPTIONS)(func)


#: id of a compiled function -> (the function, its fused twin); the function is kept so that its
#: id is not reused
_twins: dict[int, tuple[Any, Any]] = {}


def _jit_disabled() -> bool:
    """Whether Numba runs the functions as plain Python (``NUMBA_DISABLE_JIT=1``)."""
    return bool(getattr(numba.config, "DISABLE_JIT", 0))


def _inlined(obj: object) -> bool:
    """Whether ``obj`` is a compiled function meant to be inlined into a kernel (a sub-model,
    or a kernel's own helper inlined in Numba's IR)."""
    options = getattr(obj, "targetoptions", None)
    return isinstance(options, dict) and bool(
        options.get("forceinline") or options.get("inline") == "always"
    )


def _names(code: types.CodeType) -> Iterator[str]:
    """The global names that ``code`` and the code nested in it may load."""
    yield from code.co_names
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            yield from _names(const)


def _copy(func: Callable[..., Any]) -> tuple[types.FunctionType, dict[str, Any]]:
    """A copy of the plain function ``func`` with a global scope of its own (to re-bind) and
    the fused twins of the sub-models it holds in its closure."""
    scope = dict(func.__globals__)
    closure = func.__closure__
    if closure is not None:
        closure = tuple(
            types.CellType(fused(c.cell_contents)) if _inlined(c.cell_contents) else c
            for c in closure
        )
    copy = types.FunctionType(func.__code__, scope, func.__name__, func.__defaults__, closure)
    copy.__qualname__ = func.__qualname__
    copy.__module__ = func.__module__
    copy.__doc__ = func.__doc__
    copy.__kwdefaults__ = func.__kwdefaults__
    return copy, scope


def _bind_twins(code: types.CodeType, scope: dict[str, Any]) -> None:
    """Re-bind, in ``scope``, each sub-model or inlined helper that ``code`` calls to its twin."""
    for name in set(_names(code)):
        if _inlined(scope.get(name)):
            scope[name] = fused(scope[name])


def fused_source(func: F) -> F:
    """``func`` (a plain Python function) re-bound so that every sub-model or inlined helper it
    calls, directly or through others, is the :func:`fused` twin: the function to compile with
    :data:`FUSED_OPTIONS`. With the JIT disabled, ``func`` itself."""
    if _jit_disabled():
        return func
    copy, scope = _copy(func)
    _bind_twins(func.__code__, scope)
    return copy  # type: ignore[return-value]


def fused(dispatcher: F) -> F:
    """The fused twin of a sub-model compiled by :func:`subfunction` (or of an inlined kernel
    helper): the same source with :data:`FUSED_OPTIONS`, calling the fused twins of what it
    calls; one per process. With the JIT disabled, the function itself."""
    if _jit_disabled() or not _inlined(dispatcher):
        return dispatcher
    known = _twins.get(id(dispatcher))
    if known is not None:
        return known[1]
    options = getattr(dispatcher, "targetoptions", {})
    inline = {k: options[k] for k in ("forceinline", "inline") if options.get(k)}
    py_func = dispatcher.py_func  # type: ignore[attr-defined]
    copy, scope = _copy(py_func)
    twin = numba.njit(**inline, **FUSED_OPTIONS)(copy)
    _twins[id(dispatcher)] = (dispatcher, twin)  # first: a module's scope holds the function
    _bind_twins(py_func.__code__, scope)
    return twin
