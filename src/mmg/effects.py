"""The effects known by name: the catalog's (:mod:`mmg.catalog`) and generated ones.

:func:`get_effect` looks an effect up by the name a config's ``effects=[...]`` or a parameter
file gives: a catalog effect, an effect added with :func:`register`, or a generated
``discovered:<term>+<term>...`` effect (:mod:`mmg.discovered`) or shape effect
``shape:<group>+<group>...`` (:mod:`mmg.shapes`), built on first use in any process. What
an effect is and its hooks: :mod:`mmg.effect`.
"""

from __future__ import annotations

from mmg import discovered, domain, fixed, shapes
from mmg.catalog import EFFECTS as _CATALOG_EFFECTS
from mmg.effect import DISCOVERED_PREFIX, Effect

#: effects by name: the catalog's, in the catalog's order, then any registered later
_REGISTRY: dict[str, Effect] = {e.name: e for e in _CATALOG_EFFECTS}


def register(effect: Effect) -> Effect:
    """Add an effect to the registry under its name (replacing one of the same name)."""
    _REGISTRY[effect.name] = effect
    return effect


def get_effect(name: str) -> Effect:
    """Look an effect up by name; raises KeyError listing the known names.

    A name ``discovered:<term>+<term>...`` is a generated effect (:mod:`mmg.discovered`): it is
    built from the term library on first use, in any process, so that parameter files carrying
    it load everywhere. A name ``shape:<group>+<group>...`` is a shape effect (:mod:`mmg.shapes`),
    built from its spec likewise. A name ``<effect>@held(<box>)`` or ``<effect>@off(<box>)`` is
    that effect restricted to a box of states (:mod:`mmg.domain`), built alike; a name
    ``<effect>@fixed(<values>)`` is that effect held at the values (:mod:`mmg.fixed`).
    """
    if name in _REGISTRY:
        return _REGISTRY[name]
    try:
        if fixed.split_name(name)[1] is not None:  # <effect>@fixed(...): mmg.fixed
            return fixed.by_name(name, get_effect)
        inner, box = domain.split_name(name)  # <effect>@held(...): mmg.domain
        if box is not None:
            return domain.within(get_effect(inner), box)
    except (ValueError, KeyError) as exc:
        raise KeyError(f"effect {name!r}: {exc.args[0]}") from None
    if name.startswith(DISCOVERED_PREFIX):
        try:
            return discovered.by_name(name)
        except ValueError as exc:
            raise KeyError(f"effect {name!r}: {exc}") from None
    if name.startswith(shapes.SHAPE_PREFIX):
        try:
            return shapes.by_name(name)
        except ValueError as exc:
            raise KeyError(f"effect {name!r}: {exc}") from None
    made = {*discovered.generated_names(), *shapes.generated_names()}
    known = ", ".join(sorted({*_REGISTRY, *made}))
    raise KeyError(f"unknown effect {name!r}; known effects: {known}") from None


def catalog() -> dict[str, Effect]:
    """The catalog's effects by name (registered effects except generated ``discovered:`` ones,
    which exist only once something asked for them)."""
    return {n: e for n, e in _REGISTRY.items() if not n.startswith(DISCOVERED_PREFIX)}


__all__ = ["catalog", "get_effect", "register"]
