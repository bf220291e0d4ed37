"""Figures of a sweep (the paper's Figs. 5-8): the sweep at a glance, a job's convergence and
its trajectories against the recorded ones. Each function draws on its own matplotlib Figure
(no pyplot state) and saves a PNG at the given path."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from numpy.typing import NDArray

from sweep.service.outcome import COLUMNS, OBJECTIVE_NAMES, SUBSETS
from sweep.service.tables import EFD_ROW, column_name

__all__ = ["plot_convergence", "plot_sweep", "plot_trajectories"]

FloatArray = NDArray[np.float64]


def plot_sweep(
    tables: Mapping[str, pd.DataFrame],
    histories: Mapping[str, Sequence[tuple[float, float]]],
    path: str | Path,
) -> Path:
    """The sweep at a glance: for J1, J2 and J3, bars per test subset for every
    objective-training pair (mean over seeds, the seeds' standard deviation as error bars) with
    the EFD value as a line; below, the convergence of every job (best J so far against
    evaluations, log scale), coloured by objective."""
    Js = [J for J in OBJECTIVE_NAMES if J in tables]
    fig = Figure(figsize=(5.2 * max(1, len(Js)), 8.0))
    gs = fig.add_gridspec(2, max(1, len(Js)), height_ratios=[1.2, 1.0])
    subsets = [s for s in SUBSETS if s not in ("B", "total")]
    for i, J in enumerate(Js):
        ax = fig.add_subplot(gs[0, i])
        table = tables[J]
        cases = [c for c in table.index if c != EFD_ROW]
        width = 0.8 / max(1, len(cases))
        x = np.arange(len(subsets))
        for k, case in enumerate(cases):
            row = table.loc[case]
            means = row[[column_name(COLUMNS[s], "mean") for s in subsets]].to_numpy(
                dtype=np.float64, na_value=np.nan
            )
            stds = np.nan_to_num(
                row[[column_name(COLUMNS[s], "std") for s in subsets]].to_numpy(
                    dtype=np.float64, na_value=np.nan
                )
            )
            ax.bar(x + (k - (len(cases) - 1) / 2) * width, means, width, yerr=stds,
                   label=case, capsize=2)  # fmt: skip
        if EFD_ROW in table.index:
            refs = table.loc[EFD_ROW, [column_name(COLUMNS[s], "mean") for s in subsets]]
            for j, ref in enumerate(refs.to_numpy(dtype=np.float64)):
                ax.hlines(ref, j - 0.45, j + 0.45, colors="k", linestyles="--", lw=1)
            ax.plot([], [], "k--", lw=1, label="EFD")
        ax.set_xticks(x, [COLUMNS[s] for s in subsets], rotation=30, fontsize=8)
        ax.set_yscale("log")
        ax.set_title(f"{J} on the test set (mean, seed std)", fontsize=10)
        if i == 0:
            ax.legend(fontsize=7, ncol=2)
    ax = fig.add_subplot(gs[1, :])
    colours = {J: f"C{k}" for k, J in enumerate(OBJECTIVE_NAMES)}
    for key, rows in sorted(histories.items()):
        if not rows:
            continue
        J = next((J for J in OBJECTIVE_NAMES if f"objective={J}" in key), "")
        ev = [r[0] for r in rows]
        best = [r[1] for r in rows]
        ax.plot(ev, best, lw=0.9, color=colours.get(J, "0.4"), alpha=0.8)
    for J, c in colours.items():
        ax.plot([], [], color=c, label=f"objective {J}")
    ax.set_yscale("log")
    ax.set_xlabel("evaluations")
    ax.set_ylabel("best training J so far")
    ax.set_title("convergence of every job", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return Path(path)


def plot_convergence(
    history: Sequence[Mapping[str, float]], path: str | Path, title: str = ""
) -> Path:
    """The paper's Fig. 5: J of each generation's best and min J so far vs evaluations.

    ``history``: rows with evaluations, best_f, best_so_far and restart (the history of
    sweep.identification.cmaes).
    Restarts are dashed vertical lines; the optimum is marked. Returns ``path``.
    """
    if not history:
        raise ValueError("empty history: nothing to plot")
    evals = np.array([row["evaluations"] for row in history], dtype=np.float64)
    best = np.array([row["best_f"] for row in history], dtype=np.float64)
    so_far = np.array([row["best_so_far"] for row in history], dtype=np.float64)
    restart = np.array([row.get("restart", 0.0) for row in history], dtype=np.float64)
    fig = Figure(figsize=(7.0, 4.0), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(evals, best, lw=0.8, color="tab:blue", label="J of the generation's best")
    ax.plot(evals, so_far, lw=1.6, color="tab:red", label="min J so far")
    for k, i in enumerate(np.flatnonzero(np.diff(restart) != 0) + 1):
        ax.axvline(evals[i - 1], color="0.5", lw=0.7, ls="--", label="restart" if k == 0 else None)
    i_opt = int(np.flatnonzero(so_far == so_far[-1])[0])
    ax.plot(evals[i_opt], so_far[i_opt], "o", color="tab:red", ms=5)
    ax.annotate(
        f"optimum {so_far[i_opt]:.4g} at {int(evals[i_opt])} evaluations",
        (evals[i_opt], so_far[i_opt]),
        textcoords="offset points",
        xytext=(-4, 8) if evals[i_opt] > 0.5 * evals[-1] else (4, 8),
        ha="right" if evals[i_opt] > 0.5 * evals[-1] else "left",
        fontsize=8,
    )
    if np.all(best > 0):
        ax.set_yscale("log")
    ax.set_xlabel("function evaluations")
    ax.set_ylabel("J")
    if title:
        ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    out = Path(path)
    fig.savefig(out, dpi=120)
    return out


def plot_trajectories(
    recorded_x: Any,
    simulated: Mapping[str, Any],
    path: str | Path,
    title: str = "",
    dt: float = 0.1,
) -> Path:
    """The paper's Figs. 6-8: the x0-y0 track (equal aspect, x0 up) over time series of u, v_m,
    r and psi, recorded (black) against each simulated model.

    ``recorded_x`` (N, 6) states (x0, u, y0, v_m, psi, r); ``simulated`` {label: (M, 6)} with
    NaN after a divergence allowed; ``dt`` [s] the sample interval. Returns ``path``.
    """
    rec = np.asarray(recorded_x, dtype=np.float64)
    sims = {label: np.asarray(x, dtype=np.float64) for label, x in simulated.items()}
    for label, x in {"recorded_x": rec, **sims}.items():
        if x.ndim != 2 or x.shape[1] != 6:
            raise ValueError(f"{label}: expected states of shape (N, 6), got {x.shape}")
    # fixed margins: a constrained layout measured every label and took 45 % of the figure's
    # time (three of these per job of a sweep)
    fig = Figure(figsize=(10.0, 10.0))
    grid = fig.add_gridspec(
        3, 2, height_ratios=(1.6, 1.0, 1.0), left=0.08, right=0.98, bottom=0.055,
        top=0.95 if title else 0.98, hspace=0.3, wspace=0.22,
    )  # fmt: skip
    track = fig.add_subplot(grid[0, :])
    series = [fig.add_subplot(grid[1 + i // 2, i % 2]) for i in range(4)]
    lines: list[tuple[str, FloatArray, dict[str, Any]]] = [
        ("recorded", rec, {"color": "black", "lw": 1.4})
    ]
    lines += [(label, x, {"lw": 1.0}) for label, x in sims.items()]
    panels = [  # (state index, scale, axis label)
        (1, 1.0, "u [m/s]"),
        (3, 1.0, "v_m [m/s]"),
        (5, 180.0 / np.pi, "r [deg/s]"),
        (4, 180.0 / np.pi, "psi [deg]"),
    ]
    for label, x, style in lines:
        t = np.arange(x.shape[0]) * dt
        (line,) = track.plot(x[:, 2], x[:, 0], label=label, **style)
        track.plot(x[0, 2], x[0, 0], "o", color=line.get_color(), ms=4)
        for ax, (j, scale, _) in zip(series, panels, strict=True):
            ax.plot(t, x[:, j] * scale, color=line.get_color(), lw=style["lw"])
    track.set_aspect("equal", adjustable="datalim")
    track.set_xlabel("y0 [m]")
    track.set_ylabel("x0 [m]")
    track.legend(fontsize=8)
    track.grid(alpha=0.3)
    for ax, (_, _, ylabel) in zip(series, panels, strict=True):
        ax.set_xlabel("t [s]")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    out = Path(path)
    fig.savefig(out, dpi=110)
    return out
