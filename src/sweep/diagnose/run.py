"""The diagnosis: identify the base model, locate the mismatch, rank candidate physics, re-identify.

Procedure (:func:`diagnose`), all on the training recordings unless said otherwise:

1. The training recordings are cut into the objective's 100-s windows and put in a *fit* half
   and a *held-out* half: whole runs when there are several (longest first to the half with
   less recorded time), so that a term must carry over to other runs; the windows alternately
   (0, 2, 4, ... fit; 1, 3, 5, ... held out) when one run holds most of the time.
2. Base identification on all training windows, from two starts that compete (the lower J
   wins): CMA-ES from ``--params`` (``base_budget`` evaluations) followed by Levenberg-Marquardt
   refinement (:mod:`sweep.identification.polish`, up to ``final_polish_iterations``), and
   Levenberg-Marquardt alone from ``--params`` (up to ``base_lm_iterations``). Neither dominates: of
   the 40 planted benchmark cases, the descent alone ended more than 1.5 x lower in 6 (up to 5.3 x:
   CMA-ES had led the refinement into a worse basin of the 57-parameter landscape), CMA-ES first in
   3 (up to 80 x: the descent alone stuck). The base model absorbs what it can of any missing
   effect, as in practice. When the misfit test (step 5's floor) finds the base above the noise
   floor, a second CMA-ES start (another seed) runs first and the lower end becomes the base: an
   identification stopped in another basin is not missing physics (a no-effect case of the
   planted benchmark went from 1.52 to 1.01 against the true model's 0.90; its two routes had
   ended at 1.52 and 2.77). When the two routes ended within ``base_retry_agreement`` of each
   other, both reached one point and the second start is not run.
   Every Levenberg-Marquardt refinement of the diagnosis minimises J plus a weak prior
   ``prior_weight |z - z_start|^2`` on the 57 base parameters (normalised box, ``z_start`` the
   ``--params`` values): along directions the data leave nearly flat (a_H traded against an
   effect's coefficient) it keeps the parameters near the captive-model values instead of
   letting them wander to wherever the descent stopped; ``Fit.f`` and all scores are J alone.
3. Location: residuals of the base model per run, window and regime
   (:mod:`sweep.diagnose.locate`): where the trajectory residual concentrates (eta^2 of each
   regime variable) and where the equations of motion have a biased residual.
4. Candidates, in two folds (fit on one half, judge on the other, then the other way round):
   each catalog effect is fitted first alone on top of the base (a grid over its one or two
   parameters), then jointly with the 57 base parameters from there (Levenberg-Marquardt;
   ``candidate_budget`` > 0 adds CMA-ES evaluations before it). A *control* fit of the base
   alone by the same procedure measures what refitting does without new physics. The procedure
   is deterministic, so control and candidates start from the same point and differ only by
   what the effect can explain.
   The three leading candidates (by dBIC) and the control are then refined: their fold fits are
   continued with up to ``refine_iterations`` more iterations (a joint fit that must undo what
   the base had absorbed of the effect can still be descending), and scored again.
   Scores: the information criterion over both folds' fits,
   ``dBIC = N_eff ln(J_fit(effect) / J_fit(control)) + k ln(N_eff)``, with
   ``N_eff = channels x T / TAU`` (trajectory residuals decorrelate over about ``TAU`` = 10 s),
   and the held-out improvement, the typical change of J on a held-out window:
   ``1 - exp(mean over held-out windows of ln(J_ho(effect) / J_ho(control)))`` (a geometric
   mean of the per-window ratios: one window that a half's fit throws off, for control or
   candidate alike, cannot decide it; the change of the summed held-out J is reported beside).
5. Verdict. A candidate is *accepted* when its dBIC is at most the acceptance threshold and its
   held-out improvement >= ``min_improvement`` (a veto against an effect that makes a typical
   unseen window clearly worse). The threshold is calibrated on the data at hand
   (:mod:`sweep.diagnose.threshold`): the ``alpha`` quantile of the best candidate's dBIC over
   noise-only copies of the training windows, with the fold fits linearised, capped at -10
   (``--max-delta-bic`` sets it by hand instead). The verdict is the accepted candidate with the
   lowest dBIC; among candidates tied with it (:data:`TIE_MARGIN`) a catalog effect goes before
   discovered terms, then the best held-out improvement. The held-out improvement is noisy (the
   held-out windows are few, and refitting 57 parameters on half of them moves parameters the
   half does not constrain), so it vetoes and breaks ties but does not rank: ranking accepted
   candidates by it chose, on the real Train-R recordings, position terms that improved the
   typical held-out window by 12.9 % and made the test set 11 % worse, where the dBIC winner
   (N_s3b) made it 2 % better. With no accepted candidate the verdict is ``unexplained`` when
   the misfit test (:mod:`sweep.diagnose.floor`) finds the base model significantly above the
   noise floor, or when the base re-identified in step 6 misses the test recordings beyond what
   a model exact in form, identified on these windows, would (:mod:`sweep.diagnose.generalise`:
   an effect the training manoeuvres do not excite); ``none`` when neither does.
   Discovery adds candidates before the fits: terms of the library proposed from the
   equation-level residuals (:mod:`sweep.diagnose.discover`; with up to two alternatives
   without the heading, position or time terms of the proposal, step 4b there) and terms
   selected on the trajectory residuals by the same linearised fits
   (:meth:`Linearised.select`), each only beyond its own null at ``alpha``.
6. Re-identification on all training windows (``final_budget`` CMA-ES evaluations, then the
   refinement, its prior ``final_prior_weight``, far weaker: see :data:`FINAL_PRIOR_WEIGHT`)
   of the base model plus the chosen effect (from the candidate's better fold fit
   and from the base plus the effect's values; the better end wins), and of the base model
   alone by the same procedure ("before"); J1, J2, J3 of both on every test recording.

Every stage's result is stored in ``DIR/stages/`` as soon as it is done; running the same command
again resumes after the last finished stage.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from mmg import Effect, Parameters, catalog, get_effect
from mmg.discovered import discovered_effect, with_bounds
from mmg.effects import DISCOVERED_PREFIX
from mmg.params import N_THETA
from mmg.precompile import precompile, tasks
from sweep.data.objective import CHANNELS, OBJECTIVES, T_F, Objective, split_recording
from sweep.data.recordings import Recording
from sweep.diagnose.discover import DiscoverySettings, Proposal, discover, resemblance
from sweep.diagnose.fit import Fit, FitSettings, effect_values, fit, with_effects
from sweep.diagnose.floor import (
    MisfitTest,
    NoiseModel,
    calibrated_noise,
    misfit_test,
    noise_floor,
    run_of,
)
from sweep.diagnose.generalise import ALPHA as GENERALISATION_ALPHA
from sweep.diagnose.generalise import DRAWS as GENERALISATION_DRAWS
from sweep.diagnose.generalise import MARGIN as GENERALISATION_MARGIN
from sweep.diagnose.generalise import GeneralisationTest, generalisation_test
from sweep.diagnose.linearised import Linearised, TrajectorySelection
from sweep.diagnose.locate import (
    equation_residuals,
    locate,
    locate_bias,
    rank_windows,
    residual_frame,
)
from sweep.diagnose.threshold import CEILING, AcceptanceNull, acceptance_null
from sweep.identification.polish import PolishSettings

FloatArray = NDArray[np.float64]

#: decorrelation time of trajectory residuals [s] used for the effective sample count of dBIC
TAU = 10.0
#: held-out improvement a candidate needs (a veto: a typical held-out window may get at most 25 %
#: worse; on the planted benchmark refitting alone changed held-out J by -89 % to +36 %, see docs/)
MIN_IMPROVEMENT = -0.25
#: draws of the acceptance null (:mod:`sweep.diagnose.threshold`): linear algebra on one
#: simulation of the windows per draw, so a few hundred cost seconds
THRESHOLD_DRAWS = 200
#: candidates whose dBIC is within TIE_MARGIN x |best dBIC| (at least TIE_ABSOLUTE) of the best are
#: tied, and the held-out improvement decides between them: N_eff is an estimate, so differences of
#: a few per cent of dBIC are within its uncertainty (e.g. a rudder offset and a propeller walk
#: both act as a yaw moment growing with n_p^2 and reach nearly the same fit)
TIE_MARGIN = 0.05
TIE_ABSOLUTE = 10.0
#: weight of the prior toward the starting parameters, in units of J per squared normalised
#: coordinate. A coordinate 0.05 of its interval away from the start costs 0.0025: a few per cent
#: of one 100-s window's J at the noise level of the recordings (J2 about 0.04 per window), so
#: the prior decides only along directions the data leave nearly flat (a_H against k_aH of
#: ``a_h_drift``, see the README); on the real recordings (J2 of thousands) it is negligible
PRIOR_WEIGHT = 1.0
#: weight of the same prior in the re-identification on all training windows (step 6). The
#: prior above holds the fold fits on half the windows together; on all of them it costs more
#: than the data can tell apart: the search boxes of m_x, m_y and J_zz are narrow (EFD +- 30 %),
#: so a ship 15 % off its captive-model masses pays about 0.06 of J per mass at weight 1 (a
#: tenth of a 12-window training J at the noise level; the other 54 parameters, boxes +- 10 x,
#: pay 0.00006 each): the prior pinned the masses and the rest compensated along the directions
#: the windows leave flat. Measured on the planted benchmark (``benchmarks/final_prior_probe.py``:
#: Levenberg-Marquardt continued from each case's final model, 25 cases): the test J2 over the
#: true model's went from 1.0-4.3 x to 1.0-1.7 x at 0.01, the catalog parameters' errors fell
#: (k_aH 3.2 -> 0.5 %); at 0 some ends wandered (5.2 x).
FINAL_PRIOR_WEIGHT = 0.01
#: version of the fitting procedure; raise it when a change alters what a stage computes
PROCEDURE_VERSION = 7
#: shortest window kept [s] (the last window of a run may be short)
MIN_WINDOW = 20.0


@dataclass(frozen=True)
class DiagnoseSettings:
    """Budgets and rules of one diagnosis."""

    objective: str = "J2"
    base_budget: int = 6000
    candidate_budget: int = 0  # CMA-ES evaluations before the refinement (0: grid + LM only)
    final_budget: int = 0
    polish_iterations: int = 30  # Levenberg-Marquardt iterations of control and candidates
    effect_only_budget: int = 300  # evaluations of an effect's grid with the base held fixed
    #: dBIC a candidate must reach; None: calibrated on the data at hand at false-alarm rate
    #: ``alpha`` (:mod:`sweep.diagnose.threshold`)
    max_delta_bic: float | None = None
    threshold_draws: int = THRESHOLD_DRAWS
    tie_margin: float = TIE_MARGIN
    refine_top: int = 3  # leading candidates (by dBIC) refined before the verdict
    refine_iterations: int = 70  # further Levenberg-Marquardt iterations of their fold fits
    final_polish_iterations: int = 100  # ... of the base and final identifications
    base_lm_iterations: int = 300  # Levenberg-Marquardt alone from --params, competing (0: off)
    #: weight mu of the prior mu |z - z_start|^2 on the 57 base parameters (normalised box) in
    #: every refinement: among parameter sets that fit about equally well, the one nearest the
    #: starting (captive-model) values; 0 switches it off
    prior_weight: float = PRIOR_WEIGHT
    #: ... in the re-identification on all training windows (step 6)
    final_prior_weight: float = FINAL_PRIOR_WEIGHT
    seed: int = 0
    candidates: tuple[str, ...] = ()  # empty: every catalog effect
    min_improvement: float = MIN_IMPROVEMENT
    sigma0: float = 0.03
    effect_sigma: float = 0.15
    refit_sigma: float = 0.003  # base coordinates when refitting from the base fit
    workers: int | None = 0
    #: propose terms from the library (:mod:`sweep.diagnose.discover`) as one more candidate
    discover: bool = True
    discover_terms: int = DiscoverySettings.max_terms
    #: further term sets proposed without the proposal's heading, position or time terms
    discover_alternatives: int = DiscoverySettings.alternatives
    null_draws: int = DiscoverySettings.null_draws
    #: false-alarm rate of the discovery's proposal and of the acceptance threshold
    alpha: float = DiscoverySettings.alpha
    floor_draws: int = 12  # noise draws of the J floor
    floor_margin: float = 0.10  # the misfit must exceed the floor by this share (and z > 3)
    #: noise-only copies of the generalisation test on the test recordings (0: no test)
    generalisation_draws: int = GENERALISATION_DRAWS
    generalisation_alpha: float = GENERALISATION_ALPHA
    generalisation_margin: float = GENERALISATION_MARGIN
    #: a misfit above the floor first gets the base a second CMA-ES start (another seed) ...
    base_retry: bool = True
    #: ... unless the base's two routes ended within this share of each other's J: the
    #: landscape led CMA-ES and the descent alone to one point (the planted case the second
    #: start was made for had ended at 1.52 and 2.77)
    base_retry_agreement: float = 0.01

    def candidate_effects(self) -> tuple[Effect, ...]:
        names = self.candidates or tuple(sorted(catalog()))
        return tuple(get_effect(n) for n in names)

    def fingerprint(self) -> str:
        # thresholds decide the verdict only: stages fitted under other thresholds are reused
        # (the misfit test's margin and draws stay in: they decide whether the base gets a
        # second start, and every later stage starts from the base)
        # (the alternatives only add candidates, each with its own stages)
        skip = (
            "workers",
            "min_improvement",
            "max_delta_bic",
            "tie_margin",
            "discover_alternatives",
            "final_prior_weight",  # (in the final stages' names)
            "generalisation_draws",
            "generalisation_alpha",
            "generalisation_margin",
        )
        data = {k: v for k, v in asdict(self).items() if k not in skip}
        data["procedure"] = PROCEDURE_VERSION  # stages of an older procedure are not reused
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:12]


def cut_windows(
    recordings: Sequence[Recording], t_f: float = T_F, min_window: float = MIN_WINDOW
) -> list[Recording]:
    """Each recording cut into the objective's windows (shorter than ``min_window`` [s] dropped;
    0 keeps every window the objective sums over)."""
    out: list[Recording] = []
    for rec in recordings:
        for seg in split_recording(rec, t_f):
            if seg.n_steps * rec.dt < min_window - 1e-9:
                continue
            sl = slice(seg.start, seg.start + seg.n_steps + 1)
            t = np.asarray(rec.t[sl])
            out.append(
                Recording(
                    name=f"{rec.name}@{t[0]:.1f}s",
                    path=None,
                    t=t,
                    x=np.asarray(rec.x[sl]),
                    u=np.asarray(rec.u[sl]),
                    w=np.asarray(rec.w[sl]),
                )
            )
    return out


def split_windows(windows: Sequence[Recording]) -> tuple[list[Recording], list[Recording]]:
    """(fit, held-out) windows; needs at least two windows.

    Whole runs are held out when there are several: the windows of one recording share its
    conditions (the day's wind, the basin's region, the run's manoeuvre), so a term must carry
    over to other runs to count as better. The runs go, longest first, to the fold with less
    recorded time so far. From a single run (or when one run holds nearly all the time) the
    windows alternate between the folds instead."""
    if len(windows) < 2:
        raise ValueError(
            f"the training recordings give {len(windows)} window(s) of up to {T_F:.0f} s; "
            "the diagnosis needs at least 2 (one to fit, one held out)"
        )
    runs: dict[str, list[Recording]] = {}
    for w in windows:
        runs.setdefault(run_of(w), []).append(w)
    total = sum(w.duration for w in windows)
    longest = max(sum(w.duration for w in ws) for ws in runs.values())
    if len(runs) < 2 or longest > (2.0 / 3.0) * total:
        return list(windows[0::2]), list(windows[1::2])
    folds: tuple[list[Recording], list[Recording]] = ([], [])
    time_in = [0.0, 0.0]
    for ws in sorted(runs.values(), key=lambda ws: -sum(w.duration for w in ws)):
        j = 0 if time_in[0] <= time_in[1] else 1
        folds[j].extend(ws)
        time_in[j] += sum(w.duration for w in ws)
    return folds


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


@dataclass
class StageStore:
    """Finished stages of one diagnosis, as JSON files under ``DIR/stages``."""

    directory: Path
    fingerprint: str

    def path(self, name: str) -> Path:
        return self.directory / f"{name}.json"

    def load(self, name: str, effects: Sequence[Effect]) -> Fit | None:
        p = self.path(name)
        if not p.exists():
            return None
        data = json.loads(p.read_text())
        if data.get("fingerprint") != self.fingerprint:
            return None
        params = Parameters.from_dict(data["params"], origin=str(p))
        return Fit(
            params=params,
            effects=tuple(effects),
            f=float(data["f"]),
            evaluations=int(data["evaluations"]),
            seconds=float(data["seconds"]),
            history=list(data.get("history", [])),
            ends=tuple(float(v) for v in data.get("ends", ())),
        )

    def save(self, name: str, result: Fit) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        payload = {
            "fingerprint": self.fingerprint,
            "params": result.params.to_dict(),
            "f": result.f,
            "evaluations": result.evaluations,
            "seconds": result.seconds,
            "history": result.history,
            "ends": list(result.ends),
        }
        tmp = self.path(name).with_suffix(".tmp")
        tmp.write_text(json.dumps(payload) + "\n")
        tmp.replace(self.path(name))


Log = Callable[[str], None]


def _stderr(message: str) -> None:
    print(f"[diagnose] {message}", file=sys.stderr, flush=True)


def _progress(log: Log, label: str, every: float = 10.0) -> Any:
    last = [time.perf_counter()]

    def show(state: Any, row: dict[str, float]) -> None:
        now = time.perf_counter()
        if now - last[0] >= every:
            last[0] = now
            log(
                f"{label}: {int(row['evaluations'])}/{state.settings.max_evaluations} evaluations,"
                f" best {row['best_so_far']:.2f}"
            )

    return show


@dataclass
class Diagnosis:
    """Everything the report shows."""

    settings: DiagnoseSettings
    train_windows: int
    fit_windows: int
    heldout_windows: int
    base: Fit
    control: Fit
    candidates: list[CandidateScore]
    verdict: str
    before: Fit
    after: Fit
    test_before: dict[str, dict[str, float]]
    test_after: dict[str, dict[str, float]]
    regimes: list[dict[str, Any]]
    biases: list[dict[str, Any]]
    windows: list[dict[str, Any]]
    seconds: float
    n_eff: float
    misfit: MisfitTest | None = None
    proposal: Proposal | None = None
    #: the test recordings' J of the model before (after) against a model exact in form
    generalisation: GeneralisationTest | None = None
    generalisation_after: GeneralisationTest | None = None
    #: the chosen candidate's effect name (the verdict is ``discovered`` for a generated one)
    verdict_effect: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def threshold(self) -> float:
        """The dBIC a candidate had to reach."""
        acc = self.extra.get("acceptance", {})
        used = acc.get("used", self.settings.max_delta_bic)
        return float(used) if used is not None else float("nan")

    @property
    def chosen(self) -> CandidateScore | None:
        name = self.verdict_effect or self.verdict
        return next((c for c in self.candidates if c.effect == name), None)


def routes_agree(ends: Sequence[float], tolerance: float) -> bool:
    """Whether the competing routes of a fit (at least two) ended within ``tolerance`` times
    the lowest J of each other (never with ``tolerance`` 0)."""
    if tolerance <= 0.0 or len(ends) < 2 or not all(math.isfinite(f) for f in ends):
        return False
    return max(ends) - min(ends) <= tolerance * abs(min(ends))


def rank(scores: Sequence[CandidateScore], tie_margin: float = TIE_MARGIN) -> list[CandidateScore]:
    """Candidates by dBIC, except that those tied with the best (dBIC within
    ``max(TIE_ABSOLUTE, tie_margin x |best|)``) come first: accepted ones before the others, a
    catalog effect before generated (discovered) terms that fit as well (named physics over a
    generic form: n_p|n_p| terms imitate a propeller walk), then by held-out improvement."""
    by_bic = sorted(scores, key=lambda c: c.delta_bic)
    if not by_bic:
        return []
    best = by_bic[0].delta_bic
    margin = max(TIE_ABSOLUTE, tie_margin * abs(best)) if math.isfinite(best) else 0.0
    tied = [c for c in by_bic if c.delta_bic - best <= margin]
    tied.sort(
        key=lambda c: (not c.accepted, c.effect.startswith(DISCOVERED_PREFIX), -c.improvement)
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


def delta_bic(J_effect: float, J_control: float, k: int, n_eff: float) -> float:
    """BIC(effect) - BIC(control) with J as the residual sum of squares of n_eff samples."""
    if J_effect <= 0 or J_control <= 0:
        return math.inf
    return n_eff * math.log(J_effect / J_control) + k * math.log(n_eff)


def test_table(
    params: Parameters, recordings: Sequence[Recording], labels: Sequence[str]
) -> dict[str, dict[str, float]]:
    """{J: {label: value, "Total": value}} of ``params`` (with its effects) on the recordings."""
    effects = tuple(get_effect(n) for n, _ in params.effects)
    obj = Objective(recordings, labels=labels, effects=effects, ship=params.ship)
    raw = obj.table(params)
    out: dict[str, dict[str, float]] = {}
    for J in OBJECTIVES:
        row = {label: float(raw[J][label][0]) for label in dict.fromkeys(labels)}
        row["Total"] = float(sum(row.values()))
        out[J] = row
    return out


def _staged(
    store: StageStore,
    name: str,
    effects: Sequence[Effect],
    log: Log,
    run: Callable[[], Fit],
) -> Fit:
    done = store.load(name, effects)
    if done is not None:
        log(f"{name}: resumed from {store.path(name)} (J = {done.f:.2f})")
        return done
    result = run()
    store.save(name, result)
    n, sec = result.evaluations, result.seconds
    log(f"{name}: J = {result.f:.2f} after {n} evaluations ({sec:.0f} s)")
    return result


def diagnose(
    start: Parameters,
    train: Sequence[Recording],
    test: Sequence[Recording],
    out: Path,
    settings: DiagnoseSettings | None = None,
    test_labels: Sequence[str] | None = None,
    log: Log = _stderr,
) -> Diagnosis:
    """Run the whole procedure (see the module docstring); stages are stored under ``out``.

    Linear algebra runs on one BLAS thread: between the simulator's parallel kernels, OpenBLAS's
    second thread spins on and takes a core from them (Train-R with the paper's test set on 2
    cores: 190-192 -> 164-165 s), and the fits' numbers no longer depend on the machine's core
    count."""
    with threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(start, train, test, out, settings or DiagnoseSettings(), test_labels, log)


def _diagnose(
    start: Parameters,
    train: Sequence[Recording],
    test: Sequence[Recording],
    out: Path,
    s: DiagnoseSettings,
    test_labels: Sequence[str] | None,
    log: Log,
) -> Diagnosis:
    t0 = time.perf_counter()
    windows = cut_windows(train)
    fit_w, held_w = split_windows(windows)
    log(
        f"{len(train)} training recording(s) -> {len(windows)} windows: "
        f"{len(fit_w)} to fit, {len(held_w)} held out; {len(test)} test recording(s)"
    )
    store = StageStore(out / "stages", s.fingerprint() + _data_fingerprint(train, start))
    # the kernels of the base model and of every catalog effect, compiled side by side where
    # the cache lacks them (one after another as the stages reach them took minutes)
    precompile(
        tasks([()], ("simulate", "moments", "derivatives"))
        + tasks((e,) for e in s.candidate_effects()),
        log=log,
    )

    def lm(iterations: int, rtol: float, prior_weight: float = s.prior_weight) -> PolishSettings:
        # every refinement carries a weak prior toward the starting parameters
        return PolishSettings(
            max_iterations=iterations,
            rtol=rtol,
            max_evaluations=10**7,
            prior_weight=prior_weight,
            prior_dims=N_THETA,
        )

    common = FitSettings(
        objective=s.objective,
        sigma0=s.sigma0,
        effect_sigma=s.effect_sigma,
        polish=lm(s.final_polish_iterations, 1e-4),
    )
    w = s.workers

    def refit(
        recs: Sequence[Recording],
        p0: Parameters,
        effs: Sequence[Effect],
        settings: FitSettings,
        label: str,
    ) -> Fit:
        # every fit of the diagnosis: the prior of its refinement is centred on --params
        return fit(recs, p0, effs, settings, w, _progress(log, label), prior_center=start)

    def base_fit() -> Fit:
        # two starts, the better end wins (see step 2 of the module docstring)
        ends = [
            refit(windows, start, (), replace(common, budget=s.base_budget, seed=s.seed), "base")
        ]
        if s.base_lm_iterations > 0:
            descent = replace(common, budget=0, polish=lm(s.base_lm_iterations, 1e-4))
            ends.append(refit(windows, start, (), descent, "base, descent alone"))
            log(f"base: CMA-ES then descent J = {ends[0].f:.2f}, descent alone J = {ends[1].f:.2f}")
        best = min(ends, key=lambda e: e.f)
        return replace(
            best,
            evaluations=sum(e.evaluations for e in ends),
            seconds=sum(e.seconds for e in ends),
            ends=tuple(e.f for e in ends),
        )

    base = _staged(store, "base", (), log, base_fit)
    n_eff = n_effective(windows, s.objective)
    position = {id(w): i for i, w in enumerate(windows)}

    def floor_and_null(
        base_params: Parameters,
    ) -> tuple[NoiseModel, Linearised, AcceptanceNull, MisfitTest]:
        # the noise of the recordings and the floor of J it gives; the acceptance threshold:
        # the null of the best candidate's dBIC on these windows, from the fold fits linearised
        # at the base (with the library: the discovered candidate's null); is anything missing
        # at all? the base's misfit against the floor of a *fitted* model (its 57 parameters
        # also fit part of the noise: the refit factor, from the null)
        rng = np.random.default_rng(s.seed + 7)
        noise = calibrated_noise(windows, base_params, rng)
        floor = noise_floor(base_params, windows, noise, rng, s.floor_draws)
        lin = Linearised(
            base_params,
            windows,
            ([position[id(w)] for w in fit_w], [position[id(w)] for w in held_w]),
            s.candidate_effects(),
            objective=s.objective,
            prior_weight=s.prior_weight,
            library_terms=s.discover_terms if s.discover else 0,
        )
        null = acceptance_null(
            lin,
            noise,
            np.random.default_rng(s.seed + 11),
            n_eff=n_eff,
            draws=s.threshold_draws,
            alpha=s.alpha,
        )
        misfit = misfit_test(
            floor, s.objective, margin=s.floor_margin, refit_factor=null.refit_factor
        )
        log(
            f"misfit: {s.objective} {misfit.J:.3g} on the training windows, {misfit.ratio:.2f} x "
            f"the noise floor of a fitted model, {misfit.floor:.3g} (the refit keeps "
            f"{100 * null.refit_factor:.0f} % of the noise's J; z = {misfit.z:.1f}): "
            + ("significant" if misfit.significant else "within the floor")
        )
        return noise, lin, null, misfit

    noise, lin, null, misfit = floor_and_null(base.params)
    base_retry: dict[str, float] | None = None
    # the base's routes: CMA-ES then descent, the descent alone
    routes = {f"J_route{i + 1}": f for i, f in enumerate(base.ends)}
    agree = routes_agree(base.ends, s.base_retry_agreement)
    if misfit.significant and s.base_retry and agree:
        log(
            "base, second start not needed: the two routes ended at J = "
            + " and ".join(f"{f:.6g}" for f in base.ends)
            + f" (within {100 * s.base_retry_agreement:g} %)"
        )
        base_retry = {"J_first": base.f, "skipped": 1.0, **routes}
    elif misfit.significant and s.base_retry:
        # a misfit above the floor may be an identification that stopped in another basin of
        # the 57-parameter landscape, not missing physics: a second CMA-ES start (another seed)
        # must not do better before the misfit counts; a better end replaces the base
        retry = _staged(
            store,
            "base-retry",
            (),
            log,
            lambda: refit(
                windows,
                start,
                (),
                replace(common, budget=s.base_budget, seed=s.seed + 100),
                "base, second start",
            ),
        )
        base_retry = {"J_first": base.f, "J_second": retry.f, **routes}
        log(f"base, second start: J = {retry.f:.4g} against {base.f:.4g}")
        if retry.f < base.f:
            spent = base.evaluations + retry.evaluations
            base = replace(retry, evaluations=spent, seconds=base.seconds + retry.seconds)
            noise, lin, null, misfit = floor_and_null(base.params)
    # where does the base model miss? (all training windows)
    frame = residual_frame(base.params, windows)
    regime_scores = locate(frame)
    eq = equation_residuals(base.params, train)
    bias_scores = locate_bias(eq)
    top_windows = rank_windows(frame, "velocity", top=8)
    log(
        "mismatch concentrates in "
        + ", ".join(
            f"{r.variable} {r.worst_bin} ({r.group}, eta2 {r.eta2:.2f})" for r in regime_scores[:3]
        )
    )
    proposal: Proposal | None = None
    extra_effects: list[Effect] = []
    if s.discover:
        proposal = discover(
            base.params,
            windows,
            noise,
            np.random.default_rng(s.seed + 13),
            DiscoverySettings(
                max_terms=s.discover_terms,
                null_draws=s.null_draws,
                alpha=s.alpha,
                alternatives=s.discover_alternatives,
            ),
            log=log,
        )
        for eff in proposal.effects():  # the proposal and its alternatives (step 4b)
            if all(e.name != eff.name for e in extra_effects):
                extra_effects.append(eff)
    trajectory: TrajectorySelection | None = None
    if s.discover:
        # discovery in trajectory space: the library terms that explain most of the base's
        # trajectory residual (linearised), proposed beyond the null of the same selection
        trajectory = lin.select(lin.residuals(windows), n_eff)
        limit = min(null.per_candidate["discovered"]["quantile"], CEILING)
        proposed = bool(trajectory.terms) and trajectory.dbic <= limit
        log(
            f"discovery (trajectories): {' + '.join(trajectory.terms) or 'no term'}, linearised "
            f"dBIC {trajectory.dbic:.1f} against the null's {s.alpha:.0%} quantile {limit:.1f} "
            f"-> {'proposed' if proposed else 'not proposed'}"
        )
        if proposed:
            half = [max(4.0 * abs(c), 1e-6) for c in trajectory.coefficients]
            eff = with_bounds(discovered_effect(trajectory.terms), half, trajectory.shapes)
            if all(e.name != eff.name for e in extra_effects):
                extra_effects.append(eff)

    precompile(tasks((e,) for e in extra_effects), log=log)
    # two folds: fit on one half, judge on the other, and the other way round; every fit is the
    # same deterministic procedure from the base fitted on all windows (the effect alone on a
    # grid, then Levenberg-Marquardt on the 57 base parameters and the effect jointly), so the
    # control and the candidates differ only by what the effect can explain
    halves = ((fit_w, held_w), (held_w, fit_w))
    cand_settings = replace(
        common,
        budget=s.candidate_budget,
        seed=s.seed + 1,
        sigma0=s.refit_sigma,
        effect_only_budget=s.effect_only_budget,
        polish=lm(s.polish_iterations, PolishSettings.rtol),
    )

    refine_settings = replace(
        cand_settings,
        budget=0,
        effect_only_budget=0,
        polish=lm(s.refine_iterations, 1e-4),
    )

    def folds(
        name: str,
        effs: tuple[Effect, ...],
        settings: FitSettings,
        starts: Sequence[Fit] | None = None,
    ) -> tuple[list[Fit], FloatArray]:
        """The two fold fits of ``effs`` (stored) and the J of every held-out window."""
        out_fits: list[Fit] = []
        J_ho: list[float] = []
        for j, (fit_half, held_half) in enumerate(halves):
            p0 = base.params if starts is None else starts[j].params
            res = _staged(
                store,
                f"{stage_label(name, effs)}-fold{j}",
                effs,
                log,
                lambda fh=fit_half, p0=p0: refit(fh, p0, effs, settings, name),  # type: ignore[misc]
            )
            out_fits.append(res)
            J_ho += heldout_per_window(held_half, res.params, s.objective)
        return out_fits, np.asarray(J_ho)

    def score(
        eff: Effect,
        cand: list[Fit],
        J_ho: FloatArray,
        control: list[Fit],
        J_ho_control: FloatArray,
    ) -> CandidateScore:
        J_fit = sum(f.f for f in cand)
        # the fold whose fit gained more over its control carries the effect's values
        best = min(range(2), key=lambda j: cand[j].f / max(control[j].f, 1e-300))
        fits[eff.name] = cand[best]
        vals = effect_values(cand[best].params, (eff,))
        return CandidateScore(
            effect=eff.name,
            description=eff.description,
            regime=eff.regime,
            params=dict(zip(eff.param_names, vals, strict=True)),
            J_fit=J_fit,
            J_heldout=float(J_ho.sum()),
            improvement=typical_change(J_ho, J_ho_control),
            improvement_total=float(1.0 - J_ho.sum() / max(J_ho_control.sum(), 1e-300)),
            delta_bic=delta_bic(J_fit, sum(f.f for f in control), len(eff.params), n_eff),
            evaluations=sum(f.evaluations for f in cand),
        )

    control_folds, J_ho_control = folds("control", (), cand_settings)
    scores: list[CandidateScore] = []
    fits: dict[str, Fit] = {}
    cand_folds: dict[str, list[Fit]] = {}
    effects = (*s.candidate_effects(), *extra_effects)
    for i, eff in enumerate(effects, 1):
        log(f"candidate {i}/{len(effects)}: {eff.name}")
        t_c = time.perf_counter()
        cand_folds[eff.name], J_ho = folds(f"candidate-{eff.name}", (eff,), cand_settings)
        c = score(eff, cand_folds[eff.name], J_ho, control_folds, J_ho_control)
        c.seconds = time.perf_counter() - t_c
        scores.append(c)
    # refinement: the leading candidates and the control, each continued from its fold fits
    # with more Levenberg-Marquardt iterations (a joint fit that must undo what the base had
    # absorbed can still be descending after the first iterations)
    threshold = null.threshold if s.max_delta_bic is None else s.max_delta_bic
    leaders = [c.effect for c in sorted(scores, key=lambda c: c.delta_bic)[: s.refine_top]]
    # ... and every discovered candidate that passes the threshold already: a proposal and its
    # alternatives (step 4b of sweep.diagnose.discover) are ranked against each other, so each
    # needs its refined score (only refined candidates can be accepted)
    leaders += [
        c.effect
        for c in scores
        if c.effect.startswith(DISCOVERED_PREFIX)
        and c.delta_bic <= threshold
        and c.effect not in leaders
    ]
    if s.refine_top > 0 and s.refine_iterations > 0:
        control_folds, J_ho_control = folds("control-refined", (), refine_settings, control_folds)
        by_name = {e.name: e for e in effects}
        refined = []
        for name in leaders:
            eff = by_name[name]
            t_c = time.perf_counter()
            ref, J_ho = folds(
                f"candidate-{name}-refined", (eff,), refine_settings, cand_folds[name]
            )
            c = score(eff, ref, J_ho, control_folds, J_ho_control)
            c.refined = True
            c.seconds = time.perf_counter() - t_c
            refined.append(c)
        others = [c for c in scores if c.effect not in leaders]
        scores = refined + others
    log(
        f"acceptance: dBIC <= {threshold:.1f} ("
        + (
            f"the {s.alpha:.0%} quantile of the best candidate's dBIC over {null.draws} "
            f"noise-only copies, {null.quantile:.1f}, capped at {CEILING:.0f}"
            if s.max_delta_bic is None
            else "set by --max-delta-bic"
        )
        + ")"
    )
    for c in scores:
        c.accepted = (
            c.refined == (s.refine_top > 0 and s.refine_iterations > 0)
            and c.improvement >= s.min_improvement
            and c.delta_bic <= threshold
        )
    top = rank([c for c in scores if c.effect in leaders], s.tie_margin)
    scores = top + sorted([c for c in scores if c.effect not in leaders], key=lambda c: c.delta_bic)
    verdict_effect = scores[0].effect if scores and scores[0].accepted else ""
    if verdict_effect:
        verdict = "discovered" if verdict_effect.startswith(DISCOVERED_PREFIX) else verdict_effect
    else:
        verdict = "unexplained" if misfit.significant else "none"
    log(
        "ranking: "
        + ", ".join(
            f"{c.effect} dBIC {c.delta_bic:.0f} ({100 * c.improvement:+.1f}% held out)"
            for c in scores
        )
        + f" -> verdict: {verdict}"
    )

    final_settings = replace(
        common,
        budget=s.final_budget,
        seed=s.seed + 2,
        sigma0=s.refit_sigma,
        polish=lm(s.final_polish_iterations, 1e-4, s.final_prior_weight),
    )
    # the final stages' names carry their prior's weight (the settings' fingerprint does not)
    final = f"final-w{s.final_prior_weight:g}"
    before = _staged(
        store,
        f"{final}-base",
        (),
        log,
        lambda: refit(windows, base.params, (), final_settings, "final base"),
    )
    resembles: dict[str, float] = {}
    confirmation: dict[str, Any] | None = None
    if not verdict_effect:
        after = before
    else:
        chosen_eff = (next(e for e in effects if e.name == verdict_effect),)
        after_settings = replace(final_settings, effect_only_share=0.0, effect_only_budget=0)

        def final_after() -> Fit:
            # three starts, the better end wins: the candidate's joint fold fit (base re-balanced
            # with the effect, but on half the windows), the base fitted on all windows plus
            # the effect's values (which had absorbed part of the effect), and the base with the
            # effect at neutral (so that the model with the effect never ends above the base)
            starts = (
                fits[verdict_effect].params,
                with_effects(
                    base.params, chosen_eff, effect_values(fits[verdict_effect].params, chosen_eff)
                ),
                with_effects(before.params, chosen_eff),
            )
            ends = [
                refit(windows, p0, chosen_eff, after_settings, f"final {verdict}") for p0 in starts
            ]
            return min(ends, key=lambda e: e.f)

        after = _staged(
            store,
            stage_label(f"{final}-3-{verdict_effect}", chosen_eff),  # (three starts)
            chosen_eff,
            log,
            final_after,
        )
        # confirmation on all windows: the effect re-identified with the 57 parameters must
        # still pass the threshold against the base re-identified alike; an effect that refits
        # to nothing (its fold fits only re-balanced the base) is no missing physics
        confirm = delta_bic(after.f, before.f, len(chosen_eff[0].params), n_eff)
        confirmation = {"effect": verdict_effect, "delta_bic": confirm}
        if confirm > threshold:
            log(
                f"re-identification on all windows: {verdict_effect} changes the training J from "
                f"{before.f:.4g} to {after.f:.4g} (dBIC {confirm:.1f} > {threshold:.1f}): not "
                "confirmed"
            )
            verdict_effect = ""
            verdict = "unexplained" if misfit.significant else "none"
            after = before
        elif verdict == "discovered":  # which catalog effect's force pattern it is most like
            resembles = resemblance(base.params, windows, chosen_eff[0], scores, effects)
    labels = list(test_labels) if test_labels is not None else [r.name for r in test]
    test_before = test_table(before.params, test, labels) if test else {}
    test_after = test_table(after.params, test, labels) if test else {}
    if test:
        log(
            f"test {s.objective}: before {test_before[s.objective]['Total']:.1f}, "
            f"after {test_after[s.objective]['Total']:.1f}"
        )
    # does the model carry over to the test recordings? (an effect the training manoeuvres do
    # not excite leaves the training windows at the floor)
    gen: GeneralisationTest | None = None
    gen_after: GeneralisationTest | None = None
    # (every window the test J sums over, the short last one of each recording too)
    test_w = cut_windows(test, min_window=0.0) if test and s.generalisation_draws > 0 else []
    if test_w:

        def carry_over(p: Parameters) -> GeneralisationTest:
            return generalisation_test(
                p,
                windows,
                test_w,
                noise,
                np.random.default_rng(s.seed + 17),
                objective=s.objective,
                prior_weight=s.final_prior_weight,
                draws=s.generalisation_draws,
                alpha=s.generalisation_alpha,
                margin=s.generalisation_margin,
            )

        gen = carry_over(before.params)
        if verdict_effect:
            gen_after = carry_over(after.params)
        for label, g in (("before", gen), ("after", gen_after)):
            if g is not None:
                log(
                    f"test recordings ({label}): {s.objective} {g.J:.3g}, {g.ratio:.2f} x the "
                    f"median of a model exact in form identified on these windows "
                    f"({g.median:.3g}; {100 * (1 - g.alpha):.0f} % quantile {g.quantile:.3g}): "
                    + ("significant" if g.significant else "within")
                )
        if not verdict_effect and gen.significant and verdict == "none":
            verdict = "unexplained"
            log("verdict: unexplained (the model does not carry over to the test recordings)")
    return Diagnosis(
        settings=s,
        train_windows=len(windows),
        fit_windows=len(fit_w),
        heldout_windows=len(held_w),
        base=base,
        control=control_folds[0],
        candidates=scores,
        verdict=verdict,
        before=before,
        after=after,
        test_before=test_before,
        test_after=test_after,
        regimes=[asdict(r) for r in regime_scores[:10]],
        biases=[asdict(b) for b in bias_scores[:10]],
        windows=[{str(k): v for k, v in r.items()} for r in top_windows.to_dict("records")],
        seconds=time.perf_counter() - t0,
        n_eff=n_eff,
        misfit=misfit,
        proposal=proposal,
        generalisation=gen,
        generalisation_after=gen_after,
        verdict_effect=verdict_effect,
        extra={
            "J_heldout_control": float(J_ho_control.sum()),
            "J_heldout_control_per_window": [float(v) for v in J_ho_control],
            "noise": noise.as_dict(),
            "resemblance": resembles,
            "acceptance": {**null.as_dict(), "used": threshold},
            "trajectory_discovery": asdict(trajectory) if trajectory is not None else None,
            "confirmation": confirmation,
            "base_retry": base_retry,
        },
    )


def stage_label(name: str, effects: Sequence[Effect]) -> str:
    """A file-name-safe stage name; a generated effect's name is replaced by a hash of its terms
    and search box (a different proposal is a different stage)."""
    for e in effects:
        if e.name.startswith(DISCOVERED_PREFIX) and e.name in name:
            h = hashlib.sha256(e.name.encode())
            h.update(json.dumps(e.bounds).encode())
            name = name.replace(e.name, f"discovered-{h.hexdigest()[:10]}")
    return name


def _data_fingerprint(recordings: Sequence[Recording], start: Parameters) -> str:
    h = hashlib.sha256()
    for r in recordings:
        h.update(r.name.encode())
        h.update(np.ascontiguousarray(r.x).tobytes())
        h.update(np.ascontiguousarray(r.u).tobytes())
    h.update(json.dumps(start.to_dict(), sort_keys=True).encode())
    return h.hexdigest()[:12]
