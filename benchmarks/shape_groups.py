"""Each group of the learned shapes alone, at a diagnosed planted case's base: why a shape was, or
was not, proposed.

The shapes' selection (:mod:`sweep.diagnose.shapes`) enters a group while it raises the held-out
gain and lowers the linearised in-sample dBIC. This prints, for the case's base model (the
stages of its diagnosis, resumed), the control fold fits' drift (their J on the other fold's
windows over the base's), the selection, and the best groups alone: their held-out gain as a
share of the control's held-out J, and the in-sample share of J, effective degrees of freedom
and dBIC of each at the smoothing the held-out gain chose. ``--prior-weights`` repeats it with
the fold fits' prior at other weights (the diagnosis uses ``DiagnoseSettings.prior_weight``):

    PYTHONPATH=. python benchmarks/shape_groups.py CASE_DIR [--prior-weights 1,10,100] [--top 8]

CASE_DIR is a case of ``benchmarks/diagnose_planted.py --out DIR`` whose diagnosis has run
(``DIR/case-NNN-R``). Figures from it are development figures.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from threadpoolctl import threadpool_limits

from benchmarks.refit_forms import open_case
from sweep.diagnose.base import identify_base, second_start
from sweep.diagnose.calibration import calibrate
from sweep.diagnose.context import stderr_log
from sweep.diagnose.shapes import ShapeColumns, candidate_groups, insample_share
from sweep.diagnose.shaping import default_variables


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path, help="a case directory of benchmarks/diagnose_planted.py")
    ap.add_argument(
        "--prior-weights",
        default=None,
        help="comma-separated prior weights of the fold fits (default: the diagnosis' own)",
    )
    ap.add_argument("--top", type=int, default=8, help="groups shown per prior weight")
    args = ap.parse_args(argv)
    opened = open_case(args.case, stderr_log)
    if opened is None:
        return 2
    ctx = opened.ctx
    try:
        weights = (
            [float(w) for w in args.prior_weights.split(",")]
            if args.prior_weights
            else [ctx.settings.prior_weight]
        )
    except ValueError:
        print(f"error: --prior-weights {args.prior_weights!r}: not numbers", file=sys.stderr)
        return 2
    with threadpool_limits(limits=1, user_api="blas"):
        base = identify_base(ctx)
        base, cal, _ = second_start(ctx, base, calibrate(ctx, base.params))
        groups = candidate_groups(ctx.windows, base.params, variables=default_variables(ctx))
        r = cal.lin.residuals(ctx.windows)
        n = ctx.n_eff
        print(f"{args.case.name} ({opened.spec.form}): base training J {base.f:.4g}, n_eff {n:g}")
        for w in weights:
            lin = cal.lin.with_prior(w)
            columns = ShapeColumns(lin, groups)
            drift = lin.refit_drift(r)
            sel = columns.select(r, n)
            print(
                f"prior weight {w:g}: the control's fold fits make the held-out windows' J "
                f"{drift.ratio:.2f} x the base's ({drift.window}: {100 * drift.share:.0f} % of "
                f"it); selection {sel.spec or 'no group'}, dBIC {sel.dbic:.1f}"
            )
            print(f"  {'held-out':>8}  {'in-sample':>9}  {'edf':>5}  {'dBIC':>6}  group (kappa)")
            for gain, group, kappa in columns.singles(r)[: args.top]:
                one = columns.restricted(r, n, [(group, kappa)])
                share = insample_share(one.dbic, one.edf, n)
                print(
                    f"  {100 * gain:7.1f}%  {100 * share:8.2f}%  {sum(one.edf):5.1f}  "
                    f"{one.dbic:6.1f}  "
                    f"{group.text} ({kappa:g})"
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
