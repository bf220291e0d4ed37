"""The paper's train/test split of FRT-DS-ESSO, the data directory, and the berthing sides.

The split of Miyauchi et al. (2022), Table 4, is configuration: ``conf/train/{R,TR,TZR}.yaml``
(``name`` and ``files``) and ``conf/test/paper.yaml`` (``name`` and ``subsets``), paths relative
to the data root. :func:`load_split` reads them with plain YAML from :data:`CONF_DIR` (an
editable install; otherwise pass the YAML file's path). :func:`data_root` is an explicit
argument, else ``$MMG_DATA_DIR``, else the user cache directory; the recordings are never part of
the repository (``python -m sweep.download`` fetches them).

Which berthing run is starboard-side (B-S) and which port-side (B-P) the source does not say;
:func:`berthing_evidence` decides it from the tracks: both the mean v_m over the last 20 s and
the final lateral offset from the approach line are positive for B-S (12-Nov-2020_11_49_21:
+0.0152 m/s, +5.95 m) and negative for B-P (12-Nov-2020_13_21_03: -0.0226 m/s, -5.49 m).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Literal

import numpy as np
import platformdirs
import yaml

from sweep.data.recordings import PathLike, Recording, read_recording
from sweep.errors import UserError

CONF_DIR = Path(__file__).resolve().parents[3] / "conf"
"""The repository's Hydra ``conf/`` directory (found relative to this file; editable install)."""
SPLIT_GROUPS: tuple[str, ...] = ("train", "test")
"""Config groups holding split files."""
ENV_VAR = "MMG_DATA_DIR"
"""Environment variable naming the data root."""
APP_NAME = "mmg-sweep"
"""Application name of the user cache directory (platformdirs)."""
DATASET_DIRNAME = "frt-ds-esso"
"""Data root below the user cache directory when neither an argument nor the variable names one."""

BERTHING_TAIL_S = 20.0
"""Final window over which the lateral velocity is averaged [s]."""
BERTHING_HEAD_S = 5.0
"""Initial window defining the approach line (position and heading) [s]."""


class DataNotFoundError(FileNotFoundError, UserError):
    """The data directory or a recording listed by a split is missing."""


class SplitError(ValueError, UserError):
    """A split YAML file is missing, unknown or malformed."""


def _download_hint(root: Path) -> str:
    return (
        f"Download the FRT-DS-ESSO recordings with `python -m sweep.download --root {root}` "
        f"(or `mmg-data --root {root}`), or set {ENV_VAR} to a directory holding them "
        "(layout: data/<kind>/<file>.csv)."
    )


def data_root(explicit: str | os.PathLike[str] | None = None, must_exist: bool = True) -> Path:
    """The directory holding the FRT-DS-ESSO files (``data/<kind>/<file>.csv`` below it).

    Args:
        explicit: a directory given by the caller; wins over everything else.
        must_exist: raise if the directory does not exist (False for the downloader).

    Returns:
        ``explicit``, else ``$MMG_DATA_DIR``, else
        ``platformdirs.user_cache_dir("mmg-sweep") / "frt-ds-esso"`` (user ``~`` expanded).

    Raises:
        DataNotFoundError: ``must_exist`` and the directory does not exist; the message names
            the directory, where the choice came from and how to download the data.
    """
    env = os.environ.get(ENV_VAR, "")
    if explicit is not None and str(explicit) != "":
        root, origin = Path(explicit), "given explicitly"
    elif env:
        root, origin = Path(env), f"from ${ENV_VAR}"
    else:
        root = Path(platformdirs.user_cache_dir(APP_NAME)) / DATASET_DIRNAME
        origin = f"the default; set ${ENV_VAR} to use another directory"
    root = root.expanduser()
    if must_exist and not root.is_dir():
        raise DataNotFoundError(
            f"FRT-DS-ESSO data directory {root} ({origin}) does not exist. {_download_hint(root)}"
        )
    return root


@dataclass(frozen=True)
class Split:
    """A named set of recordings, as read from a split YAML file.

    Attributes:
        name: the split's name (``"Train-R"``, ``"Test"``, ...).
        group: the config group (``"train"``, ``"test"``) or ``""`` for a file elsewhere.
        source: the YAML file.
        subsets: label -> path relative to the data root (POSIX separators). Test subsets are
            labelled as in the paper (``"Test-B-S"``); training files by their file stem.
    """

    name: str
    group: str
    source: Path
    subsets: dict[str, str]

    @property
    def files(self) -> tuple[str, ...]:
        """Relative paths of the files, in the YAML order."""
        return tuple(self.subsets.values())

    def paths(self, root: str | os.PathLike[str] | None = None) -> dict[str, Path]:
        """Label -> absolute path below :func:`data_root` ``(root)``.

        Raises:
            DataNotFoundError: the directory or any listed file is missing (all are named).
        """
        base = data_root(root)
        out = {label: base / rel for label, rel in self.subsets.items()}
        missing = [str(p) for p in out.values() if not p.is_file()]
        if missing:
            raise DataNotFoundError(
                f"split {self.name!r} ({self.source}): {len(missing)} of {len(out)} file(s) "
                f"missing in {base}: {', '.join(missing)}. {_download_hint(base)}"
            )
        return out

    def load(self, root: str | os.PathLike[str] | None = None) -> dict[str, Recording]:
        """Label -> validated :class:`~sweep.data.recordings.Recording`, in the YAML order."""
        return {label: read_recording(p) for label, p in self.paths(root).items()}


def available_splits() -> list[str]:
    """Names ``"<group>/<stem>"`` of the split files in :data:`CONF_DIR`."""
    return [f"{g}/{f.stem}" for g in SPLIT_GROUPS for f in sorted((CONF_DIR / g).glob("*.yaml"))]


def _check_rel(rel: Any, source: Path) -> str:
    if not isinstance(rel, str) or not rel.strip():
        raise SplitError(f"{source}: file entries must be non-empty strings, got {rel!r}")
    p = PurePosixPath(rel.strip())
    if p.is_absolute() or ".." in p.parts or "\\" in rel:
        raise SplitError(
            f"{source}: {rel!r} must be a relative POSIX path inside the data root "
            "(like data/random/<file>.csv)"
        )
    if p.suffix.lower() not in (".csv", ".parquet", ".pq"):
        raise SplitError(f"{source}: {rel!r} is not a .csv or .parquet file")
    return str(p)


def _parse_split(doc: Any, source: Path, group: str) -> Split:
    if not isinstance(doc, dict):
        raise SplitError(f"{source}: expected a mapping with 'name' and 'files' or 'subsets'")
    name = doc.get("name")
    if not isinstance(name, str) or not name:
        raise SplitError(f"{source}: missing or invalid 'name'")
    has_files, has_subsets = "files" in doc, "subsets" in doc
    if has_files == has_subsets:
        raise SplitError(f"{source}: give exactly one of 'files' (a list) or 'subsets' (a mapping)")
    subsets: dict[str, str] = {}
    if has_files:
        files = doc["files"]
        if not isinstance(files, list) or not files:
            raise SplitError(f"{source}: 'files' must be a non-empty list of relative paths")
        for entry in files:
            rel = _check_rel(entry, source)
            label = PurePosixPath(rel).stem
            if label in subsets:
                raise SplitError(f"{source}: duplicate file {rel!r}")
            subsets[label] = rel
    else:
        mapping = doc["subsets"]
        if not isinstance(mapping, dict) or not mapping:
            raise SplitError(f"{source}: 'subsets' must be a non-empty mapping label -> path")
        for label, entry in mapping.items():
            subsets[str(label)] = _check_rel(entry, source)
    if len(set(subsets.values())) != len(subsets):
        raise SplitError(f"{source}: a file is listed twice")
    return Split(name=name, group=group, source=source, subsets=subsets)


def split_from_mapping(doc: Any, origin: str = "config") -> Split:
    """A split from an already-parsed mapping (e.g. the ``train`` node of a Hydra config)."""
    group = "test" if isinstance(doc, dict) and "subsets" in doc else "train"
    return _parse_split(doc, Path(origin), group)


def _read_yaml(path: Path) -> Any:
    try:
        with path.open(encoding="utf-8") as fh:
            return yaml.safe_load(fh)
    except yaml.YAMLError as exc:
        raise SplitError(f"{path}: invalid YAML ({exc})") from None


def load_split(name_or_yaml_path: str | os.PathLike[str]) -> Split:
    """Read a split from :data:`CONF_DIR` by name, or from a YAML file.

    Args:
        name_or_yaml_path: a path to a ``.yaml``/``.yml`` file, or a split name: the file stem
            (``"R"``, ``"TR"``, ``"TZR"``, ``"paper"``), ``"<group>/<stem>"`` (``"train/R"``,
            ``"test/paper"``) or the ``name`` inside the file (``"Train-R"``, ``"Test"``),
            case-insensitive.

    Raises:
        SplitError: unknown name (the available ones are listed), ambiguous name, or a
            malformed file.
    """
    text = os.fspath(name_or_yaml_path)
    as_path = Path(text).expanduser()
    if as_path.suffix.lower() in (".yaml", ".yml") or as_path.is_file():
        if not as_path.is_file():
            raise SplitError(f"split file {as_path} not found")
        group = as_path.parent.name if as_path.parent.name in SPLIT_GROUPS else ""
        return _parse_split(_read_yaml(as_path), as_path, group)

    key = text.strip().lower()
    matches: list[Split] = []
    for group in SPLIT_GROUPS:
        for f in sorted((CONF_DIR / group).glob("*.yaml")):
            split = _parse_split(_read_yaml(f), f, group)
            aliases = {f.stem.lower(), f"{group}/{f.stem}".lower(), split.name.lower()}
            if key in aliases:
                matches.append(split)
    if not matches:
        raise SplitError(
            f"unknown split {text!r}; available in {CONF_DIR}: {available_splits()} "
            "(or pass the path of a YAML file)"
        )
    if len(matches) > 1:
        raise SplitError(
            f"ambiguous split {text!r}: {[str(m.source) for m in matches]}; use '<group>/<stem>'"
        )
    return matches[0]


# ---------------------------------------------------------------------------------------------
# berthing side


@dataclass(frozen=True)
class BerthingEvidence:
    """Evidence of the berthing side of a run (the rule: :func:`berthing_evidence`).

    Attributes:
        name: the recording's name.
        mean_v_m_end: mean lateral velocity v_m over the last ``tail_s`` seconds [m/s];
            positive = moving to starboard.
        lateral_offset: final midship position relative to the approach line [m], along the
            starboard direction of the initial heading; positive = ends to starboard.
        heading_change: final minus initial heading [rad] (unwrapped, positive = clockwise).
        tail_s: the final window [s].
    """

    name: str
    mean_v_m_end: float
    lateral_offset: float
    heading_change: float
    tail_s: float

    @property
    def side(self) -> Literal["starboard", "port", "ambiguous"]:
        """``"starboard"`` if both pieces of evidence are positive, ``"port"`` if both negative."""
        if self.mean_v_m_end > 0 and self.lateral_offset > 0:
            return "starboard"
        if self.mean_v_m_end < 0 and self.lateral_offset < 0:
            return "port"
        return "ambiguous"


def berthing_evidence(
    rec: Recording, tail_s: float = BERTHING_TAIL_S, head_s: float = BERTHING_HEAD_S
) -> BerthingEvidence:
    """Lateral velocity at the end and lateral offset from the approach line of a run.

    Ship axes: x forward, y to starboard; at heading psi the earth-fixed starboard direction is
    (-sin psi, cos psi). The approach line runs through the mean midship position of the first
    ``head_s`` seconds along their mean heading. A run is starboard-side berthing when both
    ``mean_v_m_end`` and ``lateral_offset`` are positive, port-side when both are negative.

    Args:
        rec: a recording (typically a berthing run).
        tail_s: final window for the mean of v_m [s].
        head_s: initial window defining the approach line: mean midship position and mean
            (unwrapped) heading over the first ``head_s`` seconds [s].
    """
    t = rec.t
    tail = t >= t[-1] - tail_s - 1e-9
    head = t <= t[0] + head_s + 1e-9
    x0, y0, psi = rec.x[:, 0], rec.x[:, 2], rec.x[:, 4]
    psi_0 = float(np.mean(psi[head]))
    start = np.array([np.mean(x0[head]), np.mean(y0[head])])
    starboard = np.array([-np.sin(psi_0), np.cos(psi_0)])
    end = np.array([x0[-1], y0[-1]])
    return BerthingEvidence(
        name=rec.name,
        mean_v_m_end=float(np.mean(rec.x[tail, 3])),
        lateral_offset=float((end - start) @ starboard),
        heading_change=float(psi[-1] - psi_0),
        tail_s=tail_s,
    )


def berthing_side(path_or_recording: PathLike | Recording) -> Literal["starboard", "port"]:
    """The berthing side of a run, from :func:`berthing_evidence`.

    Raises:
        ValueError: the two pieces of evidence disagree (the numbers are in the message).
    """
    rec = (
        path_or_recording
        if isinstance(path_or_recording, Recording)
        else read_recording(path_or_recording)
    )
    ev = berthing_evidence(rec)
    side = ev.side
    if side == "ambiguous":
        raise ValueError(
            f"{rec.name}: ambiguous berthing side (mean v_m over the last {ev.tail_s:g} s = "
            f"{ev.mean_v_m_end:+.4f} m/s, lateral offset = {ev.lateral_offset:+.3f} m)"
        )
    return side
