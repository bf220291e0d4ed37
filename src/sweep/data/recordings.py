"""Free-running recordings: a typed, validated in-memory form and CSV/Parquet input/output.

A recording is one run in the FRT-DS-ESSO format: one row per sample at 10 Hz, with the columns
(header -> symbol, unit)

================================  ====================  ======================================
header                            symbol                unit / role
================================  ====================  ======================================
``t [s]``                         t                     s (need not start at 0)
``x_position_mid [m]``            x0                    m, midship, earth-fixed
``u_velo [m/s]``                  u                     m/s, surge velocity of midship
``y_position_mid [m]``            y0                    m, midship, earth-fixed
``vm_velo [m/s]``                 v_m                   m/s, sway velocity of midship
``psi_hat [rad]``                 psi                   rad, wrapped to [-pi, pi] in the file
``r_angvelo [rad/s]``             r                     rad/s
``n_prop [rps]``                  n_p                   rev/s
``delta_rudder [rad]``            delta                 rad
``wind_velo_true [m/s]``          U_T                   m/s
``wind_dir_true [rad]``           gamma_T               rad (direction the wind blows from)
``wind_velo_relative_mid [m/s]``  U_A                   m/s, optional (apparent wind)
``wind_dir_relative_mid [rad]``   gamma_A               rad, optional (apparent wind)
================================  ====================  ======================================

The apparent-wind columns are optional (the model computes the apparent wind); when present they
must be numeric. Other extra columns are ignored unless their name is a near-miss of an expected
one (reported as a misspelling). CSV and Parquet files use the same column names.

Checks (each a one-line :class:`RecordingError` naming the file, the column and the row; row k is
line k + 1 of a CSV file): missing or misspelled columns; non-numeric, empty or non-finite values
inside a run; time steps of ``DT`` = 0.1 s within ``DT_TOL``; implausible units (``|delta| >
pi/2``, ``|r| > 3 rad/s``, ``|psi_hat| > pi``, ``|gamma| > 2 pi``, ``|n_p| > 100 rev/s``, negative
wind speed), r against the heading rate (:func:`_check_yaw_rate`) and the velocities against the
track (:func:`_check_track`); fewer than ``MIN_SAMPLES`` samples. Trailing rows whose fields are
all empty are dropped with a :class:`RecordingWarning`.

In memory (:class:`Recording`) the heading is unwrapped (:func:`numpy.unwrap`);
:func:`write_parquet` wraps it back to [-pi, pi]. ``Recording.duration`` is (N - 1) * DT, which
gives the data README's split totals (Train-R 2694.6 s, Test 1623.6 s).
"""

from __future__ import annotations

import csv
import difflib
import os
import tempfile
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from sweep.errors import UserError

FloatArray = NDArray[np.float64]
PathLike = str | os.PathLike[str]

DT = 0.1
"""Sampling step of the recordings [s] (10 Hz)."""
DT_TOL = 1e-3
"""Largest accepted deviation of a time step from :data:`DT` [s]."""
MIN_SAMPLES = 101
"""Shortest accepted run [samples] (10 s at 10 Hz)."""
YAW_RATE_WINDOW = 10
"""Window of the r-against-heading unit check [samples] (1 s)."""
YAW_RATE_RATIO_RANGE = (0.1, 5.0)
"""Accepted rms(r) / rms(d psi/dt) over 1 s windows (r-against-heading unit check) [-]."""
MIN_YAW_RATE_RMS_LOW = 0.02
"""rms heading rate from which a too small ratio is reported (heading in degrees) [rad/s]."""
MIN_YAW_RATE_RMS = 0.005
"""rms heading rate below which the r-against-heading unit check is skipped [rad/s]."""
TRACK_SPAN = 50
"""Span of the velocities-against-track check [samples] (5 s)."""
TRACK_TOLERANCE = 0.15
"""Largest accepted rms misfit of the 5-s displacements, relative to their rms [-]."""
TRACK_MIN_RMS = 0.05
"""rms 5-s displacement below which the velocities-against-track check is skipped [m]."""

TIME_COLUMN = "t [s]"
"""Column of the time t [s] (need not start at 0)."""
STATE_COLUMNS: tuple[str, ...] = (
    "x_position_mid [m]",
    "u_velo [m/s]",
    "y_position_mid [m]",
    "vm_velo [m/s]",
    "psi_hat [rad]",
    "r_angvelo [rad/s]",
)
"""Columns of the state x = (x0, u, y0, v_m, psi, r), in state order."""
CONTROL_COLUMNS: tuple[str, ...] = ("delta_rudder [rad]", "n_prop [rps]")
"""Columns of the control u = (delta, n_p), in control order."""
WIND_COLUMNS: tuple[str, ...] = ("wind_velo_true [m/s]", "wind_dir_true [rad]")
"""Columns of the true wind w = (U_T, gamma_T), in wind order."""
APPARENT_WIND_COLUMNS: tuple[str, ...] = (
    "wind_velo_relative_mid [m/s]",
    "wind_dir_relative_mid [rad]",
)
"""Optional columns of the apparent wind (U_A, gamma_A)."""
REQUIRED_COLUMNS: tuple[str, ...] = (TIME_COLUMN, *STATE_COLUMNS, *CONTROL_COLUMNS, *WIND_COLUMNS)
"""Columns every recording file must have."""
FILE_COLUMNS: tuple[str, ...] = (
    TIME_COLUMN,
    *STATE_COLUMNS,
    "n_prop [rps]",
    "delta_rudder [rad]",
    *APPARENT_WIND_COLUMNS,
    *WIND_COLUMNS,
)
"""All known columns, in the order of the FRT-DS-ESSO files (used when writing)."""

_PSI = "psi_hat [rad]"
_MISSING_TOKENS = frozenset({"", "nan", "na", "null"})
_SUFFIXES = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}

# (column, largest plausible |value|, unit, what a larger value suggests)
_MAGNITUDE_LIMITS: tuple[tuple[str, float, str, str], ...] = (
    ("delta_rudder [rad]", np.pi / 2, "rad", "degrees where radians are expected?"),
    ("r_angvelo [rad/s]", 3.0, "rad/s", "degrees per second where rad/s is expected?"),
    (
        _PSI,
        np.pi + 1e-3,
        "rad",
        "degrees where radians are expected? (the heading is stored wrapped to [-pi, pi])",
    ),
    ("wind_dir_true [rad]", 2 * np.pi + 1e-3, "rad", "degrees where radians are expected?"),
    (
        "wind_dir_relative_mid [rad]",
        2 * np.pi + 1e-3,
        "rad",
        "degrees where radians are expected?",
    ),
    ("n_prop [rps]", 100.0, "rev/s", "rpm where rev/s (rps) is expected?"),
)
_SPEED_COLUMNS: tuple[str, ...] = ("wind_velo_true [m/s]", "wind_velo_relative_mid [m/s]")


class RecordingError(ValueError, UserError):
    """A recording file is unreadable or fails validation; the message names file, column, row."""


class RecordingWarning(UserWarning):
    """A recording file had a defect that was repaired (e.g. trailing empty rows dropped)."""


def _readonly(a: Any, shape: tuple[int | None, ...], what: str) -> FloatArray:
    arr = np.array(a, dtype=np.float64, copy=True)
    if arr.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(arr.shape, shape, strict=False)
    ):
        raise RecordingError(f"{what}: shape {arr.shape}, expected {shape} (None = any length)")
    if not np.all(np.isfinite(arr)):
        raise RecordingError(f"{what}: contains non-finite values")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Recording:
    """One validated free-running run, sampled every :data:`DT` = 0.1 s.

    Attributes:
        name: identifier, the file stem (e.g. ``"random_06-Aug-2020_16_24_25_1"``).
        path: the file it was read from, or None for a recording built in memory.
        t: (N,) time [s], increasing by 0.1 s (checked when read from a file); need not start
            at 0.
        x: (N, 6) state (x0 [m], u [m/s], y0 [m], v_m [m/s], psi [rad], r [rad/s]) at midship,
            with psi UNWRAPPED (continuous; it may leave [-pi, pi]).
        u: (N, 2) control (delta [rad], n_p [rev/s]).
        w: (N, 2) true wind (U_T [m/s], gamma_T [rad], the direction it blows from).
        w_apparent: (N, 2) recorded apparent wind (U_A [m/s], gamma_A [rad]) or None when the
            file had no such columns. Informational: the model computes the apparent wind.

    Arrays are float64 and read-only.
    """

    name: str
    path: Path | None
    t: FloatArray
    x: FloatArray
    u: FloatArray
    w: FloatArray
    w_apparent: FloatArray | None = None

    def __post_init__(self) -> None:
        what = f"recording {self.name!r}"
        t = _readonly(self.t, (None,), f"{what}: t")
        n = t.shape[0]
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "x", _readonly(self.x, (n, 6), f"{what}: x"))
        object.__setattr__(self, "u", _readonly(self.u, (n, 2), f"{what}: u"))
        object.__setattr__(self, "w", _readonly(self.w, (n, 2), f"{what}: w"))
        if self.w_apparent is not None:
            wa = _readonly(self.w_apparent, (n, 2), f"{what}: w_apparent")
            object.__setattr__(self, "w_apparent", wa)
        if self.path is not None:
            object.__setattr__(self, "path", Path(self.path))

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])

    @property
    def dt(self) -> float:
        """Sampling step [s]: the nominal 0.1 s, which every step matches within ``DT_TOL``."""
        return DT

    @property
    def duration(self) -> float:
        """Time spanned by the samples [s]: (N - 1) * dt, i.e. t[-1] - t[0] on the 0.1 s grid."""
        return (self.n_samples - 1) * DT

    @property
    def psi_wrapped(self) -> FloatArray:
        """(N,) heading wrapped to [-pi, pi] [rad], as stored in the files."""
        return wrap_angle(self.x[:, 4])

    def frame(self) -> pd.DataFrame:
        """The recording as a table with the FRT-DS-ESSO column names (heading wrapped)."""
        cols: dict[str, FloatArray] = {TIME_COLUMN: np.array(self.t)}
        for j, name in enumerate(STATE_COLUMNS):
            cols[name] = np.array(self.x[:, j])
        cols[_PSI] = self.psi_wrapped
        for j, name in enumerate(CONTROL_COLUMNS):
            cols[name] = np.array(self.u[:, j])
        if self.w_apparent is not None:
            for j, name in enumerate(APPARENT_WIND_COLUMNS):
                cols[name] = np.array(self.w_apparent[:, j])
        for j, name in enumerate(WIND_COLUMNS):
            cols[name] = np.array(self.w[:, j])
        order = [c for c in FILE_COLUMNS if c in cols]
        return pd.DataFrame({c: cols[c] for c in order})


def wrap_angle(a: Any) -> FloatArray:
    """Angles [rad] wrapped to [-pi, pi], same shape as ``a``; undoes np.unwrap to ~1e-15 rad."""
    arr = np.asarray(a, dtype=np.float64)
    out: FloatArray = arr - 2 * np.pi * np.round(arr / (2 * np.pi))
    return out


# ---------------------------------------------------------------------------------------------
# reading


def _check_columns(header: Sequence[str], source: str) -> None:
    """Raise RecordingError for duplicate, missing or misspelled columns."""
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise RecordingError(f"{source}: duplicate column {name!r}")
        seen.add(name)
    present = set(header)
    unknown = [h for h in header if h not in FILE_COLUMNS]
    problems: list[str] = []
    for expected in FILE_COLUMNS:
        if expected in present:
            continue
        close = difflib.get_close_matches(expected, unknown, n=1, cutoff=0.6)
        required = expected in REQUIRED_COLUMNS
        if close:
            problems.append(
                f"column {close[0]!r} is not an expected name: did you mean {expected!r}?"
            )
        elif required:
            problems.append(f"missing required column {expected!r}")
    if problems:
        raise RecordingError(
            f"{source}: " + "; ".join(problems) + f" (expected columns: {list(REQUIRED_COLUMNS)}"
            f", optional: {list(APPARENT_WIND_COLUMNS)})"
        )


def _parse_column(values: Sequence[Any], column: str, source: str) -> FloatArray:
    """Float64 values of one column; empty fields and NaN tokens become NaN.

    Raises RecordingError naming the column and the 1-based row of a non-numeric value.
    """
    try:
        arr = np.array(values, dtype=np.float64)
        if arr.ndim == 1:
            return arr
    except (ValueError, TypeError):
        pass
    out = np.empty(len(values), dtype=np.float64)
    for i, v in enumerate(values):
        if v is None:
            out[i] = np.nan
            continue
        if isinstance(v, bool | np.bool_):
            raise RecordingError(
                f"{source}: column {column!r}, row {i + 1}: non-numeric value {v!r}"
            )
        if isinstance(v, int | float | np.integer | np.floating):
            out[i] = float(v)
            continue
        s = str(v).strip()
        if s.lower() in _MISSING_TOKENS:
            out[i] = np.nan
            continue
        try:
            out[i] = float(s)
        except ValueError:
            raise RecordingError(
                f"{source}: column {column!r}, row {i + 1}: non-numeric value {str(v)!r}"
            ) from None
    return out


def _read_csv_columns(path: Path, source: str) -> tuple[list[str], dict[str, list[str]]]:
    """Header and raw string values (per column) of a CSV file."""
    with path.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise RecordingError(f"{source}: empty file (no header)") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise RecordingError(f"{source}: not a readable CSV file ({exc})") from None
        columns: list[list[str]] = [[] for _ in header]
        width = len(header)
        try:
            for k, row in enumerate(reader, start=1):
                if len(row) != width:
                    if all(f.strip() == "" for f in row):
                        row = [""] * width
                    else:
                        raise RecordingError(
                            f"{source}: row {k} (line {k + 1}) has {len(row)} fields, "
                            f"the header has {width}"
                        )
                for j, field in enumerate(row):
                    columns[j].append(field)
        except (csv.Error, UnicodeDecodeError) as exc:
            raise RecordingError(f"{source}: not a readable CSV file ({exc})") from None
    return header, {h: columns[j] for j, h in enumerate(header)}


def _read_parquet_columns(path: Path, source: str) -> tuple[list[str], dict[str, Any]]:
    """Header and raw values (per column) of a Parquet file."""
    try:
        df = pd.read_parquet(path, engine="pyarrow")
    except Exception as exc:  # pyarrow raises several unrelated types for corrupt files
        raise RecordingError(f"{source}: not a readable Parquet file ({exc})") from None
    header = [str(c).strip() for c in df.columns]
    raw: dict[str, Any] = {}
    for name, col in zip(header, df.columns, strict=True):
        series = df[col]
        if pd.api.types.is_bool_dtype(series.dtype):
            raise RecordingError(f"{source}: column {name!r}, row 1: non-numeric (boolean) values")
        if pd.api.types.is_numeric_dtype(series.dtype):
            raw[name] = series.to_numpy(dtype=np.float64, na_value=np.nan)
        else:
            raw[name] = series.to_numpy(dtype=object).tolist()
    return header, raw


def _drop_trailing_empty(data: dict[str, FloatArray], source: str) -> dict[str, FloatArray]:
    """Drop rows at the end whose known fields are all empty, warning how many."""
    missing = np.column_stack([np.isnan(v) for v in data.values()])
    filled = np.flatnonzero(~missing.all(axis=1))
    n = missing.shape[0]
    if filled.size == 0:
        raise RecordingError(f"{source}: no data rows (all {n} rows are empty)")
    last = int(filled[-1]) + 1
    if last < n:
        warnings.warn(
            f"{source}: dropped {n - last} trailing empty rows (rows {last + 1}-{n}); "
            f"{last} data rows kept",
            RecordingWarning,
            stacklevel=3,
        )
        return {c: v[:last] for c, v in data.items()}
    return data


def _check_values(data: Mapping[str, FloatArray], source: str) -> None:
    """Raise RecordingError for missing, non-finite or implausible values, or a short run."""
    names = list(data)
    matrix = np.column_stack([data[c] for c in names])
    nan = np.isnan(matrix)
    bad_rows = np.flatnonzero(nan.any(axis=1))
    if bad_rows.size:
        i = int(bad_rows[0])
        if nan[i].all():
            raise RecordingError(
                f"{source}: row {i + 1} (line {i + 2}) is empty in the middle of the run "
                f"({int(nan.all(axis=1).sum())} empty row(s) before the last data row)"
            )
        col = names[int(np.flatnonzero(nan[i])[0])]
        raise RecordingError(
            f"{source}: column {col!r}, row {i + 1}: missing value (empty or NaN) in the middle "
            "of the run"
        )
    inf = ~np.isfinite(matrix)
    if inf.any():
        i, j = (int(k) for k in np.argwhere(inf)[0])
        raise RecordingError(
            f"{source}: column {names[j]!r}, row {i + 1}: non-finite value {matrix[i, j]!r}"
        )
    n = matrix.shape[0]
    if n < MIN_SAMPLES:
        raise RecordingError(
            f"{source}: too short a run: {n} samples ({(n - 1) * DT:.1f} s), at least "
            f"{MIN_SAMPLES} samples ({(MIN_SAMPLES - 1) * DT:.0f} s) are required"
        )
    t = data[TIME_COLUMN]
    steps = np.diff(t)
    down = np.flatnonzero(steps <= 0)
    if down.size:
        k = int(down[0])
        raise RecordingError(
            f"{source}: column {TIME_COLUMN!r}, row {k + 2}: time does not increase "
            f"(t = {t[k + 1]:.6g} s after t = {t[k]:.6g} s at row {k + 1})"
        )
    irregular = np.flatnonzero(np.abs(steps - DT) > DT_TOL)
    if irregular.size:
        k = int(irregular[0])
        raise RecordingError(
            f"{source}: column {TIME_COLUMN!r}, row {k + 2}: irregular time step "
            f"{steps[k]:.6g} s from row {k + 1} (t = {t[k]:.6g} s) to row {k + 2} "
            f"(t = {t[k + 1]:.6g} s); expected {DT} s +- {DT_TOL} s (10 Hz sampling)"
        )
    for col, limit, unit, hint in _MAGNITUDE_LIMITS:
        if col not in data:
            continue
        over = np.flatnonzero(np.abs(data[col]) > limit)
        if over.size:
            i = int(over[0])
            raise RecordingError(
                f"{source}: column {col!r}, row {i + 1}: implausible value {data[col][i]:.6g} "
                f"(|value| > {limit:.4g} {unit}; {over.size} such rows): {hint}"
            )
    for col in _SPEED_COLUMNS:
        if col not in data:
            continue
        neg = np.flatnonzero(data[col] < 0)
        if neg.size:
            i = int(neg[0])
            raise RecordingError(
                f"{source}: column {col!r}, row {i + 1}: negative wind speed {data[col][i]:.6g}"
            )
    _check_yaw_rate(data[_PSI], data["r_angvelo [rad/s]"], source)
    x0, u, y0, v_m, psi = (data[c] for c in STATE_COLUMNS[:5])
    _check_track(x0, u, y0, v_m, psi, source)


def _track_misfit(
    x0: FloatArray, u: FloatArray, y0: FloatArray, v_m: FloatArray, psi: FloatArray
) -> tuple[float, float, float, float]:
    """(relative rms misfit, ratio, correlation, rms displacement) of the recorded 5-s
    displacements against those integrated from the velocities and heading."""
    psi = np.unwrap(psi)
    vx = u * np.cos(psi) - v_m * np.sin(psi)
    vy = u * np.sin(psi) + v_m * np.cos(psi)
    cx = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * DT)])  # trapezoid
    cy = np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * DT)])
    i = np.arange(0, x0.size - TRACK_SPAN, TRACK_SPAN)
    j = i + TRACK_SPAN
    rec = np.concatenate([x0[j] - x0[i], y0[j] - y0[i]])
    pred = np.concatenate([cx[j] - cx[i], cy[j] - cy[i]])
    rms = float(np.sqrt(np.mean(rec * rec))) if rec.size else 0.0
    if rms == 0.0 or not np.any(pred):
        return (0.0 if rms == 0.0 else 1.0), 0.0, 0.0, rms
    misfit = float(np.sqrt(np.mean((rec - pred) ** 2))) / rms
    ratio = float(rec @ pred / (pred @ pred))
    corr = float(np.corrcoef(rec, pred)[0, 1]) if np.std(rec) > 0 and np.std(pred) > 0 else 0.0
    return misfit, ratio, corr, rms


def _check_track(
    x0: FloatArray, u: FloatArray, y0: FloatArray, v_m: FloatArray, psi: FloatArray, source: str
) -> None:
    """Raise RecordingError if the recorded velocities and heading do not integrate to the
    recorded track; the message names the reading that would fit.

    Compares the displacement over every ``TRACK_SPAN`` samples (5 s) from the recorded x0, y0
    with the one integrated from u, v_m and psi (x0_dot = u cos psi - v_m sin psi, y0_dot =
    u sin psi + v_m cos psi). On the 13 recordings their rms difference is 3-5 % of the rms
    displacement and the least-squares ratio 0.997-1.006; velocities in cm/s give a ratio of 0.01,
    swapped x0 and y0 a misfit of 95-176 %, a v_m of the wrong sign 20-123 %, a heading of the
    wrong sense 51-152 %. Above ``TRACK_TOLERANCE`` (15 %) the file is rejected only when a
    mistaken reading (units, swapped columns, a sign) makes the columns agree within 15 % and
    three times better; a misfit no such reading explains (a current, a heading offset) is
    physics or measurement error the diagnosis may name, and passes."""
    misfit, ratio, corr, rms = _track_misfit(x0, u, y0, v_m, psi)
    if rms < TRACK_MIN_RMS or misfit <= TRACK_TOLERANCE:
        return
    readings = {
        "u and v_m in cm/s (or the positions in m while the velocities are 100x too large)": (
            x0,
            0.01 * u,
            y0,
            0.01 * v_m,
            psi,
        ),
        "u and v_m in mm/s": (x0, 0.001 * u, y0, 0.001 * v_m, psi),
        "u and v_m in knots": (x0, 0.5144 * u, y0, 0.5144 * v_m, psi),
        "the x and y position columns swapped": (y0, u, x0, v_m, psi),
        "v_m of the opposite sign (positive to port)": (x0, u, y0, -v_m, psi),
        "the heading of the opposite sense (anticlockwise)": (x0, u, y0, v_m, -psi),
        "the u and v_m columns swapped": (x0, v_m, y0, u, psi),
    }
    fits = [(_track_misfit(*cols)[0], what) for what, cols in readings.items()]
    best, what = min(fits)
    if best > TRACK_TOLERANCE or best > misfit / 3.0:
        # no mistaken reading explains it: a physical difference (a current, a heading offset
        # the diagnosis may name) is not for the reader to reject
        return
    raise RecordingError(
        f"{source}: columns 'u_velo [m/s]', 'vm_velo [m/s]' and 'psi_hat [rad]' do not "
        f"integrate to the track 'x_position_mid [m]', 'y_position_mid [m]': the 5-s "
        f"displacements differ by {100 * misfit:.0f} % rms (expected <= "
        f"{100 * TRACK_TOLERANCE:.0f} %; recorded / integrated ratio {ratio:.3g}, correlation "
        f"{corr:.2f}); with {what} they would agree within {100 * best:.0f} %"
    )


def _check_yaw_rate(psi: FloatArray, r: FloatArray, source: str) -> None:
    """Raise RecordingError if r and the rate of change of the heading differ by a unit factor.

    Compares, over 1 s windows (``YAW_RATE_WINDOW`` samples), the root-mean-square of the mean
    of r with that of the heading rate (psi[k + 10] - psi[k]) / 1 s, psi unwrapped; both are
    rad/s when the units are right. Over every 10-100 s segment of the 13 recordings the ratio
    is 0.10-1.11 (0.52-1.11 where the rms heading rate is >= 0.02 rad/s); r in deg/s makes it
    ~57 times larger (>= 6), a heading in degrees ~57 times smaller (<= 0.025, with an rms
    heading rate >= 0.07 rad/s). Hence: ratio > 5 -> r in deg/s (checked when the rms heading
    rate is >= ``MIN_YAW_RATE_RMS``); ratio < 0.1 -> heading in degrees (checked when it is >=
    ``MIN_YAW_RATE_RMS_LOW``, so that a noisy heading of a quiet run is not mistaken for one).
    """
    w = YAW_RATE_WINDOW
    unwrapped = np.unwrap(psi)
    rate = (unwrapped[w:] - unwrapped[:-w]) / (w * DT)
    rms_rate = float(np.sqrt(np.mean(rate**2)))
    if rms_rate < MIN_YAW_RATE_RMS:
        return
    c = np.concatenate([[0.0], np.cumsum(r)])
    r_mean = (c[w:] - c[:-w])[: rate.size] / w
    ratio = float(np.sqrt(np.mean(r_mean**2))) / rms_rate
    low, high = YAW_RATE_RATIO_RANGE
    if ratio > high:
        raise RecordingError(
            f"{source}: column 'r_angvelo [rad/s]' is {ratio:.3g} times the rate of change of "
            f"'psi_hat [rad]' (rms over 1 s windows; expected {low:g}-{high:g}): degrees per "
            "second where rad/s is expected?"
        )
    if ratio < low and rms_rate >= MIN_YAW_RATE_RMS_LOW:
        raise RecordingError(
            f"{source}: column 'psi_hat [rad]' changes {1 / ratio:.3g} times faster than "
            f"'r_angvelo [rad/s]' says (rms over 1 s windows; expected ratio {low:g}-{high:g}): "
            "heading in degrees where radians are expected?"
        )


def read_recording(path: PathLike) -> Recording:
    """Read and validate one recording from a CSV or Parquet file (FRT-DS-ESSO column names).

    Args:
        path: a ``.csv``, ``.parquet`` or ``.pq`` file.

    Returns:
        The :class:`Recording`, named after the file stem, with the heading unwrapped.

    Raises:
        FileNotFoundError: the file does not exist.
        RecordingError: the file is malformed (see the module docstring for the checks).

    Warns:
        RecordingWarning: trailing empty rows were dropped (the message gives their number).
    """
    p = Path(path)
    source = str(p)
    kind = _SUFFIXES.get(p.suffix.lower())
    if kind is None:
        raise RecordingError(
            f"{source}: unsupported file type {p.suffix!r} (expected one of {sorted(_SUFFIXES)})"
        )
    if not p.is_file():
        raise FileNotFoundError(f"{source}: recording file not found")
    header: list[str]
    raw: Mapping[str, Any]
    if kind == "csv":
        header, raw = _read_csv_columns(p, source)
    else:
        header, raw = _read_parquet_columns(p, source)
    _check_columns(header, source)
    data = {c: _parse_column(raw[c], c, source) for c in FILE_COLUMNS if c in raw}
    data = _drop_trailing_empty(data, source)
    _check_values(data, source)

    x = np.column_stack([data[c] for c in STATE_COLUMNS])
    x[:, 4] = np.unwrap(x[:, 4])
    w_apparent = None
    if all(c in data for c in APPARENT_WIND_COLUMNS):
        w_apparent = np.column_stack([data[c] for c in APPARENT_WIND_COLUMNS])
    return Recording(
        name=p.stem,
        path=p,
        t=data[TIME_COLUMN],
        x=x,
        u=np.column_stack([data[c] for c in CONTROL_COLUMNS]),
        w=np.column_stack([data[c] for c in WIND_COLUMNS]),
        w_apparent=w_apparent,
    )


def _expand(paths: PathLike | Iterable[PathLike]) -> list[Path]:
    items: Iterable[PathLike]
    items = [paths] if isinstance(paths, str | os.PathLike) else paths
    files: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in _SUFFIXES)
            if not found:
                raise RecordingError(f"{p}: no *.csv or *.parquet recordings in this directory")
            files.extend(found)
        else:
            files.append(p)
    return files


def read_recordings(paths: PathLike | Iterable[PathLike]) -> list[Recording]:
    """Read several recordings.

    Args:
        paths: a file or directory, or an iterable of them. A directory contributes every
            ``*.csv`` / ``*.parquet`` / ``*.pq`` file below it (recursively), sorted by path.

    Returns:
        The recordings, in the order given (directories expanded in sorted order).

    Raises:
        FileNotFoundError, RecordingError: as :func:`read_recording`; RecordingError also for a
            directory holding no recordings.
    """
    return [read_recording(p) for p in _expand(paths)]


def write_parquet(recording: Recording, path: PathLike) -> Path:
    """Write a recording as Parquet with the FRT-DS-ESSO column names; returns the path.

    The heading is written wrapped to [-pi, pi] (like the CSV files), so reading the file back
    gives the same recording (heading equal to ~1e-15 rad). The file is written to a temporary
    name in the same directory and then renamed, so a reader never sees a partial file; parent
    directories are created.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    os.close(fd)
    try:
        recording.frame().to_parquet(tmp, engine="pyarrow", index=False)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p
