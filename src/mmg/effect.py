"""What a piece of extra physics is: :class:`Effect` and its parameters (no registry).

Extra physics plugs into the MMG model without editing its sub-models. The catalog's effects
(:mod:`mmg.catalog`) and the generated ones (:mod:`mmg.discovered`) are built from these types;
:mod:`mmg.effects` knows them all by name.

An :class:`Effect` adds named parameters and one or more hooks, each a scalar function
compiled with :func:`mmg._jit.subfunction` and defined at module level (the kernel generator imports
it by name):

- ``force(u, v_m, r, psi, delta, n_p, U_T, gamma_T, e, th, sh) -> (dX [N], dY [N], dN [N m])``:
  an additional force and moment at midship, added to the sum of paper Eq. (2);
- ``force_at(t, x0, y0, u, v_m, r, psi, delta, n_p, U_T, gamma_T, e, th, sh) -> (dX, dY, dN)``:
  like ``force``, for forces that also depend on where and when: the position of midship
  (x0, y0) [m] (a bank, shallow patch or a field of the basin) and the time t [s] on the
  recording's clock (the time column of the file: a force that builds up or dies away over a
  run); generated effects (:mod:`mmg.discovered`) use it;
- ``current(x0, y0, psi, e) -> (u_c, v_c)`` [m/s]: the body-frame velocity of the water at the ship.
  The hydrodynamic sub-models then see the velocity through the water (u - u_c, v_m - v_c), the
  wind still sees the velocity over ground, and the equations of motion are written for the
  velocity through the water of a uniform steady current (u_c, v_c rotate with the heading:
  d u_c / dt = r v_c, d v_c / dt = -r u_c). The state keeps the velocity over ground, as recorded;
- ``inputs(delta_log, n_log, delta_prev, n_prev, dt, e) -> (delta, n_p)``: the controls that act on
  the ship, from the logged ones at this step and the acting ones of the previous step (actuator
  lag, offsets of the log). The kernel applies it once per time step (zero-order hold); at the
  first step of a simulation delta_prev, n_prev are the logged values. With several input effects
  the hooks are chained in order, and ``*_prev`` is the output of the whole chain;
- ``delay(e) -> (tau_delta, tau_n)`` [s]: dead times between the log and the acting controls:
  the controls that act at time t are the logged ones at t - tau (linearly interpolated between
  samples; within tau of the start of a simulation, the first logged value). Dead times of
  several effects add up; ``inputs`` hooks then act on the delayed values;
- ``observe(e) -> (b_psi, b_v)`` [rad]: how the measurement differs from the true state: the
  logged heading is psi + b_psi, and the logged body velocities are the true ones rotated by
  -b_v (u_log = u cos b_v + v_m sin b_v, v_log = -u sin b_v + v_m cos b_v: a velocity over
  ground resolved along a heading that is off by b_v). Simulations start from the true state
  implied by the logged one and report the logged quantities.

``e`` is the effect's own parameter NamedTuple. Values that make the effect vanish are the
``neutral`` values of its parameters.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

#: how the compiled kernel runs an effect (:meth:`Effect.kernel_form`): the effect whose code is
#: compiled, the values of its leading parameters when held (None: from the parameter vector),
#: the numbers that follow them in its parameter rows
KernelForm = tuple["Effect", tuple[float, ...] | None, tuple[float, ...]]

#: names of generated effects start with this (the rest lists the library terms)
DISCOVERED_PREFIX = "discovered:"


class EffectParam(NamedTuple):
    """One parameter of an effect: name, unit, neutral value, search interval, meaning."""

    name: str
    unit: str
    neutral: float
    lower: float
    upper: float
    description: str


@dataclass(frozen=True)
class Effect:
    """A candidate piece of physics: hooks, parameter table and plain-words description."""

    name: str
    description: str
    regime: str
    params: tuple[EffectParam, ...]
    param_type: type  # NamedTuple class of the parameters, fields = names of ``params``
    force: Callable[..., Any] | None = None
    force_at: Callable[..., Any] | None = None
    current: Callable[..., Any] | None = None
    inputs: Callable[..., Any] | None = None
    observe: Callable[..., Any] | None = None
    delay: Callable[..., Any] | None = None

    def __post_init__(self) -> None:
        fields = getattr(self.param_type, "_fields", None)
        if fields != tuple(p.name for p in self.params):
            raise ValueError(f"effect {self.name}: param_type fields differ from params")
        if not self.hooks:
            raise ValueError(
                f"effect {self.name}: needs a force, force_at, current, inputs, observe or "
                "delay hook"
            )

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle field by field: the hooks are importable module-level functions. (Generated
        effects, whose module is not on the import path, pickle by name:
        :class:`mmg.discovered.DiscoveredEffect`.)"""
        values = tuple(getattr(self, f) for f in self.__dataclass_fields__)
        return (Effect, values)

    @property
    def hooks(self) -> tuple[Callable[..., Any], ...]:
        """The hook functions the effect defines."""
        return tuple(
            f
            for f in (
                self.force,
                self.force_at,
                self.current,
                self.inputs,
                self.observe,
                self.delay,
            )
            if f is not None
        )

    @property
    def bounds(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(lower, upper) of the search interval of each parameter."""
        return tuple(p.lower for p in self.params), tuple(p.upper for p in self.params)

    @property
    def param_names(self) -> tuple[str, ...]:
        """The parameters' names, in kernel order."""
        return tuple(p.name for p in self.params)

    def neutral(self) -> tuple[float, ...]:
        """Parameter values for which the effect vanishes."""
        return tuple(p.neutral for p in self.params)

    def kernel_form(self) -> KernelForm:
        """How the compiled kernel runs this effect: (the effect whose code it is compiled
        from, the values of that effect's leading parameters when this effect holds them (None:
        this effect's own parameters, from the parameter vector), numbers that follow them in
        that effect's parameter rows). A plain effect runs itself. An effect held at values
        (:mod:`mmg.fixed`) or restricted to a box (:mod:`mmg.domain`) runs a kernel whose code
        holds none of its numbers: they are parameter rows, and one compiled kernel serves
        every value and every box (:func:`mmg.fixed.kernel_effects`,
        :func:`mmg.integrate.kernel_rows`)."""
        return self, None, ()


__all__ = ["DISCOVERED_PREFIX", "Effect", "EffectParam", "KernelForm"]
