"""Checkpoint storage that outlives the node a job ran on: a local path or a pyarrow URI.

A job's coordinator writes its checkpoint after every CMA-ES generation. With ``sweep.storage``
unset the checkpoint sits in the job's directory under ``multirun/`` on the coordinator's node
(enough on one machine). With ``sweep.storage=URI`` it goes to
``URI/<sweep name>/<job key>/checkpoint.pkl`` on any file system pyarrow reaches (a directory
every node mounts, ``s3://``, ``gs://``, ``hdfs://``...): a job resubmitted to another node after
its node was lost resumes from there.

Writes are atomic: a temporary object is written and then moved over the old one (a rename on a
local or mounted file system; an object store replaces the object whole), so a crash mid-write
leaves the previous checkpoint readable.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

from pyarrow import fs as pafs


def _resolve(location: str | os.PathLike[str]) -> tuple[pafs.FileSystem, str]:
    text = os.fspath(location)
    if "://" not in text:
        return pafs.LocalFileSystem(), str(Path(text).resolve())
    filesystem, path = pafs.FileSystem.from_uri(text)
    return filesystem, path


def join(base: str | os.PathLike[str], *parts: str) -> str:
    """``base/part/...`` for a path or a URI."""
    text = os.fspath(base).rstrip("/")
    return "/".join([text, *(p.strip("/") for p in parts)])


def exists(location: str | os.PathLike[str]) -> bool:
    filesystem, path = _resolve(location)
    return bool(filesystem.get_file_info(path).type != pafs.FileType.NotFound)


def read_bytes(location: str | os.PathLike[str]) -> bytes:
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
    with filesystem.open_output_stream(tmp) as stream:
        stream.write(data)
    filesystem.move(tmp, path)


def check(location: str) -> None:
    """Raise ValueError naming the setting if ``location`` is not a usable storage URI."""
    try:
        _resolve(location)  # the scheme and its file system (no listing: no network here)
    except Exception as exc:  # pyarrow raises several types for a bad URI
        raise ValueError(f"sweep.storage={location!r} is not a usable location: {exc}") from None
