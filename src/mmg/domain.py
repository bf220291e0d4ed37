"""Where an effect holds: an effect restricted to the box of states it was fitted on.

A force found on some manoeuvres is known only over the states those manoeuvres reached. Outside
them it may be anything: a yaw moment fitted on random runs at up to 10 rps and 20 deg of drift
says nothing about a berthing run astern at -20 rps. :func:`within` wraps an effect so that its
force and moment hooks see the state only inside a box of

- U [m/s]: the speed through the water, sqrt(u^2 + v_m^2) (its upper bound),
- u, v_m [m/s]: the velocity through the water at midship (surge, sway),
- r [rad/s]: the yaw rate,
- delta [rad]: the acting rudder angle,
- n_p [rev/s]: the acting propeller revolution rate,

(:data:`VARIABLES`) and, outside it, either

- ``held`` (the default): the force is the effect's force at the nearest state of the box (each
  variable clamped to its interval: the force stays at its boundary value). Above the top speed
  U_max the state is first brought to U_max by similarity: u, v_m, r, n_p and the true wind
  speed U_T are scaled by s = U_max / U (the drift angle, r L / U, the advance ratio and the
  wind's angle stay), and the force found there is divided by s^2. So what is held beyond the
  top speed is the force's non-dimensional coefficient, X / (0.5 rho L d U^2) as the MMG model
  writes every force, not its value in newtons: a force that grows with U^2 (the hull's, the
  rudder's, a bank's, the wind's) keeps growing, and a force that does not is overstated by
  (U / U_max)^2; or
- ``off``: no force.

The wrapped effect keeps the name of the effect it wraps followed by its box, e.g.
``propeller_walk@held(U=0:1.31,u=0.2:1.3,v_m=-0.2:0.2,r=-0.04:0.04,delta=-0.61:0.61,n_p=3:10)``;
its parameters are the inner effect's, so a parameter file written with the plain effect's values
reads the same values. Like a ``discovered:`` effect it is generated at run time (a small module
in ``<kernel dir>/effects``, named by a hash of its text) and rebuilt from its name in any process
(:func:`mmg.get_effect` splits the name, :func:`split_name`, and wraps the inner effect). The
kernel runs it as a *boxed* effect (:func:`boxed`) whose code reads the box's bounds from
parameter rows after the effect's own: every box of an effect that bounds the same variables
shares one compiled kernel (:meth:`DomainEffect.kernel_form`). Hooks
that are not forces (a current, the controls, the measurement) pass through unchanged. A box
without U (a name written before U was part of it) clamps each variable alone.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field, replace
from decimal import ROUND_CEILING, ROUND_FLOOR, Decimal
from typing import Any

from mmg._generated import HOOK_ARGS, generated_module, with_numbers
from mmg.effect import Effect, EffectParam, KernelForm

#: the variables of the box, in the order of a name's box
VARIABLES = ("U", "u", "v_m", "r", "delta", "n_p")
#: units of :data:`VARIABLES`
UNITS = {"U": "m/s", "u": "m/s", "v_m": "m/s", "r": "rad/s", "delta": "rad", "n_p": "rev/s"}
#: the state variables a box clamps one by one (U brings the state to the top speed first)
CLAMPED = ("u", "v_m", "r", "delta", "n_p")
#: the arguments scaled with the speed above the top speed (U_T: the true wind speed)
SCALED = ("u", "v_m", "r", "n_p", "U_T")
#: what an effect does outside its box
MODES = ("held", "off")
#: separates an effect's name from its box
SEPARATOR = "@"

_NAME = re.compile(r"^(?P<inner>.+)@(?P<mode>held|off)\((?P<box>[^()]*)\)$")
_INTERVAL = re.compile(r"^(?P<var>[A-Za-z_]+)=(?P<lo>[^:]+):(?P<hi>.+)$")

#: the wrapped effects of this process by name
_made: dict[str, Effect] = {}


@dataclass(frozen=True)
class Domain:
    """The box of states an effect acts in and what it does outside (``held`` or ``off``).

    ``lower``, ``upper``: {variable: bound} in the units of :data:`UNITS`; a variable missing
    from the maps is not bounded."""

    lower: dict[str, float]
    upper: dict[str, float]
    mode: str = "held"

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"domain mode {self.mode!r}: use one of {', '.join(MODES)}")
        for var in {*self.lower, *self.upper}:
            if var not in VARIABLES:
                raise ValueError(f"domain variable {var!r}: use {', '.join(VARIABLES)}")
            lo = self.lower.get(var, -math.inf)
            hi = self.upper.get(var, math.inf)
            if not lo <= hi:
                raise ValueError(f"domain of {var}: lower {lo} above upper {hi}")

    @property
    def spec(self) -> str:
        """``mode(var=lo:hi,...)``, the bounds in 4 significant digits (widened outward so that
        the rounded box still holds the states it was measured on)."""
        parts = []
        for var in VARIABLES:
            if var in self.lower or var in self.upper:
                lo = _round(self.lower.get(var, -math.inf), math.floor)
                hi = _round(self.upper.get(var, math.inf), math.ceil)
                parts.append(f"{var}={lo}:{hi}")
        return f"{self.mode}({','.join(parts)})"

    def rounded(self) -> Domain:
        """The domain as its :attr:`spec` states it (what a wrapped effect acts on)."""
        return parse_spec(self.spec)

    def with_mode(self, mode: str) -> Domain:
        """The same box, another mode."""
        return replace(self, mode=mode)

    def contains(self, var: str, value: float) -> bool:
        """Whether ``value`` of ``var`` lies in its interval."""
        return self.lower.get(var, -math.inf) <= value <= self.upper.get(var, math.inf)


def _round(x: float, direction: Any) -> str:
    """``x`` in 4 significant digits, rounded in ``direction`` (math.floor or math.ceil).

    Rounded in decimal, from the shortest text of ``x``: a bound read back from the text rounds
    to the same text (in binary, 0.02521 / 1e-5 is 2520.9999... and fell to 0.0252), so a box
    rebuilt from an effect's name is the box the effect was made with."""
    if not math.isfinite(x):
        return "inf" if x > 0 else "-inf"
    if x == 0.0:
        return "0"
    d = Decimal(repr(float(x)))
    mode = ROUND_FLOOR if direction is math.floor else ROUND_CEILING
    q = d.quantize(Decimal(1).scaleb(d.adjusted() - 3), rounding=mode)
    return f"{float(q):.4g}"


def parse_spec(spec: str) -> Domain:
    """The :class:`Domain` of a spec ``mode(var=lo:hi,...)``; raises ValueError."""
    m = re.match(r"^(?P<mode>\w+)\((?P<box>[^()]*)\)$", spec.strip())
    if m is None:
        raise ValueError(f"domain {spec!r}: expected mode(var=lo:hi,...)")
    lower: dict[str, float] = {}
    upper: dict[str, float] = {}
    for part in filter(None, m["box"].split(",")):
        iv = _INTERVAL.match(part.strip())
        if iv is None:
            raise ValueError(f"domain {spec!r}: cannot read {part!r} (expected var=lo:hi)")
        try:
            lower[iv["var"]] = float(iv["lo"])
            upper[iv["var"]] = float(iv["hi"])
        except ValueError:
            msg = f"domain {spec!r}: {part!r} has a bound that is not a number"
            raise ValueError(msg) from None
    return Domain(lower, upper, m["mode"])


def split_name(name: str) -> tuple[str, Domain | None]:
    """(the inner effect's name, its domain) of an effect name (None: not a wrapped effect)."""
    m = _NAME.match(name)
    if m is None:
        return name, None
    return m["inner"], parse_spec(f"{m['mode']}({m['box']})")


_BOX_TEMPLATE = '''\
"""Generated by mmg.domain: {inner} {where} a box whose bounds are its parameters {fields}.
One module (and one compiled kernel) for every box of these bounds. Do not edit."""
import math
from typing import NamedTuple

from mmg._jit import subfunction
from {ptype_module} import {ptype} as _P
{imports}


class {own}(NamedTuple):
    """The parameters of {inner}, then the bounds of the box."""

{field_lines}
{hooks}
'''


def bound_fields(d: Domain) -> list[tuple[str, float]]:
    """(field, value) of the bounds the code of a box uses, in :data:`VARIABLES` order: the top
    speed U_max (``box_hi_U``) and the finite ends of the clamped variables (``box_lo_u``,
    ``box_hi_u``, ...). Boxes with the same fields share one kernel; the values are parameter
    rows."""
    out: list[tuple[str, float]] = []
    for var in VARIABLES:
        lo, hi = d.lower.get(var, -math.inf), d.upper.get(var, math.inf)
        if var in CLAMPED and math.isfinite(lo):
            out.append((f"box_lo_{var}", float(lo)))
        if math.isfinite(hi):
            out.append((f"box_hi_{var}", float(hi)))
    return out


def _clamp(var: str, arg: str, fields: set[str]) -> str:
    expr = arg
    if f"box_hi_{var}" in fields:
        expr = f"min({expr}, e.box_hi_{var})"
    if f"box_lo_{var}" in fields:
        expr = f"max({expr}, e.box_lo_{var})"
    return expr


def _box_hook(kind: str, inner_fields: tuple[str, ...], fields: set[str], mode: str) -> str:
    """The boxed kernel's hook ``kind`` (its name ``{kind}_KEY``): a force hook clamps the state
    to the box read from ``e`` (:func:`bound_fields`) and calls the inner hook with the inner
    parameters; any other hook calls the inner one as it is."""
    before, after = HOOK_ARGS[kind]
    args = [*before, "e", *after]
    inner_e = f"_P({', '.join(f'e.{f}' for f in inner_fields)})"
    head = f"@subfunction\ndef {kind}_KEY({', '.join(args)}):\n"
    if kind not in ("force", "force_at"):
        call = ", ".join([*before, inner_e, *after])
        return head + f"    return _{kind}({call})\n"
    lines = ["    s = 1.0"]
    if "box_hi_U" in fields:  # above the top speed: the similar state at U_max
        lines += [
            "    UU = u * u + v_m * v_m",
            "    if UU > e.box_hi_U * e.box_hi_U:",
            "        s = e.box_hi_U / math.sqrt(UU)",
        ]
    for v in CLAMPED:
        lines.append(f"    {v}_c = {_clamp(v, f's * {v}' if v in SCALED else v, fields)}")
    lines.append("    U_T_c = s * U_T")
    clamped = {v: f"{v}_c" for v in (*CLAMPED, "U_T")}
    call_args = [inner_e if a == "e" else clamped.get(a, a) if mode == "held" else a for a in args]
    lines.append(f"    dX, dY, dN = _{kind}({', '.join(call_args)})")
    if mode == "held":
        lines.append("    k = 1.0 / (s * s)  # the non-dimensional force held above U_max")
        lines.append("    return k * dX, k * dY, k * dN")
    else:
        inside = " and ".join(["s == 1.0", *(f"{v}_c == {v}" for v in CLAMPED)])
        lines.append(f"    w = 1.0 if {inside} else 0.0")
        lines.append("    return w * dX, w * dY, w * dN")
    return head + "\n".join(lines) + "\n"


#: the boxed kernels' effects of this process by (inner kernel effect, mode, bound fields)
_boxed: dict[tuple[Effect, str, tuple[str, ...]], Effect] = {}


def boxed(inner: Effect, d: Domain) -> Effect:
    """The effect the kernel runs for ``inner`` (an effect the kernel runs as it is) in a box
    of ``d``'s kind: its parameters are ``inner``'s followed by the box's bounds
    (:func:`bound_fields`), so that one compiled kernel serves every box with these bounds; a
    wrapped effect's rows are its parameters' and then its box's values."""
    fields = tuple(f for f, _ in bound_fields(d))
    request = (inner, d.mode, fields)
    made = _boxed.get(request)
    if made is not None:
        return made
    hooks = {k: getattr(inner, k) for k in HOOK_ARGS if getattr(inner, k) is not None}
    inner_fields = inner.param_names
    where = "held at the boundary of" if d.mode == "held" else "switched off outside"
    body = "\n\n".join(_box_hook(k, inner_fields, set(fields), d.mode) for k in hooks)
    text = _BOX_TEMPLATE.format(
        inner=inner.name,
        where=where,
        fields=", ".join(fields) or "(none)",
        ptype_module=inner.param_type.__module__,
        ptype=inner.param_type.__name__,
        imports="\n".join(
            f"from {h.__module__} import {h.__name__} as _{k}" for k, h in hooks.items()
        ),
        own="BoxParams_KEY",
        field_lines="\n".join(f"    {f}: float" for f in (*inner_fields, *fields)),
        hooks="\n\n" + body if body else "",
    )
    key = hashlib.sha256(text.encode()).hexdigest()[:16]
    module = generated_module(f"mmg_box_{key}", text.replace("KEY", key))
    # (the bounds' values come with each wrapped effect's rows: DomainEffect.kernel_form)
    box_params = tuple(
        EffectParam(f, "-", 0.0, 0.0, 0.0, f"bound of the box ({f[4:6]} {f[7:]})") for f in fields
    )
    made = Effect(
        name=f"{inner.name}@{d.mode}[{','.join(f[4:] for f in fields)}]",
        description=f"{inner.description} ({where} a box given by its parameters)",
        regime=inner.regime,
        params=(*inner.params, *box_params),
        param_type=getattr(module, f"BoxParams_{key}"),
        **{k: getattr(module, f"{k}_{key}") for k in hooks},
    )
    _boxed[request] = made
    return made


@dataclass(frozen=True)
class DomainEffect(Effect):
    """A wrapped effect: ``inner`` acting in ``domain``. It pickles as the two (its module lives
    in the kernel directory, not on the import path, and is written again where it is loaded)."""

    # (the name states both: they take no part in comparisons and the hash)
    inner: Effect | None = field(default=None, compare=False)
    domain: Domain | None = field(default=None, compare=False)

    def __reduce__(self) -> tuple[Any, ...]:
        return (within, (self.inner, self.domain))

    def kernel_form(self) -> KernelForm:
        """The boxed kernel of the inner effect's kernel (:func:`boxed`), its rows followed by
        the box's bounds."""
        assert self.inner is not None and self.domain is not None
        kernel, held, constants = self.inner.kernel_form()
        bounds = tuple(v for _, v in bound_fields(self.domain))
        return boxed(kernel, self.domain), held, (*constants, *bounds)


def within(effect: Effect, domain: Domain) -> Effect:
    """``effect`` acting only inside ``domain`` (rounded as its name states it); an effect
    already wrapped is re-wrapped around the effect inside."""
    if isinstance(effect, DomainEffect) and effect.inner is not None:
        effect = replace(effect.inner, params=effect.params)
    d = domain.rounded()
    name = f"{effect.name}{SEPARATOR}{d.spec}"
    made = _made.get(name)
    if made is not None and made.params == effect.params:
        return made
    # the hooks: the boxed kernel's, called with this effect's values and its box put in
    kernel, held, numbers = effect.kernel_form()
    fields = effect.param_names if held is None else ()
    numbers = (*(held or ()), *numbers, *(v for _, v in bound_fields(d)))
    hooks = with_numbers("mmg.domain", name, fields, boxed(kernel, d), numbers)
    where = "held at the boundary of" if d.mode == "held" else "switched off outside"
    wrapped = DomainEffect(
        name=name,
        description=f"{effect.description} ({where} the states it was fitted on: {d.spec})",
        regime=effect.regime,
        params=effect.params,
        param_type=effect.param_type,
        force=hooks.get("force"),
        force_at=hooks.get("force_at"),
        current=effect.current,
        inputs=effect.inputs,
        observe=effect.observe,
        delay=effect.delay,
        inner=effect,
        domain=d,
    )
    _made[name] = wrapped
    return wrapped


def inner_name(name: str) -> str:
    """The name of the effect inside a wrapped one (the name itself otherwise)."""
    return split_name(name)[0]


__all__ = [
    "MODES",
    "UNITS",
    "VARIABLES",
    "Domain",
    "DomainEffect",
    "inner_name",
    "parse_spec",
    "split_name",
    "within",
]
