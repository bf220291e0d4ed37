"""sweep: system identification of the MMG model on the FRT-DS-ESSO free-running recordings.

The package in four concerns, and the commands at its top level:

- :mod:`sweep.data` (recordings and objectives): validated recordings and their CSV/Parquet
  files (:mod:`sweep.data.recordings`), the paper's train/test splits and the data directory
  (:mod:`sweep.data.datasets`), the objective functions J1, J2, J3 (:mod:`sweep.data.objective`),
  parameter sets named on a command line (:mod:`sweep.data.parameters`);
- :mod:`sweep.identification`: restart CMA-ES (:mod:`sweep.identification.cmaes`),
  Levenberg-Marquardt refinement (:mod:`sweep.identification.polish`), population evaluation in
  process or on worker processes (:mod:`sweep.identification.workers`), the parameter vector and
  search box with effects (:mod:`sweep.identification.vector`), where checkpoints are kept
  (:mod:`sweep.identification.store`);
- :mod:`sweep.service` (the sweep service, with Ray and MLflow at its edges): config rules
  (:mod:`sweep.service.schema`), jobs and their outcomes (:mod:`sweep.service.job`,
  :mod:`sweep.service.outcome`), the orchestration (:mod:`sweep.service.orchestration`), Ray
  (:mod:`sweep.service.raycluster`), checkpoint storage (:mod:`sweep.service.storage`), summary
  tables and run notes (:mod:`sweep.service.tables`), figures (:mod:`sweep.service.figures`),
  MLflow (:mod:`sweep.service.tracking`);
- :mod:`sweep.diagnose` (missing physics): location, noise floor, discovery, calibrated
  acceptance (the planted benchmark's forms are ``benchmarks.planted``, outside the package).

Commands: ``python -m sweep`` (the Hydra sweep), ``sweep.evaluate``, ``sweep.identify``,
``sweep.diagnose``, ``sweep.report`` (a sweep's tables, regenerated from MLflow), ``sweep.publish``,
``sweep.ui`` (the MLflow UI on a sweep), ``sweep.download`` (the recordings at a pinned commit);
:mod:`sweep.errors` (importing nothing of ``sweep``: every layer derives its users' mistakes
from its :class:`~sweep.errors.UserError`) turns them into one-line errors for all of them.
"""
