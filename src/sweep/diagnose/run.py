"""The diagnosis: identify the base model, locate the mismatch, rank candidate physics, re-identify.

:func:`diagnose` runs the stages in order over one :class:`~sweep.diagnose.context.Context`:
base (:mod:`~sweep.diagnose.base`), floor, null and misfit
(:mod:`~sweep.diagnose.calibration`), location (:mod:`~sweep.diagnose.location`), proposals
(:mod:`~sweep.diagnose.proposals`), the learned shape (:mod:`~sweep.diagnose.shaping`),
candidates and their refinement
(:mod:`~sweep.diagnose.candidates`), threshold and verdict (:mod:`~sweep.diagnose.verdict`),
re-identification and confirmation (:mod:`~sweep.diagnose.final`), the test recordings
(:mod:`~sweep.diagnose.carry_over`), and returns the :class:`Diagnosis` the report shows. Every
fit is stored in ``DIR/stages/`` as soon as it is done; running the same command again resumes
after the last finished stage.

The procedure is described in the user guide (docs/guide/diagnosis.md).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from mmg import Parameters
from mmg.discovered import discovered_effect
from mmg.domain import inner_name
from mmg.effect import Effect
from mmg.library import SEARCHED
from mmg.precompile import precompile, tasks
from mmg.shapes import probe_effect
from sweep.data.ranges import Departure, Ranges
from sweep.data.recordings import Recording
from sweep.diagnose.base import identify_base, second_start
from sweep.diagnose.calibration import Calibration, calibrate
from sweep.diagnose.candidates import Candidates, fit_candidates, refine
from sweep.diagnose.carry_over import CarryOver, carry_over
from sweep.diagnose.context import Context, Log, stderr_log
from sweep.diagnose.discover import Proposal
from sweep.diagnose.final import reidentify
from sweep.diagnose.fit import Fit
from sweep.diagnose.floor import MisfitTest, above_floor
from sweep.diagnose.generalise import GeneralisationTest
from sweep.diagnose.location import Location, locate_misfit
from sweep.diagnose.memory import probe_kernels, propose_memory
from sweep.diagnose.proposals import Proposals, propose
from sweep.diagnose.scoring import CandidateScore
from sweep.diagnose.sessions import check_sessions
from sweep.diagnose.settings import DiagnoseSettings
from sweep.diagnose.shapes import probe_groups
from sweep.diagnose.shaping import ShapeProposal, propose_shape
from sweep.diagnose.transfer import check_transfer
from sweep.diagnose.trust import trust_of
from sweep.diagnose.verdict import acceptance_threshold, decide
from sweep.diagnose.waves import PEAK_TERMS, propose_waves


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
    #: the ranges of the training recordings' states (where the finding was fitted)
    ranges: Ranges | None = None
    #: the test recordings' departures from those ranges
    departures: list[Departure] = field(default_factory=list)
    #: the test table of the finding without its box (extrapolated beyond the ranges)
    test_unbounded: dict[str, dict[str, float]] = field(default_factory=dict)
    #: {"before"/"after": {label: [diverged, all] subsequences}}: the test recordings on which
    #: the model's simulation diverged (their J is the divergence penalty, not a misfit)
    test_diverged: dict[str, dict[str, list[int]]] = field(default_factory=dict)
    #: the learned shape of the missing force (None with shapes off)
    shape: ShapeProposal | None = None

    @property
    def threshold(self) -> float:
        """The dBIC a candidate had to reach."""
        acc = self.extra.get("acceptance", {})
        used = acc.get("used", self.settings.max_delta_bic)
        return float(used) if used is not None else float("nan")

    @property
    def finding_name(self) -> str:
        """The name the finding carries in the model after (its box appended,
        :mod:`mmg.domain`); "" without a finding."""
        if not self.verdict_effect:
            return ""
        return next(
            (n for n, _ in self.after.params.effects if inner_name(n) == self.verdict_effect), ""
        )

    def finding_values(self) -> dict[str, float]:
        """The finding's parameter values in the model after (empty without one)."""
        name = self.finding_name
        return dict(next((v for n, v in self.after.params.effects if n == name), ()))

    @property
    def more_missing(self) -> bool:
        """Whether the model with the finding is still above the noise floor on the training
        windows (the misfit test's floor and rule; False without a finding)."""
        m = self.misfit
        if m is None or not self.verdict_effect:
            return False
        J = float(self.after.f)
        return above_floor(J, m.floor, (J - m.floor) / m.floor_sd, m.margin, m.z_crit)

    @property
    def chosen(self) -> CandidateScore | None:
        """The chosen candidate's score (None when nothing was chosen)."""
        name = self.verdict_effect or self.verdict
        return next((c for c in self.candidates if c.effect == name), None)


def diagnose(
    start: Parameters,
    train: Sequence[Recording],
    test: Sequence[Recording],
    out: Path,
    settings: DiagnoseSettings | None = None,
    test_labels: Sequence[str] | None = None,
    log: Log = stderr_log,
) -> Diagnosis:
    """Run the whole procedure from ``start`` on the training recordings, judged on the test
    recordings (labelled ``test_labels``); stages are stored under ``out``.

    Linear algebra runs on one BLAS thread: between the simulator's parallel kernels, OpenBLAS's
    second thread spins on and takes a core from them (Train-R with the paper's test set on 2
    cores: 190-192 -> 164-165 s), and the fits' numbers no longer depend on the machine's core
    count."""
    with threadpool_limits(limits=1, user_api="blas"):
        t0 = time.perf_counter()
        ctx = Context.open(
            start, train, test, out, settings or DiagnoseSettings(), test_labels, log
        )
        return run_stages(ctx, t0)


#: the directory of round K (K > 1) of :func:`diagnose_rounds`, below the first round's
ROUND_DIR = "round-{k}"


def round_dir(out: Path, k: int) -> Path:
    """Where round ``k`` (1-based) of a diagnosis in ``out`` keeps its stages and report."""
    return out if k == 1 else out / ROUND_DIR.format(k=k)


def diagnose_rounds(
    start: Parameters,
    train: Sequence[Recording],
    test: Sequence[Recording],
    out: Path,
    settings: DiagnoseSettings | None = None,
    test_labels: Sequence[str] | None = None,
    log: Log = stderr_log,
) -> list[Diagnosis]:
    """:func:`diagnose` in rounds: while the last round's finding leaves the training windows
    above the noise floor (:attr:`Diagnosis.more_missing`) and ``settings.rounds`` allows, the
    next round diagnoses the model with the finding (its ``after``), the finding held at its
    values and the base parameters refitted around it (:func:`sweep.diagnose.context.held_start`),
    in ``out/round-K``. The test recordings take no part in the decision. Returns the rounds'
    diagnoses; the last one with a finding holds the final model (:func:`final_round`)."""
    s = settings or DiagnoseSettings()
    rounds = [diagnose(start, train, test, out, s, test_labels, log)]
    while len(rounds) < s.rounds and rounds[-1].more_missing:
        k = len(rounds) + 1
        last = rounds[-1]
        log(
            f"round {k}: the model with {last.verdict_effect} is still above the noise floor on "
            f"the training windows (J {last.after.f:.4g}); what is missing beyond it, the finding "
            f"held at its values -> {round_dir(out, k)}"
        )
        later = replace(s, take="")  # --take names a candidate of the first round
        rounds.append(
            diagnose(last.after.params, train, test, round_dir(out, k), later, test_labels, log)
        )
    return rounds


def final_round(rounds: Sequence[Diagnosis]) -> Diagnosis:
    """The round whose model after is the final model: the last one that accepted a finding
    (the first round when none did)."""
    return next((d for d in reversed(rounds) if d.verdict_effect), rounds[0])


class StageClock:
    """Wall time per stage [s], logged as one line at the end."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        """The time since the previous lap goes to stage ``name``."""
        now = time.perf_counter()
        self.seconds[name] = self.seconds.get(name, 0.0) + now - self._last
        self._last = now

    def text(self) -> str:
        return ", ".join(f"{k} {v:.0f} s" for k, v in self.seconds.items())


def probes(discover: bool = True, shapes: bool = True) -> list[tuple[Effect, tuple[str, ...]]]:
    """(effect, kernel entry points) of the probes that the discovery's library columns (every
    searched term, through one generated effect) and the shapes' columns (one probe for every
    candidate group: its knots come with the lanes) simulate and evaluate, and of the equation
    data of the waves' periodogram (:mod:`sweep.diagnose.waves`)."""
    out: list[tuple[Effect, tuple[str, ...]]] = []
    if discover:
        out.append((discovered_effect(list(SEARCHED)), ("simulate", "accelerations")))
    if shapes:
        out.append((probe_effect(probe_groups([])), ("simulate",)))
        # the equation data of the waves' periodogram (its residual and the base's regressors)
        out.append((discovered_effect(list(PEAK_TERMS)), ("accelerations",)))
    return out


def probe_tasks(ctx: Context) -> list[tuple[tuple[Effect, ...], str]]:
    """The kernels of :func:`probes` on the base model, with the stages that use them on."""
    s = ctx.settings
    out = [
        task
        for probe, entries in probes(s.discover, s.shapes)
        for task in tasks([ctx.with_base((probe,))], entries)
    ]
    if s.shapes:
        out += probe_kernels(ctx)
    return out


def run_stages(ctx: Context, t0: float) -> Diagnosis:
    """The stages in order; ``t0`` [s, ``time.perf_counter``] is when the diagnosis began."""
    s = ctx.settings
    clock = StageClock()
    # the kernels of the base model, of every catalog effect and of the probes of the library
    # and of the shapes, compiled side by side where the cache lacks them (one after another as
    # the stages reach them took minutes)
    precompile(
        tasks([ctx.base_effects], ("simulate", "moments", "derivatives"))
        + tasks(ctx.with_base((e,)) for e in ctx.candidate_effects())
        + probe_tasks(ctx),
        log=ctx.log,
    )
    clock.lap("compilation")
    base = identify_base(ctx)
    clock.lap("base")
    base, cal, base_retry = second_start(ctx, base, calibrate(ctx, base.params))
    clock.lap("calibration")
    location = locate_misfit(ctx, base.params)
    clock.lap("location")
    proposals = propose(ctx, base.params, cal)
    clock.lap("proposals")
    shape = propose_shape(ctx, base, cal)
    extra = proposals.effects
    if shape is not None and shape.proposed:
        extra = (*extra, shape.effect)
        named = tuple(e for e in (shape.form, shape.closest) if e is not None)
        extra = (*extra, *named)
        sets = [ctx.with_base((shape.effect,)), *(ctx.with_base((e,)) for e in named)]
        precompile(tasks(sets), log=ctx.log)
    memory = propose_memory(ctx, base, cal)
    # (a rate limit the shapes named already is that candidate: not fitted twice)
    if memory is not None and memory.proposed and memory.name not in {e.name for e in extra}:
        extra = (*extra, memory.proposal)
        precompile(tasks([ctx.with_base((memory.proposal,))]), log=ctx.log)
    waves = propose_waves(ctx, base, cal)
    if waves is not None and waves.proposed and waves.name not in {e.name for e in extra}:
        extra = (*extra, waves.proposal)
        precompile(tasks([ctx.with_base((waves.proposal,))]), log=ctx.log)
    clock.lap("shapes")
    threshold = acceptance_threshold(s, cal.null)
    cands = refine(ctx, base, fit_candidates(ctx, base, extra), threshold)
    check_sessions(ctx, base, cands)
    check_transfer(ctx, base, cands, cal.null, threshold, cal.misfit.significant)
    clock.lap("candidates")
    verdict = decide(ctx, cands.scores, cands.leaders, cal.null, cal.misfit.significant)
    final = reidentify(ctx, base, cands, verdict, threshold, cal.misfit.significant)
    clock.lap("re-identification")
    tested = carry_over(ctx, final, cal.noise)
    clock.lap("test recordings")
    trust = {
        "before": trust_of(
            tested.final.before.params, ctx.windows, s.objective, np.random.default_rng(s.seed + 23)
        )
    }
    if tested.final.verdict.effect:
        trust["after"] = trust_of(
            tested.final.after.params, ctx.windows, s.objective, np.random.default_rng(s.seed + 23)
        )
    clock.lap("trust")
    ctx.log(f"time per stage: {clock.text()}")
    out = report(ctx, t0, base, cal, base_retry, location, proposals, cands, tested)
    out.shape = shape
    out.extra["memory"] = memory.as_dict() if memory is not None else None
    out.extra["waves"] = waves.as_dict() if waves is not None else None
    out.extra["stage_seconds"] = clock.seconds
    out.extra["trust"] = trust
    out.extra["time_step"] = float(np.median(np.concatenate([np.diff(w.t) for w in ctx.windows])))
    return out


def report(
    ctx: Context,
    t0: float,
    base: Fit,
    cal: Calibration,
    base_retry: dict[str, float] | None,
    location: Location,
    proposals: Proposals,
    cands: Candidates,
    tested: CarryOver,
) -> Diagnosis:
    """The :class:`Diagnosis` of the stages' results."""
    final = tested.final
    trajectory = proposals.trajectory
    J_ho_control = cands.control.J_heldout
    return Diagnosis(
        settings=ctx.settings,
        train_windows=len(ctx.windows),
        fit_windows=len(ctx.fit_w),
        heldout_windows=len(ctx.held_w),
        base=base,
        control=cands.control.fits[0],
        candidates=final.verdict.scores,
        verdict=final.verdict.verdict,
        before=final.before,
        after=final.after,
        test_before=tested.test_before,
        test_after=tested.test_after,
        regimes=[asdict(r) for r in location.regimes[:10]],
        biases=[asdict(b) for b in location.biases[:10]],
        windows=[{str(k): v for k, v in r.items()} for r in location.windows.to_dict("records")],
        seconds=time.perf_counter() - t0,
        n_eff=ctx.n_eff,
        misfit=cal.misfit,
        proposal=proposals.proposal,
        generalisation=tested.generalisation,
        generalisation_after=tested.generalisation_after,
        verdict_effect=final.verdict.effect,
        ranges=tested.ranges,
        departures=tested.departures,
        test_unbounded=tested.test_unbounded,
        test_diverged=tested.test_diverged,
        extra={
            "J_heldout_control": float(J_ho_control.sum()),
            "J_heldout_control_per_window": [float(v) for v in J_ho_control],
            "noise": cal.noise.as_dict(),
            "noise_first_sample": cal.noise.first.as_dict(),
            "resemblance": final.resemblance,
            "acceptance": {
                **cal.null.as_dict(),
                "used": acceptance_threshold(ctx.settings, cal.null),
            },
            "trajectory_discovery": asdict(trajectory) if trajectory is not None else None,
            "confirmation": final.confirmation,
            "base_retry": base_retry,
            "taken": final.verdict.taken,
        },
    )
