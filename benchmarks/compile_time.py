"""How long the simulator's kernels take to compile, in one process, on an empty cache.

Usage: ``python benchmarks/compile_time.py [EFFECTS ...] [--entries simulate moments derivatives]``

Each EFFECTS argument is one kernel: comma-separated effect names (``-`` for the base model);
the default is the base model and two catalog effects (``- propeller_walk rudder_offset``).
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
        print(f"{'kernel':32s} {'entry':14s} {'seconds':>8s}")
        for spec in args.kernels:
            names = tuple(n for n in spec.split(",") if n and n != "-")
            for entry in args.entries:
                seconds = compile_entry(names, entry)
                total += seconds
                print(f"{spec:32s} {entry:14s} {seconds:8.1f}", flush=True)
        print(f"{'total':47s} {total:8.1f}  (wall {time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
