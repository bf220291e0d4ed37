"""How a candidate is scored against the control fit and how candidates are ranked.

``dBIC = N_eff ln(J_fit(effect) / J_fit(control)) + k ln(N_eff)`` over both folds' fits, and the
held-out improvement, the typical change of J on a held-out window. The procedure is described
in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mmg import Parameters, get_effect
from mmg.effect import DISCOVERED_PREFIX
from mmg.shapes import SHAPE_PREFIX, is_closed_form
from sweep.data.objective import CHANNELS, OBJECTIVES, Objective
from sweep.data.recordings import Recording

FloatArray = NDArray[np.float64]

#: decorrelation time of trajectory residuals [s] used for the effective sample count of dBIC
TAU = 10.0
#: candidates whose dBIC is within TIE_MARGIN x |best dBIC| (at least TIE_ABSOLUTE) of the best are
#: tied, and the held-out improvement decides between them: N_eff is an estimate, so differences of
#: a few per cent of dBIC are within its uncertainty (e.g. a rudder offset and a propeller walk
#: both act as a yaw moment growing with n_p^2 and reach nearly the same fit)
TIE_MARGIN = 0.05
TIE_ABSOLUTE = 10.0
#: a learned shape is stated by the closed form it was named after (or a library term, a
#: catalog effect) when that form is accepted too and keeps at least this share of the shape's
#: held-out gain; among tied candidates, a more specific name goes first when it keeps this
#: share of the largest held-out gain among them
KEEP = 0.9


@dataclass
class CandidateScore:
    """One candidate effect after its joint fit."""

    effect: str
    description: str
    regime: str
    params: dict[str, float]
    J_fit: float
    J_heldout: float
    improvement: float  # typical held-out improvement over the control fit (geometric mean)
    delta_bic: float
    accepted: bool = False
    evaluations: int = 0
    seconds: float = 0.0
    refined: bool = False  # scores after the refinement of the leading candidates
    improvement_total: float = 0.0  # relative change of the summed held-out J
    #: what the fits take off the control's summed J on the held-out runs [J] (positive: better)
    heldout_gain: float = 0.0
    #: the held-out run the fits make relatively worst, by how much (relative change of its J
    #: against the control's) and its loss [J]
    worst_run: str = ""
    worst_run_change: float = 0.0
    worst_run_loss: float = 0.0
    #: per held-out run: J with the effect minus the control's [J], and that relative to the
    #: control's J of the run (positive: worse)
    run_losses: dict[str, float] = field(default_factory=dict)
    run_changes: dict[str, float] = field(default_factory=dict)
    #: the largest loss of a held-out run as a share of that run's noise J
    #: (:meth:`sweep.diagnose.threshold.AcceptanceNull.run_excess`)
    worst_run_excess: float = 0.0
    #: the held-out gain exceeds the null's and no held-out run gets worse than the null allows
    #: (:mod:`sweep.diagnose.threshold`)
    carries_over: bool = False
    #: for a generated candidate tied to heading, position or time (:mod:`sweep.diagnose.sessions`):
    #: "checked" (fitted on some sessions' runs, judged on the others'), "one session" (all
    #: training runs are of one session: it cannot be checked) or "" (not tied, or not a leader)
    sessions: str = ""
    #: ... its gain on the other sessions' runs [J], and per held-out run its loss [J] and
    #: relative change, against the control fitted alike
    session_gain: float = 0.0
    session_run_losses: dict[str, float] = field(default_factory=dict)
    session_run_changes: dict[str, float] = field(default_factory=dict)
    #: ... and whether it carries over there (True when not checked)
    sessions_carry: bool = True
    #: the transfer check (:mod:`sweep.diagnose.transfer`; a generated candidate refused by its
    #: held-out runs, :func:`~sweep.diagnose.transfer.needs_transfer`): whether it ran, the J it
    #: takes off the control's on the runs the base was refitted on with the effect held [J]
    #: (positive: better), that relative to the control's J (negative: better), and per run the
    #: relative change
    transfer_checked: bool = False
    transfer_gain: float = 0.0
    transfer_change: float = 0.0
    transfer_run_changes: dict[str, float] = field(default_factory=dict)
    #: ... when it passed and the runs are of several sessions, the same check across sessions
    #: (held as fitted on some sessions' runs, the base refitted on the others')
    session_transfer_checked: bool = False
    session_transfer_gain: float = 0.0
    session_transfer_change: float = 0.0
    session_transfer_run_changes: dict[str, float] = field(default_factory=dict)

    @property
    def runs_better(self) -> int:
        """How many held-out runs the fits make better."""
        return sum(v < 0.0 for v in self.run_changes.values())


def generated(effect: str) -> bool:
    """Whether ``effect`` is generated (library terms or a learned shape), not a named one."""
    return effect.startswith((DISCOVERED_PREFIX, SHAPE_PREFIX))


def judged_as_generated(effect: str, significant: bool) -> bool:
    """Whether ``effect``'s worst held-out run is judged in units of its noise J and it may
    have the transfer check: a generated one always, a catalog effect when the base's misfit
    is within the noise floor (not ``significant``), where no missing force inflates the
    control's J of a run (:mod:`sweep.diagnose.threshold`)."""
    return generated(effect) or not significant


def name_kind(effect: str) -> int:
    """How specific a candidate's name is, most specific first: 0 a catalog effect, 1 library
    terms (``discovered:``), 2 a learned shape's closed form, 3 a learned spline shape."""
    if effect.startswith(DISCOVERED_PREFIX):
        return 1
    if effect.startswith(SHAPE_PREFIX):
        return 2 if is_closed_form(effect) else 3
    return 0


def shape_and_form(
    scores: Sequence[CandidateScore],
) -> tuple[CandidateScore | None, CandidateScore | None]:
    """The learned spline shape's score and that of the closed form it was named after (each
    None when not among ``scores``)."""
    shape = next(
        (c for c in scores if c.effect.startswith(SHAPE_PREFIX) and not is_closed_form(c.effect)),
        None,
    )
    form = next((c for c in scores if is_closed_form(c.effect)), None)
    return shape, form


def form_share(scores: Sequence[CandidateScore]) -> float | None:
    """The share of the learned spline shape's held-out gain that the closed form named after it
    keeps (None without both candidates, or when the shape gains nothing)."""
    shape, form = shape_and_form(scores)
    if shape is None or form is None or shape.heldout_gain <= 0:
        return None
    return form.heldout_gain / shape.heldout_gain


def rank(scores: Sequence[CandidateScore], tie_margin: float = TIE_MARGIN) -> list[CandidateScore]:
    """Candidates by dBIC, except that those tied with the best (dBIC within
    ``max(TIE_ABSOLUTE, tie_margin x |best|)``) come first: accepted ones before the others,
    then those that keep :data:`KEEP` of the largest held-out gain among the tied accepted ones,
    then the most specific name (:func:`name_kind`: a catalog effect, library terms, a learned
    shape's closed form, the shape itself; named physics over a generic form that fits as well:
    n_p|n_p| terms imitate a propeller walk, a line in U imitates the library's u^4 term), then
    by held-out improvement."""
    by_bic = sorted(scores, key=lambda c: c.delta_bic)
    if not by_bic:
        return []
    best = by_bic[0].delta_bic
    margin = max(TIE_ABSOLUTE, tie_margin * abs(best)) if math.isfinite(best) else 0.0
    tied = [c for c in by_bic if c.delta_bic - best <= margin]
    top = max((c.heldout_gain for c in tied if c.accepted), default=0.0)
    tied.sort(
        key=lambda c: (
            not c.accepted,
            top > 0.0 and c.heldout_gain < KEEP * top,
            name_kind(c.effect),
            -c.improvement,
        )
    )
    return tied + [c for c in by_bic if c not in tied]


def heldout_per_window(
    windows: Sequence[Recording], params: Parameters, objective: str
) -> list[float]:
    """J of ``params`` (with its effects) on each window, in order (:func:`test_table`)."""
    labels = [f"w{i}" for i in range(len(windows))]
    row = test_table(params, windows, labels)[objective]
    return [row[lab] for lab in labels]


def typical_change(J_effect: FloatArray, J_control: FloatArray) -> float:
    """Held-out improvement of an effect: 1 - the geometric mean of the per-window ratios
    J(effect) / J(control) (positive: the held-out windows fit better). A diverged window
    (J infinite or NaN) counts as 100 times worse."""
    a = np.asarray(J_effect, dtype=np.float64)
    b = np.asarray(J_control, dtype=np.float64)
    if a.size == 0:
        return 0.0
    ratio = np.where(np.isfinite(a), a, np.inf) / np.maximum(b, 1e-300)
    ratio = np.where(np.isfinite(ratio), ratio, 100.0)
    return float(1.0 - np.exp(np.mean(np.log(np.maximum(ratio, 1e-12)))))


def n_effective(windows: Sequence[Recording], objective: str) -> float:
    """Effective number of independent residuals: channels x duration / TAU."""
    duration = sum(w.duration for w in windows)
    return len(CHANNELS[objective]) * duration / TAU


def delta_bic(J_effect: float, J_control: float, k: float, n_eff: float) -> float:
    """BIC(effect) - BIC(control) with J as the residual sum of squares of n_eff samples."""
    if J_effect <= 0 or J_control <= 0:
        return math.inf
    return n_eff * math.log(J_effect / J_control) + k * math.log(n_eff)


def test_table(
    params: Parameters, recordings: Sequence[Recording], labels: Sequence[str]
) -> dict[str, dict[str, float]]:
    """{J: {label: value, "Total": value}} of ``params`` (with its effects) on the recordings."""
    return test_table_diverged(params, recordings, labels)[0]


def diverged_text(runs: dict[str, list[int]]) -> str:
    """``label (k/n subsequences), ...`` of {label: [diverged, all]}."""
    return ", ".join(f"{label} ({k}/{n} subsequences)" for label, (k, n) in runs.items())


def test_table_diverged(
    params: Parameters, recordings: Sequence[Recording], labels: Sequence[str]
) -> tuple[dict[str, dict[str, float]], dict[str, list[int]]]:
    """(:func:`test_table`, {label: [diverged, all]} subsequences of t_f = 100 s of each label
    whose simulation diverged, for the labels with at least one): a diverged subsequence hit the
    limiter of Algorithm 1 or left the finite numbers, and its J is the divergence penalty
    (:data:`sweep.data.objective.PENALTY_FACTOR` x its duration per channel), not a misfit."""
    effects = tuple(get_effect(n) for n, _ in params.effects)
    obj = Objective(recordings, labels=labels, effects=effects, ship=params.ship)
    cost, bad = obj.costs(params)
    raw = obj.table_of(cost)
    out: dict[str, dict[str, float]] = {}
    for J in OBJECTIVES:
        row = {label: float(raw[J][label][0]) for label in dict.fromkeys(labels)}
        row["Total"] = float(sum(row.values()))
        out[J] = row
    diverged = {
        label: [int(bad[0, obj.data.groups[label]].sum()), len(obj.data.groups[label])]
        for label in dict.fromkeys(labels)
        if bad[0, obj.data.groups[label]].any()
    }
    return out, diverged
