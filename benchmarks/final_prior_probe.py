"""How the prior's weight in the re-identification moves the test J2 of planted cases.

For each case of a planted-benchmark directory (``benchmarks/diagnose_planted.py --out DIR``),
continue Levenberg-Marquardt (100 iterations) from the case's stored final model with the prior
toward the EFD values at each weight, and print the training J and the test J2 over the true
model's (and, where the verdict is a catalog effect, its parameter error).

    PYTHONPATH=. python benchmarks/final_prior_probe.py --out benchmarks/out/diag19 \
        --cases 17,18,15,33,20,35,26 --weights 1,0.1,0.01,0,10 [--stage final]

``--stage`` names the stored final stages to start from: ``final`` for procedure 9's
(``final-base.json``, ``final3-*.json``), ``final-w0.01`` for procedure 10's; ``--from-truth``
starts from the true model instead (no-effect cases: does the prior pull the truth away?).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

from benchmarks.planted import PlantedSpec, true_model
from mmg import Effect, Parameters, efd_parameters, get_effect
from mmg.params import N_THETA
from sweep.data.objective import Objective
from sweep.data.recordings import read_recordings
from sweep.diagnose.fit import FitSettings, fit
from sweep.diagnose.windows import cut_windows
from sweep.identification.polish import PolishSettings


def final_stage(stages: Path, prefix: str, effect: str) -> Path:
    """The stored final model of a case: the base's (``effect`` empty) or the effect's. A
    directory resumed across procedures holds the final stages of other proposals too, so the
    stage is the one whose parameters carry ``effect``."""
    if not effect:
        return stages / f"{prefix}-base.json"
    pattern = "final3-*.json" if prefix == "final" else f"{prefix}-3-*.json"
    for path in sorted(stages.glob(pattern)):
        if effect in json.loads(path.read_text())["params"]["effects"]:
            return path
    raise FileNotFoundError(f"no {pattern} stage with {effect} in {stages}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="a diagnose_planted.py output directory")
    ap.add_argument("--cases", required=True, help="comma-separated case numbers")
    ap.add_argument("--weights", default="1,0.1,0.01,0", help="comma-separated prior weights")
    ap.add_argument("--stage", default="final", help="final (procedure 9) or final-w0.01")
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--from-truth", action="store_true", help="start from the true model")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    root = Path(args.out)
    weights = [float(w) for w in args.weights.split(",")]
    for c in (int(x) for x in args.cases.split(",")):
        case = root / f"case-{c:02d}-0"
        res = json.loads((root / f"result-{c:02d}-0.json").read_text())
        verdict = res["verdict"]
        # the verdict's effect by name (get_effect rebuilds a discovered one from its terms)
        name = next(iter(res["after_effect_params"]), "")
        effects: tuple[Effect, ...] = (get_effect(name),) if name else ()
        stage = final_stage(case / "diagnosis" / "stages", args.stage, name)
        p0 = Parameters.from_dict(json.loads(stage.read_text())["params"])
        if args.from_truth:
            truth = json.loads((case / "truth.json").read_text())
            spec = PlantedSpec(**truth["spec"])
            p0, effects = true_model(Parameters.from_dict(truth["ship"]), spec)
        train = cut_windows(read_recordings(case / "train"))
        test = Objective(read_recordings(case / "test"), "J2", effects=effects)
        J_true = res["J2_test_true"]
        line = f"{c:>3} {res['form']:16s} stored {res['J2_test_after'] / J_true:.2f}x"
        for w in weights:
            t0 = time.perf_counter()
            lm = PolishSettings(
                max_iterations=args.iterations,
                rtol=1e-4,
                max_evaluations=10**7,
                prior_weight=w,
                prior_dims=N_THETA,
            )
            f = fit(
                train,
                p0,
                effects,
                FitSettings(budget=0, polish=lm),
                0,
                None,
                None,
                prior_center=efd_parameters(),
            )
            ratio = float(test.evaluate(f.params)[0]) / J_true
            errors = ""
            if verdict == res["family"] and res["param_errors"]:
                fitted = dict(next(v for n, v in f.params.effects if n == verdict))
                for k in res["param_errors"]:
                    if k.endswith("_candidate_fit"):
                        continue
                    true_v = res["values"][k] if k in res["values"] else res["values"]["tau"]
                    errors += f" {k} {100 * abs(fitted[k] - true_v) / abs(true_v):.1f} %"
            seconds = time.perf_counter() - t0
            line += f" | w={w:g}: J {f.f:.3f}, test {ratio:.2f}x{errors} ({seconds:.0f} s)"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
