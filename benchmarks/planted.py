"""Recordings with a concealed effect, for proving the diagnosis blind.

A *case* takes 100-s windows of the real runs (their recorded first state, rudder, propeller and
true wind), simulates them with a "true" ship (the EFD parameters perturbed, since a real ship
differs from its captive tests) plus one planted effect, adds measurement noise with the levels of
the real recordings, and writes the windows as recordings. The diagnosis sees only the files.

Planted effects come in the catalog's own functional forms and in *other* forms, so that the
benchmark does not reward a diagnosis tuned to its own formulas:

- ``stall_tanh``: sin(alpha_R) replaced by sin(alpha_s) tanh(sin(alpha_R) / sin(alpha_s)) (a
  smooth saturation instead of the catalog's kink);
- ``a_h_piecewise``: a_H(beta) = a_H max(-1, 1 - |beta| / beta_0) (piecewise linear, not sin^2);
- ``walk_advance``: a propeller walk fading with the advance ratio, (1 - J_P / J_0)+;
- ``delay``: the controls act a pure dead time after the log (not a first-order lag);
- ``heading_only``: a heading offset that leaves the logged velocities alone (b_v = 0).

Each maps to the catalog family the diagnosis should name (:data:`FAMILY`). The forms in no
catalog entry (:data:`UNLISTED`) map to ``discovered``, except those the paper's model already has
(:data:`IN_FORM`): ``reverse_sway`` is Eqs. (12)-(13) with their constant coefficients shifted,
so the 57 parameters absorb it and the right verdict is ``none`` (family ``in_form``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from mmg import Effect, EffectParam, Parameters, bounds, efd_parameters, get_effect, simulate_batch
from mmg._jit import subfunction
from mmg.model import rudder_inflow_at
from mmg.params import N_THETA, Ship, Theta
from mmg.propeller import wake_factor
from mmg.rudder import lift_gradient
from mmg.trig import atan2, sincos
from sweep.data.recordings import Recording
from sweep.diagnose.floor import ar1

# --------------------------------------------------------------------------- other forms


class StallTanhParams(NamedTuple):
    """The parameters of the planted form ``stall_tanh`` (unit of each after its field)."""

    alpha_s: float  # [rad]


@subfunction
def stall_tanh_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: StallTanhParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Rudder forces change for sin(alpha) -> sin(alpha_s) tanh(sin(alpha) / sin(alpha_s))."""
    u_R, v_R = rudder_inflow_at(u, v_m, r, n_p, th, sh)  # as in hydrodynamic_forces
    if u_R <= 0.0:
        return 0.0, 0.0, 0.0
    alpha_R = delta - atan2(v_R, u_R)
    s_a = sincos(alpha_R)[0]
    s_s = sincos(e.alpha_s)[0]
    d_sin = s_s * math.tanh(s_a / s_s) - s_a
    f_alpha = lift_gradient(sh)  # Eq. (18)
    dF_N = 0.5 * sh.rho * sh.A_R * f_alpha * u_R * u_R * d_sin  # continuous at u_R = 0
    sin_d, cos_d = sincos(delta)
    L = sh.L_pp
    return (
        -(1.0 - th.t_R) * dF_N * sin_d,
        -(1.0 + th.a_H) * dF_N * cos_d,
        -(sh.x_R_nd * L + th.a_H * th.x_H * L) * dF_N * cos_d,
    )


class AHPiecewiseParams(NamedTuple):
    """The parameters of the planted form ``a_h_piecewise`` (unit of each after its field)."""

    beta_0: float  # drift angle at which a_H changes sign [rad]


@subfunction
def a_h_piecewise_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: AHPiecewiseParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """a_H(beta) = a_H max(-1, 1 - |beta| / beta_0) instead of a constant a_H."""
    if u * u + v_m * v_m <= 0.0:
        return 0.0, 0.0, 0.0
    beta = abs(atan2(-v_m, u))
    beta = min(beta, math.pi - beta)  # astern: the drift from the stern
    dA = th.a_H * (max(-1.0, 1.0 - beta / e.beta_0) - 1.0)
    u_R, v_R = rudder_inflow_at(u, v_m, r, n_p, th, sh)  # as in hydrodynamic_forces
    sin_d, cos_d = sincos(delta)
    f_alpha = lift_gradient(sh)  # Eq. (18)
    U_R = math.sqrt(u_R * u_R + v_R * v_R)
    F_N = 0.5 * sh.rho * sh.A_R * f_alpha * U_R * (u_R * sin_d - v_R * cos_d)
    return 0.0, -dA * F_N * cos_d, -dA * th.x_H * sh.L_pp * F_N * cos_d


class WalkAdvanceParams(NamedTuple):
    """The parameters of the planted form ``walk_advance`` (unit of each after its field)."""

    C_Yw: float  # [-], as propeller_walk's
    C_Nw: float  # [-], as propeller_walk's
    J_0: float  # advance ratio at which the walk vanishes [-]


@subfunction
def walk_advance_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: WalkAdvanceParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Propeller walk (n_p > 0) fading linearly with the advance ratio J_P."""
    if n_p <= 0.0:
        return 0.0, 0.0, 0.0
    J_P = u * wake_factor(u, v_m, r, th, sh) / (n_p * sh.D_p)
    fade = max(0.0, 1.0 - max(J_P, 0.0) / e.J_0)
    q = 0.5 * sh.rho * sh.L_pp * sh.d * (n_p * sh.D_p) ** 2 * fade
    return 0.0, q * e.C_Yw, q * sh.L_pp * e.C_Nw


# ----------------------------------------------------------- forms outside the catalog
# None of these has a catalog entry: the diagnosis can only explain them by discovery. They act
# in different equations and through different variables (state, controls, heading, position);
# two (the bank and the wave resistance) are outside the term library's span too.


class BankParams(NamedTuple):
    """The parameters of the planted form ``bank`` (unit of each after its field)."""

    C_b: float  # strength of the bank suction [-]
    y_b: float  # where it changes sign [m]
    W_b: float  # width of the transition [m]


@subfunction
def bank_force_at(
    t: float,
    x0: float,
    y0: float,
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: BankParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Bank suction: Y = 0.5 rho L d C_b U^2 tanh((y0 - y_b) / W_b), N = -0.2 L Y (position)."""
    q = 0.5 * sh.rho * sh.L_pp * sh.d * (u * u + v_m * v_m)
    Y = q * e.C_b * math.tanh((y0 - e.y_b) / e.W_b)
    return 0.0, Y, -0.2 * sh.L_pp * Y


class WaveResistanceParams(NamedTuple):
    """The parameters of the planted form ``wave_resistance`` (unit of each after its field)."""

    C_w: float  # [-], X = -0.5 rho L d C_w u^4 / U_ref^2


@subfunction
def wave_resistance_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: WaveResistanceParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Wave-making resistance growing with u^4 (surge only, ahead only)."""
    if u <= 0.0:
        return 0.0, 0.0, 0.0
    return -0.5 * sh.rho * sh.L_pp * sh.d * e.C_w * u * u * u * u, 0.0, 0.0


class AsternCrossflowParams(NamedTuple):
    """The parameters of the planted form ``astern_crossflow`` (unit of each after its field)."""

    C_a: float  # [-]


@subfunction
def astern_crossflow_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: AsternCrossflowParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Going astern, the stern leads: extra yaw moment N = 0.5 rho L^2 d C_a v_m |v_m| (u < 0)."""
    if u >= 0.0:
        return 0.0, 0.0, 0.0
    return 0.0, 0.0, 0.5 * sh.rho * sh.L_pp * sh.L_pp * sh.d * e.C_a * v_m * abs(v_m)


class EarthForceParams(NamedTuple):
    """The parameters of the planted form ``earth_force`` (unit of each after its field)."""

    F_e: float  # [N], a steady force fixed to the basin
    chi_e: float  # its direction, clockwise from x0 [rad]


@subfunction
def earth_force_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: EarthForceParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """A steady earth-fixed push (a slope, a towline, an unmodelled steady wind): heading."""
    s, c = sincos(e.chi_e - psi)
    return e.F_e * c, e.F_e * s, 0.0


class WashYawParams(NamedTuple):
    """The parameters of the planted form ``wash_yaw`` (unit of each after its field)."""

    C_d: float  # [-]


@subfunction
def wash_yaw_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: WashYawParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """Yaw moment of the rudder in the propeller wash: N = 0.5 rho L^2 d C_d sin(2 delta) (n D)^2
    (controls)."""
    nD = n_p * sh.D_p
    s2 = sincos(2.0 * delta)[0]
    return 0.0, 0.0, 0.5 * sh.rho * sh.L_pp * sh.L_pp * sh.d * e.C_d * s2 * nD * nD


class ReverseSwayParams(NamedTuple):
    """The parameters of the planted form ``reverse_sway`` (unit of each after its field)."""

    C_r: float  # [-]


@subfunction
def reverse_sway_force(
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: ReverseSwayParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """A reversing propeller's lateral force: Y = 0.5 rho L d C_r (n D)^2 for n_p < 0, with the
    moment of a force at the stern (quadrant)."""
    if n_p >= 0.0:
        return 0.0, 0.0, 0.0
    nD = n_p * sh.D_p
    Y = 0.5 * sh.rho * sh.L_pp * sh.d * e.C_r * nD * nD
    return 0.0, Y, -0.5 * sh.L_pp * Y


def _form(name: str, params: tuple[EffectParam, ...], ptype: type, force: Any) -> Effect:
    return Effect(name, f"planted form {name}", "", params, ptype, force=force)


def _form_at(name: str, params: tuple[EffectParam, ...], ptype: type, force: Any) -> Effect:
    return Effect(name, f"planted form {name}", "", params, ptype, force_at=force)


def _p(*names: str) -> tuple[EffectParam, ...]:
    return tuple(EffectParam(n, "-", 0.0, -1e9, 1e9, "") for n in names)


class BuildUpParams(NamedTuple):
    """The parameters of the planted form ``build_up`` (unit of each after its field)."""

    C_t: float  # strength of the side force once built up [-]
    tau_t: float  # how fast it builds up [s]


@subfunction
def build_up_force_at(
    t: float,
    x0: float,
    y0: float,
    u: float,
    v_m: float,
    r: float,
    psi: float,
    delta: float,
    n_p: float,
    U_T: float,
    gamma_T: float,
    e: BuildUpParams,
    th: Theta,
    sh: Ship,
) -> tuple[float, float, float]:
    """A side force that builds up over the run (a circulation developing in the basin):
    Y = 0.5 rho L d C_t (1 m/s)^2 (1 - exp(-t / tau_t)), N = -0.25 L Y (time)."""
    Y = 0.5 * sh.rho * sh.L_pp * sh.d * e.C_t * (1.0 - math.exp(-t / e.tau_t))
    return 0.0, Y, -0.25 * sh.L_pp * Y


#: planted forms in no catalog entry: only discovery can explain them
UNLISTED: dict[str, Effect] = {
    "bank": _form_at("bank", _p("C_b", "y_b", "W_b"), BankParams, bank_force_at),
    "wave_resistance": _form(
        "wave_resistance", _p("C_w"), WaveResistanceParams, wave_resistance_force
    ),
    "astern_crossflow": _form(
        "astern_crossflow", _p("C_a"), AsternCrossflowParams, astern_crossflow_force
    ),
    "earth_force": _form("earth_force", _p("F_e", "chi_e"), EarthForceParams, earth_force_force),
    "wash_yaw": _form("wash_yaw", _p("C_d"), WashYawParams, wash_yaw_force),
    "reverse_sway": _form("reverse_sway", _p("C_r"), ReverseSwayParams, reverse_sway_force),
    "build_up": _form_at("build_up", _p("C_t", "tau_t"), BuildUpParams, build_up_force_at),
}


#: planted forms that are not in the catalog (not registered: the diagnosis never sees them)
OTHER_FORMS: dict[str, Effect] = {
    "stall_tanh": _form(
        "stall_tanh",
        (EffectParam("alpha_s", "rad", 1.5, 0.1, 1.5, ""),),
        StallTanhParams,
        stall_tanh_force,
    ),
    "a_h_piecewise": _form(
        "a_h_piecewise",
        (EffectParam("beta_0", "rad", 1e3, 0.1, 1e3, ""),),
        AHPiecewiseParams,
        a_h_piecewise_force,
    ),
    "walk_advance": _form(
        "walk_advance",
        (
            EffectParam("C_Yw", "-", 0.0, -1, 1, ""),
            EffectParam("C_Nw", "-", 0.0, -1, 1, ""),
            EffectParam("J_0", "-", 1.0, 0.1, 2, ""),
        ),
        WalkAdvanceParams,
        walk_advance_force,
    ),
}

#: planted forms that are in the paper's model's own form, by the parameters that absorb them.
#: A reversed propeller's side force 0.5 rho L d C_r (n_p D_p)^2 with the moment of a force at
#: the stern (-L/2) is Eqs. (12)-(13) with A1, A3, A5 shifted by C_r and B1, B3, B5 by -C_r / 2:
#: nothing is missing from the form, the right verdict is ``none`` (family ``in_form``)
IN_FORM: dict[str, dict[str, tuple[tuple[str, float], ...]]] = {
    "reverse_sway": {
        "C_r": (("A1", 1.0), ("A3", 1.0), ("A5", 1.0), ("B1", -0.5), ("B3", -0.5), ("B5", -0.5))
    },
}

#: the catalog family the diagnosis should name for each planted form
FAMILY: dict[str, str] = {
    "none": "none",
    "current": "current",
    "propeller_walk": "propeller_walk",
    "walk_advance": "propeller_walk",
    "rudder_stall": "rudder_stall",
    "stall_tanh": "rudder_stall",
    "a_h_drift": "a_h_drift",
    "a_h_piecewise": "a_h_drift",
    "actuator_lag": "actuator_lag",
    "delay": "actuator_lag",
    "rudder_offset": "rudder_offset",
    "heading_bias": "heading_bias",
    "heading_only": "heading_bias",
    **{name: "discovered" for name in UNLISTED if name not in IN_FORM},
    **{name: "in_form" for name in IN_FORM},
}

# --------------------------------------------------------------------------- noise

#: state columns (x0, u, y0, v_m, psi, r)
STATE_NAMES = ("x0", "u", "y0", "v_m", "psi", "r")


def noise_levels(recordings: Sequence[Recording]) -> dict[str, float]:
    """White-noise standard deviation of each state channel of real recordings.

    The second difference of a smooth 10-Hz signal is tiny, that of white noise of standard
    deviation s has variance 6 s^2: s = median over runs of std(second difference) / sqrt(6).
    """
    levels: dict[str, list[float]] = {n: [] for n in STATE_NAMES}
    for rec in recordings:
        d2 = np.diff(np.asarray(rec.x), n=2, axis=0)
        for j, n in enumerate(STATE_NAMES):
            levels[n].append(float(np.std(d2[:, j]) / math.sqrt(6.0)))
    return {n: float(np.median(v)) for n, v in levels.items()}


# --------------------------------------------------------------------------- cases


@dataclass(frozen=True)
class PlantedSpec:
    """What to plant: a form (catalog effect name, other form, ``delay`` or ``none``) and values."""

    form: str
    values: dict[str, float] = field(default_factory=dict)

    @property
    def family(self) -> str:
        """The catalog family the diagnosis should name for this form (:data:`FAMILY`)."""
        return FAMILY[self.form]

    @property
    def expected(self) -> str:
        """The verdict a right diagnosis gives: the family, ``none`` for a form in the model's."""
        return expected_verdict(self.family)


def expected_verdict(family: str) -> str:
    """The verdict that is right for a planted family (``in_form``: ``none``)."""
    return "none" if family == "in_form" else family


def perturbed_ship(rng: np.random.Generator, spread: float) -> Parameters:
    """EFD parameters each scaled by exp(N(0, spread)), kept inside the search domain."""
    p = efd_parameters()
    lo, hi = bounds()
    v = p.vector() * np.exp(rng.normal(0.0, spread, N_THETA))
    v = np.clip(v, lo + 0.02 * (hi - lo), hi - 0.02 * (hi - lo))
    return Parameters.from_vector(v, ship=p.ship)


@dataclass(frozen=True)
class Window:
    """One 100-s piece of a real run, with a little history for a dead time."""

    run: str
    start: int  # first sample in the run
    n: int  # samples
    rec: Recording


def pick_windows(
    runs: Mapping[str, Sequence[Recording]],
    counts: Mapping[str, int],
    rng: np.random.Generator,
    length: int = 1001,
    history: int = 50,
) -> list[Window]:
    """``counts[kind]`` windows of ``length`` samples from the runs of each kind (no overlap)."""
    out: list[Window] = []
    for kind, k in counts.items():
        slots = [
            (rec, start)
            for rec in runs[kind]
            for start in range(history, rec.n_samples - length, length)
        ]
        if len(slots) < k:
            raise ValueError(f"only {len(slots)} windows of kind {kind}, {k} wanted")
        for i in rng.choice(len(slots), size=k, replace=False):
            rec, start = slots[int(i)]
            out.append(Window(rec.name, start, length, rec))
    return out


def _controls(win: Window, spec: PlantedSpec) -> np.ndarray:
    """(n - 1, 2) acting controls of the window: the log, or the log a dead time earlier."""
    u = np.asarray(win.rec.u)
    lo, hi = win.start, win.start + win.n - 1
    if spec.form != "delay":
        return u[lo:hi].copy()
    d = round(spec.values["tau"] / win.rec.dt)
    return u[lo - d : hi - d].copy()


def truth_effects(spec: PlantedSpec) -> tuple[tuple[Effect, ...], Parameters | None]:
    """(effects for the simulator, and a Parameters template carrying their values)."""
    if spec.form in ("none", "delay"):
        return (), None
    if spec.form == "heading_only":
        eff = get_effect("heading_bias")
        vals = {"b_psi": spec.values["b_psi"], "b_v": 0.0}
        return (eff,), Parameters(
            efd_parameters().theta, effects=(("heading_bias", tuple(vals.items())),)
        )
    eff = OTHER_FORMS.get(spec.form) or UNLISTED.get(spec.form) or get_effect(spec.form)
    values = tuple((q.name, float(spec.values.get(q.name, q.neutral))) for q in eff.params)
    return (eff,), Parameters(efd_parameters().theta, effects=((eff.name, values),))


def generate(
    windows: Sequence[Window],
    ship: Parameters,
    spec: PlantedSpec,
    noise: dict[str, float],
    rng: np.random.Generator,
    phi: float = 0.0,
) -> tuple[list[Recording], bool]:
    """Simulated noisy recordings of the windows; also whether any simulation diverged.

    ``phi`` > 0 colours the noise: a first-order low-pass (AR(1), correlation phi between
    samples) of the same standard deviation, as a filtered sensor would give."""
    effects, template = truth_effects(spec)
    p = ship if template is None else Parameters(ship.theta, ship.ship, template.effects)
    x0 = np.stack([np.asarray(w.rec.x[w.start]) for w in windows])
    u = np.stack([_controls(w, spec) for w in windows])
    wind = np.stack([np.asarray(w.rec.w[w.start : w.start + w.n - 1]) for w in windows])
    t0 = np.array([float(w.rec.t[w.start]) for w in windows])
    sim = simulate_batch(x0, u, wind, p, effects=effects, t0=t0)
    sigma = np.array([noise[n] for n in STATE_NAMES])
    out = []
    for i, w in enumerate(windows):
        e = rng.normal(0.0, 1.0, sim.states[i].shape)
        e = ar1(e, phi)
        x = sim.states[i] + e * sigma
        x[0] = sim.states[i][0]  # the first logged state is the real one (the simulation's start)
        sl = slice(w.start, w.start + w.n)
        out.append(
            Recording(
                name=f"{w.run}_{w.start}",
                path=None,
                t=np.asarray(w.rec.t[sl]),
                x=x,
                u=np.asarray(w.rec.u[sl]),  # the LOG, not the acting controls
                w=np.asarray(w.rec.w[sl]),
            )
        )
    return out, bool(sim.diverged.any())


def write_case(
    directory: Path,
    train: Sequence[Recording],
    test: Sequence[Recording],
    spec: PlantedSpec,
    ship: Parameters,
) -> None:
    """train/*.csv, test/*.csv (what the diagnosis sees) and truth.json (what it must not)."""
    for sub, recs in (("train", train), ("test", test)):
        d = directory / sub
        d.mkdir(parents=True, exist_ok=True)
        for rec in recs:
            rec.frame().to_csv(d / f"{rec.name}.csv", index=False)
    truth = {"spec": asdict(spec), "family": spec.family, "ship": ship.to_dict()}
    (directory / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")


def true_model(ship: Parameters, spec: PlantedSpec) -> tuple[Parameters, tuple[Effect, ...]]:
    """The true model in a form the project's simulator can evaluate on the logs. A planted
    dead time becomes the catalog's ``actuator_lag`` with that dead time and no lag, which holds
    the first logged value within tau of a window's start where the generator had the run's
    earlier samples."""
    if spec.form == "delay":
        eff = get_effect("actuator_lag")
        tau = spec.values["tau"]
        vals = {"T_delta": 0.0, "T_n": 0.0, "tau_delta": tau, "tau_n": tau}
        return Parameters(ship.theta, ship.ship, (("actuator_lag", tuple(vals.items())),)), (eff,)
    effects, template = truth_effects(spec)
    p = ship if template is None else Parameters(ship.theta, ship.ship, template.effects)
    return p, effects
