"""What every stage of a diagnosis reads: the inputs, the windows, the settings, the stage store
and the log, with the one way the diagnosis fits a model (:meth:`Context.refit`) and stores a
stage (:meth:`Context.staged`)."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from mmg import Effect, Parameters, get_effect
from mmg.domain import inner_name
from mmg.fixed import fixed
from mmg.fixed import split_name as fixed_split
from mmg.params import N_THETA
from sweep.data.recordings import Recording
from sweep.diagnose.fit import Fit, FitSettings, fit
from sweep.diagnose.scoring import n_effective
from sweep.diagnose.settings import DiagnoseSettings
from sweep.diagnose.store import StageStore, data_fingerprint
from sweep.diagnose.windows import cut_windows, split_sessions, split_windows
from sweep.identification.polish import PolishSettings
from sweep.identification.vector import effect_values, with_effects

#: where the diagnosis reports its progress: one line per call
Log = Callable[[str], None]


def stderr_log(message: str) -> None:
    """The default :data:`Log`: ``[diagnose] message`` on standard error."""
    print(f"[diagnose] {message}", file=sys.stderr, flush=True)


def progress(log: Log, label: str, every: float = 10.0) -> Any:
    """A CMA-ES progress callback that logs ``label``'s evaluations at most every ``every`` s."""
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


def held_start(start: Parameters) -> Parameters:
    """``start`` with each effect it carries held at its values (:func:`mmg.fixed.fixed`): a
    model that carries findings is diagnosed for what is missing beyond them (its base
    parameters are refitted around them, the findings stay as they are)."""
    held = []
    for name, values in start.effects:
        eff = get_effect(name)
        if eff.params:
            eff = fixed(eff, dict(values))
        held.append((eff.name, ()))
    return Parameters(start.theta, start.ship, tuple(held))


@dataclass(frozen=True)
class Context:
    """One diagnosis's inputs and surroundings, shared by its stages.

    ``windows`` are the training recordings cut into the objective's windows, ``fit_w`` and
    ``held_w`` their two halves (the same Recording objects); ``n_eff`` is the effective number
    of independent residuals of all windows (:func:`sweep.diagnose.scoring.n_effective`).
    """

    start: Parameters
    train: Sequence[Recording]
    test: Sequence[Recording]
    test_labels: list[str]
    settings: DiagnoseSettings
    windows: list[Recording]
    fit_w: list[Recording]
    held_w: list[Recording]
    store: StageStore
    log: Log
    n_eff: float
    #: the windows in two halves of whole sessions (days; None: all of one session), for the
    #: check of findings tied to heading, position or time (:mod:`sweep.diagnose.sessions`)
    session_w: tuple[list[Recording], list[Recording]] | None = None
    #: per generated effect with a smoothness penalty (a learned shape): the penalty (k, k) its
    #: fits add, its effective degrees of freedom (dBIC's parameter count) and start values
    penalties: dict[str, tuple[tuple[float, ...], ...]] = field(default_factory=dict)
    dof: dict[str, float] = field(default_factory=dict)
    starts: dict[str, list[float]] = field(default_factory=dict)

    @property
    def base_effects(self) -> tuple[Effect, ...]:
        """The effects the model of ``start`` carries, held at its values (:func:`held_start`):
        part of every model the diagnosis fits."""
        return tuple(get_effect(n) for n, _ in self.start.effects)

    def candidate_effects(self) -> tuple[Effect, ...]:
        """The settings' catalog candidates without those the base already carries (held:
        a second copy of an identified effect adds nothing but a shift of its values)."""
        held = {inner_name(fixed_split(e.name)[0]) for e in self.base_effects}
        return tuple(e for e in self.settings.candidate_effects() if e.name not in held)

    def with_base(self, effs: Sequence[Effect]) -> tuple[Effect, ...]:
        """``effs`` after the effects the base model carries (:attr:`base_effects`)."""
        names = {e.name for e in effs}
        return (*(e for e in self.base_effects if e.name not in names), *effs)

    def parameter_count(self, effect: Effect) -> float:
        """The parameters an effect counts in dBIC: its effective degrees of freedom when it has
        a penalty, else its number of parameters."""
        return self.dof.get(effect.name, float(len(effect.params)))

    @classmethod
    def open(
        cls,
        start: Parameters,
        train: Sequence[Recording],
        test: Sequence[Recording],
        out: Path,
        settings: DiagnoseSettings,
        test_labels: Sequence[str] | None,
        log: Log,
    ) -> Context:
        """Cut and split the training windows and open the stage store under ``out/stages``."""
        start = held_start(start)
        windows = cut_windows(train)
        fit_w, held_w = split_windows(windows)
        log(
            f"{len(train)} training recording(s) -> {len(windows)} windows: "
            f"{len(fit_w)} to fit, {len(held_w)} held out; {len(test)} test recording(s)"
        )
        fingerprint = settings.fingerprint() + data_fingerprint(train, start)
        return cls(
            start=start,
            train=train,
            test=test,
            test_labels=list(test_labels) if test_labels is not None else [r.name for r in test],
            settings=settings,
            windows=windows,
            fit_w=fit_w,
            held_w=held_w,
            store=StageStore(out / "stages", fingerprint),
            log=log,
            n_eff=n_effective(windows, settings.objective),
            session_w=split_sessions(windows),
        )

    def lm(self, iterations: int, rtol: float, prior_weight: float | None = None) -> PolishSettings:
        """Levenberg-Marquardt settings; every refinement carries the weak prior toward the
        starting parameters (``prior_weight``, by default the settings')."""
        return PolishSettings(
            max_iterations=iterations,
            rtol=rtol,
            max_evaluations=10**7,
            prior_weight=self.settings.prior_weight if prior_weight is None else prior_weight,
            prior_dims=N_THETA,
        )

    @property
    def common(self) -> FitSettings:
        """The fit settings every stage starts from."""
        s = self.settings
        return FitSettings(
            objective=s.objective,
            sigma0=s.sigma0,
            effect_sigma=s.effect_sigma,
            polish=self.lm(s.final_polish_iterations, 1e-4),
        )

    def refit(
        self,
        recs: Sequence[Recording],
        p0: Parameters,
        effs: Sequence[Effect],
        settings: FitSettings,
        label: str,
    ) -> Fit:
        """Every fit of the diagnosis: from ``p0`` on ``recs``; its refinement's prior is
        centred on the start (``--params``). The effects the base carries
        (:attr:`base_effects`) come first, held at their values. An effect with a penalty (a
        learned shape) is fitted with it, by Levenberg-Marquardt from its values in ``p0`` (no
        effect-only search)."""
        penalised = [self.penalties[e.name] for e in effs if e.name in self.penalties]
        if penalised and len(effs) == 1:
            settings = replace(settings, penalty=penalised[0], effect_only_budget=0)
        every = self.with_base(effs)
        p0 = with_effects(p0, every, effect_values(p0, every))
        return fit(
            recs,
            p0,
            every,
            settings,
            self.settings.workers,
            progress(self.log, label),
            prior_center=self.start,
        )

    def staged(self, name: str, effects: Sequence[Effect], run: Callable[[], Fit]) -> Fit:
        """The fit of stage ``name``: from the store when it is there, else ``run()`` stored."""
        done = self.store.load(name, effects)
        if done is not None:
            self.log(f"{name}: resumed from {self.store.path(name)} (J = {done.f:.2f})")
            return done
        result = run()
        self.store.save(name, result)
        n, sec = result.evaluations, result.seconds
        self.log(f"{name}: J = {result.f:.2f} after {n} evaluations ({sec:.0f} s)")
        return result
