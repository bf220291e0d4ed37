"""The ranges of the state and controls that recordings cover, and where other recordings leave
them: where a finding fitted on some runs is known to hold.

:func:`ranges_of` measures, over every sample of the recordings,

- U [m/s]: the speed over ground, sqrt(u^2 + v_m^2);
- beta [deg]: the drift angle at midship, atan2(-v_m, u) (the paper's beta = atan(-v_m / u),
  continued to astern motion);
- r [deg/s]: the yaw rate;
- delta [deg]: the rudder angle;
- n_p [rev/s]: the propeller revolution rate;
- J [-]: the geometric advance ratio u / (n_p D_p) (no wake fraction: a property of the
  recording, not of a model), over samples with |n_p| of at least 0.5 rev/s;
- u, v_m [m/s]: surge and sway velocity (the box :mod:`mmg.domain` clamps, with r, delta, n_p);

and the share of samples in each propeller-and-motion quadrant (:data:`QUADRANTS`).
:func:`departures` names the variables another recording takes beyond those ranges, by how much
and for how long.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg.domain import Domain
from mmg.params import ESSO_OSAKA, Ship
from sweep.data.recordings import Recording

FloatArray = NDArray[np.float64]

#: the variables and their units, in the order a table shows them
VARIABLES = {
    "U": "m/s",
    "beta": "deg",
    "r": "deg/s",
    "delta": "deg",
    "n_p": "rev/s",
    "J": "-",
    "u": "m/s",
    "v_m": "m/s",
}
#: the four quadrants of (motion, propeller): ahead or astern (sign of u), and the propeller
#: turning ahead or astern (sign of n_p)
QUADRANTS = {
    "Q1": "ahead, propeller ahead",
    "Q2": "ahead, propeller astern",
    "Q3": "astern, propeller astern",
    "Q4": "astern, propeller ahead",
}
#: |n_p| [rev/s] below which the advance ratio is not taken (it grows without bound)
N_MIN = 0.5
#: a recording leaves a range only when more than this share of its samples lies outside
MIN_SHARE = 0.01


def samples(rec: Recording, ship: Ship = ESSO_OSAKA) -> dict[str, FloatArray]:
    """Every variable of :data:`VARIABLES` at every sample of ``rec`` (units of the table;
    ``J`` is NaN where |n_p| < :data:`N_MIN`) and the quadrant index 0-3 (``quadrant``)."""
    x = np.asarray(rec.x, dtype=np.float64)
    c = np.asarray(rec.u, dtype=np.float64)
    u, v_m, r = x[:, 1], x[:, 3], x[:, 5]
    delta, n_p = c[:, 0], c[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        J = np.where(np.abs(n_p) >= N_MIN, u / (n_p * ship.D_p), np.nan)
    ahead = u >= 0.0
    prop_ahead = n_p >= 0.0
    quadrant = np.where(ahead, np.where(prop_ahead, 0, 1), np.where(prop_ahead, 3, 2))
    return {
        "U": np.hypot(u, v_m),
        "beta": np.degrees(np.arctan2(-v_m, u)),
        "r": np.degrees(r),
        "delta": np.degrees(delta),
        "n_p": n_p,
        "J": J,
        "u": u,
        "v_m": v_m,
        "quadrant": quadrant.astype(np.float64),
    }


@dataclass(frozen=True)
class Ranges:
    """{variable: (lowest, highest)} over the recordings, the share of samples per quadrant,
    and the number of samples."""

    intervals: dict[str, tuple[float, float]]
    quadrants: dict[str, float]
    samples: int

    def domain(self, mode: str = "held") -> Domain:
        """The box of (U, u, v_m, r, delta, n_p) in the model's units (:mod:`mmg.domain`; U
        bounded above only: beyond the top speed a held effect keeps its non-dimensional
        force)."""
        iv = self.intervals
        lower = {
            "U": 0.0,
            "u": iv["u"][0],
            "v_m": iv["v_m"][0],
            "r": math.radians(iv["r"][0]),
            "delta": math.radians(iv["delta"][0]),
            "n_p": iv["n_p"][0],
        }
        upper = {
            "U": iv["U"][1],
            "u": iv["u"][1],
            "v_m": iv["v_m"][1],
            "r": math.radians(iv["r"][1]),
            "delta": math.radians(iv["delta"][1]),
            "n_p": iv["n_p"][1],
        }
        return Domain(lower, upper, mode)

    @classmethod
    def of_domain(cls, domain: Domain) -> Ranges:
        """The ranges a box states (:mod:`mmg.domain`, e.g. read from an effect's name): U, u,
        v_m, r, delta and n_p in the table's units; every quadrant counts as covered."""
        scale = {
            "U": 1.0,
            "u": 1.0,
            "v_m": 1.0,
            "r": 180.0 / math.pi,
            "delta": 180.0 / math.pi,
            "n_p": 1.0,
        }
        intervals = {
            k: (domain.lower.get(k, -math.inf) * f, domain.upper.get(k, math.inf) * f)
            for k, f in scale.items()
            if k in domain.lower or k in domain.upper
        }
        return cls(intervals, dict.fromkeys(QUADRANTS, 1.0), 0)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: {"intervals": {variable: {"min", "max", "unit"}}, "quadrants": ...}."""
        return {
            "intervals": {
                k: {"min": lo, "max": hi, "unit": VARIABLES[k]}
                for k, (lo, hi) in self.intervals.items()
            },
            "quadrants": self.quadrants,
            "samples": self.samples,
        }

    def text(self) -> str:
        """One line: ``U 0.20-1.31 m/s, beta -21-19 deg, ...; quadrants Q1 100 %``."""
        parts = [
            f"{k} {lo:.3g} to {hi:.3g} {VARIABLES[k]}"
            for k, (lo, hi) in self.intervals.items()
            if k not in ("u", "v_m")
        ]
        quads = ", ".join(f"{q} {100 * s:.0f} %" for q, s in self.quadrants.items() if s > 0)
        return "; ".join(parts) + f"; quadrants {quads}"


def ranges_of(recordings: Sequence[Recording], ship: Ship = ESSO_OSAKA) -> Ranges:
    """The ranges the recordings cover (every sample of each)."""
    if not recordings:
        raise ValueError("ranges need at least one recording")
    per = [samples(r, ship) for r in recordings]
    intervals: dict[str, tuple[float, float]] = {}
    for k in VARIABLES:
        v = np.concatenate([p[k] for p in per])
        v = v[np.isfinite(v)]
        intervals[k] = (float(v.min()), float(v.max())) if v.size else (math.nan, math.nan)
    q = np.concatenate([p["quadrant"] for p in per]).astype(int)
    shares = np.bincount(q, minlength=4) / max(q.size, 1)
    return Ranges(
        intervals,
        {name: float(s) for name, s in zip(QUADRANTS, shares, strict=True)},
        int(q.size),
    )


@dataclass(frozen=True)
class Departure:
    """Where a recording leaves a range: the variable, how far beyond [its unit] (the largest
    excursion past either end), that as a share of the range's width, and the share of the
    recording's samples outside. ``variable`` is ``quadrant`` for samples in a quadrant the
    ranges never saw (``beyond`` then names it)."""

    recording: str
    variable: str
    low: float
    high: float
    extreme: float  # the recording's value farthest outside
    beyond: float  # |extreme - nearest bound|
    width_share: float
    time_share: float
    quadrant: str = ""

    def text(self) -> str:
        """``Test-T/run3: r to 5.2 deg/s, 1.4 deg/s beyond 3.8 (12 % of the time)``."""
        if self.variable == "quadrant":
            return (
                f"{self.recording}: {self.quadrant} ({QUADRANTS[self.quadrant]}), never in the "
                f"fitted runs ({100 * self.time_share:.0f} % of the time)"
            )
        unit = VARIABLES[self.variable]
        bound = self.low if self.extreme < self.low else self.high
        return (
            f"{self.recording}: {self.variable} to {self.extreme:.3g} {unit}, {self.beyond:.3g} "
            f"{unit} beyond {bound:.3g} ({100 * self.time_share:.0f} % of the time)"
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def departures(
    ranges: Ranges,
    recordings: Sequence[Recording],
    labels: Sequence[str] | None = None,
    ship: Ship = ESSO_OSAKA,
    min_share: float = MIN_SHARE,
) -> list[Departure]:
    """Every variable each recording (named by ``labels`` or its name) takes outside
    ``ranges`` for more than ``min_share`` of its samples, largest excursion first per
    recording (u and v_m only where U or beta do not already say it)."""
    out: list[Departure] = []
    names = list(labels) if labels is not None else [r.name for r in recordings]
    for rec, name in zip(recordings, names, strict=True):
        s = samples(rec, ship)
        found: list[Departure] = []
        for k, (lo, hi) in ranges.intervals.items():
            v = s[k]
            ok = np.isfinite(v)
            if not ok.any() or math.isnan(lo):
                continue
            v = v[ok]
            outside = (v < lo) | (v > hi)
            share = float(outside.mean())
            if share <= min_share:
                continue
            below, above = lo - float(v.min()), float(v.max()) - hi
            extreme = float(v.min()) if below > above else float(v.max())
            beyond = max(below, above)
            width = hi - lo if math.isfinite(hi - lo) else math.inf
            found.append(
                Departure(
                    name,
                    k,
                    lo,
                    hi,
                    extreme,
                    beyond,
                    beyond / width if width > 0 else math.inf,
                    share,
                )
            )
        q = s["quadrant"].astype(int)
        for i, quad in enumerate(QUADRANTS):
            share = float((q == i).mean())
            if ranges.quadrants.get(quad, 0.0) == 0.0 and share > min_share:
                found.append(
                    Departure(name, "quadrant", 0, 0, 0, 0, math.inf, share, quadrant=quad)
                )
        if any(d.variable in ("U", "beta") for d in found):  # u, v_m say it again
            found = [d for d in found if d.variable not in ("u", "v_m")]
        found.sort(key=lambda d: -d.width_share)
        out += found
    return out


__all__ = ["QUADRANTS", "VARIABLES", "Departure", "Ranges", "departures", "ranges_of", "samples"]
