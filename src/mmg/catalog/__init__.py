"""Catalog of candidate extra physics (see :mod:`mmg.effects`). Each module registers one effect."""

from mmg.catalog import current, propeller_walk

__all__ = ["current", "propeller_walk"]
