"""User mistakes become one line on stderr and exit status 2, never a traceback."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

from mmg.params import ParameterError
from sweep.data.datasets import DataNotFoundError, SplitError
from sweep.data.recordings import RecordingError
from sweep.service.schema import ConfigError

#: exceptions that report a mistake in the user's input or set-up, not a bug
USER_ERRORS: tuple[type[BaseException], ...] = (
    DataNotFoundError,
    SplitError,
    RecordingError,
    ParameterError,
    ConfigError,
)


@contextmanager
def exit_on_user_error() -> Iterator[None]:
    """Turn a user error (including a refused config change) into ``error: ...`` and exit 2."""
    from sweep.service.tracking import ConfigChangedError

    errors: tuple[type[BaseException], ...] = (*USER_ERRORS, ConfigChangedError)
    try:
        yield
    except errors as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
