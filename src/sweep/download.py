"""Download the 13 FRT-DS-ESSO recordings of the paper's split, at a pinned commit, verified.

Usage::

    python -m sweep.download [--root DIR] [--url URL] [--force]

The recordings (CC BY-NC-SA 4.0, Wakita et al. 2022, Miyauchi et al. 2022) come from the public
GitHub repository NAOE-5thLab/FRT-DS-ESSO at commit :data:`COMMIT` (a short SHA, the one the
data README names; the checksums pin the content regardless), as GitHub's tar.gz archive. Only
the 13 files of the split (:data:`CHECKSUMS`) plus ``LICENSE`` and ``README.md`` are extracted
into the data root, keeping the ``data/<kind>/<file>.csv`` layout. Every file is checked against
its SHA-256; files already verified are left alone (no network access when all are); the
archive is extracted and verified in a temporary directory inside the root before anything is
renamed into place, so a failure leaves the root as it was.
"""

from __future__ import annotations

import argparse
import hashlib
import http.client
import os
import shutil
import sys
import tarfile
import tempfile
import urllib.error
import urllib.request
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO, TextIO

from sweep.data.datasets import data_root

REPOSITORY = "NAOE-5thLab/FRT-DS-ESSO"
"""GitHub repository of the recordings (owner/name)."""
COMMIT = "e694dfd"
"""Pinned commit of :data:`REPOSITORY` (short SHA)."""
DEFAULT_URL = f"https://codeload.github.com/{REPOSITORY}/tar.gz/{COMMIT}"
"""The tar.gz archive GitHub serves for :data:`COMMIT` (``--url`` overrides it)."""

CHECKSUMS: dict[str, str] = {
    "data/random/random_06-Aug-2020_16_24_25_1.csv": (
        "58144de9e197449d6ff19d9299f200293e66177e60345444273781d9df716a1e"
    ),
    "data/random/random_06-Aug-2020_16_24_25_3.csv": (
        "95344c92c05ccb60a1fa31a32ab02c85a9927b2581870721433b10d51458e7b9"
    ),
    "data/random/random_06-Aug-2020_16_24_25_4.csv": (
        "61dcab5b97f0a039ce59ff18a5b6d6a67f1d35e0b1cdff536ac9192b8c89cc52"
    ),
    "data/random/random_06-Aug-2020_16_24_25_5.csv": (
        "402ce69616c48f99f086a491811efd59cf26cc0a1f154c7ceeec844312eabcd4"
    ),
    "data/random/random_06-Aug-2020_16_24_25_6.csv": (
        "875dfed9570e83b50e4ecbfe52ef18f12b3cfb18f0f8f4f71f0332691d128eba"
    ),
    "data/turning/turn_14-Sep-2020_14_50_41.csv": (
        "3d11c8133aadbd79239987e78cc71b76ec0c83d74e0bfd28bc24cca2a17a4bd1"
    ),
    "data/turning/turn_cut_14-Sep-2020_15_58_08.csv": (
        "7045db0012e33603955580c070522dc8a06d67e9a50972448acc3dbd86498ee7"
    ),
    "data/turning/turn_cut_14-Sep-2020_16_09_02.csv": (
        "c5620305b7f3e52f67e84cababff7c67f59ec2ca175b803b6dc2e17621b0c94a"
    ),
    "data/zigzag/zigzag_31-Jul-2020_13_22_52.csv": (
        "47d317d8405f88c524fc3e6646224ab4500c9b05184339dd35d14200a71cd8ff"
    ),
    "data/zigzag/zigzag_31-Jul-2020_13_50_28.csv": (
        "e04f52593cc350281dc2d0b39750a48253fff9e35b3be11d28fc8fa157bbdffa"
    ),
    "data/zigzag/zigzag_31-Jul-2020_14_10_05.csv": (
        "b59c883731ee5f32ef896c80abf11ade212b815001e32d7b2c109d0bd9e27ed2"
    ),
    "data/berthing/berthing_12-Nov-2020_11_49_21.csv": (
        "264cfe5e74a8f01f644d20f065e87dda992f5d29a3a18a805e6f6db92478a281"
    ),
    "data/berthing/berthing_12-Nov-2020_13_21_03.csv": (
        "a29111bb1fe80b911e1b00da4fe40e20cf6ae2417cf5385a8198bebf5659ad5f"
    ),
}
"""SHA-256 of the 13 recordings of the split, by path relative to the data root."""
EXTRA_FILES: tuple[str, ...] = ("LICENSE", "README.md")
"""Extracted when present in the archive (not verified; kept if already present)."""

CHUNK = 1 << 16
"""Read/write block [bytes]."""
PROGRESS_EVERY = 1 << 18
"""Progress line refresh interval [bytes]."""
TIMEOUT_S = 60.0
"""Network timeout [s]."""


class DownloadError(RuntimeError):
    """Download, extraction or verification failed; the message says what and where."""


@dataclass(frozen=True)
class DownloadResult:
    """Outcome of :func:`download`.

    Attributes:
        root: the data root.
        written: relative paths written in this run (recordings and extras).
        already_ok: recordings that were present with the right checksum and left untouched.
        bytes_downloaded: size of the downloaded archive [bytes] (0 if nothing was downloaded).
    """

    root: Path
    written: tuple[str, ...]
    already_ok: tuple[str, ...]
    bytes_downloaded: int


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file."""
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def check_files(root: Path) -> dict[str, str]:
    """Status of each of the 13 recordings below ``root``: ``"ok"``, ``"missing"`` or ``"bad"``."""
    status: dict[str, str] = {}
    for rel, expected in CHECKSUMS.items():
        p = root / rel
        if not p.is_file():
            status[rel] = "missing"
        else:
            status[rel] = "ok" if sha256_file(p) == expected else "bad"
    return status


def _fetch(url: str, dest: Path, out: TextIO | None, timeout: float) -> int:
    """Stream ``url`` into ``dest``, reporting bytes on ``out``; returns the byte count."""
    request = urllib.request.Request(url, headers={"User-Agent": "mmg-sweep-download"})
    received = 0
    total = ""
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            length = response.headers.get("Content-Length")
            total = f" of {int(length):,}" if length and length.isdigit() else ""
            shown = -PROGRESS_EVERY
            with dest.open("wb") as fh:
                while True:
                    block = response.read(CHUNK)
                    if not block:
                        break
                    fh.write(block)
                    received += len(block)
                    if out is not None and received - shown >= PROGRESS_EVERY:
                        out.write(f"\r  {received:,}{total} bytes")
                        out.flush()
                        shown = received
    except urllib.error.HTTPError as exc:
        raise DownloadError(f"could not download {url}: HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, http.client.HTTPException, OSError, ValueError) as exc:
        reason = exc.reason if isinstance(exc, urllib.error.URLError) else exc
        raise DownloadError(
            f"could not download {url}: {reason}. Check the network connection and the URL (--url)."
        ) from None
    if out is not None:
        out.write(f"\r  {received:,}{total} bytes received\n")
        out.flush()
    return received


def _copy_hashing(src: IO[bytes], dest: Path) -> str:
    h = hashlib.sha256()
    dest.parent.mkdir(parents=True, exist_ok=True)
    with dest.open("wb") as fh:
        for block in iter(lambda: src.read(CHUNK), b""):
            h.update(block)
            fh.write(block)
    return h.hexdigest()


def _extract(archive: Path, wanted: set[str], into: Path) -> dict[str, str]:
    """Extract the ``wanted`` relative paths from a tar.gz into ``into``; returns their SHA-256.

    A member matches by its full name or by its name without the first (top-level) component.
    """
    digests: dict[str, str] = {}
    try:
        with tarfile.open(archive, mode="r:gz") as tar:
            for member in tar:
                if not member.isfile():
                    continue
                parts = PurePosixPath(member.name).parts
                candidates = ["/".join(parts), "/".join(parts[1:])]
                rel = next((c for c in candidates if c in wanted), None)
                if rel is None:
                    continue
                src = tar.extractfile(member)
                if src is None:
                    continue
                with src:
                    digests[rel] = _copy_hashing(src, into / rel)
    except (tarfile.TarError, EOFError, zlib.error, OSError) as exc:
        raise DownloadError(f"the downloaded archive is corrupt or not a tar.gz ({exc})") from None
    return digests


def download(
    root: str | os.PathLike[str] | None = None,
    url: str = DEFAULT_URL,
    force: bool = False,
    out: TextIO | None = None,
    timeout: float = TIMEOUT_S,
) -> DownloadResult:
    """Make the 13 verified recordings present below the data root, downloading if needed.

    Args:
        root: data root; None = :func:`sweep.data.datasets.data_root` default (``$MMG_DATA_DIR`` or
            the user cache directory). Created if missing.
        url: the tar.gz archive of the repository at the pinned commit.
        force: download and rewrite even if every file is present and verified.
        out: stream for progress and status messages (None = silent).
        timeout: network timeout [s].

    Raises:
        DownloadError: network error, corrupt archive, missing file in the archive or checksum
            mismatch; the root is then left unchanged.
    """
    base = data_root(root, must_exist=False)
    status = check_files(base) if base.is_dir() else dict.fromkeys(CHECKSUMS, "missing")
    ok = tuple(rel for rel, s in status.items() if s == "ok")
    needed = [rel for rel in CHECKSUMS if force or status[rel] != "ok"]

    def say(msg: str) -> None:
        """One progress line to ``out`` (nothing when ``out`` is None)."""
        if out is not None:
            out.write(msg + "\n")
            out.flush()

    if not needed:
        say(f"all {len(CHECKSUMS)} recordings present and verified in {base}; nothing to download")
        return DownloadResult(root=base, written=(), already_ok=ok, bytes_downloaded=0)
    for rel in needed:
        if status[rel] == "bad":
            say(f"{base / rel}: wrong checksum, it will be replaced")

    created = not base.exists()
    try:
        base.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".download-", dir=base))
    except OSError as exc:
        raise DownloadError(f"cannot write to the data root {base}: {exc}") from None
    try:
        say(f"downloading {len(needed)} recording(s) of {REPOSITORY}@{COMMIT} from {url}")
        archive = tmp / "archive.tar.gz"
        n_bytes = _fetch(url, archive, out, timeout)
        extras = {e for e in EXTRA_FILES if force or not (base / e).exists()}
        digests = _extract(archive, set(needed) | extras, tmp / "tree")
        absent = [rel for rel in needed if rel not in digests]
        if absent:
            raise DownloadError(
                f"the archive from {url} lacks {len(absent)} expected file(s): "
                f"{', '.join(absent)} (is it {REPOSITORY} at commit {COMMIT}?)"
            )
        bad = [rel for rel in needed if digests[rel] != CHECKSUMS[rel]]
        if bad:
            details = "; ".join(
                f"{rel}: expected {CHECKSUMS[rel]}, got {digests[rel]}" for rel in bad
            )
            raise DownloadError(
                f"checksum mismatch in the archive from {url} for {len(bad)} file(s): {details}. "
                f"Nothing was written to {base}."
            )
        written = list(needed) + sorted(e for e in extras if e in digests)
        try:
            for rel in written:
                dest = base / rel
                dest.parent.mkdir(parents=True, exist_ok=True)
                os.replace(tmp / "tree" / rel, dest)
        except OSError as exc:
            raise DownloadError(f"cannot write to the data root {base}: {exc}") from None
        say(f"verified and wrote {len(written)} file(s) to {base}")
        return DownloadResult(
            root=base, written=tuple(written), already_ok=ok, bytes_downloaded=n_bytes
        )
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created:
            shutil.rmtree(base, ignore_errors=True)
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status (0 = success, 1 = failure)."""
    parser = argparse.ArgumentParser(
        prog="python -m sweep.download",
        description=(
            f"Download the 13 FRT-DS-ESSO recordings of the paper's split ({REPOSITORY} at "
            f"commit {COMMIT}, CC BY-NC-SA 4.0) and verify their SHA-256."
        ),
    )
    parser.add_argument(
        "--root",
        default=None,
        help="data directory (default: $MMG_DATA_DIR, else the user cache directory "
        "<cache>/mmg-sweep/frt-ds-esso)",
    )
    parser.add_argument("--url", default=DEFAULT_URL, help=f"archive URL (default: {DEFAULT_URL})")
    parser.add_argument(
        "--force", action="store_true", help="download even if all files are present and valid"
    )
    args = parser.parse_args(argv)
    try:
        download(root=args.root, url=args.url, force=args.force, out=sys.stderr)
    except DownloadError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("error: interrupted; nothing was written", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
