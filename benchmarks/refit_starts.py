"""How much a planted case's test figure depends on where its re-identification starts.

A diagnosis re-identifies the base with its finding on all training windows from three starts
and keeps the end of the lowest training J (:func:`sweep.diagnose.final.reidentify_with`). When
the training windows leave directions of the 57 parameters free, ends of almost the same
training J can predict the test recordings very differently. This refits a diagnosed case's
finding from every stored fold fit of it (the ``candidate-...-foldJ`` stages that hold it),
each three ways as the diagnosis does (the fold fit itself; the base with the fold fit's values
of the finding; the base re-identified without a finding, with those values), and prints each
end's training J and its test J2 over the true model's:

    PYTHONPATH=. python benchmarks/refit_starts.py CASE_DIR EFFECT

CASE_DIR is a case of ``benchmarks/diagnose_planted.py --out DIR``; EFFECT the finding's
registered name without its box (e.g. ``discovered:N_bt+Y_bt``). Figures from it are
development figures.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from benchmarks.refit_forms import open_case
from mmg import get_effect
from sweep.data.objective import Objective
from sweep.diagnose.final import final_prefix, finding_settings
from sweep.identification.vector import effect_values, with_effects


def _quiet(message: str) -> None:
    """The diagnosis' log, left out: only the table is printed."""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path, help="a case directory of benchmarks/diagnose_planted.py")
    ap.add_argument("effect", help="the finding's effect name, e.g. discovered:N_bt+Y_bt")
    args = ap.parse_args(argv)
    case: Path = args.case
    try:
        eff = (get_effect(args.effect),)
    except (KeyError, ValueError) as err:
        print(f"error: {args.effect}: {err}", file=sys.stderr)
        return 2
    opened = open_case(case, _quiet)
    if opened is None:
        return 2
    ctx, test, J_true = opened.ctx, opened.test, opened.J_true
    base = ctx.store.load("base", ())
    before = ctx.store.load(f"{final_prefix(ctx)}-base", ())
    if base is None or before is None:
        print(f"error: {case} has no stage base or {final_prefix(ctx)}-base", file=sys.stderr)
        return 2
    print(f"{case.name} ({opened.spec.form}): true model's test J2 {J_true:.4g}; {args.effect}")
    fold_stage = re.compile(r"^candidate-.*fold\d+$")
    stages = sorted(
        p.stem
        for p in (case / "diagnosis" / "stages").glob("candidate-*.json")
        if fold_stage.match(p.stem)
        and "-sessions-" not in p.stem
        and list(json.loads(p.read_text())["params"].get("effects", {})) == [args.effect]
    )
    if not stages:
        print(f"error: no fold fit of {args.effect} among {case}'s stages", file=sys.stderr)
        return 2
    settings = finding_settings(ctx)
    for name in stages:
        fold = ctx.store.load(name, eff)
        if fold is None:
            continue
        values = effect_values(fold.params, eff)
        starts = {
            "fold fit": fold.params,
            "base + its values": with_effects(base.params, eff, values),
            "re-identified base + its values": with_effects(before.params, eff, values),
        }
        for label, p0 in starts.items():
            end = ctx.refit(ctx.windows, p0, eff, settings, label)
            J = float(Objective(test, "J2", effects=eff).evaluate(end.params)[0])
            found = ", ".join(f"{v:.4g}" for v in effect_values(end.params, eff))
            print(
                f"  {name:<50} {label:<32} training J {end.f:8.4g}  test J2 {J:8.4g} "
                f"({J / J_true:5.2f} x)  finding {found}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
