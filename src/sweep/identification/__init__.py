"""Identification: restart CMA-ES, Levenberg-Marquardt refinement, and the evaluation of a
population in-process or on worker processes."""
