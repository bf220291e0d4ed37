"""The flat parameter vector and search box of a model with extra-physics effects.

The optimisers work on one flat vector: the paper's 57 base parameters in
:data:`mmg.PARAMETER_NAMES` order (:meth:`mmg.Parameters.vector`), followed by each effect's own
parameters in the order of ``effects`` and, within an effect, of :attr:`mmg.Effect.params`
("kernel order", as the compiled kernel reads them). Its search box is the paper's box
(:func:`mmg.bounds`) followed by each effect parameter's search interval
(:class:`mmg.EffectParam`). Units are those of each parameter's table entry (the base ones are
dimensionless; an effect parameter's unit is its ``EffectParam.unit``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mmg import Effect, Parameters, bounds, get_effect
from mmg.params import N_THETA
from sweep.identification.cmaes import Box

FloatArray = NDArray[np.float64]


def with_effects(
    base: Parameters, effects: Sequence[Effect], values: Sequence[float] | None = None
) -> Parameters:
    """``base`` carrying ``effects`` with the given values in kernel order (neutral if None).

    ``values``: (k,) the effects' parameter values, k = the total number of their parameters,
    each in its parameter's unit; the base's own effect values are replaced, except those of
    its effects held at given values (:mod:`mmg.fixed`: part of the model, no parameters to
    fit), which stay first unless ``effects`` lists them.
    """
    names = {e.name for e in effects}
    out: list[tuple[str, tuple[tuple[str, float], ...]]] = [
        (n, v) for n, v in base.effects if not v and n not in names and not get_effect(n).params
    ]
    i = 0
    for eff in effects:
        k = len(eff.params)
        vals = eff.neutral() if values is None else tuple(float(v) for v in values[i : i + k])
        i += k
        out.append((eff.name, tuple(zip(eff.param_names, vals, strict=True))))
    return Parameters(base.theta, base.ship, tuple(out))


def effect_values(p: Parameters, effects: Sequence[Effect]) -> list[float]:
    """The (k,) values of ``effects``' parameters in ``p``, in kernel order, each in its
    parameter's unit (the neutral value where ``p`` does not give it)."""
    values: list[float] = []
    for eff in effects:
        given = p.effect_values(eff.name)
        values += [given.get(q.name, q.neutral) for q in eff.params]
    return values


def full_vector(p: Parameters, effects: Sequence[Effect]) -> FloatArray:
    """(57 + k,) the base parameters of ``p`` then its values of ``effects``' k parameters."""
    return np.concatenate([p.vector(), np.asarray(effect_values(p, effects), dtype=np.float64)])


def from_full_vector(v: Any, ship_of: Parameters, effects: Sequence[Effect]) -> Parameters:
    """Inverse of :func:`full_vector`: ``v`` (57 + k,) as Parameters of the ship of ``ship_of``
    carrying ``effects``."""
    v = np.asarray(v, dtype=np.float64)
    base = Parameters.from_vector(v[:N_THETA], ship=ship_of.ship)
    return with_effects(base, effects, v[N_THETA:])


def joint_box(effects: Sequence[Effect]) -> Box:
    """The (57 + k)-dimensional search box: the paper's box of the base parameters, then each
    effect parameter's search interval [lower, upper]."""
    lo, hi = bounds()
    e_lo = [q.lower for e in effects for q in e.params]
    e_hi = [q.upper for e in effects for q in e.params]
    return Box(np.concatenate([lo, e_lo]), np.concatenate([hi, e_hi]))


__all__ = ["effect_values", "from_full_vector", "full_vector", "joint_box", "with_effects"]
