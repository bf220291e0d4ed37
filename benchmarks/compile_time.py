"""How long the simulator's kernels take to compile, in one process, on an empty cache.

Usage: ``python benchmarks/compile_time.py [EFFECTS ...] [--entries simulate moments derivatives]``

Each EFFECTS argument is one kernel: comma-separated effect names (``-`` for the base model;
commas inside a name's brackets belong to the name, e.g. a box ``walk@held(u=0:1,n_p=3:5)``);
the default is the base model and two catalog effects (``- propeller_walk rudder_offset``).
A kernel whose code an earlier one already compiled (the same effects held at other values,
in another box, a learned shape over other knot ranges) takes next to nothing.
The kernels are compiled one after the other in this process, as a diagnosis or a test worker
compiles them, into a fresh temporary kernel directory (``$MMG_KERNEL_DIR`` is set for this run
only, so nothing is loaded from an earlier cache). Prints the seconds per entry point and the
total. The first kernel pays for compiling the sub-models; later ones reuse them.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time


def split_names(spec: str) -> tuple[str, ...]:
    """The effect names of one EFFECTS argument: split at the commas outside brackets."""
    names, depth, part = [], 0, ""
    for ch in spec:
        depth += ch in "(["
        depth -= ch in ")]"
        if ch == "," and depth == 0:
            names.append(part)
            part = ""
        else:
            part += ch
    names.append(part)
    return tuple(n for n in names if n and n != "-")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("kernels", nargs="*", default=["-", "propeller_walk", "rudder_offset"])
    parser.add_argument(
        "--entries", nargs="+", default=["simulate", "moments", "derivatives"], metavar="ENTRY"
    )
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="mmg-compile-") as directory:
        os.environ["MMG_KERNEL_DIR"] = directory  # before mmg reads it
        from mmg.precompile import compile_entry, tasks

        try:
            tasks([], args.entries)  # checks the entry points' names
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        total = 0.0
        t0 = time.perf_counter()
        width = max(32, *(len(k) for k in args.kernels))
        print(f"{'kernel':{width}s} {'entry':14s} {'seconds':>8s}")
        for spec in args.kernels:
            names = split_names(spec)
            for entry in args.entries:
                seconds = compile_entry(names, entry)
                total += seconds
                print(f"{spec:{width}s} {entry:14s} {seconds:8.1f}", flush=True)
        wall = time.perf_counter() - t0
        print(f"{'total':{width + 15}s} {total:8.1f}  (wall {wall:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
