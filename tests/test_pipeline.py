"""Stages of the diagnosis on their own, from hand-made contexts and inputs (no simulation)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import numpy as np
import pytest

from mmg import efd_parameters, get_effect
from sweep.diagnose.candidates import FoldFits, leading, score
from sweep.diagnose.context import Context
from sweep.diagnose.fit import Fit
from sweep.diagnose.report import names_shape, names_shape_text
from sweep.diagnose.scoring import CandidateScore, typical_change
from sweep.diagnose.settings import DiagnoseSettings
from sweep.diagnose.store import StageStore
from sweep.diagnose.threshold import AcceptanceNull
from sweep.diagnose.transfer import needs_transfer
from sweep.diagnose.verdict import decide
from sweep.identification.vector import with_effects

N_EFF = 400.0


def _context(tmp_path: Path, lines: list[str], **settings: object) -> Context:
    """A context without windows: enough for the stages that only score, rank and store."""
    return Context(
        start=efd_parameters(),
        train=(),
        test=(),
        test_labels=[],
        settings=DiagnoseSettings(**settings),  # type: ignore[arg-type]
        windows=[],
        fit_w=[],
        held_w=[],
        store=StageStore(tmp_path / "stages", "fingerprint"),
        log=lines.append,
        n_eff=N_EFF,
    )


def _null(threshold: float, heldout: float = 0.0, worst_run: float = 0.3) -> AcceptanceNull:
    return AcceptanceNull(
        alpha=0.05,
        draws=3,
        threshold=threshold,
        quantile=threshold,
        best=[],
        heldout_quantile=heldout,
        worst_run_quantile=worst_run,
        noise_J=1.0,
        run_noise={"run1": 1.0, "run2": 2.0, "run3": 1.0},
    )


def _score(
    effect: str, dbic: float, improvement: float, refined: bool = True, gain: float = 1.0
) -> CandidateScore:
    """A score whose held-out runs follow its gain: two better and one unchanged for a gain,
    two worse for a loss."""
    sign = -1.0 if gain > 0 else 1.0
    return CandidateScore(
        effect=effect,
        description="",
        regime="",
        params={},
        J_fit=1.0,
        J_heldout=1.0,
        improvement=improvement,
        delta_bic=dbic,
        refined=refined,
        heldout_gain=gain,
        run_changes={"run1": 0.1 * sign, "run2": 0.05 * sign, "run3": 0.0},
        worst_run_change=max(0.1 * sign, 0.0),
    )


def _fit(f: float, value: float = 0.0) -> Fit:
    params = with_effects(efd_parameters(), (get_effect("rudder_offset"),), [value])
    return Fit(params=params, effects=(), f=f, evaluations=10, seconds=0.0, history=[])


def test_the_verdict_stage_accepts_ranks_and_names_the_verdict(tmp_path: Path) -> None:
    lines: list[str] = []
    ctx = _context(tmp_path, lines)
    scores = [
        _score("rudder_offset", -50.0, 0.10),
        _score("current", -48.0, 0.30),  # tied with the best (within 10): held out decides
        _score("propeller_walk", -45.0, -0.40),  # passes dBIC, vetoed by the held-out change
        _score("rudder_stall", 5.0, 0.0, refined=False),  # not a leader: after them, unrefined
    ]
    leaders = ["rudder_offset", "current", "propeller_walk"]
    v = decide(ctx, scores, leaders, _null(-10.0), significant=True)
    assert [c.effect for c in v.scores] == [
        "current",
        "rudder_offset",
        "propeller_walk",
        "rudder_stall",
    ]
    assert [c.accepted for c in v.scores] == [True, True, False, False]
    assert (v.verdict, v.effect) == ("current", "current")
    assert lines[0].startswith("acceptance: dBIC <= -10.0 (the 5% quantile")
    assert lines[1].startswith("carrying over: a held-out gain above 0 ")
    assert lines[2].endswith("-> verdict: current")


def test_a_candidate_that_does_not_carry_over_to_held_out_runs_is_not_accepted(
    tmp_path: Path,
) -> None:
    """Passing dBIC is not enough: the fits must gain on the held-out runs more than the best
    candidate's fits gain on noise alone (here 0.5), make more held-out runs better than worse,
    and make no run worse than the null's worst run (here 0.3): relative to the control's J of
    the run for a catalog effect, in units of its noise J for a generated one; a loss there
    never passes."""
    lines: list[str] = []
    ctx = _context(tmp_path, lines)
    scores = [
        _score("rudder_offset", -200.0, 0.05, gain=0.4),  # gains, but less than noise would
        _score("current", -190.0, -0.02, gain=-3.0),  # worse on the held-out runs
        _score("propeller_walk", -30.0, 0.02, gain=0.6),
    ]
    leaders = ["rudder_offset", "current", "propeller_walk"]
    v = decide(ctx, scores, leaders, _null(-10.0, heldout=0.5), significant=True)
    assert {c.effect: c.carries_over for c in v.scores} == {
        "rudder_offset": False,
        "current": False,
        "propeller_walk": True,
    }
    # the better fits do not carry over: the first accepted candidate in rank order is chosen
    assert (v.verdict, v.effect) == ("propeller_walk", "propeller_walk")
    assert "does not carry over" in lines[2]
    # a catalog effect that makes one held-out run worse, relative to the control's J of that
    # run, than the null's worst run is not accepted ...
    scores[2].worst_run_change = 0.45
    scores[2].run_changes = {"run1": -0.5, "run2": 0.45, "run3": -0.1}
    v = decide(ctx, scores, leaders, _null(-10.0, heldout=0.5), significant=True)
    assert (v.verdict, v.effect) == ("unexplained", "")
    assert "2 of 3 runs better, worst run +45.0 %" in lines[-1]
    # ... nor one that makes as many held-out runs worse as better
    scores[2].worst_run_change = 0.08
    scores[2].run_changes = {"run1": -0.5, "run2": 0.08, "run3": 0.0}
    v = decide(ctx, scores, leaders, _null(-10.0, heldout=0.5), significant=True)
    assert (v.verdict, v.effect) == ("unexplained", "")
    scores[2].run_changes = {"run1": -0.5, "run2": 0.08, "run3": -0.01}
    scores[2].run_losses = {"run1": -0.5, "run2": 0.8, "run3": -0.01}
    v = decide(ctx, scores, leaders, _null(-10.0, heldout=0.5), significant=True)
    assert (v.verdict, v.effect) == ("propeller_walk", "propeller_walk")
    # a generated candidate with the same runs: its loss on run2 is 0.4 x that run's noise J,
    # beyond the null's 0.3
    found = "discovered:N_nn"
    scores[2].effect = found
    v = decide(ctx, scores, [*leaders[:2], found], _null(-10.0, heldout=0.5), significant=True)
    assert (v.verdict, v.effect) == ("unexplained", "")
    assert "largest loss of a run +40 % of its noise J: does not carry over" in lines[-1]
    scores[2].run_losses = {"run1": -0.5, "run2": 0.5, "run3": -0.01}
    v = decide(ctx, scores, [*leaders[:2], found], _null(-10.0, heldout=0.5), significant=True)
    assert (v.verdict, v.effect) == ("discovered", found)
    # a negative null quantile does not let a held-out loss through
    v = decide(ctx, scores[1:2], ["current"], _null(-10.0, heldout=-5.0), significant=False)
    assert (v.verdict, v.effect) == ("none", "")


def test_within_the_noise_floor_a_catalog_effect_s_worst_run_counts_in_its_noise_j(
    tmp_path: Path,
) -> None:
    """A catalog effect whose worst held-out run is 8 % worse relative to the control's J of it
    (within the null's 30 %) but 0.4 x that run's noise J (beyond 0.3) carries over when the
    base misses a force (the misfit beyond the floor) and not when the misfit is within the
    floor, where the control's J is no longer inflated by a missing force."""
    lines: list[str] = []
    ctx = _context(tmp_path, lines)
    c = _score("propeller_walk", -50.0, 0.1, gain=0.6)
    c.run_changes = {"run1": -0.5, "run2": 0.08, "run3": -0.01}
    c.run_losses = {"run1": -0.5, "run2": 0.8, "run3": -0.01}
    c.worst_run_change = 0.08
    v = decide(ctx, [c], ["propeller_walk"], _null(-10.0, heldout=0.5), significant=True)
    assert (v.verdict, v.effect) == ("propeller_walk", "propeller_walk")
    assert "of the control's J of that run for a catalog effect" in lines[1]
    v = decide(ctx, [c], ["propeller_walk"], _null(-10.0, heldout=0.5), significant=False)
    assert (v.verdict, v.effect) == ("none", "")
    assert not v.scores[0].carries_over
    assert (
        "of its noise J for every candidate, the misfit being within the noise floor" in (lines[-2])
    )
    assert "largest loss of a run +40 % of its noise J: does not carry over" in lines[-1]


def test_within_the_noise_floor_a_refused_catalog_effect_gets_the_transfer_check(
    tmp_path: Path,
) -> None:
    """The transfer check's second look goes to generated candidates refused by their worst
    run, and, within the noise floor, to catalog effects refused alike; never to one that
    passes, nor to a catalog effect where the base misses a force (its worst run is then judged
    relative to the control's J, and that verdict stands)."""
    ctx = _context(tmp_path, [])
    null = _null(-10.0, heldout=0.5)
    c = _score("heading_bias", -30.0, 0.17, gain=0.6)
    c.run_changes = {"run1": -0.5, "run2": 0.26, "run3": -0.1}
    c.run_losses = {"run1": -0.5, "run2": 0.8, "run3": -0.1}  # 0.4 x run2's noise J: > 0.3
    assert not needs_transfer(ctx, null, -10.0, c, significant=True)
    assert needs_transfer(ctx, null, -10.0, c, significant=False)
    c.effect = "discovered:N_nn"
    assert needs_transfer(ctx, null, -10.0, c, significant=True)
    c.run_losses = {"run1": -0.5, "run2": 0.5, "run3": -0.1}  # 0.25 x: carries over as it is
    assert not needs_transfer(ctx, null, -10.0, c, significant=False)


def test_the_verdict_stage_without_an_accepted_candidate(tmp_path: Path) -> None:
    lines: list[str] = []
    ctx = _context(tmp_path, lines, max_delta_bic=-60.0)  # set by hand: nothing reaches it
    for significant, verdict in ((True, "unexplained"), (False, "none")):
        scores = [_score("rudder_offset", -50.0, 0.1), _score("current", -20.0, 0.2)]
        v = decide(ctx, scores, ["rudder_offset", "current"], _null(-10.0), significant)
        assert (v.verdict, v.effect) == (verdict, "")
        assert not any(c.accepted for c in v.scores)
    assert "set by --max-delta-bic" in lines[0]


def test_a_catalog_effect_goes_before_tied_discovered_terms(tmp_path: Path) -> None:
    ctx = _context(tmp_path, [])
    found = "discovered:X_nn"
    scores = [_score(found, -100.0, 0.5), _score("propeller_walk", -97.0, 0.1)]
    v = decide(ctx, scores, [found, "propeller_walk"], _null(-10.0), significant=True)
    assert v.effect == "propeller_walk"
    # ... but not when the catalog effect is beyond the tie margin
    scores = [_score(found, -300.0, 0.5), _score("propeller_walk", -97.0, 0.1)]
    v = decide(ctx, scores, [found, "propeller_walk"], _null(-10.0), significant=True)
    assert (v.verdict, v.effect) == ("discovered", found)


def test_without_refinement_the_unrefined_scores_are_accepted(tmp_path: Path) -> None:
    ctx = _context(tmp_path, [], refine_top=0)
    scores = [_score("current", -40.0, 0.1, refined=False)]
    assert decide(ctx, scores, ["current"], _null(-10.0), significant=False).effect == "current"
    ctx = _context(tmp_path, [])
    scores = [_score("current", -40.0, 0.1, refined=False)]
    assert decide(ctx, scores, ["current"], _null(-10.0), significant=False).verdict == "none"


def test_the_leaders_are_the_best_by_dbic_and_every_passing_discovered_candidate() -> None:
    scores = [
        _score("a", -5.0, 0.0),
        _score("discovered:x", -30.0, 0.0),
        _score("b", -50.0, 0.0),
        _score("discovered:y", -11.0, 0.0),
        _score("discovered:z", -9.0, 0.0),
    ]
    assert leading(scores, -10.0, 2) == ["b", "discovered:x", "discovered:y"]
    assert leading(scores, -10.0, 0) == ["discovered:x", "discovered:y"]


def test_a_candidate_is_scored_against_the_control_fold_by_fold() -> None:
    eff = get_effect("rudder_offset")
    control = FoldFits([_fit(4.0), _fit(3.0)], np.array([1.0, 2.0, 4.0]))
    cand = FoldFits([_fit(2.0, 0.03), _fit(3.0, 0.07)], np.array([0.5, 2.0, 2.0]))
    c, carrier = score(eff, cand, control, N_EFF)
    assert carrier is cand.fits[0]  # 2/4 gained more over its control than 3/3
    assert c.params == {"delta_0": pytest.approx(0.03)}
    assert c.J_fit == 5.0 and c.J_heldout == 4.5 and c.evaluations == 20
    assert c.delta_bic == pytest.approx(N_EFF * math.log(5.0 / 7.0) + math.log(N_EFF))
    assert c.improvement == pytest.approx(1.0 - (0.5 * 1.0 * 0.5) ** (1 / 3))
    assert c.improvement == typical_change(cand.J_heldout, control.J_heldout)
    assert c.improvement_total == pytest.approx(1.0 - 4.5 / 7.0)
    assert not c.accepted and not c.refined


def test_a_stored_stage_is_resumed_and_another_fingerprint_is_not(tmp_path: Path) -> None:
    lines: list[str] = []
    ctx = _context(tmp_path, lines)
    first = ctx.staged("candidate-rudder_offset-fold0", (), lambda: _fit(2.5, 0.04))
    assert (tmp_path / "stages" / "candidate-rudder_offset-fold0.json").exists()

    def refit() -> Fit:
        raise AssertionError("a stored stage was fitted again")

    again = ctx.staged("candidate-rudder_offset-fold0", (), refit)
    assert again.f == first.f and again.params.to_dict() == first.params.to_dict()
    assert "resumed from" in lines[-1]
    other = StageStore(tmp_path / "stages", "another")
    assert other.load("candidate-rudder_offset-fold0", ()) is None


def test_the_settings_fingerprint_names_the_stored_stages_as_before() -> None:
    """The fingerprint of the defaults (and of the end-to-end tests' settings) is pinned, so
    that a change to what the stages compute is a deliberate one; thresholds do not enter it.
    With the descent over growing horizons switched off, the directories written before it
    existed keep resuming."""
    assert DiagnoseSettings().fingerprint() == "70399cbce961"
    quick = DiagnoseSettings(candidates=("rudder_offset", "current"), base_budget=200)
    assert quick.fingerprint() == "f0daa5bde017"
    assert DiagnoseSettings(max_delta_bic=-5.0, tie_margin=0.2).fingerprint() == "70399cbce961"
    assert DiagnoseSettings(base_horizons=()).fingerprint() == "2f9052432b11"
    assert replace(quick, base_horizons=()).fingerprint() == "76ffddc613fa"


SHAPE = "shape:N~beta[-0.6:0.6]/8"
FORM = "shape:N~beta[-0.6:0.6]:up(0.3)"


@pytest.mark.parametrize(
    ("form_gain", "form_dbic", "chosen"),
    [
        (0.95, -80.0, FORM),  # keeps 95 % of the shape's held-out gain: the formula is stated
        (0.80, -80.0, SHAPE),  # keeps 80 %: the shape itself is the finding
        (0.95, 5.0, SHAPE),  # keeps enough but is not accepted on its own
    ],
)
def test_a_learned_shape_is_stated_by_its_closed_form_when_that_keeps_its_gain(
    tmp_path: Path, form_gain: float, form_dbic: float, chosen: str
) -> None:
    lines: list[str] = []
    ctx = _context(tmp_path, lines)
    scores = [
        _score(SHAPE, -100.0, 0.5, gain=1.0),
        _score(FORM, form_dbic, 0.45, gain=form_gain),
        _score("propeller_walk", -20.0, 0.01, gain=0.01),
    ]
    v = decide(ctx, scores, [SHAPE, FORM, "propeller_walk"], _null(-10.0), significant=True)
    assert (v.verdict, v.effect) == ("shape", chosen)
    assert f"keeps {100 * form_gain:.0f} % of the learned shape's held-out gain" in lines[2]


def test_a_closed_form_ahead_of_the_shape_is_chosen_as_any_candidate(tmp_path: Path) -> None:
    ctx = _context(tmp_path, [])
    scores = [_score(FORM, -120.0, 0.5, gain=0.5), _score(SHAPE, -100.0, 0.5, gain=1.0)]
    v = decide(ctx, scores, [SHAPE, FORM], _null(-10.0), significant=True)
    assert (v.verdict, v.effect) == ("shape", FORM)


@pytest.mark.parametrize(
    ("term_gain", "form_gain", "chosen", "verdict"),
    [
        # a library term keeps more of the shape's held-out gain than its own closed form
        (1.01, 0.95, "discovered:X_uuuau", "discovered"),
        (0.92, 0.95, FORM, "shape"),  # the closed form keeps more: it is the name
        (0.85, 0.80, SHAPE, "shape"),  # neither keeps 90 %: the shape itself
    ],
)
def test_a_learned_shape_is_named_after_the_accepted_closed_form_that_keeps_most_of_its_gain(
    tmp_path: Path, term_gain: float, form_gain: float, chosen: str, verdict: str
) -> None:
    lines: list[str] = []
    ctx = _context(tmp_path, lines)
    # the library term outside the tie margin of the shape's dBIC (tied, the more specific name
    # keeping 90 % of the largest held-out gain would go first: test_diagnose.py)
    scores = [
        _score(SHAPE, -100.0, 0.5, gain=1.0),
        _score(FORM, -95.0, 0.45, gain=form_gain),
        _score("discovered:X_uuuau", -80.0, 0.44, gain=term_gain),
    ]
    v = decide(ctx, scores, [SHAPE, FORM, "discovered:X_uuuau"], _null(-10.0), significant=True)
    assert (v.verdict, v.effect) == (verdict, chosen)
    if verdict == "discovered":
        assert "the library term discovered:X_uuuau keeps 101 %" in "\n".join(lines)


def test_a_closed_form_chosen_ahead_of_the_shape_keeps_its_place_before_a_weaker_name(
    tmp_path: Path,
) -> None:
    """The chosen closed form is itself a name: a library term of less held-out gain, behind it
    by more than the tie margin of dBIC, does not replace it, even when that keeps 90 % of it."""
    ctx = _context(tmp_path, [])
    scores = [
        _score(FORM, -120.0, 0.5, gain=1.0),
        _score("discovered:N_vvv", -105.0, 0.45, gain=0.95),
        _score(SHAPE, -100.0, 0.5, gain=-0.1),
    ]
    v = decide(ctx, scores, [FORM, SHAPE, "discovered:N_vvv"], _null(-10.0), significant=True)
    assert (v.verdict, v.effect) == ("shape", FORM)


def test_the_report_says_which_learned_shape_a_library_term_names() -> None:
    term = _score("discovered:X_uuuau", -98.0, 0.44, gain=0.95)
    shape = _score(SHAPE, -100.0, 0.5, gain=1.0)
    for c in (term, shape):
        c.accepted = True
    d = cast(Any, SimpleNamespace(candidates=[shape, term], chosen=term))
    assert names_shape(d) == {"shape": SHAPE, "kept": pytest.approx(0.95)}
    assert f"It names the learned shape {SHAPE} (accepted too): it keeps 95 %" in (
        names_shape_text(d)
    )
    term.heldout_gain = 0.8  # keeps less than 90 %: no longer its name
    assert names_shape(d) is None and names_shape_text(d) == ""
    shape.accepted = False  # a shape refused on its own is not named
    term.heldout_gain = 0.95
    assert names_shape(d) is None
