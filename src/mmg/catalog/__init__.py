"""Catalog of candidate extra physics (see :mod:`mmg.effects`). Each module registers one effect."""

from mmg.catalog import (
    a_h_drift,
    actuator_lag,
    current,
    heading_bias,
    propeller_walk,
    rudder_offset,
    rudder_stall,
)

__all__ = [
    "a_h_drift",
    "actuator_lag",
    "current",
    "heading_bias",
    "propeller_walk",
    "rudder_offset",
    "rudder_stall",
]
