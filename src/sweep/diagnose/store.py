"""The finished stages of one diagnosis, stored as JSON files under ``DIR/stages``.

A stage's file carries the fingerprint of the settings and the data it was computed from; a
file with another fingerprint is not reused, so running the same command again resumes after
the last finished stage and a changed setting refits what depends on it.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mmg import Effect, Parameters
from mmg.effect import DISCOVERED_PREFIX
from mmg.shapes import SHAPE_PREFIX
from sweep.data.recordings import Recording
from sweep.diagnose.fit import Fit


@dataclass
class StageStore:
    """Finished stages of one diagnosis, as JSON files under ``DIR/stages``."""

    directory: Path
    fingerprint: str

    def path(self, name: str) -> Path:
        """The file of stage ``name``."""
        return self.directory / f"{name}.json"

    def load(self, name: str, effects: Sequence[Effect]) -> Fit | None:
        """The stored fit of stage ``name`` (with ``effects``), or None when there is none
        under this fingerprint."""
        p = self.path(name)
        if not p.exists():
            return None
        data = json.loads(p.read_text())
        if data.get("fingerprint") != self.fingerprint:
            return None
        params = Parameters.from_dict(data["params"], origin=str(p))
        return Fit(
            params=params,
            effects=tuple(effects),
            f=float(data["f"]),
            evaluations=int(data["evaluations"]),
            seconds=float(data["seconds"]),
            history=list(data.get("history", [])),
            ends=tuple(float(v) for v in data.get("ends", ())),
        )

    def save(self, name: str, result: Fit) -> None:
        """Store the fit of stage ``name`` (written to a temporary file, then renamed)."""
        self.directory.mkdir(parents=True, exist_ok=True)
        payload = {
            "fingerprint": self.fingerprint,
            "params": result.params.to_dict(),
            "f": result.f,
            "evaluations": result.evaluations,
            "seconds": result.seconds,
            "history": result.history,
            "ends": list(result.ends),
        }
        tmp = self.path(name).with_suffix(".tmp")
        tmp.write_text(json.dumps(payload) + "\n")
        tmp.replace(self.path(name))


def stage_label(name: str, effects: Sequence[Effect]) -> str:
    """A file-name-safe stage name; a generated effect's name is replaced by a hash of its terms
    and search box (a different proposal is a different stage)."""
    for e in effects:
        for prefix in (DISCOVERED_PREFIX, SHAPE_PREFIX):
            if e.name.startswith(prefix) and e.name in name:
                h = hashlib.sha256(e.name.encode())
                h.update(json.dumps(e.bounds).encode())
                name = name.replace(e.name, f"{prefix[:-1]}-{h.hexdigest()[:10]}")
    return name


def data_fingerprint(recordings: Sequence[Recording], start: Parameters) -> str:
    """12 hex digits naming the recordings (names, states, controls) and the start."""
    h = hashlib.sha256()
    for r in recordings:
        h.update(r.name.encode())
        h.update(np.ascontiguousarray(r.x).tobytes())
        h.update(np.ascontiguousarray(r.u).tobytes())
    h.update(json.dumps(start.to_dict(), sort_keys=True).encode())
    return h.hexdigest()[:12]
