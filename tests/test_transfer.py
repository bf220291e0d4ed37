"""The transfer check's rule (:mod:`sweep.diagnose.transfer`): pure, no simulation."""

from __future__ import annotations

from sweep.diagnose.sessions import place_or_time
from sweep.diagnose.threshold import AcceptanceNull


def _null(limit: float = 1.0, heldout: float = 0.05, noise_J: float = 2.0) -> AcceptanceNull:
    return AcceptanceNull(
        alpha=0.05,
        draws=10,
        threshold=-10.0,
        quantile=-10.0,
        best=[0.0],
        heldout_quantile=heldout,
        worst_run_quantile=limit,
        noise_J=noise_J,
        run_noise={"a": 0.1, "b": 0.1, "c": 0.1},
    )


def test_a_candidate_transfers_when_the_refitted_runs_get_better():
    null = _null(limit=1.0)
    assert null.transfers(0.5, {"a": -0.3, "b": -0.1, "c": 0.2}, heldout_gain=0.5)


def test_a_candidate_does_not_transfer_when_the_summed_j_rises():
    assert not _null().transfers(-0.01, {"a": -0.3, "b": -0.1, "c": 0.2}, heldout_gain=0.5)


def test_a_candidate_does_not_transfer_when_more_runs_get_worse():
    assert not _null().transfers(0.5, {"a": -0.9, "b": 0.01, "c": 0.02}, heldout_gain=0.5)


def test_a_candidate_does_not_transfer_when_one_run_gets_worse_than_the_limit():
    null = _null(limit=0.5)
    assert not null.transfers(0.5, {"a": -0.3, "b": -0.1, "c": 0.6}, heldout_gain=0.5)
    assert null.transfers(0.5, {"a": -0.3, "b": -0.1, "c": 0.4}, heldout_gain=0.5)


def test_the_gain_must_beat_the_null_in_one_of_the_two_checks():
    """The gain on runs the effect was not fitted on must beat the held-out null (0.1 here) with
    the base refitted alongside (held-out) or with the base alone refitted (transfer)."""
    null = _null(heldout=0.05, noise_J=2.0)
    changes = {"a": -0.3, "b": -0.1, "c": 0.2}
    assert null.transfers(0.05, changes, heldout_gain=0.5)  # the held-out gain beats it
    assert null.transfers(0.5, changes, heldout_gain=-5.0)  # one run's loss; transfer beats it
    assert not null.transfers(0.05, changes, heldout_gain=0.05)  # neither does


def test_position_and_time_are_told_from_the_heading():
    """The transfer check leaves out findings tied to position or time, not the heading."""
    pos_time = ("position", "time")
    assert place_or_time("discovered:E_y0+E_x0")
    assert not place_or_time("discovered:E_y0+E_x0", pos_time)
    assert place_or_time("discovered:N_x+Y_sy", pos_time)
    assert place_or_time("discovered:N_bt", pos_time)
    assert place_or_time("shape:N~x0[0:30]/8", pos_time)
    assert not place_or_time("shape:N~psi[-3:3]/8", pos_time)
    assert place_or_time("shape:N~psi[-3:3]/8")
    assert not place_or_time("shape:N~delta[-0.6:0.6]/8")


def test_the_held_out_conditions_are_those_of_carrying_over():
    """heldout_ok is the first part of carries_over: a gain above the null's threshold (its
    quantile times the noise's J) and more held-out runs better than worse."""
    null = _null(heldout=0.05, noise_J=2.0)  # threshold 0.1
    changes = {"a": -0.2, "b": -0.1, "c": 5.0}
    assert null.heldout_ok(0.2, changes)
    assert not null.heldout_ok(0.05, changes)
    assert not null.heldout_ok(0.2, {"a": -0.2, "b": 0.1, "c": 5.0})
    # the run far worse than its noise J refuses a generated candidate on the held-out runs
    losses = {"a": -0.1, "b": -0.1, "c": 1.0}
    assert not null.carries_over(0.2, losses, changes, generated=True)


def test_a_transfer_must_also_hold_across_sessions_when_checked_there():
    """A candidate that passes the transfer check within the sessions is refused when the same
    check across sessions (held as fitted on some days' runs) makes more runs worse; not
    checked there (one session), the transfer within decides."""
    from sweep.diagnose.scoring import CandidateScore
    from sweep.diagnose.verdict import transferred

    null = _null(limit=1.0)
    c = CandidateScore("shape:N~U[0:0.4]/8*v", "", "shapes", {}, 1.0, 1.0, 0.1, -50.0)
    assert not transferred(null, c)  # not checked
    c.transfer_checked = True
    c.transfer_gain, c.transfer_run_changes = 0.5, {"a": -0.3, "b": -0.1, "c": 0.2}
    c.heldout_gain = 0.5
    assert transferred(null, c)
    c.session_transfer_checked = True
    c.session_transfer_gain = 0.3
    c.session_transfer_run_changes = {"a": -0.3, "b": 0.1, "c": 0.2}  # 2 of 3 runs worse
    assert not transferred(null, c)
    c.session_transfer_run_changes = {"a": -0.3, "b": -0.1, "c": 0.2}
    assert transferred(null, c)
    c.session_transfer_gain = 0.05  # below the held-out null (0.1): the size is judged within
    assert transferred(null, c)
    c.session_transfer_run_changes = {"a": -0.3, "b": -0.1, "c": 1.5}  # one run beyond the limit
    assert not transferred(null, c)
    c.session_transfer_run_changes = {"a": -0.3, "b": -0.1, "c": 0.2}
    c.session_transfer_gain = -0.1  # the other days' runs worse in sum
    assert not transferred(null, c)


def test_a_run_worse_by_a_negligible_share_of_its_j_does_not_refuse_a_finding():
    """A quiet run's noise J can be a small share of its J where the control misses the effect:
    a loss of 2 % of that J is many times its noise J. A run worse by at most NEGLIGIBLE of its
    J is not held against a generated candidate; a larger share still is."""
    from sweep.diagnose.threshold import NEGLIGIBLE

    null = _null(limit=1.0, heldout=0.0)  # noise J 0.1 on each run
    losses = {"a": -3.0, "b": -2.0, "c": 0.2}  # run c: 2 x its noise J
    changes = {"a": -0.5, "b": -0.4, "c": 0.02}  # ... and 2 % of its J (10)
    assert null.run_excess(losses) == 2.0
    assert null.run_excess(losses, changes) == 0.0
    assert null.carries_over(1.0, losses, changes, generated=True)
    changes["c"] = 2 * NEGLIGIBLE  # the same loss, 10 % of a J of 2
    assert not null.carries_over(1.0, losses, changes, generated=True)
    # a catalog effect is judged relative to the run's J, never stricter than NEGLIGIBLE
    tight = _null(limit=0.01, heldout=0.0)
    assert tight.carries_over(1.0, losses, {"a": -0.5, "b": -0.4, "c": 0.03}, generated=False)
    assert not tight.carries_over(1.0, losses, {"a": -0.5, "b": -0.4, "c": 0.06}, generated=False)
