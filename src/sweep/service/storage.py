"""Checkpoint storage that outlives the node a job ran on: a local path or a pyarrow URI.

A job's coordinator writes its checkpoint (:mod:`sweep.identification.cmaes` says when) through
the :class:`Location` the job injects as its store. With ``sweep.storage``
unset the checkpoint sits in the job's directory under ``multirun/`` on the coordinator's node
(enough on one machine). With ``sweep.storage=URI`` it goes to
``URI/<sweep name>/<job directory name>/checkpoint.pkl`` on any file system pyarrow reaches (a
directory every node mounts, ``s3://``, ``gs://``, ``hdfs://``...): a job resubmitted to another
node after its node was lost resumes from there.

Writes are atomic: a temporary object is written and then moved over the old one (a rename on a
local or mounted file system; an object store replaces the object whole), so a crash mid-write
leaves the previous checkpoint readable. Beside the checkpoint, the optimiser keeps the previous
one (``checkpoint.pkl.prev``) and sets a rejected one aside (``checkpoint.pkl.bad-<n>``): both
are signed and verified (:mod:`sweep.identification.checkpoint`), since anyone who can write
to the storage could otherwise plant code there.

The file system of a URI is made once per scheme and authority (for ``s3://`` that asks the
bucket's region over the network) and reused.
"""

from __future__ import annotations

import contextlib
import functools
import os
import uuid
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote, unquote, urlsplit

from pyarrow import fs as pafs

#: URI schemes pyarrow's file systems understand
SCHEMES = ("file", "s3", "gs", "gcs", "hdfs", "viewfs", "abfs", "abfss")


@functools.lru_cache(maxsize=16)
def _filesystem(scheme: str, authority: str) -> tuple[pafs.FileSystem, str]:
    """(file system, path prefix) of ``scheme://authority`` (cached: made once per process)."""
    if scheme == "file":
        return pafs.LocalFileSystem(), ""
    filesystem, root = pafs.FileSystem.from_uri(f"{scheme}://{authority}/")
    return filesystem, root.rstrip("/")


def _resolve(location: str | os.PathLike[str]) -> tuple[pafs.FileSystem, str]:
    text = os.fspath(location)
    if "://" not in text:
        return pafs.LocalFileSystem(), str(Path(text).resolve())
    parts = urlsplit(text)
    filesystem, root = _filesystem(parts.scheme, parts.netloc)
    path = unquote(parts.path)
    return filesystem, f"{root}/{path.lstrip('/')}" if root else path


def absolute(location: str) -> str:
    """``location`` with a local path made absolute (on the driver, before jobs travel)."""
    return location if "://" in location else str(Path(location).resolve())


def join(base: str | os.PathLike[str], *parts: str) -> str:
    """``base/part/...`` for a path or a URI (parts of a URI are percent-encoded, so that a
    ``#`` or ``?`` in a sweep name cannot cut the path short)."""
    text = os.fspath(base).rstrip("/")
    if "://" in text:
        parts = tuple(quote(p.strip("/"), safe="=,._-+") for p in parts)
    return "/".join([text, *(p.strip("/") for p in parts)])


def exists(location: str | os.PathLike[str]) -> bool:
    """Whether ``location`` (a path or URI) names an existing file or directory."""
    filesystem, path = _resolve(location)
    return bool(filesystem.get_file_info(path).type != pafs.FileType.NotFound)


def read_bytes(location: str | os.PathLike[str]) -> bytes:
    """The bytes of the file at ``location`` (a path or URI)."""
    filesystem, path = _resolve(location)
    with filesystem.open_input_stream(path) as stream:
        return bytes(stream.read())


def write_bytes(location: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` atomically (temporary object, then moved over the target)."""
    filesystem, path = _resolve(location)
    parent = path.rsplit("/", 1)[0]
    if parent:
        filesystem.create_dir(parent, recursive=True)
    tmp = f"{path}.{uuid.uuid4().hex[:8]}.tmp"
    try:
        with filesystem.open_output_stream(tmp) as stream:
            stream.write(data)
        filesystem.move(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            filesystem.delete_file(tmp)
        raise


def move(source: str | os.PathLike[str], target: str | os.PathLike[str]) -> None:
    """Move the file ``source`` to ``target`` (same file system; replaces ``target``): a rename
    on a local or mounted file system, a copy and delete on an object store."""
    filesystem, path = _resolve(source)
    _, target_path = _resolve(target)
    filesystem.move(path, target_path)


def check(location: str) -> None:
    """Raise ValueError if ``location`` is not a path or a URI of a known scheme (no network)."""
    if "://" not in location:
        return
    scheme = urlsplit(location).scheme
    if scheme not in SCHEMES:
        raise ValueError(
            f"unknown storage scheme {scheme!r} (known: {', '.join(SCHEMES)}, or a plain path)"
        )


@dataclass(frozen=True)
class Location:
    """A checkpoint at a path or storage URI: the
    :class:`~sweep.identification.store.Store` a job hands to the optimiser."""

    #: a local path or a URI of one of :data:`SCHEMES`
    uri: str

    def __str__(self) -> str:
        return self.uri

    def exists(self) -> bool:
        """Whether something is stored there."""
        return exists(self.uri)

    def read_bytes(self) -> bytes:
        """The stored bytes."""
        return read_bytes(self.uri)

    def write_bytes(self, data: bytes) -> None:
        """Replace the stored bytes by ``data`` atomically (:func:`write_bytes`)."""
        write_bytes(self.uri, data)

    def sibling(self, suffix: str) -> Location:
        """The location ``<uri><suffix>`` (the same directory)."""
        return Location(self.uri + suffix)

    def rename(self, suffix: str) -> Location:
        """Move the stored bytes to ``<uri><suffix>`` (:func:`move`); returns that location."""
        target = self.sibling(suffix)
        move(self.uri, target.uri)
        return target


def create_exclusive(location: str | os.PathLike[str], data: bytes) -> bool:
    """Create the file ``location`` holding ``data`` unless it exists; whether this call made it.

    On a local or mounted file system this is atomic between processes and machines: the bytes
    go to a temporary file that is then hard-linked to the name, which fails if the name exists
    (so a reader never sees a half-written file). An object store has no create-if-absent:
    there the object is written when absent and read back, and the call has made it if the
    bytes read are its own; two writers within the store's propagation delay can both see
    their own bytes (strongly consistent stores such as S3 shrink that window to the few
    milliseconds between one writer's check and its write)."""
    filesystem, path = _resolve(location)
    parent = path.rsplit("/", 1)[0]
    if parent:
        filesystem.create_dir(parent, recursive=True)
    if isinstance(filesystem, pafs.LocalFileSystem):
        tmp = f"{path}.{uuid.uuid4().hex[:8]}.tmp"
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.link(tmp, path)
        except FileExistsError:
            return False
        finally:
            os.unlink(tmp)
        return True
    if filesystem.get_file_info(path).type != pafs.FileType.NotFound:
        return False
    write_bytes(location, data)
    try:
        return read_bytes(location) == data
    except FileNotFoundError:
        return False


def list_names(location: str | os.PathLike[str]) -> list[str]:
    """The names of the files directly in the directory ``location`` (none if it is absent)."""
    filesystem, path = _resolve(location)
    selector = pafs.FileSelector(path, allow_not_found=True)
    return sorted(
        info.base_name
        for info in filesystem.get_file_info(selector)
        if info.type == pafs.FileType.File
    )


def delete(location: str | os.PathLike[str]) -> None:
    """Delete the file ``location`` (nothing if it is already gone)."""
    filesystem, path = _resolve(location)
    with contextlib.suppress(FileNotFoundError):
        filesystem.delete_file(path)
