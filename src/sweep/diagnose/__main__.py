"""Find the physics a model leaves out: ``python -m sweep.diagnose``.

    python -m sweep.diagnose --params {efd|PATH.json} --train PATH [PATH ...] --test PATH [PATH ...]
                             --out DIR [--budget N] [--base-descent N] [--candidate-budget N]
                             [--final-budget N]
                             [--seed S] [--objective J2] [--candidates a,b,...]
                             [--prior-weight MU] [--outside held|off]
                             [--tracking-uri URI | --no-tracking] [--experiment NAME]

PATHs are CSV/Parquet recordings or directories of them, or one split name: ``--train R`` (or
TR, TZR) and ``--test paper`` read the paper's split below ``--data-dir`` / ``MMG_DATA_DIR``.
``--params`` is the starting point of the base identification (``--budget`` CMA-ES evaluations
then Levenberg-Marquardt, against up to ``--base-descent`` Levenberg-Marquardt iterations alone) and
the centre of the weak prior of every refinement (``--prior-weight``, 0 to switch it off).
A finding acts only in the box of states the training recordings reached: beyond it, it is held
at its boundary value (above the top speed its non-dimensional force; ``--outside held``, the
default) or switched off (``--outside off``).
Writes ``DIR/report.json``, ``DIR/report.md`` with its plots, ``DIR/params_before.json`` and
``DIR/params_after.json`` (loadable by ``python -m sweep.evaluate --params``), and one MLflow run
(default store: ./mlflow.db, experiment ``mmg-diagnose``). Stages are kept in ``DIR/stages``:
the same command resumes an interrupted run.
See :mod:`sweep.diagnose.run` for the procedure.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from itertools import pairwise
from pathlib import Path
from typing import Any

from mmg import catalog
from sweep.data.datasets import CONF_DIR, DataNotFoundError, SplitError, load_split
from sweep.data.parameters import load_parameters
from sweep.data.recordings import Recording, read_recordings
from sweep.diagnose.run import Diagnosis, diagnose_rounds, final_round, round_dir
from sweep.diagnose.settings import DiagnoseSettings
from sweep.errors import UserError, command_status


def _paths(values: Sequence[str], what: str) -> list[Path]:
    paths = [Path(v) for v in values]
    for p in paths:
        if not p.exists():
            raise UserError(f"{what}: {p}: no such file or directory")
    return paths


def _recordings(
    values: Sequence[str], what: str, group: str, data_dir: str | None
) -> tuple[list[Recording], list[str]]:
    """Recordings and their labels from paths, or from one split name of ``conf/<group>/``.

    A split name (``R``, ``TR``, ``TZR`` for training, ``paper`` for the test set) reads the
    split's files below the data directory and labels them as the split does (``Test-B-S``).
    """
    if len(values) == 1 and not Path(values[0]).exists() and values[0] in _split_names(group):
        try:
            recs = load_split(str(CONF_DIR / group / f"{values[0]}.yaml")).load(data_dir)
        except (DataNotFoundError, SplitError) as exc:
            raise UserError(f"{what} {values[0]}: {exc}") from None
        return list(recs.values()), list(recs)
    read = read_recordings(_paths(values, what))
    return read, [r.name for r in read]


def _split_names(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def _base_options(ap: argparse.ArgumentParser, d: DiagnoseSettings) -> None:
    """The options of the base's identification."""
    ap.add_argument("--budget", type=int, default=d.base_budget, help="base identification")
    ap.add_argument(
        "--base-descent",
        type=int,
        default=d.base_lm_iterations,
        help="Levenberg-Marquardt iterations of the base's second route, the descent alone from "
        "--params (0: CMA-ES route only)",
    )
    ap.add_argument(
        "--base-horizons",
        type=float,
        nargs="*",
        default=list(d.base_horizons),
        metavar="SECONDS",
        help="beside the base's second start, the descent from --params over the training "
        "windows cut to each of these horizons in turn, then over the windows (default "
        "%(default)s; none given: off)",
    )
    ap.add_argument(
        "--base-retry-agreement",
        type=float,
        default=d.base_retry_agreement,
        help="the base gets a second CMA-ES start and the descent over growing horizons unless "
        "its two routes ended within this share of each other's J (default %(default)s; 0: "
        "always); the descent over horizons replaces the base only when lower by more than this",
    )


def parse(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line's options (``argv`` None: ``sys.argv[1:]``)."""
    ap = argparse.ArgumentParser(
        prog="python -m sweep.diagnose", description=(__doc__ or "").splitlines()[0]
    )
    d = DiagnoseSettings()
    ap.add_argument("--params", required=True, help="'efd' or a parameter JSON file")
    ap.add_argument(
        "--train",
        nargs="+",
        required=True,
        help="training recordings (files/dirs), or a training split: "
        + ", ".join(_split_names("train")),
    )
    ap.add_argument(
        "--test",
        nargs="+",
        default=[],
        help="test recordings (files/dirs), or a test split: " + ", ".join(_split_names("test")),
    )
    ap.add_argument("--data-dir", default=None, help="recordings of split names (MMG_DATA_DIR)")
    ap.add_argument("--out", required=True, help="output directory")
    _base_options(ap, d)
    ap.add_argument("--candidate-budget", type=int, default=d.candidate_budget)
    ap.add_argument("--final-budget", type=int, default=d.final_budget)
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--objective", default=d.objective, choices=["J1", "J2", "J3"])
    ap.add_argument("--candidates", default="", help="comma-separated effect names (default all)")
    ap.add_argument("--min-improvement", type=float, default=d.min_improvement)
    ap.add_argument(
        "--shape-variables",
        default="",
        help="comma-separated variables the learned shapes may depend on, or 'all' (default: "
        "all when the training runs come from several sessions, else the ship's state and "
        "controls, without heading, position and time)",
    )
    ap.add_argument(
        "--no-shapes",
        action="store_true",
        help="do not learn the shape of the missing force as a candidate",
    )
    ap.add_argument(
        "--shape-pairs",
        action="store_true",
        help="shapes of two variables (interactions of the first chosen group's variable with "
        "each other one) among the learned shapes' candidates; off by default: a surface "
        "learnt where the training runs went can make other manoeuvres far worse",
    )
    ap.add_argument(
        "--exact-starts",
        action="store_true",
        help="where the windows begin at exact states (a simulation's start, as planted data "
        "may), the noise-only copies behind the floor and the acceptance nulls begin exactly "
        "too; off by default: the diagnosis' rules were set with copies that begin noisy (the "
        "test recordings' null begins as the windows do either way)",
    )
    ap.add_argument(
        "--rounds",
        type=int,
        default=d.rounds,
        help="diagnoses in all: while a finding leaves the training windows above the noise "
        "floor, the next round diagnoses the model with it, held at its values, in "
        "DIR/round-K (default %(default)s: one diagnosis)",
    )
    ap.add_argument(
        "--outside",
        choices=("held", "off"),
        default=d.outside,
        help="what a finding does beyond the states of the training recordings: held at its "
        "value on the boundary of their box, above the top speed its non-dimensional force "
        "(default), or switched off",
    )
    ap.add_argument(
        "--prior-weight",
        type=float,
        default=d.prior_weight,
        help="weight of the prior toward --params (J per squared normalised coordinate)",
    )
    ap.add_argument(
        "--final-prior-weight",
        type=float,
        default=d.final_prior_weight,
        help="... in the re-identification on all training windows",
    )
    ap.add_argument("--max-delta-bic", type=float, default=d.max_delta_bic)
    ap.add_argument(
        "--take",
        default=d.take,
        metavar="EFFECT",
        help="re-identify with this candidate whatever the verdict (its name in the ranking, "
        "'best' or 'shape'), to see what it does on the test recordings; the report says it "
        "was taken, and whether it was accepted",
    )
    ap.add_argument(
        "--no-discovery",
        action="store_true",
        help="do not propose terms from the library (catalog candidates only)",
    )
    ap.add_argument(
        "--discover-terms",
        type=int,
        default=d.discover_terms,
        help="most library terms in a discovered effect",
    )
    ap.add_argument(
        "--alpha",
        type=float,
        default=d.alpha,
        help="false-alarm rate of the discovery's proposal (null quantile 1 - alpha)",
    )
    ap.add_argument("--tracking-uri", default=None, help="MLflow store (default ./mlflow.db)")
    ap.add_argument("--experiment", default="mmg-diagnose")
    ap.add_argument("--no-tracking", action="store_true", help="do not log an MLflow run")
    return ap.parse_args(argv)


def _checked(args: argparse.Namespace) -> tuple[str, ...]:
    """The ``--candidates`` names, after checking every option a user can get wrong; raises
    :class:`~sweep.errors.UserError`."""
    known = catalog()
    names = tuple(n.strip() for n in args.candidates.split(",") if n.strip())
    unknown = [n for n in names if n not in known]
    if unknown:
        raise UserError(f"--candidates: unknown effect(s) {unknown}; known: {sorted(known)}")
    for flag, value in (
        ("--budget", args.budget),
        ("--candidate-budget", args.candidate_budget),
        ("--final-budget", args.final_budget),
    ):
        if value != 0 and value < 20:
            raise UserError(
                f"{flag} must be 0 (refinement only) or at least 20 evaluations (one generation)"
            )
    if args.rounds < 1:
        raise UserError(f"--rounds must be >= 1; got {args.rounds}")
    if args.discover_terms < 1:
        raise UserError(f"--discover-terms must be >= 1; got {args.discover_terms}")
    if not 0.0 < args.alpha < 1.0:
        raise UserError(f"--alpha must be between 0 and 1; got {args.alpha}")
    if args.base_descent < 0:
        raise UserError(f"--base-descent must be >= 0 iterations; got {args.base_descent}")
    horizons = args.base_horizons
    if any(not (h > 0.0 and math.isfinite(h)) for h in horizons):
        raise UserError(f"--base-horizons must be positive seconds; got {horizons}")
    if any(b <= a for a, b in pairwise(horizons)):
        raise UserError(f"--base-horizons must grow, shortest first; got {horizons}")
    if not args.base_retry_agreement >= 0.0:
        raise UserError(f"--base-retry-agreement must be >= 0; got {args.base_retry_agreement}")
    if not args.prior_weight >= 0.0:
        raise UserError(f"--prior-weight must be >= 0; got {args.prior_weight}")
    if not args.final_prior_weight >= 0.0:
        raise UserError(f"--final-prior-weight must be >= 0; got {args.final_prior_weight}")
    return names


def run(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Read the recordings and parameters the command line names, diagnose, write the report;
    returns the report's JSON object. User mistakes raise :class:`~sweep.errors.UserError`."""
    args = parse(argv)
    names = _checked(args)
    start = load_parameters(args.params)
    train, _ = _recordings(args.train, "--train", "train", args.data_dir)
    test: list[Recording] = []
    labels: list[str] = []
    if args.test:
        test, labels = _recordings(args.test, "--test", "test", args.data_dir)
    settings = DiagnoseSettings(
        objective=args.objective,
        base_budget=args.budget,
        base_lm_iterations=args.base_descent,
        base_retry_agreement=args.base_retry_agreement,
        base_horizons=tuple(float(h) for h in args.base_horizons),
        candidate_budget=args.candidate_budget,
        final_budget=args.final_budget,
        seed=args.seed,
        candidates=names,
        min_improvement=args.min_improvement,
        outside=args.outside,
        shapes=not args.no_shapes,
        shape_pairs=args.shape_pairs,
        exact_starts=args.exact_starts,
        rounds=args.rounds,
        shape_variables=_shape_variables(args.shape_variables),
        max_delta_bic=args.max_delta_bic,
        take=args.take.strip(),
        prior_weight=args.prior_weight,
        final_prior_weight=args.final_prior_weight,
        discover=not args.no_discovery,
        discover_terms=args.discover_terms,
        alpha=args.alpha,
    )
    out = Path(args.out)
    try:
        rounds = diagnose_rounds(start, train, test, out, settings, test_labels=labels)
    except ValueError as exc:  # too little data, recordings of different steps
        raise UserError(str(exc)) from None
    from sweep.diagnose.report import write_report

    report: dict[str, Any] = {}
    for k, r in enumerate(rounds, start=1):
        where = round_dir(out, k)
        written = write_report(r, test, where, rounds)
        report = report or written
        print(("" if len(rounds) == 1 else f"round {k}: ") + str(written["statement"]))
        print(f"report: {where / 'report.md'}")
    if len(rounds) > 1:
        final = round_dir(out, rounds.index(final_round(rounds)) + 1)
        print(f"final model: {final / 'params_after.json'}")
    if not args.no_tracking:
        _track(args, rounds, report, out)
    return report


def _track(
    args: argparse.Namespace, rounds: Sequence[Diagnosis], report: dict[str, Any], out: Path
) -> None:
    """One MLflow run of the diagnosis: the first round's candidates, harm, misfit and test
    tables, and the final model's test table."""
    from sweep.service.tracking import MlflowTracker, default_tracking_uri, metric_part

    result = rounds[0]
    uri = args.tracking_uri or default_tracking_uri()

    def key(effect: str) -> str:
        """A candidate's part of a metric name: its name as MLflow takes it (each candidate its
        own metric, :func:`~sweep.service.tracking.metric_part`)."""
        return metric_part(effect, limit=200)

    metrics = {f"improvement/{key(c.effect)}": c.improvement for c in result.candidates}
    metrics.update(
        {
            f"delta_bic/{key(c.effect)}": c.delta_bic
            for c in result.candidates
            if c.delta_bic == c.delta_bic and abs(c.delta_bic) < float("inf")
        }
    )
    metrics.update({f"heldout_gain/{key(c.effect)}": c.heldout_gain for c in result.candidates})
    harm = report.get("harm")
    if harm:
        metrics["harm/harmful"] = float(harm["harmful"])
        metrics["harm/harmed_subsets"] = float(len(harm["harmed_subsets"]))
        metrics["harm/total_change"] = harm["total_change"]
    metrics["departures"] = float(len({d.recording for d in result.departures}))
    metrics["rounds"] = float(len(rounds))
    for J, row in final_round(rounds).test_after.items():  # the final model's
        for label, value in row.items():
            metrics[f"final_test_after/{J}/{metric_part(label)}"[:250]] = value
    if result.misfit is not None:
        metrics["misfit/ratio_to_floor"] = result.misfit.ratio
        metrics["misfit/z"] = result.misfit.z
    if result.generalisation is not None:
        metrics["generalisation/ratio_to_median"] = result.generalisation.ratio
        metrics["generalisation/significant"] = float(result.generalisation.significant)
    for when, table in (("before", result.test_before), ("after", result.test_after)):
        for J, row in table.items():
            for label, value in row.items():
                metrics[f"test_{when}/{J}/{metric_part(label)}"[:250]] = value
    params = {k: v for k, v in vars(args).items() if k not in ("train", "test")}
    params["train"] = " ".join(args.train)
    params["test"] = " ".join(args.test)
    rid = MlflowTracker(uri, args.experiment).log_diagnosis(
        f"diagnose-{out.name}", params, metrics, {"verdict": result.verdict}, out
    )
    print(f"MLflow run {rid} in {uri} (experiment {args.experiment})")


def _shape_variables(text: str) -> tuple[str, ...]:
    """The ``--shape-variables`` list: names of the shape variables, ``all``, or empty."""
    from sweep.diagnose.shapes import VARIABLES

    if not text.strip():
        return ()
    if text.strip() == "all":
        return VARIABLES
    names = tuple(v.strip() for v in text.split(",") if v.strip())
    unknown = [v for v in names if v not in VARIABLES]
    if unknown:
        raise UserError(
            f"--shape-variables: unknown {', '.join(unknown)}; known: {', '.join(VARIABLES)}, all"
        )
    return names


def main(argv: Sequence[str] | None = None) -> int:
    """The command: exit status 0, or 2 with one line on stderr for a user mistake."""
    return command_status(run, argv)


if __name__ == "__main__":
    sys.exit(main())
