"""Planted-effect benchmark of the diagnosis: can it name a concealed effect, blind?

Every case simulates 100-s windows of the real runs (their first states, controls and wind) with a
"true" ship (EFD parameters perturbed by exp(N(0, 0.15)) each) and one planted effect, in the
catalog's form or in another one (see :mod:`benchmarks.planted`), at a realistic magnitude,
or none; adds white measurement noise at the levels of the real recordings; writes the windows as
CSV files, and runs :func:`sweep.diagnose.run.diagnose` on the files only (blind), starting from
the EFD parameters. Printed per case: planted form, verdict, held-out improvement of the top
candidates, recovered effect parameters; then per family the top-1 rate, the false-positive rate
on the no-effect cases, parameter errors, and the test-set J2 before / after / of the true model.

    python benchmarks/diagnose_planted.py [--set twin|unforeseen|all]
        [--cases all|quick|N,M,...|NAME,...] [--repeats R]
        [--base-budget 6000] [--candidate-budget 0] [--final-budget 0] [--base-retry-agreement 0.01]
        [--rounds 1]
        [--scale 1] [--out DIR] [--results FILE]
        [--weak] [--markdown]

Three sets, each reported in its own rows (``--set``, default ``twin``):

- ``twin``, the forms with a library twin (:data:`SPECS`, cases 0-35): catalog effects in their
  own and in other forms, forms outside the catalog that a library term expresses, a form in the
  paper's own form, and no-effect cases;
- ``unforeseen``, forms no library term or catalog effect expresses
  (:data:`benchmarks.planted.UNFORESEEN_CASES`, cases 100-152, named like ``seiche/strong``):
  each at a strong, a weak and a medium magnitude set by the rule of :mod:`benchmarks.planted`
  (the true ship without the effect at 8-12 x, 1.8-2.2 x and 3.5-5 x the true model's test J2),
  and no-effect cases with their own seeds in each magnitude's row;
- ``fresh``, six more forms no library term or catalog effect expresses
  (:data:`benchmarks.planted.FRESH_CASES`, cases 160-177, named like ``yaw_hinge/fresh_strong``),
  written after the method was tuned on the others and run once, at the strong and the medium
  magnitude, with two no-effect cases of their own in each row.

``--scale`` and ``--weak`` apply to the twin set.

Per row: cases **explained** (an accepted finding, the re-identified base's test J2 above 1.5 x
the true model's and the model with the finding within 1.5 x), **named** (the verdict names the
planted family; ``discovered`` or ``shape`` for a form outside the catalog), **flagged**
(``unexplained``), false alarms on the no-effect cases, and **harm** (:mod:`benchmarks.harm`):
accepted findings that make the test J2 worse by more than 5 % in total, and per test recording
by more than 10 % (and 5 %).

``--weak`` sets each case's magnitude (by bisection on the scale, same ship, windows and noise)
so that the effect raises the true ship's test J2 by only 20-35 % over the true model's, the
noise floor: the detection limit.

``--scale s`` plants every effect s times as strong (its strength parameters times s; the onset
angle of the tanh stall and of the piecewise a_H divided by s) in the same ships, windows and
noise: how the figures depend on the magnitude.

Results (one JSON per case) go to ``--out`` (default ``benchmarks/out/diagnose``); a case already
there is not run again, so an interrupted benchmark resumes. All of them, the rows and the command
that made them also go to ``--results`` (default
``benchmarks/results/diagnose_planted-SET[-weak].json``).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harm import Harm, finding_harm, total
from benchmarks.machine import machine
from benchmarks.planted import (
    FAMILY,
    FRESH_CASES,
    UNFORESEEN_CASES,
    PlantedSpec,
    expected_verdict,
    generate,
    noise_levels,
    perturbed_ship,
    pick_windows,
    true_model,
    unforeseen_spec,
    write_case,
)
from benchmarks.refit_forms import planted_reach
from mmg import Parameters, efd_parameters
from sweep.data.datasets import data_root
from sweep.data.objective import Objective
from sweep.data.recordings import Recording, read_recordings
from sweep.diagnose.context import stderr_log
from sweep.diagnose.run import diagnose_rounds, final_round
from sweep.diagnose.settings import DiagnoseSettings

KINDS = ("random", "turning", "zigzag", "berthing")
TRAIN = {"random": 5, "turning": 3, "zigzag": 2, "berthing": 2}
TEST = {"random": 2, "turning": 1, "zigzag": 1}

#: (form, values) of the planted effects: catalog forms and other forms, two magnitudes each
SPECS: list[PlantedSpec] = [
    PlantedSpec("none"),
    PlantedSpec("current", {"V_c": 0.015, "beta_c": 2.0}),
    PlantedSpec("current", {"V_c": 0.025, "beta_c": -1.0}),
    PlantedSpec("propeller_walk", {"C_Yw": 2e-4, "C_Nw": -1e-4}),
    PlantedSpec("walk_advance", {"C_Yw": 3e-4, "C_Nw": -1.5e-4, "J_0": 0.6}),
    PlantedSpec("rudder_stall", {"alpha_s": 0.35, "k_s": 0.8}),
    PlantedSpec("stall_tanh", {"alpha_s": 0.4}),
    PlantedSpec("a_h_drift", {"k_aH": -0.8}),
    PlantedSpec("a_h_piecewise", {"beta_0": math.radians(45.0)}),
    PlantedSpec("actuator_lag", {"T_delta": 1.5, "T_n": 0.0}),
    PlantedSpec("delay", {"tau": 1.0}),
    PlantedSpec("rudder_offset", {"delta_0": 0.035}),
    PlantedSpec("rudder_offset", {"delta_0": -0.026}),
    PlantedSpec("heading_bias", {"b_psi": 0.05, "b_v": 0.05}),
    PlantedSpec("heading_only", {"b_psi": 0.04}),
    PlantedSpec("none"),
    PlantedSpec("none"),
    PlantedSpec("none"),
    PlantedSpec("none"),
    PlantedSpec("none"),
    # forms in no catalog entry (only discovery explains them), two magnitudes each
    PlantedSpec("bank", {"C_b": 0.002, "y_b": 1.0, "W_b": 3.0}),
    PlantedSpec("bank", {"C_b": 0.005, "y_b": -2.0, "W_b": 4.0}),
    PlantedSpec("wave_resistance", {"C_w": 0.1}),
    PlantedSpec("wave_resistance", {"C_w": 0.3}),
    PlantedSpec("astern_crossflow", {"C_a": 0.05}),
    PlantedSpec("astern_crossflow", {"C_a": 0.2}),
    PlantedSpec("earth_force", {"F_e": 0.03, "chi_e": 1.0}),
    PlantedSpec("earth_force", {"F_e": 0.08, "chi_e": -2.0}),
    PlantedSpec("wash_yaw", {"C_d": 5e-5}),
    PlantedSpec("wash_yaw", {"C_d": 2e-4}),
    # ... and one that is in the paper's model's own form (planted.IN_FORM: Eqs. (12)-(13) with
    # shifted constants): nothing is missing, the right verdict is none
    PlantedSpec("reverse_sway", {"C_r": 1e-4}),
    PlantedSpec("reverse_sway", {"C_r": 3e-4}),
    PlantedSpec("none"),
    PlantedSpec("none"),
    # a form in time (a side force building up over the run), two magnitudes
    PlantedSpec("build_up", {"C_t": 1.5e-4, "tau_t": 600.0}),
    PlantedSpec("build_up", {"C_t": 3e-4, "tau_t": 300.0}),
]
#: cases whose measurement noise is coloured (AR(1), correlation between samples), the rest white
NOISE_PHI: dict[int, float] = {i: 0.6 for i in (21, 23, 25, 27, 29, 31, 32, 33, 35)}
#: parameters that set a planted effect's strength: ``--scale s`` multiplies them by s
STRENGTH: dict[str, tuple[str, ...]] = {
    "current": ("V_c",),
    "propeller_walk": ("C_Yw", "C_Nw"),
    "walk_advance": ("C_Yw", "C_Nw"),
    "rudder_stall": ("k_s",),
    "a_h_drift": ("k_aH",),
    "actuator_lag": ("T_delta", "T_n"),
    "delay": ("tau",),
    "rudder_offset": ("delta_0",),
    "heading_bias": ("b_psi", "b_v"),
    "heading_only": ("b_psi",),
    "bank": ("C_b",),
    "wave_resistance": ("C_w",),
    "astern_crossflow": ("C_a",),
    "earth_force": ("F_e",),
    "wash_yaw": ("C_d",),
    "reverse_sway": ("C_r",),
    "build_up": ("C_t",),
}
#: ... and, for the forms whose strength is the angle where the effect takes hold, that angle,
#: which ``--scale s`` divides by s (a weaker tanh stall saturates later)
ONSET: dict[str, tuple[str, ...]] = {"stall_tanh": ("alpha_s",), "a_h_piecewise": ("beta_0",)}


#: ``--weak``: each effect's magnitude is set so that it raises the test J2 of the true ship by
#: this much over the true model's (the noise floor): 20 to 35 %
WEAK = (0.20, 0.35)


def scaled(spec: PlantedSpec, scale: float) -> PlantedSpec:
    """``spec`` with its effect made ``scale`` times as strong (shape parameters unchanged)."""
    values = dict(spec.values)
    for name in STRENGTH.get(spec.form, ()):
        values[name] *= scale
    for name in ONSET.get(spec.form, ()):
        values[name] /= scale
    return PlantedSpec(spec.form, values)


#: parameters whose recovery is scored, per planted form (same form: same parameter)
RECOVERED = {
    "current": ("V_c",),
    "propeller_walk": ("C_Nw",),
    "rudder_stall": ("k_s",),
    "a_h_drift": ("k_aH",),
    "actuator_lag": ("T_delta",),
    "rudder_offset": ("delta_0",),
    "heading_bias": ("b_psi",),
    "heading_only": ("b_psi",),
    "delay": ("tau_delta", "tau_n"),  # the dead time of both controls
}


def load_runs(root: Path) -> dict[str, list[Recording]]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {k: read_recordings(root / "data" / k) for k in KINDS}


def planted_value(spec: PlantedSpec, name: str) -> float:
    if spec.form == "delay":
        return spec.values["tau"]
    return spec.values[name]


def make_case(
    index: int,
    spec: PlantedSpec,
    repeat: int,
    runs: dict[str, list[Recording]],
    noise: dict[str, float],
    phi: float | None = None,
) -> tuple[Parameters, list[Recording], list[Recording], bool]:
    """(true ship, training windows, test windows, diverged) of a case: the ship, the windows
    and the noise depend on (index, repeat) only, not on the planted magnitude. ``phi``: the
    noise's AR(1) correlation (None: the twin set's, :data:`NOISE_PHI`)."""
    seed = 1000 * repeat + index
    rng = np.random.default_rng(seed)
    ship = perturbed_ship(rng, 0.15)
    wins = pick_windows(runs, {k: TRAIN[k] + TEST.get(k, 0) for k in KINDS}, rng)
    phi = NOISE_PHI.get(index, 0.0) if phi is None else phi
    recs, diverged = generate(wins, ship, spec, noise, rng, phi=phi)
    # the first TEST[k] windows of each kind are the test set
    test: list[Recording] = []
    train: list[Recording] = []
    i = 0
    for k in KINDS:
        n = TRAIN[k] + TEST.get(k, 0)
        test += recs[i : i + TEST.get(k, 0)]
        train += recs[i + TEST.get(k, 0) : i + n]
        i += n
    return ship, train, test, diverged


def excess(
    index: int,
    spec: PlantedSpec,
    repeat: int,
    runs: dict[str, list[Recording]],
    noise: dict[str, float],
    phi: float | None = None,
) -> float:
    """How much the planted effect raises the test J2 over the noise floor: J2 of the true ship
    without the effect over J2 of the true model (ship and effect), both on the noisy test set."""
    ship, _, test, diverged = make_case(index, spec, repeat, runs, noise, phi)
    if diverged:
        return math.inf
    truth = true_model(ship, spec)
    J_true = float(Objective(test, "J2", effects=truth[1]).evaluate(truth[0])[0])
    J_without = float(Objective(test, "J2").evaluate(ship)[0])
    return J_without / J_true - 1.0


def weak_scale(
    index: int,
    spec: PlantedSpec,
    repeat: int,
    runs: dict[str, list[Recording]],
    noise: dict[str, float],
    target: tuple[float, float] = WEAK,
) -> tuple[float, float]:
    """(scale, excess): the magnitude scale that puts the case's excess test J2 inside
    ``target`` (bisection in log-scale; the excess grows with the magnitude)."""
    if spec.form == "none":
        return 1.0, 0.0
    return scale_to(lambda s: excess(index, scaled(spec, s), repeat, runs, noise), target)


def scale_to(
    excess_at: Callable[[float], float],
    target: tuple[float, float],
    lo: float = 1e-3,
    hi: float = 10.0,
    steps: int = 30,
) -> tuple[float, float]:
    """(scale, excess): bisection in log-scale from scale 1 within (lo, hi) until
    ``excess_at(scale)``, which grows with the scale, is inside ``target``."""
    mid = 0.5 * (target[0] + target[1])
    scale, e = 1.0, excess_at(1.0)
    for _ in range(steps):
        if target[0] <= e <= target[1]:
            break
        if e > mid:
            hi = scale
        else:
            lo = scale
        scale = math.sqrt(lo * hi)
        e = excess_at(scale)
    return scale, e


@dataclass(frozen=True)
class Case:
    """A case to run: its set (``twin`` or ``unforeseen``), index (its seed), name, planted
    form at magnitude scale 1, and for the unforeseen set its magnitude band and noise colour."""

    set: str
    index: int
    name: str
    spec: PlantedSpec
    band: tuple[float, float] | None = None  # None: the twin set (--scale, --weak)
    phi: float | None = None  # None: the twin set's NOISE_PHI

    @property
    def row(self) -> str:
        """The summary row the case counts in."""
        if self.set == "twin":
            return ROWS["twin"]
        label = self.name.split("/")[1].split("-")[0]
        return ROWS[self.set] + ", " + label.removeprefix("fresh_")


#: the rows of the summary
ROWS = {
    "twin": "forms with a library twin",
    "unforeseen": "forms no library term expresses",
    "fresh": "fresh forms no library term expresses",
}
#: the sets ``--set`` runs
SETS = ("twin", "unforeseen", "fresh", "all")


def all_cases(which: str) -> list[Case]:
    """The cases of a set (``all``: both)."""
    out: list[Case] = []
    if which in ("twin", "all"):
        out += [Case("twin", i, f"{i}:{spec.form}", spec) for i, spec in enumerate(SPECS)]
    if which in ("unforeseen", "all"):
        out += [
            Case("unforeseen", c.index, c.name, unforeseen_spec(c.form), c.band, c.phi)
            for c in UNFORESEEN_CASES
        ]
    if which in ("fresh", "all"):
        out += [
            Case("fresh", c.index, c.name, unforeseen_spec(c.form), c.band, c.phi)
            for c in FRESH_CASES
        ]
    return out


def select_cases(which: str, cases: str) -> list[Case]:
    """``--cases`` of ``--set``: all, quick (twin 0, 3, 5), or comma-separated indices or names
    of either set; an unknown one is a clear error."""
    if cases == "all":
        return all_cases(which)
    if cases == "quick":
        return [c for c in all_cases("twin") if c.index in (0, 3, 5)]
    known = all_cases("all")
    by_key = {str(c.index): c for c in known} | {c.name: c for c in known}
    wanted = [k.strip() for k in cases.split(",") if k.strip()]
    unknown = [k for k in wanted if k not in by_key]
    if unknown:
        names = ", ".join(c.name for c in known if c.set != "twin")
        raise SystemExit(
            f"unknown case(s) {', '.join(unknown)}: give indices 0-{len(SPECS) - 1} or "
            f"{UNFORESEEN_CASES[0].index}-{UNFORESEEN_CASES[-1].index}, "
            f"{FRESH_CASES[0].index}-{FRESH_CASES[-1].index}, or names: {names}"
        )
    return [by_key[k] for k in wanted]


def band_scale(
    case: Case, repeat: int, runs: dict[str, list[Recording]], noise: dict[str, float]
) -> tuple[float, float]:
    """(scale, excess) of an unforeseen case: its magnitude set to its band (the rule of
    :mod:`benchmarks.planted`) on its own ship, windows and noise."""
    if case.spec.form == "none" or case.band is None:
        return 1.0, 0.0
    form = case.spec.form
    return scale_to(
        lambda s: excess(case.index, unforeseen_spec(form, s), repeat, runs, noise, case.phi),
        case.band,
        lo=1e-4,
        hi=1e4,
        steps=40,
    )


#: families of the cases without an effect to explain (nothing planted; the paper's own form)
NO_EFFECT = ("none", "in_form")


def case_directory(out: Path, index: int, repeat: int) -> Path:
    """Where case ``index`` (repeat ``repeat``) keeps its recordings, truth and diagnosis."""
    return out / f"case-{index:02d}-{repeat}"


def run_case(
    index: int,
    spec: PlantedSpec,
    repeat: int,
    runs: dict[str, list[Recording]],
    noise: dict[str, float],
    settings: DiagnoseSettings,
    out: Path,
    phi: float | None = None,
) -> dict[str, Any]:
    ship, train, test, diverged = make_case(index, spec, repeat, runs, noise, phi)
    case_dir = case_directory(out, index, repeat)
    write_case(case_dir, train, test, spec, ship)
    blind_train = read_recordings(case_dir / "train")
    blind_test = read_recordings(case_dir / "test")
    t0 = time.perf_counter()
    rounds = diagnose_rounds(
        efd_parameters(), blind_train, blind_test, case_dir / "diagnosis", settings
    )
    seconds = time.perf_counter() - t0
    # the verdict and candidates are the first round's; the model after is the final one
    d, last = rounds[0], final_round(rounds)
    truth = true_model(ship, spec)
    J_true = float(Objective(blind_test, "J2", effects=truth[1]).evaluate(truth[0])[0])
    errors: dict[str, float] = {}
    if d.verdict == spec.family and spec.form in RECOVERED:
        chosen = d.chosen
        assert chosen is not None
        fitted = chosen.params
        after = d.finding_values()  # (the finding carries its box in its name after)
        for name in RECOVERED[spec.form]:
            true_v = planted_value(spec, name)
            errors[name] = abs(after[name] - true_v) / abs(true_v)
            errors[name + "_candidate_fit"] = abs(fitted[name] - true_v) / abs(true_v)
    return {
        "index": index,
        "repeat": repeat,
        "form": spec.form,
        "values": spec.values,
        "family": spec.family,
        "verdict": d.verdict,
        "correct": names_family(d.verdict, spec.family),
        "diverged_truth": diverged,
        "candidates": [asdict(c) for c in d.candidates],
        "after_effect_params": {n: dict(v) for n, v in last.after.params.effects},
        "param_errors": errors,
        "J2_test_before": d.test_before["J2"]["Total"],
        "J2_test_after": last.test_after["J2"]["Total"],
        # the finding acting beyond the box of the training states too (as found, unbounded)
        "J2_test_after_unbounded": (last.test_unbounded.get("J2") or last.test_after["J2"])[
            "Total"
        ],
        "J2_test_true": J_true,
        # per test recording, for the harm count
        "J2_test_before_table": d.test_before["J2"],
        "J2_test_after_table": last.test_after["J2"],
        "J2_base_fit": d.base.f,
        # the base's two routes' ends and the second start's (when it ran)
        "base_retry": d.extra.get("base_retry"),
        "misfit_ratio": d.misfit.ratio if d.misfit else None,
        "misfit_significant": d.misfit.significant if d.misfit else None,
        # the test recordings' J of the re-identified base over the null's median
        "generalisation_ratio": d.generalisation.ratio if d.generalisation else None,
        "generalisation_significant": d.generalisation.significant if d.generalisation else None,
        # ... over the null's 1 - alpha quantile (significant beyond 1 + margin), and whether
        # the null's copies began exactly, as the windows do
        "generalisation_over_quantile": (
            d.generalisation.J / d.generalisation.quantile if d.generalisation else None
        ),
        "generalisation_copies_exact": d.generalisation.copies_exact if d.generalisation else None,
        # the report says more is missing than the finding: the model after is still above the
        # floor on the training windows, or still significant on the test recordings
        "more_missing": bool(
            last.verdict_effect
            and (
                last.more_missing
                or bool(last.generalisation_after and last.generalisation_after.significant)
            )
        ),
        # each round's verdict, finding and test J2 after (the first round's J2 before)
        "rounds": [
            {
                "verdict": r.verdict,
                "finding": r.verdict_effect,
                "J2_train_after": float(r.after.f),
                "more_missing": r.more_missing,
                "J2_test_after": r.test_after["J2"]["Total"],
            }
            for r in rounds
        ],
        "proposed_terms": d.proposal.terms if d.proposal else [],
        "noise_phi": NOISE_PHI.get(index, 0.0) if phi is None else phi,
        "seconds": seconds,
    }


def _classified(r: dict[str, Any]) -> dict[str, Any]:
    """A result with its family and correctness from the current classification of its form
    (results stored before a form was reclassified, e.g. as ``in_form``, read the same)."""
    family = FAMILY[r["form"]]
    return {**r, "family": family, "correct": names_family(r["verdict"], family)}


def names_family(verdict: str, family: str) -> bool:
    """Whether ``verdict`` names the planted ``family``: its expected verdict, or, for a form
    outside the catalog (``discovered``), a learned shape too (a shape verdict did not exist
    before the shapes, so no earlier result changes its label)."""
    return verdict == expected_verdict(family) or (family == "discovered" and verdict == "shape")


#: a case is explained when the re-identified base's test J2 is above this many times the true
#: model's and the model with the accepted finding is within it
EXPLAINED_RATIO = 1.5
#: verdicts that accept no finding
NO_FINDING = ("none", "unexplained")


def explained(r: dict[str, Any]) -> bool:
    """An accepted finding; the base's test J2 above 1.5 x the true model's (something for the
    finding to explain), the model with it within 1.5 x (explained)."""
    true = EXPLAINED_RATIO * r["J2_test_true"]
    return r["verdict"] not in NO_FINDING and r["J2_test_before"] > true >= r["J2_test_after"]


def explained_unbounded(r: dict[str, Any]) -> bool:
    """:func:`explained` with the finding acting beyond the box of the training states too (the
    default holds it at the box's boundary there, :mod:`mmg.domain`); results stored before the
    unbounded J2 was kept count as bounded."""
    after = r.get("J2_test_after_unbounded", r["J2_test_after"])
    return explained({**r, "J2_test_after": after})


def explained_former(r: dict[str, Any]) -> bool:
    """The criterion before the base's test J2 was required above 1.5 x the true model's:
    verdict ``discovered``, test J2 within 1.5 x the true model's (shown beside the current
    one, so that no case changes its label unseen)."""
    return (
        r["verdict"] == "discovered" and r["J2_test_after"] <= EXPLAINED_RATIO * r["J2_test_true"]
    )


def absorbed(r: dict[str, Any]) -> bool:
    """The re-identified base already within 1.5 x the true model's test J2: the 57 parameters
    absorb the planted force on these windows, there is nothing left to explain."""
    return r["J2_test_before"] <= EXPLAINED_RATIO * r["J2_test_true"]


def reachable(r: dict[str, Any]) -> bool | None:
    """Whether the case is shown explainable from its training windows: the base's test J2
    above 1.5 x the true model's, and the planted form itself, refitted from the diagnosis'
    base re-identified without a finding (:func:`benchmarks.refit_forms.planted_reach`,
    ``--reach``), within 1.5 x, or the diagnosis' own finding (one refit from one start is no
    strict bound: a finding re-identified from its fold fits can reach further; None: not
    measured)."""
    reach = r.get("planted_reach")
    if reach is None:
        return None
    within = reach["J2_test"] <= EXPLAINED_RATIO * r["J2_test_true"]
    return not absorbed(r) and (within or explained(r))


def case_harm(r: dict[str, Any], out: Path | None = None) -> Harm:
    """The harm counts of a case's accepted finding (:mod:`benchmarks.harm`), from its per-test-
    recording J2 (results stored before they were kept: from the case's report.json in ``out``,
    else the total alone)."""
    before, after = r.get("J2_test_before_table"), r.get("J2_test_after_table")
    report = None if out is None else case_directory(out, r["index"], r["repeat"])
    report = None if report is None else report / "diagnosis" / "report.json"
    if before is None and report is not None and report.exists():
        data = json.loads(report.read_text())
        before, after = data["J_before"].get("J2"), data["J_after"].get("J2")
    if before is None or after is None:
        before, after = {"Total": r["J2_test_before"]}, {"Total": r["J2_test_after"]}
    return finding_harm(r["verdict"], before, after)


def row_of(r: dict[str, Any]) -> str:
    """The summary row of a result (results stored before the rows: the twin set's)."""
    return str(r.get("row", ROWS["twin"]))


def row_figures(results: list[dict[str, Any]], out: Path | None = None) -> list[dict[str, Any]]:
    """Per row: cases, explained, named, flagged, absorbed, false alarms on the no-effect
    cases, and the harm counts (accepted findings of every case of the row)."""
    rows: dict[str, list[dict[str, Any]]] = {}
    for r in (_classified(r) for r in results):
        rows.setdefault(row_of(r), []).append(r)
    figures = []
    for row, rs in rows.items():
        eff = [r for r in rs if r["family"] not in NO_EFFECT]
        none = [r for r in rs if r["family"] == "none"]
        harm = total(case_harm(r, out) for r in rs)
        reach = [reachable(r) for r in eff]
        figures.append(
            {
                "row": row,
                "effects": len(eff),
                "explained": sum(explained(r) for r in eff),
                "explained_unbounded": sum(explained_unbounded(r) for r in eff),
                "explained_former": sum(explained_former(r) for r in eff),
                "named": sum(r["correct"] for r in eff),
                "flagged": sum(r["verdict"] == "unexplained" for r in eff),
                # a finding the report says leaves more missing (None: results from before)
                "more_missing": (
                    sum(bool(r.get("more_missing")) for r in eff)
                    if all("more_missing" in r for r in eff)
                    else None
                ),
                "absorbed": sum(absorbed(r) for r in eff),
                # within reach: the planted form refitted from the windows or the finding within
                # 1.5 x (--reach; None: a case of the row was not measured), and how many of
                # those are explained
                "reachable": None if None in reach else sum(bool(x) for x in reach),
                "explained_reachable": (
                    None
                    if None in reach
                    else sum(bool(x) and explained(r) for x, r in zip(reach, eff, strict=True))
                ),
                "none": len(none),
                "false_alarms": sum(r["verdict"] != "none" for r in none),
                "harm": asdict(harm),
                "harm_text": harm.text(),
            }
        )
    return figures


def rows_table(figures: list[dict[str, Any]]) -> str:
    """The rows: explained / named / flagged of the planted effects, false alarms, harm."""
    lines = [
        f"{'row':40s} {'effects':>7s} {'explained':>9s} {'(unbounded)':>11s} {'(former)':>8s} "
        f"{'named':>5s} {'flagged':>7s} {'more missing':>12s} {'absorbed':>8s} "
        f"{'reachable':>9s} {'false alarms':>12s}  harm"
    ]
    for f in figures:
        more, reach = f.get("more_missing"), f.get("reachable")
        reach_text = "-" if reach is None else f"{f['explained_reachable']} of {reach}"
        lines.append(
            f"{f['row']:40s} {f['effects']:7d} {f['explained']:9d} "
            f"{f['explained_unbounded']:11d} {f['explained_former']:8d} "
            f"{f['named']:5d} {f['flagged']:7d} {'-' if more is None else more:>12} "
            f"{f['absorbed']:8d} {reach_text:>9s} "
            f"{f['false_alarms']:>7d} of {f['none']:2d}  {f['harm_text']}"
        )
    lines.append(
        f"explained: an accepted finding, the base's test J2 > {EXPLAINED_RATIO} x the true "
        f"model's and the model with it within {EXPLAINED_RATIO} x; (unbounded): the finding "
        "acting beyond the training states' box too; (former): verdict "
        f"discovered and within {EXPLAINED_RATIO} x, without the base's condition; more missing: "
        "a finding the report says leaves more missing (the model with it still above the noise "
        "floor on the training windows, or on the test recordings; - for results from before "
        f"that was recorded); absorbed: the base already within {EXPLAINED_RATIO} x; "
        "reachable: explained of the cases where the planted form itself, refitted from the "
        f"training windows, or the finding reaches {EXPLAINED_RATIO} x (--reach; - where not "
        "measured)"
    )
    return "\n".join(lines)


def summarise(results: list[dict[str, Any]]) -> str:
    results = [_classified(r) for r in results]
    lines = []
    fams: dict[str, list[dict[str, Any]]] = {}
    for r in results:
        fams.setdefault(r["family"], []).append(r)
    lines.append(
        f"{'family':16s} {'cases':>5s} {'top-1':>6s}  {'param err (median, max)':>24s}  "
        f"{'J2 test before -> after (true)':>32s}"
    )
    for fam, rs in sorted(fams.items()):
        ok = sum(r["correct"] for r in rs)
        errs = [v for r in rs for k, v in r["param_errors"].items() if "candidate" not in k]
        err_txt = f"{100 * np.median(errs):.0f} %, {100 * max(errs):.0f} %" if errs else "-"
        before = np.median([r["J2_test_before"] for r in rs])
        after = np.median([r["J2_test_after"] for r in rs])
        true = (
            np.nanmedian([r["J2_test_true"] for r in rs])
            if any(np.isfinite(r["J2_test_true"]) for r in rs)
            else math.nan
        )
        label = "FP rate" if fam == "none" else "top-1"
        rate = (len(rs) - ok) / len(rs) if fam == "none" else ok / len(rs)
        lines.append(
            f"{fam:16s} {len(rs):5d} {100 * rate:5.0f}%  {err_txt:>24s}  "
            f"{before:10.1f} -> {after:8.1f} ({true:6.1f})   [{label}]"
        )
    # a form in the paper's model's own form plants nothing missing: its own line below
    eff = [r for r in results if r["family"] not in NO_EFFECT]
    none = [r for r in results if r["family"] == "none"]
    if eff:
        lines.append(
            f"overall top-1 on planted effects: {sum(r['correct'] for r in eff)}/{len(eff)}"
        )
    if none:
        fp = sum(not r["correct"] for r in none)
        lines.append(f"false positives on no-effect cases: {fp}/{len(none)}")
    unlisted = [r for r in results if r["family"] == "discovered"]
    if unlisted:
        n_explained = sum(explained(r) for r in unlisted)
        former = sum(explained_former(r) for r in unlisted)
        flagged = sum(r["verdict"] in ("discovered", "shape", "unexplained") for r in unlisted)
        lines.append(
            f"unlisted cases explained (accepted, base's test J2 > 1.5 x the true model's, after "
            f"within 1.5 x): {n_explained}/{len(unlisted)} (by the former criterion, discovered "
            f"and within 1.5 x: {former}/{len(unlisted)}); named or flagged unexplained: "
            f"{flagged}/{len(unlisted)}"
        )
        # the paper's model re-identified without any term already predicts the test windows
        # about as well as the true model: the planted force is within what the 57 parameters
        # can represent on these windows, nothing is missing from the model's form
        absorbed = [
            r["index"]
            for r in unlisted
            if r["verdict"] == "none" and r["J2_test_before"] <= 1.5 * r["J2_test_true"]
        ]
        lines.append(
            "unlisted cases the re-identified base model already fits (verdict none, test J2 "
            f"within 1.5 x the true model): {len(absorbed)}/{len(unlisted)} {absorbed}"
        )
    in_form = [r for r in results if r["family"] == "in_form"]
    if in_form:
        lines.append(
            "cases planted in the paper's model's own form (the right verdict is none): "
            f"{sum(r['correct'] for r in in_form)}/{len(in_form)} none; test J2 after / true "
            + ", ".join(f"{r['J2_test_after'] / r['J2_test_true']:.2f}" for r in in_form)
        )
    if eff:
        named = sum(r["correct"] or r["verdict"] == "unexplained" for r in eff)
        lines.append(
            f"all planted cases named (right family) or flagged unexplained: {named}/{len(eff)}"
        )
    if any("excess" in r for r in eff):
        ex = [100 * r["excess"] for r in eff if "excess" in r]
        lines.append(
            f"excess of the true ship's test J2 over the true model's: {min(ex):.0f} to "
            f"{max(ex):.0f} % (median {np.median(ex):.0f} %)"
        )
    errs = [v for r in results for k, v in r["param_errors"].items() if "candidate" not in k]
    if errs:
        within = sum(e <= 0.2 for e in errs)
        lines.append(f"recovered parameters within 20 %: {within}/{len(errs)}")
    best_none = [max(c["improvement"] for c in r["candidates"]) for r in none]
    if best_none:
        lines.append(
            "largest held-out improvement of any candidate on no-effect cases: "
            + ", ".join(f"{100 * b:.1f} %" for b in best_none)
        )
    return "\n".join(lines)


def markdown_table(results: list[dict[str, Any]]) -> str:
    """The per-case table of docs/missing-physics.md."""
    head = (
        "| # | planted form (values) | family | verdict | best dBIC | recovered parameter error "
        "| J2 test before -> after (true model) | time |\n"
        "|---:|---|---|---|---:|---|---|---:|"
    )
    rows = [head]
    for r in sorted(results, key=lambda r: (r["repeat"], r["index"])):
        values = ", ".join(f"{k} = {v:.4g}" for k, v in r["values"].items()) or "-"
        verdict = r["verdict"] + ("" if r["correct"] else " (miss)")
        if r["family"] == "none" and not r["correct"]:
            verdict = r["verdict"] + " (false positive)"
        best = min(c["delta_bic"] for c in r["candidates"])
        errs = ", ".join(
            f"{k} {100 * v:.1f} %" for k, v in r["param_errors"].items() if "candidate" not in k
        )
        rows.append(
            f"| {r['index']}.{r['repeat']} | {r['form']} ({values}) | {r['family']} "
            f"| {verdict} | {best:.0f} "
            f"| {errs or '-'} | {r['J2_test_before']:.1f} -> {r['J2_test_after']:.1f} "
            f"({r['J2_test_true']:.1f}) | {r['seconds']:.0f} s |"
        )
    return "\n".join(rows)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--set",
        default="twin",
        choices=SETS,
        help="twin: the forms with a library twin (0-35); unforeseen: forms no library term "
        "expresses (100-152); all: both, each in its own rows",
    )
    ap.add_argument(
        "--cases",
        default="all",
        help="all (of --set), quick, or comma-separated indices or names (e.g. seiche/strong)",
    )
    ap.add_argument("--repeats", type=int, default=1, help="cases are repeated with new ships")
    ap.add_argument("--base-budget", type=int, default=DiagnoseSettings.base_budget)
    ap.add_argument("--candidate-budget", type=int, default=DiagnoseSettings.candidate_budget)
    ap.add_argument("--final-budget", type=int, default=DiagnoseSettings.final_budget)
    ap.add_argument(
        "--base-retry-agreement",
        type=float,
        default=DiagnoseSettings.base_retry_agreement,
        help="0: the second base start runs whenever the misfit is significant",
    )
    ap.add_argument(
        "--rounds",
        type=int,
        default=DiagnoseSettings.rounds,
        help="diagnoses in all per case (a further round when a finding leaves the training "
        "windows above the floor; the case's model after is the last round's with a finding)",
    )
    ap.add_argument(
        "--shape-pairs",
        action="store_true",
        help="shapes of two variables among the learned shapes' candidates (the diagnosis' "
        "--shape-pairs)",
    )
    ap.add_argument(
        "--exact-starts",
        action="store_true",
        help="the noise-only copies behind the floor and the acceptance nulls begin exactly "
        "where the windows do (the diagnosis' --exact-starts; the planted windows begin at "
        "their simulation's exact state)",
    )
    ap.add_argument(
        "--reach",
        action="store_true",
        help="also refit each effect case's planted form itself from the diagnosis' base "
        "re-identified without a finding, as a finding is re-identified: what the planted form "
        "reaches from the case's training windows (also for cases already in --out)",
    )
    ap.add_argument("--out", default="benchmarks/out/diagnose")
    ap.add_argument(
        "--results",
        default=None,
        help="all results, the rows and the command in one JSON file "
        "(default benchmarks/results/diagnose_planted-SET[-weak].json)",
    )
    ap.add_argument("--data-root", default=None)
    ap.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help="twin set: planted effects this many times as strong (same ships, windows, noise)",
    )
    ap.add_argument(
        "--weak",
        action="store_true",
        help=f"twin set: each effect only as strong as raises the true ship's test J2 by "
        f"{100 * WEAK[0]:.0f}-{100 * WEAK[1]:.0f} %% over the noise floor (scale per case)",
    )
    ap.add_argument(
        "--markdown", action="store_true", help="also print the per-case table in Markdown"
    )
    return ap.parse_args(argv)


def magnitude(
    case: Case,
    repeat: int,
    runs: dict[str, list[Recording]],
    noise: dict[str, float],
    args: argparse.Namespace,
) -> tuple[PlantedSpec, float, float]:
    """(spec, scale, excess) of a case: the unforeseen and fresh sets' by their band; the twin
    set's by ``--weak`` or ``--scale``."""
    if case.set != "twin":
        scale, e = band_scale(case, repeat, runs, noise)
        return unforeseen_spec(case.spec.form, scale), scale, e
    spec = case.spec
    if args.weak:
        scale, e = weak_scale(case.index, spec, repeat, runs, noise)
    else:
        scale = args.scale
        none = spec.form == "none"
        e = 0.0 if none else excess(case.index, scaled(spec, scale), repeat, runs, noise)
    return scaled(spec, scale), scale, e


def row_label(case: Case, args: argparse.Namespace) -> str:
    """The case's summary row; the twin set's says how its magnitudes were set."""
    if case.set != "twin":
        return case.row
    if args.weak:
        return case.row + " (weak)"
    return case.row + ("" if args.scale == 1.0 else f" (x {args.scale:g})")


def with_reach(r: dict[str, Any], out: Path) -> bool:
    """Adds ``planted_reach`` (:func:`benchmarks.refit_forms.planted_reach`) to the result ``r``
    of an effect case whose directory is in ``out``, unless it has it; whether it was added."""
    if "planted_reach" in r or FAMILY[r["form"]] in NO_EFFECT:
        return False
    reach = planted_reach(case_directory(out, r["index"], r["repeat"]), stderr_log)
    if reach is None:
        return False
    r["planted_reach"] = reach
    print(
        f"case {r['index']:2d}.{r['repeat']}: the planted form refitted from the training windows "
        f"reaches test J2 {reach['J2_test']:.3g} ({reach['J2_test'] / r['J2_test_true']:.2f} x "
        "the true model's)",
        flush=True,
    )
    return True


def _commit() -> str:
    try:
        done = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        )
    except (OSError, subprocess.CalledProcessError):
        return ""
    return done.stdout.strip()


def write_results(path: Path, command: str, results: list[dict[str, Any]], out: Path) -> None:
    """The results of every case so far, the rows and the command that made them."""
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {
        "command": command,
        "commit": _commit(),
        "machine": machine(),
        "rows": row_figures(results, out),
        "cases": results,
    }
    path.write_text(json.dumps(data, indent=2, default=float) + "\n")


def print_case(r: dict[str, Any]) -> None:
    top = ", ".join(f"{c['effect']} {100 * c['improvement']:+.1f}%" for c in r["candidates"][:3])
    print(
        f"case {r['index']:2d}.{r['repeat']} {r.get('name', r['form']):24s} -> "
        f"{r['verdict']:15s} {'OK ' if r['correct'] else 'BAD'} [{top}] "
        f"errors {r['param_errors']} J2 test {r['J2_test_before']:.3g} -> "
        f"{r['J2_test_after']:.3g} (true {r['J2_test_true']:.3g}) {case_harm(r).text()} "
        f"{r['seconds']:.0f} s",
        flush=True,
    )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    command = shlex.join(["python", "benchmarks/diagnose_planted.py", *(argv or sys.argv[1:])])
    cases = select_cases(args.set, args.cases)
    root = data_root(args.data_root)
    runs = load_runs(root)
    noise = noise_levels([r for v in runs.values() for r in v])
    print(
        "noise levels of the real recordings: "
        + ", ".join(f"{k} {v:.2g}" for k, v in noise.items())
    )
    settings = DiagnoseSettings(
        base_budget=args.base_budget,
        candidate_budget=args.candidate_budget,
        final_budget=args.final_budget,
        base_retry_agreement=args.base_retry_agreement,
        rounds=args.rounds,
        shape_pairs=args.shape_pairs,
        exact_starts=args.exact_starts,
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    suffix = "-weak" if args.weak else ""
    results_path = Path(
        args.results or f"benchmarks/results/diagnose_planted-{args.set}{suffix}.json"
    )
    results = []
    for repeat in range(args.repeats):
        for case in cases:
            path = out / f"result-{case.index:02d}-{repeat}.json"
            if path.exists():
                r = json.loads(path.read_text())
                if args.reach and with_reach(r, out):
                    path.write_text(json.dumps(r, indent=2, default=float) + "\n")
                results.append(r)
                continue
            spec, scale, e = magnitude(case, repeat, runs, noise, args)
            if case.band is not None or args.weak:
                print(f"case {case.index:2d}.{repeat}: scale {scale:.3g} -> excess {100 * e:.0f} %")
            r = run_case(case.index, spec, repeat, runs, noise, settings, out, case.phi)
            r |= {"set": case.set, "name": case.name, "row": row_label(case, args)}
            r |= {"scale": scale, "excess": e, "command": command, "machine": machine()}
            if args.reach:
                with_reach(r, out)
            path.write_text(json.dumps(r, indent=2, default=float) + "\n")
            results.append(r)
            write_results(results_path, command, results, out)
            print_case(r)
    write_results(results_path, command, results, out)
    print()
    twin = [r for r in results if r.get("set", "twin") == "twin"]
    if twin:
        print(summarise(twin))
        print()
    print(rows_table(row_figures(results, out)))
    print(f"results: {results_path}")
    if args.markdown:
        print()
        print(markdown_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
