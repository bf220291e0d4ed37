"""Identification: restart CMA-ES (signed checkpoints through an injected store),
Levenberg-Marquardt refinement, the evaluation of a population in-process or on worker
processes, and the parameter vector and search box of a model with effects that every layer
above uses."""
