"""Discovery alone on planted windows, with the true ship as base (no identification): what the
noise floor says and which library terms the equation-level regression proposes, per form.

    python -m benchmarks.discover_probe [--null-draws 9] [--phi 0.6]

Twelve 100-s windows of the real runs (5 random, 3 turning, 2 zigzag, 2 berthing) simulated by a
perturbed ship with one unlisted form planted, AR(1) noise (``--phi``) at the real recordings'
levels. Prints the misfit ratio to the floor, the proposal and the null quantile, and the time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.diagnose_planted import KINDS, TRAIN, load_runs
from sweep.data.datasets import data_root
from sweep.diagnose.discover import DiscoverySettings, discover
from sweep.diagnose.floor import calibrated_noise, misfit_test, noise_floor
from sweep.diagnose.planted import PlantedSpec, generate, noise_levels, perturbed_ship, pick_windows
from sweep.diagnose.windows import cut_windows

FORMS = [
    ("none", {}),
    ("astern_crossflow", {"C_a": 0.2}),
    ("bank", {"C_b": 0.002, "y_b": 1.0, "W_b": 3.0}),
    ("wash_yaw", {"C_d": 2e-4}),
    ("earth_force", {"F_e": 0.03, "chi_e": 1.0}),
    ("wave_resistance", {"C_w": 0.3}),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--null-draws", type=int, default=9)
    ap.add_argument("--phi", type=float, default=0.6)
    args = ap.parse_args()
    runs = load_runs(data_root(None))
    levels = noise_levels([r for v in runs.values() for r in v])
    for form, vals in FORMS:
        rng = np.random.default_rng(5)
        ship = perturbed_ship(rng, 0.15)
        wins = pick_windows(runs, {k: TRAIN[k] for k in KINDS}, rng)
        recs, _ = generate(wins, ship, PlantedSpec(form, vals), levels, rng, phi=args.phi)
        windows = cut_windows(recs)
        t0 = time.perf_counter()
        noise = calibrated_noise(windows, ship, rng)
        m = misfit_test(noise_floor(ship, windows, noise, rng, 8))
        p = discover(ship, windows, noise, rng, DiscoverySettings(null_draws=args.null_draws))
        sel = p.selection
        print(
            f"{form:17s} misfit {m.ratio:6.2f} x floor (z {m.z:7.1f}) | "
            f"{' + '.join(sel.labels) or '-':28s} coef {[round(c, 4) for c in sel.coefficients]} "
            f"held-out R^2 {100 * sel.cv_r2:.2f} % vs null {100 * p.threshold:.2f} % -> "
            f"{'proposed' if p.proposed else 'not proposed'} ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )


if __name__ == "__main__":
    main()
