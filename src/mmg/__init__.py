"""mmg: the model-rich MMG manoeuvring model of Miyauchi et al. (2022), batched and compiled.

>>> from mmg import efd_parameters, derivatives, simulate
>>> p = efd_parameters()
"""

from mmg.effect import Effect, EffectParam

# mmg.effects loads the subpackage mmg.catalog, binding it here as ``catalog``; the import of
# the function below then binds the public name ``mmg.catalog`` to the function for good (a
# loaded module is never bound again)
from mmg.effects import catalog, get_effect
from mmg.integrate import SimulationResult, derivatives, simulate, simulate_batch
from mmg.model import all_forces
from mmg.params import (
    ESSO_OSAKA,
    N_THETA,
    PARAMETER_NAMES,
    PARAMETER_TABLE,
    Bound,
    ParameterError,
    Parameters,
    ParamSpec,
    Ship,
    Theta,
    bounds,
    efd_parameters,
    efd_theta,
)

__all__ = [
    "ESSO_OSAKA",
    "N_THETA",
    "PARAMETER_NAMES",
    "PARAMETER_TABLE",
    "Bound",
    "Effect",
    "EffectParam",
    "ParamSpec",
    "ParameterError",
    "Parameters",
    "Ship",
    "SimulationResult",
    "Theta",
    "all_forces",
    "bounds",
    "catalog",
    "derivatives",
    "efd_parameters",
    "efd_theta",
    "get_effect",
    "simulate",
    "simulate_batch",
]
