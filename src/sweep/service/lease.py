"""Job leases: one driver per job at a time, across processes and machines.

Before a driver runs a job it claims the job's lease, a small JSON file in the job's storage
directory (``<sweep.storage>/<sweep>/<job>/lease/``, or ``<job dir>/lease/`` without a storage;
any :mod:`sweep.service.storage` location), naming the driver (host, pid, a random id) and the
time its claim expires. While the job runs, a background thread (:class:`Heartbeat`) pushes the
expiry forward every third of ``sweep.lease_seconds``; at the job's end the lease is released.

A claim is a *generation*: the file ``lease/<n>.json``. The current lease is the highest
generation. A driver takes a free job (no lease, a released one, an expired one, or one of a
process of this host that is gone) by creating generation n + 1 create-exclusive
(:func:`sweep.service.storage.create_exclusive`): of two drivers that try at once, exactly one
makes the file (on one file system; on an object store, see that function for the limit), and
the other sees it held. A claim holds only if its generation is the highest right after it is
made (a listing taken while another driver swaps generations can miss both files, and the
driver that saw no lease would make generation 0 again beside the other's 1). Generations
only grow, so a stalled holder whose lease was taken over finds a higher generation at its next
renewal and knows it lost the job (:meth:`Lease.renew`).

Expiry is wall-clock time: the drivers' clocks must agree to well within ``lease_seconds``.
"""

from __future__ import annotations

import json
import os
import re
import socket
import threading
import time
import uuid
from dataclasses import dataclass

from sweep.service import storage

#: the default lifetime of a lease without a heartbeat [s] (``sweep.lease_seconds``)
LEASE_SECONDS = 30.0
_GENERATION = re.compile(r"^(\d{8})\.json$")


@dataclass(frozen=True)
class Driver:
    """Who holds a lease: a host name, a process id and a random id (unique per driver)."""

    host: str
    pid: int
    id: str

    @classmethod
    def this(cls) -> Driver:
        """A new driver identity for this process."""
        return cls(socket.gethostname(), os.getpid(), uuid.uuid4().hex[:12])

    def __str__(self) -> str:
        return f"{self.id} (host {self.host}, pid {self.pid})"

    def gone(self) -> bool:
        """Whether this driver is known to be dead: a process of this host that no longer
        exists (another host's driver is never known to be gone; its lease expires)."""
        if self.host != socket.gethostname():
            return False
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:  # alive, another user's
            return False
        return False


@dataclass(frozen=True)
class Holder:
    """One generation of a job's lease: who claimed it, until when (Unix time [s]), released."""

    driver: Driver
    generation: int
    expires: float
    released: bool = False

    def live(self, now: float | None = None) -> bool:
        """Whether the claim still stands: not released, not expired, its driver not gone."""
        now = time.time() if now is None else now
        return not self.released and self.expires > now and not self.driver.gone()

    def to_bytes(self) -> bytes:
        """The lease file's content (JSON)."""
        d = self.driver
        return json.dumps(
            {
                "driver": d.id,
                "host": d.host,
                "pid": d.pid,
                "generation": self.generation,
                "expires": self.expires,
                "released": self.released,
            },
            sort_keys=True,
        ).encode()

    @classmethod
    def from_bytes(cls, data: bytes) -> Holder:
        """Read a lease file (ValueError if it is not one)."""
        try:
            v = json.loads(data)
            driver = Driver(str(v["host"]), int(v["pid"]), str(v["driver"]))
            return cls(driver, int(v["generation"]), float(v["expires"]), bool(v["released"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a lease file: {exc}") from exc


class Lease:
    """The lease of one job, claimed by ``driver`` for ``seconds`` at a time.

    ``directory``: the job's lease directory (a path or storage URI)."""

    def __init__(self, directory: str, driver: Driver, seconds: float = LEASE_SECONDS) -> None:
        self.directory = directory
        self.driver = driver
        self.seconds = float(seconds)
        self.generation: int | None = None  # the generation this driver holds
        self._lock = threading.Lock()  # a renewal and the release never interleave

    def _file(self, generation: int) -> str:
        return storage.join(self.directory, f"{generation:08d}.json")

    def _generations(self) -> list[int]:
        names = storage.list_names(self.directory)
        return sorted(int(m.group(1)) for n in names if (m := _GENERATION.match(n)))

    def holder(self) -> Holder | None:
        """The current (highest) generation of the lease, or None if the job has none.

        A lease file that cannot be read counts as an expired claim of its generation."""
        for _ in range(5):
            generations = self._generations()
            if not generations:
                return None
            top = generations[-1]
            try:
                return Holder.from_bytes(storage.read_bytes(self._file(top)))
            except FileNotFoundError:  # removed as an older generation: look again
                continue
            except ValueError:
                return Holder(Driver("?", 0, "?"), top, 0.0)
        return None

    def acquire(self) -> Holder | None:
        """Claim the job: None once this driver holds it, else the other driver's live claim."""
        for _ in range(5):
            current = self.holder()
            now = time.time()
            if current is not None and current.driver.id == self.driver.id:
                if not current.released and current.expires > now:
                    self.generation = current.generation
                    return None
            elif current is not None and current.live(now):
                return current
            generation = 0 if current is None else current.generation + 1
            mine = Holder(self.driver, generation, now + self.seconds)
            if storage.create_exclusive(self._file(generation), mine.to_bytes()):
                # a directory listed while another driver makes the next generation and
                # removes the one before may show neither file (entries added or removed
                # during a listing may be missed): a driver that saw no lease then makes
                # generation 0 again while another holds generation 1. The claim stands only
                # if it is the highest generation; else look again (the higher one is live)
                listed = self._generations()
                if listed[-1:] != [generation]:
                    continue
                self.generation = generation
                for old in listed:  # keep the directory short
                    if old < generation:
                        storage.delete(self._file(old))
                return None
        current = self.holder()
        assert current is not None  # five generations were made meanwhile by others
        return current

    def renew(self) -> bool:
        """Push this driver's claim ``seconds`` forward; False if it was taken over (a higher
        generation exists: this driver stalled past its expiry) or never held."""
        with self._lock:
            if self.generation is None:
                return False
            if self._generations()[-1:] != [self.generation]:
                return False
            mine = Holder(self.driver, self.generation, time.time() + self.seconds)
            storage.write_bytes(self._file(self.generation), mine.to_bytes())
            return True

    def release(self) -> None:
        """Give the job up (its lease file says released; the next driver takes a new
        generation). Nothing if this driver does not hold it (any more)."""
        with self._lock:
            if self.generation is None:
                return
            if self._generations()[-1:] == [self.generation]:
                done = Holder(self.driver, self.generation, time.time(), released=True)
                storage.write_bytes(self._file(self.generation), done.to_bytes())
            self.generation = None


class Heartbeat:
    """Renews the leases a driver holds from a background thread, every ``every`` seconds.

    ``lost`` collects the directories of leases that were taken over (renewal refused); an
    error of the storage is kept in ``errors`` and the renewal tried again next time."""

    def __init__(self, every: float) -> None:
        self.every = float(every)
        self.lost: set[str] = set()
        self.errors: list[str] = []
        self._leases: dict[str, Lease] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lease-heartbeat", daemon=True)
        self._thread.start()

    def add(self, lease: Lease) -> None:
        """Keep ``lease`` alive until :meth:`remove`."""
        with self._lock:
            self._leases[lease.directory] = lease

    def remove(self, lease: Lease) -> None:
        """Stop renewing ``lease``."""
        with self._lock:
            self._leases.pop(lease.directory, None)

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            with self._lock:
                leases = list(self._leases.values())
            for lease in leases:
                try:
                    if not lease.renew():
                        self.lost.add(lease.directory)
                        self.remove(lease)
                except OSError as exc:
                    self.errors.append(f"{lease.directory}: {exc}")

    def stop(self) -> None:
        """End the thread (the leases it kept are no longer renewed)."""
        self._stop.set()
        self._thread.join(timeout=max(1.0, self.every))
