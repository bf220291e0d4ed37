"""Hydra launcher plugin of mmg-sweep: one Ray actor per job (``hydra/launcher=mmg_ray``)."""
