"""The parameter table of the model-rich MMG model (paper Table 1, section 3.3).

One table drives everything: the typed view :class:`Theta` (the 57 explored parameters, in a fixed
order), the flat vector CMA-ES searches, the JSON file, and the search domain. Values are the EFD
(captive-model test and empirical formula) values of the Esso Osaka 3 m model (paper Table 1).
Primed symbols are non-dimensional:
force' = F / (0.5 rho L d U^2), moment' = N / (0.5 rho L^2 d U^2), mass' = m / (0.5 rho L^2 d),
inertia' = I / (0.5 rho L^4 d), length' = x / L.

Search domain (paper Eqs. (38)-(39)): theta_j in [-10 |theta_EFD,j|, 10 |theta_EFD,j|], except
m_x, m_y, I_zz + J_zz in [0.7, 1.3] theta_EFD; Y'_v, N'_r in [10, 0.1] theta_EFD (negative values);
t_P, w_P0 in [0.1, 10] theta_EFD.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


class Theta(NamedTuple):
    """The 57 explored parameters (paper Table 1), in the order of the flat CMA-ES vector.

    All values are non-dimensional (primed) where the paper's symbol is primed; the polynomial
    coefficients A_i, B_i, C_i, the wind coefficients and the rudder factors are dimensionless.
    """

    # Hull, Yoshimura (2009) unified model, Eq. (4), and added masses of Eq. (1)
    m_x: float  # m'_x, added mass in surge
    m_y: float  # m'_y, added mass in sway
    I_zz_J_zz: float  # (I_zz + J_zz)', yaw inertia plus added inertia
    X_0A: float  # X'_0(A), astern resistance coefficient
    X_vr: float  # X'_vr
    Y_v: float  # Y'_v
    Y_r: float  # Y'_r
    N_v: float  # N'_v
    N_r: float  # N'_r
    C_D: float  # cross-flow drag coefficient
    C_rY: float  # cross-flow correction factor for the lateral force
    C_rN: float  # cross-flow correction factor for the yaw moment
    # Propeller, Eqs. (5)-(13)
    t_P: float  # thrust deduction factor
    w_P0: float  # wake fraction at v_m = r = 0
    tau: float  # wake coefficient (linear term)
    C_P: float  # C'_P, wake coefficient (quadratic term)
    x_P: float  # x'_P, longitudinal position in the wake model
    A1: float  # Hasegawa reversal side force, -0.35 <= J_s <= -0.06
    A2: float
    A3: float  # J_s < -0.35
    A4: float
    A5: float  # J_s > -0.06
    A6: float  # Ueno side force, u < 0, n_p >= 0
    A7: float
    A8: float
    B1: float  # Hasegawa reversal yaw moment, -0.35 <= J_s <= -0.06
    B2: float
    B3: float  # J_s < -0.35
    B4: float
    B5: float  # J_s > -0.06
    B6: float  # Ueno yaw moment, u < 0, n_p >= 0
    B7: float
    B8: float
    C3: float  # Hasegawa reversal thrust, J_s < C10
    C6: float  # J_s >= C10: C6 + C7 J_s
    C7: float
    C10: float
    # Rudder, Eqs. (14)-(26)
    t_R: float  # steering resistance deduction factor
    a_H: float  # rudder force increase factor
    x_H: float  # x'_H, position of the additional lateral force
    gamma_P: float  # flow straightening coefficient, v_m + x_R r >= 0
    gamma_N: float  # flow straightening coefficient, v_m + x_R r < 0
    l_R: float  # l'_R, effective longitudinal position of the rudder
    k_x: float  # propeller-induced velocity factor (Yoshimura)
    epsilon: float  # ratio of wake fraction at rudder and propeller
    k_xPR: float  # velocity increase factor, propeller reversal (Kitagawa)
    C_PR: float  # correction factor, propeller reversal (Kitagawa)
    # Wind, Fujiwara (1998) regression, Eqs. (27)-(28)
    X0: float
    X1: float
    X3: float
    X5: float
    Y1: float
    Y3: float
    Y5: float
    N1: float
    N2: float
    N3: float  # the paper's Table 1 says "N5"; the explored yaw coefficient is N3


class Bound(Enum):
    """Rule that turns an EFD value into a search interval (paper section 3.3, Eqs. (38)-(39))."""

    SYMMETRIC = "symmetric"  # [-10 |theta|, 10 |theta|], Eq. (38)
    MASS = "mass"  # [0.7 theta, 1.3 theta], added masses
    NEGATIVE = "negative"  # [10 theta, 0.1 theta], theta < 0 (Y'_v, N'_r)
    POSITIVE = "positive"  # [0.1 theta, 10 theta], theta > 0 (t_P, w_P0)

    def interval(self, efd: float) -> tuple[float, float]:
        """Return (lower, upper) of the search interval for an EFD value."""
        if self is Bound.SYMMETRIC:
            return -10.0 * abs(efd), 10.0 * abs(efd)
        if self is Bound.MASS:
            return 0.7 * efd, 1.3 * efd
        if self is Bound.NEGATIVE:
            return 10.0 * efd, 0.1 * efd
        return 0.1 * efd, 10.0 * efd


class ParamSpec(NamedTuple):
    """One row of the parameter table."""

    name: str  # field name in Theta (ASCII after the paper's symbol)
    symbol: str  # the paper's symbol, LaTeX
    group: str  # hull | propeller | rudder | wind
    efd: float  # EFD value of the Esso Osaka 3 m model
    bound: Bound  # search-domain rule
    source: str  # where the EFD value comes from (paper Table 1)


_S, _M, _NEG, _POS = Bound.SYMMETRIC, Bound.MASS, Bound.NEGATIVE, Bound.POSITIVE
_EMP, _CT = "empirical formulae", "captive test (Hachii 2004)"

#: one row per explored parameter, in Theta order (paper Table 1)
PARAMETER_TABLE: tuple[ParamSpec, ...] = (
    ParamSpec("m_x", "m'_x", "hull", 0.0467, _M, _EMP),
    ParamSpec("m_y", "m'_y", "hull", 0.2579, _M, _EMP),
    ParamSpec("I_zz_J_zz", "(I_{zz}+J_{zz})'", "hull", 0.0286, _M, _EMP),
    ParamSpec("X_0A", "X'_{0(A)}", "hull", -0.03189, _S, _CT),
    ParamSpec("X_vr", "X'_{vr}", "hull", 0.4535, _S, _CT),
    ParamSpec("Y_v", "Y'_v", "hull", -0.3728, _NEG, _CT),
    ParamSpec("Y_r", "Y'_r", "hull", 0.116, _S, _CT),
    ParamSpec("N_v", "N'_v", "hull", -0.1458, _S, _CT),
    ParamSpec("N_r", "N'_r", "hull", -0.04849, _NEG, _CT),
    ParamSpec("C_D", "C_D", "hull", 0.9665, _S, "empirical formulae (Yoshimura 2009)"),
    ParamSpec("C_rY", "C_{rY}", "hull", 2.217, _S, "empirical formulae (Yoshimura 2009)"),
    ParamSpec("C_rN", "C_{rN}", "hull", 0.8097, _S, "empirical formulae (Yoshimura 2009)"),
    ParamSpec("t_P", "t_P", "propeller", 0.22, _POS, "captive test (ITTC 2002)"),
    ParamSpec("w_P0", "w_{P0}", "propeller", 0.614, _POS, "captive test (ITTC 2002)"),
    ParamSpec("tau", "\\tau", "propeller", 0.871, _S, "captive test (ITTC 2002)"),
    ParamSpec("C_P", "C'_P", "propeller", -0.359, _S, "captive test (ITTC 2002)"),
    ParamSpec("x_P", "x'_P", "propeller", -0.517, _S, "captive test (ITTC 2002)"),
    ParamSpec("A1", "A_1", "propeller", -7.9e-5, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("A2", "A_2", "propeller", 7.99e-3, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("A3", "A_3", "propeller", -4.93e-3, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("A4", "A_4", "propeller", -5.87e-3, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("A5", "A_5", "propeller", -5.58e-4, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("A6", "A_6", "propeller", 5.08e-3, _S, "captive test of a training ship (Ueno 2001)"),
    ParamSpec("A7", "A_7", "propeller", 1.70e-3, _S, "captive test of a training ship (Ueno 2001)"),
    ParamSpec("A8", "A_8", "propeller", 9.16e-4, _S, "captive test of a training ship (Ueno 2001)"),
    ParamSpec("B1", "B_1", "propeller", 3.5e-5, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("B2", "B_2", "propeller", -3.17e-3, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("B3", "B_3", "propeller", 1.96e-3, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("B4", "B_4", "propeller", 2.33e-3, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("B5", "B_5", "propeller", 2.25e-4, _S, "captive test (Hasegawa 1994)"),
    ParamSpec(
        "B6", "B_6", "propeller", -2.16e-3, _S, "captive test of a training ship (Ueno 2001)"
    ),
    ParamSpec("B7", "B_7", "propeller", 6.27e-5, _S, "captive test of a training ship (Ueno 2001)"),
    ParamSpec("B8", "B_8", "propeller", 6.25e-5, _S, "captive test of a training ship (Ueno 2001)"),
    ParamSpec("C3", "C_3", "propeller", -0.251, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("C6", "C_6", "propeller", -0.175, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("C7", "C_7", "propeller", 0.33, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("C10", "C_{10}", "propeller", -0.233, _S, "captive test (Hasegawa 1994)"),
    ParamSpec("t_R", "t_R", "rudder", 0.19, _S, _CT),
    ParamSpec("a_H", "a_H", "rudder", 0.393, _S, _CT),
    ParamSpec("x_H", "x'_H", "rudder", -0.45, _S, _CT),
    ParamSpec("gamma_P", "\\gamma_P", "rudder", 0.3506, _S, _CT),
    ParamSpec("gamma_N", "\\gamma_N", "rudder", 0.4406, _S, _CT),
    ParamSpec("l_R", "l'_R", "rudder", -1.08, _S, _CT),
    ParamSpec("k_x", "k_x", "rudder", 0.288, _S, _CT),
    ParamSpec("epsilon", "\\varepsilon", "rudder", 1.42, _S, _CT),
    ParamSpec("k_xPR", "k_{xPR}", "rudder", 0.144, _S, "KVLCC1 and bulk carrier (Kitagawa 2015)"),
    ParamSpec("C_PR", "C_{PR}", "rudder", -0.176, _S, "KVLCC1 and bulk carrier (Kitagawa 2015)"),
    ParamSpec("X0", "X_0", "wind", -0.010466, _S, "regression (Fujiwara 1998)"),
    ParamSpec("X1", "X_1", "wind", -0.821992, _S, "regression (Fujiwara 1998)"),
    ParamSpec("X3", "X_3", "wind", 0.060274, _S, "regression (Fujiwara 1998)"),
    ParamSpec("X5", "X_5", "wind", 0.044558, _S, "regression (Fujiwara 1998)"),
    ParamSpec("Y1", "Y_1", "wind", 1.058172, _S, "regression (Fujiwara 1998)"),
    ParamSpec("Y3", "Y_3", "wind", 0.002321, _S, "regression (Fujiwara 1998)"),
    ParamSpec("Y5", "Y_5", "wind", -0.015293, _S, "regression (Fujiwara 1998)"),
    ParamSpec("N1", "N_1", "wind", -0.030728, _S, "regression (Fujiwara 1998)"),
    ParamSpec("N2", "N_2", "wind", 0.104116, _S, "regression (Fujiwara 1998)"),
    ParamSpec("N3", "N_3", "wind", -0.00088, _S, "regression (Fujiwara 1998)"),
)

if tuple(s.name for s in PARAMETER_TABLE) != Theta._fields:  # pragma: no cover - import guard
    raise RuntimeError("PARAMETER_TABLE and Theta list different parameters or orders")

#: number of explored parameters (57), the length of the flat CMA-ES vector
N_THETA = len(Theta._fields)
#: the explored parameters' names in Theta order (the flat vector's order)
PARAMETER_NAMES: tuple[str, ...] = Theta._fields


class Ship(NamedTuple):
    """Fixed particulars of the ship and fixed (not explored) model constants. SI units."""

    L_pp: float  # length between perpendiculars [m]
    B: float  # breadth [m]
    d: float  # draft [m]
    rho: float  # water density [kg/m^3]
    m_nd: float  # m' = m / (0.5 rho L^2 d), ship mass [-]
    x_G_nd: float  # x'_G = x_G / L, centre of gravity from midship [-]
    D_p: float  # propeller diameter [m]
    pitch_ratio: float  # P / D_p [-]
    A_R: float  # rudder area [m^2]
    lambda_R: float  # rudder aspect ratio [-]
    x_R_nd: float  # x'_R, rudder position from midship [-]
    rho_A: float  # air density [kg/m^3]
    A_T: float  # transverse projected area above water [m^2]
    A_L: float  # lateral projected area above water [m^2]
    X_0F: float  # X'_0(F), ahead resistance coefficient [-]
    k_0: float  # K_T(J) = k_0 + k_1 J + k_2 J^2
    k_1: float
    k_2: float


#: the Esso Osaka 3 m model of the recordings (model scale, SI units)
ESSO_OSAKA = Ship(
    L_pp=3.0,
    B=0.48925,
    d=0.20114,
    rho=998.0,
    m_nd=0.27078,
    x_G_nd=0.03119,
    D_p=0.084,
    pitch_ratio=0.7151,
    A_R=0.01063,
    lambda_R=1.539,
    x_R_nd=-0.5,
    rho_A=1.225,
    A_T=0.13544,
    A_L=0.52038,
    X_0F=-0.02139,
    k_0=0.3278,
    k_1=-0.3323,
    k_2=-0.156,
)


def efd_theta() -> Theta:
    """The EFD values of the 57 explored parameters."""
    return Theta(*(s.efd for s in PARAMETER_TABLE))


def bounds() -> tuple[FloatArray, FloatArray]:
    """Search domain of the paper (section 3.3): (lower, upper), each shape (57,)."""
    pairs = [s.bound.interval(s.efd) for s in PARAMETER_TABLE]
    return np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])


class ParameterError(ValueError):
    """A parameter file or vector that cannot be used (names the file and the entry)."""


@dataclass(frozen=True)
class Parameters:
    """A full parameter set: explored parameters, ship particulars and extra-physics parameters.

    ``effects`` maps an effect name (see :mod:`mmg.effects`) to its parameter values by name;
    an empty mapping is the paper's model.
    """

    theta: Theta
    ship: Ship = ESSO_OSAKA
    effects: tuple[tuple[str, tuple[tuple[str, float], ...]], ...] = ()

    def vector(self) -> FloatArray:
        """The 57 explored parameters as a flat float64 vector in Theta order."""
        return np.asarray(self.theta, dtype=np.float64)

    @classmethod
    def from_vector(cls, vector: Any, ship: Ship = ESSO_OSAKA) -> Parameters:
        """Build from a flat vector of length 57 (Theta order)."""
        v = np.asarray(vector, dtype=np.float64)
        if v.shape != (N_THETA,):
            raise ParameterError(f"expected a vector of {N_THETA} parameters, got shape {v.shape}")
        return cls(theta=Theta(*(float(x) for x in v)), ship=ship)

    def replace(self, **values: float) -> Parameters:
        """Return a copy with some explored parameters changed by name."""
        unknown = set(values) - set(PARAMETER_NAMES)
        if unknown:
            raise ParameterError(f"unknown parameter(s): {', '.join(sorted(unknown))}")
        return Parameters(self.theta._replace(**values), self.ship, self.effects)

    def effect_values(self, name: str) -> dict[str, float]:
        """Parameter values of one extra-physics effect (empty if the effect is absent)."""
        for effect, values in self.effects:
            if effect == name:
                return dict(values)
        return {}

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary: {"theta": {...}, "ship": {...}, "effects": {...}}."""
        return {
            "theta": {k: float(v) for k, v in self.theta._asdict().items()},
            "ship": {k: float(v) for k, v in self.ship._asdict().items()},
            "effects": {name: dict(values) for name, values in self.effects},
        }

    @classmethod
    def from_dict(cls, data: Any, origin: str = "parameters") -> Parameters:
        """Inverse of :meth:`to_dict`. Missing ship entries default to the Esso Osaka model.

        Raises :class:`ParameterError` naming ``origin`` and the offending entry.
        """
        if not isinstance(data, dict):
            raise ParameterError(f"{origin}: expected a JSON object, got {type(data).__name__}")
        theta_in = data.get("theta", data)
        if not isinstance(theta_in, dict):
            raise ParameterError(f"{origin}: 'theta' must be an object of name: value")
        missing = [n for n in PARAMETER_NAMES if n not in theta_in]
        if missing:
            raise ParameterError(f"{origin}: missing parameter(s) {', '.join(missing)}")
        theta = Theta(*(_number(theta_in[n], origin, f"theta.{n}") for n in PARAMETER_NAMES))
        ship_in = data.get("ship", {})
        if not isinstance(ship_in, dict):
            raise ParameterError(f"{origin}: 'ship' must be an object of name: value")
        unknown = set(ship_in) - set(Ship._fields)
        if unknown:
            raise ParameterError(f"{origin}: unknown ship entr(ies) {', '.join(sorted(unknown))}")
        ship = ESSO_OSAKA._replace(
            **{k: _number(v, origin, f"ship.{k}") for k, v in ship_in.items()}
        )
        effects_in = data.get("effects", {})
        if not isinstance(effects_in, dict):
            raise ParameterError(f"{origin}: 'effects' must be an object")
        effects = tuple(
            (
                str(name),
                tuple(
                    (str(k), _number(v, origin, f"effects.{name}.{k}"))
                    for k, v in dict(vals).items()
                ),
            )
            for name, vals in effects_in.items()
        )
        return cls(theta=theta, ship=ship, effects=effects)

    def save_json(self, path: str | Path, **metadata: Any) -> None:
        """Write as JSON; ``metadata`` (objective, seed, commit, ...) is stored under "metadata"."""
        payload = self.to_dict()
        if metadata:
            payload["metadata"] = metadata
        Path(path).write_text(json.dumps(payload, indent=2) + "\n")

    @classmethod
    def load_json(cls, path: str | Path) -> Parameters:
        """Read a file written by :meth:`save_json` (or any JSON with the 57 names)."""
        p = Path(path)
        try:
            text = p.read_text()
        except OSError as exc:
            raise ParameterError(f"{p}: cannot read ({exc.strerror})") from exc
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ParameterError(
                f"{p}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
            ) from exc
        return cls.from_dict(data, origin=str(p))


def _number(value: Any, origin: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ParameterError(f"{origin}: {where} must be a number, got {value!r}")
    x = float(value)
    if not np.isfinite(x):
        raise ParameterError(f"{origin}: {where} must be finite, got {value!r}")
    return x


def efd_parameters(ship: Ship = ESSO_OSAKA) -> Parameters:
    """The EFD (captive-model test) parameter set of the Esso Osaka 3 m model."""
    return Parameters(theta=efd_theta(), ship=ship)
