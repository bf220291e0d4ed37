"""Parameter sets named on a command line: ``efd`` or a parameter JSON file."""

from __future__ import annotations

from pathlib import Path

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


__all__ = ["load_parameters"]
