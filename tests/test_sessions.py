"""Findings tied to where and when a run was recorded: sessions, the split by session, which
generated effects are tied to heading, position or time, and the verdict's use of the check."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace
from typing import cast

import numpy as np

from sweep.data.recordings import Recording
from sweep.diagnose.context import Context
from sweep.diagnose.scoring import CandidateScore
from sweep.diagnose.sessions import memory_of_controls, place_or_time, session_bound, tie_text
from sweep.diagnose.settings import DiagnoseSettings
from sweep.diagnose.shapes import PLACE_AND_TIME, SHIP_VARIABLES, VARIABLES
from sweep.diagnose.shaping import default_variables
from sweep.diagnose.threshold import AcceptanceNull
from sweep.diagnose.verdict import carries_to_other_sessions
from sweep.diagnose.windows import session_of, split_sessions


def _window(name: str, seconds: float) -> Recording:
    n = round(seconds / 0.1) + 1
    t = np.arange(n, dtype=np.float64) * 0.1
    zeros = np.zeros((n, 2))
    return Recording(name=name, path=None, t=t, x=np.zeros((n, 6)), u=zeros, w=zeros)


def test_a_session_is_the_date_in_the_run_name_else_the_run() -> None:
    assert session_of(_window("turn_14-Sep-2020_14_50_41_1051@0.0s", 10)) == "14-Sep-2020"
    assert session_of(_window("turn_cut_14-Sep-2020_15_58_08_50@100.0s", 10)) == "14-Sep-2020"
    assert session_of(_window("trial-2021-03-05-a@0.0s", 10)) == "2021-03-05"
    assert session_of(_window("my_run@200.0s", 10)) == "my_run"


def test_whole_sessions_are_held_out_balanced_by_time_and_one_session_gives_none() -> None:
    windows = [
        _window("random_06-Aug-2020_16_24_25_1@0.0s", 100),
        _window("random_06-Aug-2020_16_24_25_2@0.0s", 100),
        _window("turn_14-Sep-2020_14_50_41@0.0s", 100),
        _window("turn_cut_14-Sep-2020_15_58_08@0.0s", 50),
        _window("zigzag_31-Jul-2020_13_22_52@0.0s", 80),
    ]
    split = split_sessions(windows)
    assert split is not None
    a, b = ({session_of(w) for w in half} for half in split)
    assert a and b and not a & b  # no session on both sides
    assert sum(len(h) for h in split) == len(windows)
    # longest first to the lighter fold: Aug (200 s) | Sep (150 s) + Jul (80 s)
    assert a == {"06-Aug-2020"} and b == {"14-Sep-2020", "31-Jul-2020"}
    assert split_sessions(windows[:2]) is None


def test_terms_and_shapes_of_heading_position_or_time_are_tied_to_the_session() -> None:
    assert place_or_time("discovered:N_Usy+Y_Usy")  # a bank: position
    assert place_or_time("discovered:N_bt+Y_bt")  # a build-up: time
    assert place_or_time("discovered:N_Ux+N_vvr")  # one position term is enough
    assert not place_or_time("discovered:X_uuuau+N_vvr")
    assert place_or_time("shape:N~x0[0:30]/8")
    assert place_or_time("shape:N~U[0:0.4]/6*t")
    assert not place_or_time("shape:N~u[-0.07:0.41]/8+Y~delta[-0.6:0.6]:sin(2)")
    assert not place_or_time("rudder_offset")


def test_a_memory_of_a_control_must_carry_over_to_another_session_too() -> None:
    """A learned memory of a control, or its closed form, is checked on another session's runs
    (how a session's programme moves the controls is the session's); a force of the state, the
    catalog's effects (the lag of actuator_lag among them) and library terms are not."""
    for memory in (
        "shape:D~ed[-4:4]:play",
        "shape:P~en[-3:3]/6",
        "shape:N~beta[-1:1]/8+D~ed[-4:4]:rate",
    ):
        assert memory_of_controls(memory) and session_bound(memory)
        assert tie_text(memory).startswith("a memory of the controls")
    for free in ("shape:YN~delta[-0.6:0.6]:step(0,0.1)", "actuator_lag", "discovered:N_vvr"):
        assert not memory_of_controls(free) and not session_bound(free)
    assert session_bound("shape:N~x0[0:30]/8") and not memory_of_controls("shape:N~x0[0:30]/8")
    assert tie_text("shape:N~x0[0:30]/8") == "tied to heading, position or time"


def _null() -> AcceptanceNull:
    null = AcceptanceNull(
        alpha=0.05,
        draws=10,
        threshold=-10.0,
        quantile=-10.0,
        best=[0.0],
        heldout_quantile=0.1,
        worst_run_quantile=2.0,
    )
    null.noise_J = 1.0
    null.run_noise = {"a": 1.0, "b": 1.0, "c": 1.0}
    return null


def _score(**kw: object) -> CandidateScore:
    c = CandidateScore("discovered:N_Usy", "", "", {}, 1.0, 1.0, 0.5, -50.0)
    for k, v in kw.items():
        setattr(c, k, v)
    return c


def test_a_tied_candidate_needs_another_sessions_runs_to_get_better() -> None:
    null = _null()
    assert carries_to_other_sessions(null, _score())  # not tied: nothing to check
    assert not carries_to_other_sessions(null, _score(sessions="one session"))
    better = {"a": -0.5, "b": -0.2, "c": 0.1}
    good = _score(
        sessions="checked",
        session_gain=3.0,
        session_run_changes=better,
        session_run_losses={"a": -2.0, "b": -1.0, "c": 0.5},
    )
    assert carries_to_other_sessions(null, good)
    # as many runs worse as better on the other sessions: not carried over
    mixed = {"a": -0.5, "b": 0.2, "c": 0.1}
    assert not carries_to_other_sessions(null, replace(good, session_run_changes=mixed))
    # a gain in total bought with one run 5 x its noise J worse: not carried over
    losses = {"a": -9.0, "b": -1.0, "c": 5.0}
    assert not carries_to_other_sessions(null, replace(good, session_run_losses=losses))


def test_shapes_use_heading_position_and_time_only_when_another_session_can_check() -> None:
    windows = [
        _window("random_06-Aug-2020_16_24_25_1@0.0s", 100),
        _window("random_06-Aug-2020_16_24_25_2@0.0s", 100),
        _window("turn_14-Sep-2020_14_50_41@0.0s", 100),
    ]

    def ctx(ws: list[Recording], **kw: object) -> Context:
        # the two fields default_variables reads (a stand-in for a full diagnosis context)
        s = replace(DiagnoseSettings(), **kw)  # type: ignore[arg-type]
        return cast(Context, SimpleNamespace(settings=s, session_w=split_sessions(ws)))

    several, one = ctx(windows), ctx(windows[:2])
    assert default_variables(several) == VARIABLES
    assert set(PLACE_AND_TIME) <= set(default_variables(several))
    assert default_variables(one) == SHIP_VARIABLES
    assert not set(PLACE_AND_TIME) & set(default_variables(one))
    # the user's list wins either way
    assert default_variables(ctx(windows[:2], shape_variables=("x0",))) == ("x0",)
    assert default_variables(ctx(windows, shape_variables=("beta",))) == ("beta",)
