"""The manoeuvre tables and figures of the documentation, and the time they take.

Usage::

    python benchmarks/manoeuvres.py --docs docs/manoeuvres [--samples NAME=S.npy ...]
    NUMBA_NUM_THREADS=1 python benchmarks/manoeuvres.py --time [--samples-count 50]

``--docs DIR`` writes, for the EFD parameters and the shipped model (results/best_params.json),
the standard manoeuvres and every recorded turning and zigzag run of the data set against the
model: ``DIR/tables.md`` (included by docs/guide/manoeuvres.md) and ``DIR/<name>.png``. The
shipped model's intervals come from 50 draws (``--seed``, 0) of its own uncertainty on the
training set and with the objective its metadata names (Train-R, J1), as
``python -m sweep.evaluate --params results/best_params.json --manoeuvres --intervals`` draws
them; the EFD parameters were not identified and have no such uncertainty: point values.
``--samples NAME=S.npy`` gives a model samples from a file instead (vectors (S, n)).

``--time`` prints the wall time of all manoeuvres of one model (the standard ones and the test
set's Test-T and Test-Z) with S parameter samples, median of three after one warm-up call. The
samples of the timing are 3 % Gaussian perturbations of the shipped model: a stand-in for the
uncertainty module's draws, used for the timing only (the time does not depend on the values).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numba
import numpy as np

from mmg.params import Parameters, efd_parameters
from sweep.data.datasets import data_root, load_split
from sweep.data.manoeuvre_figures import plot_manoeuvres
from sweep.data.manoeuvre_tables import (
    recorded_markdown,
    recorded_table,
    settings_note,
    standard_markdown,
    standard_table,
)
from sweep.data.recordings import read_recording
from sweep.data.standard_manoeuvres import (
    RecordedRun,
    compare_recorded,
    find_manoeuvre,
    predict_standard,
)
from sweep.evaluate import interval_samples

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "results" / "best_params.json"
#: the recorded turning and zigzag runs, labelled by their role in the paper's split
RUNS = {
    "Test-T": "data/turning/turn_14-Sep-2020_14_50_41.csv",
    "Test-Z": "data/zigzag/zigzag_31-Jul-2020_14_10_05.csv",
    "T 15_58_08 (Train-TR)": "data/turning/turn_cut_14-Sep-2020_15_58_08.csv",
    "T 16_09_02 (Train-TR, TZR)": "data/turning/turn_cut_14-Sep-2020_16_09_02.csv",
    "Z 13_22_52 (Train-TZR)": "data/zigzag/zigzag_31-Jul-2020_13_22_52.csv",
    "Z 13_50_28 (Train-TZR)": "data/zigzag/zigzag_31-Jul-2020_13_50_28.csv",
}


def recorded_runs() -> list[RecordedRun]:
    """Every recorded turning and zigzag run of :data:`RUNS`."""
    base = data_root()
    found = [find_manoeuvre(read_recording(base / rel), label) for label, rel in RUNS.items()]
    return [r for r in found if r is not None]


def write_docs(out: Path, samples: dict[str, np.ndarray], seed: int = 0, draws: int = 50) -> None:
    """The tables (``out/tables.md``) and figures (``out/<name>.png``) of EFD and the shipped
    model (its samples drawn from its own intervals unless ``samples`` has them)."""
    out.mkdir(parents=True, exist_ok=True)
    models = {"EFD": efd_parameters(), "shipped": Parameters.load_json(SHIPPED)}
    runs = recorded_runs()
    standard, recorded, notes = {}, {}, []
    if "shipped" not in samples:
        samples["shipped"], source = interval_samples(
            models["shipped"], str(SHIPPED), "", None, draws, seed
        )
        notes.append(f"shipped: {source}")
    notes.append("EFD: point values: the EFD parameters were not identified on recordings and")
    notes[-1] += " have no identification uncertainty."
    for name, params in models.items():
        s = samples.get(name.lower())
        pred = predict_standard(params, s)
        comparisons = compare_recorded(params, runs, s)
        standard[name] = standard_table(pred)
        recorded[name] = recorded_table(comparisons)
        notes.append(f"{name}: {settings_note(pred)}")
        title = f"{name} model: predicted manoeuvres and the recorded runs"
        plot_manoeuvres(pred, comparisons, out / f"{name.lower()}.png", title=title)
    text = [
        "<!-- written by `python benchmarks/manoeuvres.py --docs docs/manoeuvres` -->",
        "",
        "**Standard manoeuvres, full scale.**",
        "",
        standard_markdown(standard),
        "",
        *(f"- {n}" for n in notes),
        "",
        "**The recorded turning and zigzag runs against the models, model scale.**",
        "",
        recorded_markdown(recorded),
        "",
    ]
    (out / "tables.md").write_text("\n".join(text))
    print(f"wrote {out / 'tables.md'} and the figures of {', '.join(models)}")


def time_all(count: int, repeat: int = 3) -> None:
    """Median wall time of the standard manoeuvres and the test set's Test-T and Test-Z of the
    shipped model with ``count`` samples."""
    params = Parameters.load_json(SHIPPED)
    v = params.vector()
    # timing only: a stand-in for the uncertainty module's samples (see the module docstring)
    stand_in = v + 0.03 * np.abs(v) * np.random.default_rng(0).standard_normal((count, v.size))
    test = load_split("paper").load()
    runs = [find_manoeuvre(test[k], k) for k in ("Test-T", "Test-Z")]
    known = [r for r in runs if r is not None]

    def once() -> float:
        t = time.perf_counter()
        predict_standard(params, stand_in)
        compare_recorded(params, known, stand_in)
        return time.perf_counter() - t

    once()  # loads the cached kernels
    times = [once() for _ in range(repeat)]
    print(
        f"all manoeuvres of one model, {count} samples + the estimate, "
        f"{numba.get_num_threads()} thread(s): {statistics.median(times):.2f} s "
        f"(runs: {', '.join(f'{t:.2f}' for t in times)})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--docs", type=Path, help="write the tables and figures into this directory")
    ap.add_argument("--samples", nargs="*", default=[], help="NAME=S.npy (NAME: efd, shipped)")
    ap.add_argument("--time", action="store_true", help="time all manoeuvres of one model")
    ap.add_argument("--samples-count", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0, help="--docs: seed of the shipped model's draws")
    args = ap.parse_args()
    samples = {}
    for spec in args.samples:
        name, _, path = spec.partition("=")
        samples[name.lower()] = np.load(path)
    if args.docs:
        write_docs(args.docs, samples, args.seed, args.samples_count)
    if args.time:
        time_all(args.samples_count)


if __name__ == "__main__":
    main()
