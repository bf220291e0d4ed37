"""Where a checkpoint is kept: a local file, or a store the caller injects.

:func:`sweep.identification.cmaes.optimise` reads and writes its checkpoint through a
:class:`Store`, one place that says whether it holds anything, returns its bytes, replaces them
atomically, names the places beside it (the previous checkpoint, one set aside) and moves its
bytes there. A local path is a :class:`LocalFile`; the sweep service injects its own store
for checkpoints that outlive a node (:class:`sweep.service.storage.Location`, a path or a
storage URI), so that this layer knows nothing of storage URIs.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol


class Store(Protocol):
    """One place for one checkpoint (its ``str`` names it in messages)."""

    def exists(self) -> bool:
        """Whether the place holds a checkpoint."""
        ...

    def read_bytes(self) -> bytes:
        """The checkpoint's bytes."""
        ...

    def write_bytes(self, data: bytes) -> None:
        """Replace the checkpoint by ``data`` atomically: a crash mid-write leaves the previous
        one readable."""
        ...

    def sibling(self, suffix: str) -> Store:
        """The place beside this one whose name is this one's with ``suffix`` appended."""
        ...

    def rename(self, suffix: str) -> Store:
        """Move the bytes to :meth:`sibling` ``(suffix)`` (replacing what it held); returns it."""
        ...


@dataclass(frozen=True)
class LocalFile:
    """A checkpoint in a local file; its directory is made on the first write."""

    path: Path

    def __str__(self) -> str:
        return str(self.path)

    def exists(self) -> bool:
        """Whether the file exists."""
        return self.path.exists()

    def read_bytes(self) -> bytes:
        """The file's bytes."""
        return self.path.read_bytes()

    def write_bytes(self, data: bytes) -> None:
        """Write ``data`` to a temporary file next to the target, then move it over the target."""
        path = self.path.resolve()
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(f"{path}.{uuid.uuid4().hex[:8]}.tmp")
        try:
            tmp.write_bytes(data)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise

    def sibling(self, suffix: str) -> LocalFile:
        """The file ``<path><suffix>`` in the same directory."""
        return LocalFile(self.path.with_name(self.path.name + suffix))

    def rename(self, suffix: str) -> LocalFile:
        """Move the file to ``<path><suffix>`` (an atomic rename); returns that file."""
        target = self.sibling(suffix)
        os.replace(self.path, target.path)
        return target


def as_store(location: str | os.PathLike[str] | Store) -> Store:
    """``location`` as a :class:`Store`: a store as given, a local path as a :class:`LocalFile`.

    Raises ValueError for a URI (``scheme://...``): a URI's file system is the caller's to
    provide, as a store.
    """
    if not isinstance(location, (str, os.PathLike)):
        return location
    text = os.fspath(location)
    if "://" in text:
        raise ValueError(f"{text}: a checkpoint URI needs a store that reaches it, not a path")
    return LocalFile(Path(text))


__all__ = ["LocalFile", "Store", "as_store"]
