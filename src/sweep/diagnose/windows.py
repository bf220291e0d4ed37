"""The windows a diagnosis runs on: recordings cut into the objective's windows, and the
two halves of the fold fits (one fits, the other judges, then the other way round)."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

import numpy as np

from sweep.data.objective import T_F, split_recording
from sweep.data.recordings import Recording
from sweep.diagnose.floor import run_of

#: shortest window kept [s] (the last window of a run may be short)
MIN_WINDOW = 20.0
#: a date in a recording's name: the data set's own naming (``turn_14-Sep-2020_14_50_41...``)
#: or ISO (``2020-09-14``)
DATE = re.compile(r"\d{1,2}-[A-Za-z]{3}-\d{4}|\d{4}-\d{2}-\d{2}")


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
    return _balanced(runs.values())


def session_of(window: Recording) -> str:
    """The session a window's run was recorded in: the date in the run's name
    (:data:`DATE`), else the run itself (each recording its own session)."""
    run = run_of(window)
    m = DATE.search(run)
    return m.group(0) if m else run


def split_sessions(
    windows: Sequence[Recording],
) -> tuple[list[Recording], list[Recording]] | None:
    """(fit, held-out) windows with whole sessions held out (:func:`session_of`): the sessions
    go, longest first, to the fold with less recorded time so far. None when all the windows
    are of one session."""
    sessions: dict[str, list[Recording]] = {}
    for w in windows:
        sessions.setdefault(session_of(w), []).append(w)
    if len(sessions) < 2:
        return None
    return _balanced(sessions.values())


def _balanced(groups: Iterable[list[Recording]]) -> tuple[list[Recording], list[Recording]]:
    """Two folds of whole groups of windows: the groups go, longest first, to the fold with
    less recorded time so far."""
    folds: tuple[list[Recording], list[Recording]] = ([], [])
    time_in = [0.0, 0.0]
    for ws in sorted(groups, key=lambda ws: -sum(w.duration for w in ws)):
        j = 0 if time_in[0] <= time_in[1] else 1
        folds[j].extend(ws)
        time_in[j] += sum(w.duration for w in ws)
    return folds
