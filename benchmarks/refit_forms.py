"""What a form could reach: the final model of a diagnosed planted case re-identified with a form
given by hand, judged on the case's test recordings against the true model.

A planted case counts as explained when the model with the finding reaches 1.5 x the true
model's test J2. When a case is not explained, is it the form of the finding, or could no form
do better from these training windows? This refits the case's base model re-identified without
a finding (the stage ``final-w<W>-base`` of its diagnosis) with each form in turn, the way the
diagnosis re-identifies a finding (the same settings, from the base, the form's parameters from
neutral), and prints its training J and its test J2 over the true model's:

    PYTHONPATH=. python benchmarks/refit_forms.py CASE_DIR FORM [FORM ...]

CASE_DIR is a case of ``benchmarks/diagnose_planted.py --out DIR`` (``DIR/case-NNN-R``: its
``train``, ``test``, ``truth.json`` and ``diagnosis/stages``); a FORM is a registered effect's
name (a catalog effect, ``discovered:...``, ``shape:...``, with or without a closed form) or
``truth``: the planted form itself, started at its planted values, its search interval four
times their size (what the planted form reaches from these windows, refitted from this one
start: a finding re-identified from its own fold fits can reach further).
Figures from it are development figures: the forms are chosen by someone who knows the case.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from benchmarks.planted import PlantedSpec, true_model
from mmg import Effect, Parameters, efd_parameters, get_effect
from sweep.data.objective import Objective
from sweep.data.recordings import Recording, read_recordings
from sweep.diagnose.context import Context, stderr_log
from sweep.diagnose.final import final_prefix, finding_settings
from sweep.diagnose.fit import Fit
from sweep.diagnose.settings import DiagnoseSettings
from sweep.identification.vector import with_effects

#: the planted form itself, as a FORM argument
TRUTH = "truth"


def truth_form(spec: PlantedSpec, effects: tuple[Effect, ...]) -> tuple[Effect, ...]:
    """The planted effects with search intervals around their planted values (+-4 x their size,
    at least +-1): the planted forms' own intervals (+-1e9) leave the search no scale."""
    out = []
    for e in effects:
        params = []
        for p in e.params:
            v = abs(spec.values.get(p.name, p.neutral))
            params.append(p._replace(lower=min(-1.0, -4.0 * v), upper=max(1.0, 4.0 * v)))
        out.append(replace(e, params=tuple(params)))
    return tuple(out)


@dataclass(frozen=True)
class Case:
    """A diagnosed planted case opened for refits: the diagnosis' context on its stages, the
    planted form, the true model and its test J2."""

    ctx: Context
    spec: PlantedSpec
    test: list[Recording]
    true_params: Parameters
    true_effects: tuple[Effect, ...]
    J_true: float


def open_case(case: Path, log: Callable[[str], None]) -> Case | None:
    """The case directory ``case`` of ``benchmarks/diagnose_planted.py --out DIR`` opened with
    the diagnosis' default settings (``log``: its log); None, saying why on stderr, when a part
    is missing."""
    for part in ("train", "test", "truth.json", "diagnosis/stages"):
        if not (case / part).exists():
            print(f"error: {case / part} is missing: not a diagnosed planted case", file=sys.stderr)
            return None
    truth = json.loads((case / "truth.json").read_text())
    spec = PlantedSpec(**truth["spec"])
    train, test = read_recordings(case / "train"), read_recordings(case / "test")
    settings = DiagnoseSettings()
    ctx = Context.open(efd_parameters(), train, test, case / "diagnosis", settings, None, log)
    true_params, true_effects = true_model(Parameters.from_dict(truth["ship"]), spec)
    J_true = float(Objective(test, "J2", effects=true_effects).evaluate(true_params)[0])
    return Case(ctx, spec, test, true_params, true_effects, J_true)


def base_without_finding(case: Case) -> Fit | None:
    """The diagnosis' base re-identified without a finding (its stage ``final-wW-base``; None
    when the diagnosis did not get that far)."""
    return case.ctx.store.load(f"{final_prefix(case.ctx)}-base", ())


def refit_form(case: Case, before: Fit, name: str) -> tuple[float, float]:
    """(training J, test J2) of the case's base re-identified without a finding (``before``)
    refitted with the form ``name`` (a registered effect's name, or :data:`TRUTH`), the way the
    diagnosis re-identifies a finding. Raises KeyError or ValueError for an unknown name."""
    ctx, spec = case.ctx, case.spec
    if name == TRUTH:
        effects = truth_form(spec, case.true_effects)
        values = [v for _, vals in case.true_params.effects for _, v in vals]
        start = with_effects(before.params, effects, values or None)
    else:
        effects = (get_effect(name),)
        start = with_effects(before.params, effects)
    after = ctx.refit(ctx.windows, start, effects, finding_settings(ctx), name)
    J = float(Objective(case.test, "J2", effects=effects).evaluate(after.params)[0])
    return float(after.f), J


def planted_reach(case_dir: Path, log: Callable[[str], None]) -> dict[str, float] | None:
    """What the planted form itself reaches from a diagnosed case's training windows
    (:func:`refit_form` with :data:`TRUTH`; one refit from one start, not a strict bound on what
    a finding can reach): its training J, its test J2 and the true model's; None when a part of
    the case or its base re-identified without a finding is missing."""
    opened = open_case(case_dir, log)
    if opened is None:
        return None
    before = base_without_finding(opened)
    if before is None:
        return None
    J_train, J_test = refit_form(opened, before, TRUTH)
    return {"J_train": J_train, "J2_test": J_test, "J2_test_true": opened.J_true}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path, help="a case directory of benchmarks/diagnose_planted.py")
    ap.add_argument("forms", nargs="+", help=f"effect names, or {TRUTH!r}")
    args = ap.parse_args(argv)
    case: Path = args.case
    opened = open_case(case, stderr_log)
    if opened is None:
        return 2
    ctx, spec, test, J_true = opened.ctx, opened.spec, opened.test, opened.J_true
    before = base_without_finding(opened)
    if before is None:
        print(f"error: {case} has no stage {final_prefix(ctx)}-base", file=sys.stderr)
        return 2
    J_before = float(Objective(test, "J2").evaluate(before.params)[0])
    print(f"{case.name} ({spec.form}): true model's test J2 {J_true:.4g}")
    print(
        f"  {'base':<60} training J {before.f:8.4g}  test J2 {J_before:8.4g} "
        f"({J_before / J_true:.2f} x)"
    )
    for name in args.forms:
        try:
            J_train, J = refit_form(opened, before, name)
        except (KeyError, ValueError) as err:
            print(f"error: {name}: {err}", file=sys.stderr)
            return 2
        print(f"  {name:<60} training J {J_train:8.4g}  test J2 {J:8.4g} ({J / J_true:.2f} x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
