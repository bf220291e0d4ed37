"""Figures of the manoeuvres: the predicted standard manoeuvres at full scale and the recorded
turning and zigzag runs against the model, each with the band of the parameter samples. Draws on
its own matplotlib Figure (no pyplot state) and saves a PNG."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.gridspec import GridSpec

from sweep.data.manoeuvres import SCALE, course_frame
from sweep.data.standard_manoeuvres import Comparison, Prediction, Runs

BAND = (0.05, 0.95)
"""Quantiles of the samples that bound the drawn bands."""
SAMPLE_LINES = 40
"""Most sample tracks drawn per panel (tracks have no band: their samples are drawn as lines)."""


def _good(runs: Runs) -> np.ndarray:
    """(R,) bool: the lanes to draw (those that neither diverged nor lacked an approach)."""
    R = runs.states.shape[0]
    return np.ones(R, dtype=bool) if runs.bad is None else ~np.asarray(runs.bad, dtype=bool)


def _tracks(ax: Axes, runs: Runs, L: float, colour: str, label: str, to_stop: bool = False) -> None:
    """Tracks in the original course's frame (across to the right, along up) in ship lengths:
    the samples thin, the estimate bold; ``to_stop``: each up to its first u <= 0."""
    R = runs.states.shape[0]
    good = _good(runs)
    for lane in [*[k for k in range(1, R) if good[k]][:SAMPLE_LINES], 0]:
        x = runs.states[lane]
        if to_stop:
            stopped = np.flatnonzero(x[:, 1] <= 0.0)
            x = x[: int(stopped[0]) + 1] if stopped.size else x
        along, across = course_frame(x, 0)
        style = {"lw": 1.6, "label": label} if lane == 0 else {"lw": 0.5, "alpha": 0.25}
        ax.plot(across / L, along / L, color=colour, **style)


def _heading(ax: Axes, runs: Runs, time_scale: float, colour: str, label: str) -> None:
    """Heading deviation from the first sample [deg] against time: the samples' band and the
    estimate."""
    dev = np.degrees(runs.states[:, :, 4] - runs.states[:, :1, 4])
    t = runs.t * time_scale
    samples = dev[1:][_good(runs)[1:]]
    if samples.shape[0] > 0:
        lo, hi = np.nanquantile(samples, BAND, axis=0)
        ax.fill_between(t, lo, hi, color=colour, alpha=0.25, lw=0)
    ax.plot(t, dev[0], color=colour, lw=1.4, label=label)


def _standard_row(fig: Figure, grid: GridSpec, pred: Prediction, L: float) -> None:
    root = math.sqrt(SCALE)
    ax = fig.add_subplot(grid[0, 0])
    _tracks(ax, pred.runs["turning"], L, "tab:blue", "turning 35 deg")
    _tracks(ax, pred.runs["stopping"], L, "tab:red", "crash stop (to u = 0)", to_stop=True)
    ax.axhline(4.5, color="0.4", ls=":", lw=0.8)
    ax.axvline(5.0, color="0.4", ls=":", lw=0.8)
    ax.text(
        5.0,
        4.5,
        "IMO limits: advance 4.5 L, tactical diameter 5 L ",
        fontsize=7,
        ha="right",
        va="bottom",
    )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("across the approach course [L]")
    ax.set_ylabel("along the approach course [L]")
    ax.set_title("standard turning circle and crash stop", fontsize=9)
    ax.legend(fontsize=7)
    for j, name in enumerate(k for k in pred.runs if k.startswith("zigzag")):
        ax = fig.add_subplot(grid[0, 1 + j])
        runs = pred.runs[name]
        _heading(ax, runs, root, "tab:blue", "heading deviation")
        ax.plot(
            runs.t * root, np.degrees(runs.delta[0]), color="0.3", lw=0.8, ls="--", label="rudder"
        )
        check = name.removeprefix("zigzag")
        ax.set_title(f"standard zigzag {check}/{check}", fontsize=9)
        ax.set_xlabel("full-scale time after the first execute [s]")
        ax.set_ylabel("[deg]")
        ax.legend(fontsize=7, loc="lower left")


def _recorded_panel(ax: Axes, c: Comparison, L: float) -> None:
    rec, r = c.run.recording, c.run
    x = rec.x[r.k0 : r.end]
    if r.kind == "turning":
        _tracks(ax, c.runs, L, "tab:orange", "model")
        along, across = course_frame(x, 0)
        ax.plot(across / L, along / L, color="black", lw=1.2, label="recorded")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("across the course at the execute [L]")
        ax.set_ylabel("along it [L]")
    else:
        _heading(ax, c.runs, 1.0, "tab:orange", "model")
        t = rec.t[r.k0 : r.end] - rec.t[r.k0]
        ax.plot(t, np.degrees(x[:, 4] - x[0, 4]), color="black", lw=1.2, label="recorded")
        ax.plot(
            t,
            np.degrees(rec.u[r.k0 : r.end, 0]),
            color="0.3",
            lw=0.8,
            ls="--",
            label="recorded rudder",
        )
        ax.set_xlabel("time after the first execute [s] (model scale)")
        ax.set_ylabel("heading deviation [deg]")
    ax.set_title(f"{r.label}: {r.title}", fontsize=9)
    ax.legend(fontsize=7)


def plot_manoeuvres(
    pred: Prediction,
    comparisons: Sequence[Comparison],
    path: str | Path,
    title: str = "",
    L: float | None = None,
) -> Path:
    """Top row: the standard turning circle with the crash stop, and the 10/10 and 20/20
    zigzags (full scale; bands and thin lines: the parameter samples). Below: each recorded
    turning (track) and zigzag (heading) run against the model under its controls and wind
    (model scale). ``L`` the model's length [m] (default: 3 m). Returns ``path``."""
    L = L or 3.0
    cols = 3
    rows = 1 + math.ceil(len(comparisons) / cols)
    # fixed margins [in]: a constrained layout measured every label and took about half of
    # the figure's time (one of these per job of a sweep)
    width, height = 4.6 * cols, 4.2 * rows
    fig = Figure(figsize=(width, height))
    grid = fig.add_gridspec(
        rows, cols, left=0.75 / width, right=1.0 - 0.15 / width, bottom=0.55 / height,
        top=1.0 - (0.75 if title else 0.35) / height, hspace=0.3, wspace=0.25,
    )  # fmt: skip
    _standard_row(fig, grid, pred, L)
    for i, c in enumerate(comparisons):
        _recorded_panel(fig.add_subplot(grid[1 + i // cols, i % cols]), c, L)
    for ax in fig.axes:
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    out = Path(path)
    fig.savefig(out, dpi=100)
    return out


__all__ = ["plot_manoeuvres"]
