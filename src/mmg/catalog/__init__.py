"""Catalog of candidate extra physics (what an effect is: :mod:`mmg.effect`). Each module
defines one effect; :data:`EFFECTS` lists them, and :mod:`mmg.effects` knows them by name."""

from mmg.catalog import (
    a_h_drift,
    actuator_lag,
    current,
    heading_bias,
    propeller_walk,
    rudder_offset,
    rudder_stall,
)
from mmg.effect import Effect

#: the catalog's effects, in the order :func:`mmg.catalog` lists them
EFFECTS: tuple[Effect, ...] = (
    a_h_drift.A_H_DRIFT,
    actuator_lag.ACTUATOR_LAG,
    current.CURRENT,
    heading_bias.HEADING_BIAS,
    propeller_walk.PROPELLER_WALK,
    rudder_offset.RUDDER_OFFSET,
    rudder_stall.RUDDER_STALL,
)

__all__ = [
    "EFFECTS",
    "a_h_drift",
    "actuator_lag",
    "current",
    "heading_bias",
    "propeller_walk",
    "rudder_offset",
    "rudder_stall",
]
