"""Compile the kernels a long run will need ahead of time, several at once, in worker processes.

Numba compiles one function at a time per process (10-20 s per kernel entry point of the base
model, more with effects). :func:`precompile` compiles the entry points missing from Numba's
on-disk cache in ``processes`` spawned workers (Numba's thread pool does not survive a fork);
the calling process then loads them from the cache. A warm cache costs only the check (no
process is started).
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from mmg.effect import Effect
from mmg.effects import get_effect
from mmg.fixed import kernel_effects
from mmg.kernel import load_kernel
from mmg.orphans import exit_with_parent
from mmg.params import N_THETA, efd_parameters

#: entry point -> the compiled function of the kernel module behind it
ENTRIES: dict[str, str] = {
    "simulate": "simulate_thread",  # mmg.simulate_batch (its threads share)
    "moments": "moments_thread",  # mmg.integrate.segment_moments (the objective; its threads share)
    "derivatives": "rhs_share",  # mmg.integrate.derivatives / derivatives_rows
    "accelerations": "effect_share",  # mmg.integrate.effect_accelerations_rows (its last effect's)
}


def is_compiled(effects: tuple[Effect, ...], entry: str) -> bool:
    """Whether Numba's on-disk cache holds ``entry`` of the kernel for ``effects`` (its index
    file exists; an index written on another CPU still leads to a compilation at first use)."""
    dispatcher = getattr(load_kernel(kernel_effects(effects)), ENTRIES[entry])
    cache = getattr(dispatcher, "_cache", None)
    index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
    return index is not None and Path(index).exists()


def compile_entry(names: tuple[str, ...], entry: str) -> float:
    """Compile ``entry`` of the kernel for the named effects in this process (a worker of
    :func:`precompile`, or ``benchmarks/compile_time.py``); seconds taken."""
    from mmg.integrate import (
        Segments,
        derivatives,
        effect_accelerations_rows,
        segment_moments,
        simulate_batch,
    )

    t0 = time.perf_counter()
    effects = tuple(get_effect(n) for n in names)
    n = N_THETA + sum(len(e.params) for e in effects)
    theta = np.zeros(n)
    theta[:N_THETA] = efd_parameters().vector()
    for i, p in enumerate(p for e in effects for p in e.params):
        theta[N_THETA + i] = p.neutral  # any value compiles the same code
    x0 = np.zeros((1, 6))
    x0[0, 1] = 1.0
    u = np.zeros((1, 2, 2))
    if entry == "simulate":
        simulate_batch(x0, u, u, theta, effects=effects)
    elif entry == "moments":
        seg = Segments(x0, u, u, np.array([2]), np.zeros((1, 3, 7)), np.zeros((1, 7)))
        segment_moments(seg, theta[None], effects=effects)
    elif entry == "accelerations":
        effect_accelerations_rows(x0[0], u[0, 0], u[0, 0], theta[None], effects)
    else:
        derivatives(x0[0], u[0, 0], u[0, 0], theta, effects=effects)
    return time.perf_counter() - t0


def tasks(
    effect_sets: Iterable[tuple[Effect, ...]], entries: Sequence[str] = ("simulate", "moments")
) -> list[tuple[tuple[Effect, ...], str]]:
    """(effects, entry) for every effect set and entry point, for :func:`precompile`."""
    unknown = [e for e in entries if e not in ENTRIES]
    if unknown:
        raise ValueError(f"unknown kernel entry point(s) {unknown}; known: {sorted(ENTRIES)}")
    return [(tuple(effects), entry) for effects in effect_sets for entry in entries]


def _short(name: str, width: int = 100) -> str:
    """An effect's name for a log line: a long generated one (the library's every term, the
    shapes' probe: hundreds of characters) cut after ``width`` characters, with its count of
    terms or groups."""
    if len(name) <= width:
        return name
    return f"{name[:width]}... ({name.count('+') + 1} terms or groups)"


def precompile(
    wanted: Iterable[tuple[tuple[Effect, ...], str]],
    processes: int | None = None,
    log: Callable[[str], None] | None = None,
) -> int:
    """Compile the (effects, entry point) kernels of ``wanted`` (:func:`tasks`) that are not in
    the cache, ``processes`` at a time (default: one per CPU); returns how many were compiled.
    Effects travel by name (:func:`mmg.get_effect` rebuilds catalog and discovered ones in the
    workers)."""
    # by the effects whose kernel runs (a held effect runs the kernel of the effect it holds)
    # (the effects travel by their own names: a kernel's effect, e.g. a boxed one, has none
    # that mmg.get_effect reads)
    kernel_of: dict[tuple[tuple[str, ...], str], tuple[tuple[str, ...], str]] = {}
    for effects, entry in dict.fromkeys(wanted):
        if not is_compiled(effects, entry):
            names = tuple(e.name for e in effects)
            kernel_of.setdefault(
                (tuple(e.name for e in kernel_effects(effects)), entry), (names, entry)
            )
    missing = list(kernel_of.values())
    if not missing:
        return 0
    workers = max(1, min(len(missing), processes or os.cpu_count() or 1))
    if log is not None:
        log(
            f"compiling {len(missing)} simulator kernel entry point(s) not yet in the cache, "
            f"{workers} at a time (seconds to a minute each; first use only)"
        )
    t0 = time.perf_counter()
    done = 0
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        max_workers=workers,
        mp_context=context,
        initializer=exit_with_parent,
        initargs=(os.getpid(),),
    ) as pool:
        futures = {
            pool.submit(compile_entry, names, entry): (names, entry) for names, entry in missing
        }
        for future in as_completed(futures):
            names, entry = futures[future]
            future.result()  # a failure here would fail the same way in the run: say it now
            done += 1
            if log is not None:
                label = " + ".join(_short(n) for n in names) or "the base model"
                log(
                    f"compiled {entry} for {label} ({done}/{len(missing)}, "
                    f"{time.perf_counter() - t0:.0f} s)"
                )
    return done
