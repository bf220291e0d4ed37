"""User mistakes become one line on stderr and exit status 2, never a traceback.

A user mistake is a :class:`UserError`: the commands raise it for bad arguments, and the data,
config and tracking layers' own mistakes derive from it (a missing recording or split, a bad
recording file, a config value outside the rules, a refused config change). A bad parameter file
raises :class:`mmg.ParameterError` (the model knows nothing of the commands). This module imports
nothing of ``sweep``, so that every layer can derive its errors from it.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

from mmg.params import ParameterError


class UserError(Exception):
    """A mistake in the command's input, reported as one line."""


#: exceptions that report a mistake in the user's input or set-up, not a bug
USER_ERRORS: tuple[type[BaseException], ...] = (UserError, ParameterError)


@contextmanager
def exit_on_user_error() -> Iterator[None]:
    """Turn a user error (including a refused config change) into ``error: ...`` and exit 2."""
    try:
        yield
    except USER_ERRORS as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def command_status(
    run: Callable[[Sequence[str] | None], object], argv: Sequence[str] | None
) -> int:
    """A command's exit status: 0 when ``run(argv)`` returns, 2 with ``error: ...`` on stderr
    for a user error (warnings shown once each)."""
    warnings.simplefilter("default")
    try:
        run(argv)
    except USER_ERRORS as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


__all__ = ["USER_ERRORS", "UserError", "command_status", "exit_on_user_error"]
