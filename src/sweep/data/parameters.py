"""Parameter sets named on a command line: ``efd`` or a parameter JSON file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mmg.params import Parameters, efd_parameters
from sweep.errors import UserError


def load_parameters(spec: str) -> Parameters:
    """``efd`` (the EFD parameters of the paper) or the path of a parameter JSON file (as written
    by :meth:`mmg.Parameters.save_json`); raises :class:`~sweep.errors.UserError` for a missing
    file and :class:`mmg.ParameterError` for a malformed one."""
    if spec.lower() == "efd":
        return efd_parameters()
    path = Path(spec)
    if not path.exists():
        raise UserError(f"{path}: no such parameter file (use 'efd' or a JSON file)")
    return Parameters.load_json(path)


def parameter_metadata(spec: str) -> dict[str, Any]:
    """The ``metadata`` of a parameter file (what :meth:`mmg.Parameters.save_json` wrote beside
    the values: objective, training set, seed, ...); {} for ``efd`` or a file without it."""
    path = Path(spec)
    if spec.lower() == "efd" or not path.is_file():
        return {}
    try:
        meta = json.loads(path.read_text()).get("metadata", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return meta if isinstance(meta, dict) else {}


__all__ = ["load_parameters", "parameter_metadata"]
