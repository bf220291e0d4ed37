"""sweep: system identification of the MMG model on the FRT-DS-ESSO free-running recordings.

Four concerns, one subpackage each, layered one way (each uses only those before it):
:mod:`sweep.data` (recordings, splits, the objectives J1, J2, J3), :mod:`sweep.identification`
(restart CMA-ES, Levenberg-Marquardt refinement, population evaluation), :mod:`sweep.service`
(config rules, jobs, outcomes, orchestration; Ray and MLflow at its edges) and
:mod:`sweep.diagnose` (missing physics). The modules at the top level are the commands
(``python -m sweep``, ``sweep.evaluate``, ``sweep.identify``, ``sweep.diagnose``,
``sweep.report``, ``sweep.publish``, ``sweep.ui``, ``sweep.download``); :mod:`sweep.errors`
(importing nothing of ``sweep``: every layer derives its users' mistakes from its ``UserError``)
turns them into one-line errors for all of them.
"""
