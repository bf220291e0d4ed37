"""What each part of the right-hand side costs in the objective's kernel, by leaving it out.

Usage: ``PYTHONPATH=. python benchmarks/kernel_parts.py [--rounds 6] [--size 19440]
[--parts moments wind ...]``

The machine has no hardware counters to attribute time to the lines of a vectorised loop, so this
measures the other way round: for each part it writes a copy of the generated kernel (the same
source :func:`mmg.kernel.render` gives, in a temporary directory) with that part replaced by a
trivial stand-in, compiles it, and times ``moments_lanes`` (through
:func:`mmg.integrate.segment_moments`, 20 candidates x B / 20 segments of 1,000 steps) against the
unchanged copy, alternating the two in one process for ``--rounds`` rounds. It prints the median
ratio of the rates and the share of the kernel's time that the part accounts for (1 - 1 / ratio).
The shares need not add up: the out-of-order core overlaps parts, and a stand-in changes the
trajectories (branches, limiter) a little.

A variant whose anchor text is missing from the rendered kernel (the template changed) is
reported and skipped. Each copy takes about half a minute to compile.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path
from types import ModuleType

import mmg.integrate
from benchmarks.peak_fraction import moments_workload
from mmg import efd_parameters
from mmg._generated import load_module
from mmg.integrate import segment_moments
from mmg.kernel import render

STEPS = 1000

_RHS_DEF = '\n\n@numba.njit(inline="always", **JIT_OPTIONS)\ndef rhs('
#: helpers a variant may call in place of :func:`mmg.model.hydrodynamic_forces`
_HELPERS = """
from mmg.hull import hull_forces
from mmg.propeller import advance_ratio, propeller_forces, wake_factor
from mmg.rudder import rudder_forces, rudder_inflow


@numba.njit(inline="always", **JIT_OPTIONS)
def hydro_without_hull(u, v_m, r, sin_delta, cos_delta, n_p, th, sh):
    one_minus_w = wake_factor(u, v_m, r, th, sh)
    J_s = advance_ratio(u, n_p, sh)
    X_P, Y_P, N_P, K_T = propeller_forces(u, n_p, J_s, one_minus_w, th, sh)
    u_R, v_R = rudder_inflow(u, v_m, r, n_p, one_minus_w, K_T, th, sh)
    X_R, Y_R, N_R = rudder_forces(u_R, v_R, sin_delta, cos_delta, th, sh)
    return -1e6 * u, -1e6 * v_m, -1e8 * r, X_P, Y_P, N_P, X_R, Y_R, N_R


@numba.njit(inline="always", **JIT_OPTIONS)
def hydro_without_propeller_rudder(u, v_m, r, sin_delta, cos_delta, n_p, th, sh):
    X_H, Y_H, N_H = hull_forces(u, v_m, r, th, sh)
    return X_H, Y_H, N_H, 1e5 * n_p, 0.0, 0.0, 1e5 * sin_delta, 1e5 * cos_delta, 0.0

"""
_HYDRO = "    F = hydrodynamic_forces(u_w, v_w, r, sin_d, cos_d, n_p, th, sh)\n"
_WIND = (
    "    X_A, Y_A, N_A = aerodynamic_forces(u, v_m, sin_psi, cos_psi, U_T, sin_g, cos_g, th, sh)\n"
)

#: part -> (what replaces it, [(anchor, replacement), ...])
VARIANTS: dict[str, tuple[str, list[tuple[str, str]]]] = {
    "hydrodynamics": (
        "hull, propeller and rudder forces -> linear damping",
        [(_HYDRO, "    F = (-1e6 * u_w, -1e6 * v_w, -1e8 * r, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)\n")],
    ),
    "hull": (
        "hull forces (Eq. (4)) -> linear damping",
        [
            (_RHS_DEF, _HELPERS + _RHS_DEF),
            (_HYDRO, _HYDRO.replace("hydrodynamic_forces", "hydro_without_hull")),
        ],
    ),
    "propeller+rudder": (
        "propeller and rudder forces (Eqs. (5)-(26)) -> constants",
        [
            (_RHS_DEF, _HELPERS + _RHS_DEF),
            (_HYDRO, _HYDRO.replace("hydrodynamic_forces", "hydro_without_propeller_rudder")),
        ],
    ),
    "wind": (
        "wind forces (Eqs. (27)-(28)) -> zero",
        [(_WIND, "    X_A, Y_A, N_A = 0.0 * U_T, 0.0 * sin_g, 0.0 * cos_g\n")],
    ),
    "heading sin/cos": (
        "sincos(psi) in the right-hand side -> (psi, 1 - psi)",
        [
            (
                "    sin_psi, cos_psi = sincos(psi)\n    F = hydro",
                "    sin_psi, cos_psi = psi, 1.0 - psi\n    F = hydro",
            )
        ],
    ),
    "limiter flags": (
        "the per-step check for clipped or non-finite lanes -> none",
        [
            (
                "        bad[i] = k if ((not ok) and bad[i] < 0) else bad[i]",
                "        bad[i] = bad[i]",
            )
        ],
    ),
    "moments": (
        "accumulating the moments of the observables -> none",
        [
            (
                "                for q in range(7):\n                    for i in range(wp):\n"
                "                        z = Z[q, i]",
                "                for q in range(0):\n                    for i in range(wp):\n"
                "                        z = Z[q, i]",
            )
        ],
    ),
}


def variant_source(base: str, part: str) -> str | None:
    """The kernel source without ``part``, or None if an anchor is missing."""
    source = base
    for anchor, replacement in VARIANTS[part][1]:
        if anchor not in source:
            return None
        source = source.replace(anchor, replacement, 1)
    return source


class Workload:
    """Segments and candidates of the moments benchmark (:func:`peak_fraction.moments_workload`)."""

    def __init__(self, B: int) -> None:
        self.segments, self.candidates = moments_workload(B, STEPS)
        self.lane_steps = self.candidates.shape[0] * self.segments.x0.shape[0] * STEPS

    def rate(self, module: ModuleType) -> float:
        """Trajectory-steps/s of ``module``'s moments kernel (the objective's code path)."""
        mmg.integrate.load_kernel = lambda effects=(), rhs_override=None: module
        t0 = time.perf_counter()
        segment_moments(self.segments, self.candidates)
        return self.lane_steps / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=6, help="alternating A/B rounds per part")
    ap.add_argument("--size", type=int, default=19440, help="lanes B (candidates x segments)")
    ap.add_argument("--parts", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    args = ap.parse_args(argv)

    efd_parameters()
    work = Workload(args.size)
    base = render().replace("{key}", "kernel_parts")
    with tempfile.TemporaryDirectory(prefix="mmg-kernel-parts-") as tmp:
        path = Path(tmp) / "kernel_base.py"
        path.write_text(base)
        t0 = time.perf_counter()
        reference = load_module(path, "kernel_parts_base")
        work.rate(reference)  # compile
        print(f"unchanged kernel compiled in {time.perf_counter() - t0:.0f} s")
        print(f"B = {args.size}, {STEPS} steps, {args.rounds} alternating rounds per part")
        print(f"{'part left out':>18} {'ratio':>6} {'range':>11} {'share':>6}  stand-in")
        for q, part in enumerate(args.parts):
            source = variant_source(base, part)
            if source is None:
                print(f"{part:>18}  skipped: the kernel template changed (anchor not found)")
                continue
            path = Path(tmp) / f"kernel_part{q}.py"
            path.write_text(source)
            module = load_module(path, f"kernel_parts_{q}")
            work.rate(module)  # compile
            ratios = []
            for r in range(args.rounds):
                pair = (reference, module) if r % 2 == 0 else (module, reference)
                rates = {id(m): work.rate(m) for m in pair}
                ratios.append(rates[id(module)] / rates[id(reference)])
            ratio = statistics.median(ratios)
            print(
                f"{part:>18} {ratio:>6.3f} {min(ratios):>5.2f}-{max(ratios):<5.2f} "
                f"{1.0 - 1.0 / ratio:>6.1%}  {VARIANTS[part][0]}"
            )


if __name__ == "__main__":
    main()
