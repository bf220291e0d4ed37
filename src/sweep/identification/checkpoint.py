"""Signed checkpoint envelopes: verified before anything in them is read, never run from storage.

A checkpoint lives where others may write (``sweep.storage``: a bucket or a mount shared by a
cluster), and a pickle runs code while it is read. So the optimiser's state is written inside an
envelope, and nothing of a payload is unpickled before the envelope says that this job wrote it
with the driver's key:

=====  ======  ===========================================================================
bytes  field   meaning
=====  ======  ===========================================================================
8      magic   ``MMGCKPT\\0``
2      format  :data:`FORMAT_VERSION` (big-endian)
32     job     SHA-256 of the job's identity (the sweep's config hash; "" outside a sweep)
8      length  payload length in bytes (big-endian)
32     sum     SHA-256 of the fields above and the payload (tells damage from forgery)
32     mac     HMAC-SHA256 (the key) of magic, format, job, length and the payload
=====  ======  ===========================================================================

then the payload. A checkpoint is rejected (:class:`CheckpointError`) as ``truncated``,
``checksum mismatch`` (damaged: a flipped bit), ``other format`` (no envelope, e.g. a bare
pickle, or another format version), ``not authenticated`` (the sum is right but the HMAC is not:
forged, or signed with another key) or ``written for another job``.

The key (:func:`checkpoint_key`) is the driver's: ``$MMG_CHECKPOINT_KEY`` (hex, or any other
text as its UTF-8 bytes), else 32 random bytes in ``checkpoint.key`` in the user's config
directory (``platformdirs.user_config_dir("mmg-sweep")``), made with mode 0600 on first use, so
that the same user running the same command again verifies and resumes its checkpoints. It
travels with the job (never to the storage).

:class:`Checkpoint` keeps the previous good checkpoint beside the current one
(``<name>.prev``): a current one that is rejected is set aside as ``<name>.bad-<n>`` (never
deleted) and the job resumes from the previous one, or afresh without one.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import os
import secrets
import struct
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, TypeVar

import platformdirs

from sweep.errors import UserError
from sweep.identification.store import Store

MAGIC = b"MMGCKPT\0"
FORMAT_VERSION = 1
#: magic, format, job digest, payload length
_PREFIX = struct.Struct(">8sH32sQ")
HEADER_SIZE = _PREFIX.size + 32 + 32
#: the environment variable that holds the checkpoint key
KEY_VARIABLE = "MMG_CHECKPOINT_KEY"
#: the key file's name in the user's config directory
KEY_FILE = "checkpoint.key"
#: the suffix of the previous good checkpoint, beside the current one
PREVIOUS = ".prev"

T = TypeVar("T")

Reason = Literal[
    "truncated",
    "checksum mismatch",
    "other format",
    "not authenticated",
    "written for another job",
]


class CheckpointKeyError(UserError):
    """The checkpoint key cannot be read or made."""


class CheckpointError(ValueError):
    """A checkpoint that cannot be used; ``reason`` says why (see the module's table)."""

    def __init__(self, name: str, reason: Reason) -> None:
        super().__init__(f"{name}: checkpoint rejected ({reason})")
        self.name = name
        self.reason: Reason = reason


def key_path() -> Path:
    """The key file: ``checkpoint.key`` in the user's config directory."""
    return Path(platformdirs.user_config_dir("mmg-sweep")) / KEY_FILE


def checkpoint_key() -> bytes:
    """The driver's checkpoint key: ``$MMG_CHECKPOINT_KEY`` (hex, or any text as UTF-8), else the
    key file (:func:`key_path`, made with 32 random bytes and mode 0600 if absent)."""
    text = os.environ.get(KEY_VARIABLE)
    if text is not None:
        if not text.strip():
            raise CheckpointKeyError(f"{KEY_VARIABLE} is set but empty")
        try:
            return bytes.fromhex(text)
        except ValueError:
            return text.encode()
    path = key_path()
    try:
        if not path.exists():
            _create_key_file(path)
        key = path.read_bytes()
    except OSError as exc:
        raise CheckpointKeyError(f"checkpoint key {path}: {exc.strerror or exc}") from None
    if not key:
        raise CheckpointKeyError(f"checkpoint key {path} is empty (remove it to make a new one)")
    return key


def _create_key_file(path: Path) -> None:
    """Write 32 random bytes to ``path`` (mode 0600) unless another process made it first."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        with os.fdopen(fd, "wb") as stream:
            stream.write(secrets.token_bytes(32))
        with contextlib.suppress(FileExistsError):  # the first process to get there wins
            os.link(tmp, path)  # whole or not at all
    finally:
        tmp.unlink(missing_ok=True)


def job_digest(job: str) -> bytes:
    """The 32-byte digest of a job's identity, as the header holds it."""
    return hashlib.sha256(job.encode()).digest()


def seal(payload: bytes, key: bytes, job: str = "") -> bytes:
    """``payload`` in an envelope signed with ``key`` for the job ``job``."""
    prefix = _PREFIX.pack(MAGIC, FORMAT_VERSION, job_digest(job), len(payload))
    checksum = hashlib.sha256(prefix + payload).digest()
    mac = hmac.new(key, prefix + payload, hashlib.sha256).digest()
    return prefix + checksum + mac + payload


def open_sealed(data: bytes, key: bytes, job: str | None = "", name: str = "checkpoint") -> bytes:
    """The payload of an envelope written with ``key`` for the job ``job`` (None: any job, to
    inspect one); raises :class:`CheckpointError` (naming ``name``) otherwise. Nothing of the
    payload is interpreted."""
    if not data.startswith(MAGIC):
        raise CheckpointError(name, "truncated" if MAGIC.startswith(data) else "other format")
    if len(data) < HEADER_SIZE:
        raise CheckpointError(name, "truncated")
    prefix = data[: _PREFIX.size]
    _, version, digest, length = _PREFIX.unpack(prefix)
    if version != FORMAT_VERSION:
        raise CheckpointError(name, "other format")
    checksum = data[_PREFIX.size : _PREFIX.size + 32]
    mac = data[_PREFIX.size + 32 : HEADER_SIZE]
    payload = data[HEADER_SIZE:]
    if len(payload) < length:
        raise CheckpointError(name, "truncated")
    if len(payload) > length or not hmac.compare_digest(
        checksum, hashlib.sha256(prefix + payload).digest()
    ):
        raise CheckpointError(name, "checksum mismatch")
    if not hmac.compare_digest(mac, hmac.new(key, prefix + payload, hashlib.sha256).digest()):
        raise CheckpointError(name, "not authenticated")
    if job is not None and not hmac.compare_digest(digest, job_digest(job)):
        raise CheckpointError(name, "written for another job")
    return payload


@dataclass(frozen=True)
class SetAside:
    """A rejected checkpoint and where it was moved."""

    name: str
    moved_to: str
    reason: Reason


@dataclass(frozen=True)
class Recovery:
    """How a job got its starting checkpoint when the current one could not be used:
    ``resumed`` is "previous" or "fresh"; ``rejected`` the files set aside, in order."""

    resumed: Literal["previous", "fresh"]
    rejected: tuple[SetAside, ...]

    def line(self) -> str:
        """One line for the console: which files, why, and where the job goes on from."""
        files = "; ".join(
            f"{r.name}: {r.reason}, set aside as {r.moved_to.rsplit('/', 1)[-1]}"
            for r in self.rejected
        )
        then = (
            "resuming from the previous checkpoint"
            if self.resumed == "previous"
            else "starting afresh"
        )
        return f"checkpoint rejected ({files}); {then}"

    def tag(self) -> str:
        """The tracking tag's value: ``previous: truncated`` (reasons of every file set aside)."""
        return f"{self.resumed}: {', '.join(r.reason for r in self.rejected)}"


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


@dataclass
class Checkpoint:
    """A job's checkpoint in a store, signed with ``key`` for the job ``job``, with the previous
    good one kept beside it (``<store>.prev``).

    ``say`` receives the one line that tells of a rejected checkpoint (default: stderr).
    """

    store: Store
    key: bytes = field(repr=False)
    job: str = ""
    say: Callable[[str], None] = _stderr

    def __str__(self) -> str:
        return str(self.store)

    def save(self, payload: bytes) -> None:
        """Keep the current checkpoint as the previous one, then write ``payload`` as the current
        one (atomically; between the two a crash leaves the previous one to resume from)."""
        if self.store.exists():
            self.store.rename(PREVIOUS)
        self.store.write_bytes(seal(payload, self.key, self.job))

    def load(self, parse: Callable[[bytes, str], T]) -> tuple[T | None, Recovery | None]:
        """(what the newest good checkpoint holds or None, the recovery if one was rejected).

        Tries the current checkpoint, then the previous one; a rejected one is set aside.
        ``parse(payload, name)`` reads an authenticated payload, and raises
        :class:`CheckpointError` for one whose envelope is good but whose content is not (e.g.
        another code version's).
        """
        rejected: list[SetAside] = []
        found: T | None = None
        for store in (self.store, self.store.sibling(PREVIOUS)):
            if not store.exists():
                continue
            try:
                payload = open_sealed(store.read_bytes(), self.key, self.job, str(store))
                found = parse(payload, str(store))
            except CheckpointError as exc:
                rejected.append(SetAside(str(store), str(_set_aside(store)), exc.reason))
                continue
            break
        if not rejected:
            return found, None
        recovery = Recovery("previous" if found is not None else "fresh", tuple(rejected))
        self.say(recovery.line())
        return found, recovery


def _set_aside(store: Store) -> Store:
    """Move ``store``'s bytes to the first free ``<name>.bad-<n>``; returns that store."""
    n = 1
    while store.sibling(f".bad-{n}").exists():
        n += 1
    return store.rename(f".bad-{n}")


__all__ = [
    "FORMAT_VERSION",
    "KEY_VARIABLE",
    "MAGIC",
    "PREVIOUS",
    "Checkpoint",
    "CheckpointError",
    "CheckpointKeyError",
    "Recovery",
    "SetAside",
    "checkpoint_key",
    "key_path",
    "open_sealed",
    "seal",
]
