"""Tests of sweep.download against a local HTTP server serving archives built in a temp dir.

The archives are built from the recordings in $MMG_DATA_DIR (else ../shared/data/frt-ds-esso
beside the repository) into pytest's temporary directory, never into the repository.
"""

from __future__ import annotations

import hashlib
import io
import os
import socket
import subprocess
import sys
import tarfile
import threading
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from sweep import download as dl
from sweep.download import CHECKSUMS, DownloadError, download, main

PREFIX = "FRT-DS-ESSO-e694dfd0123456789abcdef0123456789abcdef0"
CORRUPTED = "data/zigzag/zigzag_31-Jul-2020_14_10_05.csv"
UNRELATED = "data/random/random_03-Aug-2020_11_04_37.csv"


def _archive(data_dir: Path, corrupt: str | None = None) -> bytes:
    """A GitHub-like tar.gz: top-level prefix, the 13 files, extras and unrelated files."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz", compresslevel=1) as tar:

        def add(name: str, payload: bytes) -> None:
            info = tarfile.TarInfo(f"{PREFIX}/{name}")
            info.size = len(payload)
            tar.addfile(info, io.BytesIO(payload))

        top = tarfile.TarInfo(PREFIX)
        top.type = tarfile.DIRTYPE
        tar.addfile(top)
        add("img/inukai.pdf", b"%PDF-1.4 not really")
        add(UNRELATED, b"t [s]\n0.0\n")
        for name in ("LICENSE", "README.md"):
            add(name, (data_dir / name).read_bytes())
        for rel in CHECKSUMS:
            payload = bytearray((data_dir / rel).read_bytes())
            if rel == corrupt:
                i = len(payload) // 2
                while not chr(payload[i]).isdigit():
                    i += 1
                payload[i] = ord("7") if payload[i] != ord("7") else ord("3")  # one byte changed
            add(rel, bytes(payload))
    return buf.getvalue()


@dataclass
class Server:
    base: str
    hits: Counter[str]
    sizes: dict[str, int]


@pytest.fixture(scope="module")
def server(data_dir: Path) -> Iterator[Server]:
    routes = {
        "/good.tar.gz": _archive(data_dir),
        "/corrupt.tar.gz": _archive(data_dir, corrupt=CORRUPTED),
        "/notatar.tar.gz": b"<html>rate limited</html>",
    }
    hits: Counter[str] = Counter()

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            hits[self.path] += 1
            body = routes.get(self.path)
            if body is None:
                self.send_error(404, "Not Found")
                return
            self.send_response(200)
            self.send_header("Content-Type", "application/x-gzip")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: object) -> None:
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield Server(
            base=f"http://127.0.0.1:{httpd.server_address[1]}",
            hits=hits,
            sizes={k: len(v) for k, v in routes.items()},
        )
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(5)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _closed_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_checksum_table_matches_the_shared_files(data_dir: Path) -> None:
    assert len(CHECKSUMS) == 13
    for rel, digest in CHECKSUMS.items():
        assert _sha(data_dir / rel) == digest, rel
    expected = f"https://codeload.github.com/NAOE-5thLab/FRT-DS-ESSO/tar.gz/{dl.COMMIT}"
    assert expected == dl.DEFAULT_URL


def test_download_verify_layout_then_idempotent(
    server: Server, data_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "new" / "frt-ds-esso"  # does not exist yet
    url = f"{server.base}/good.tar.gz"
    before = server.hits[url.removeprefix(server.base)]

    assert main(["--root", str(root), "--url", url]) == 0
    err = capsys.readouterr().err
    assert server.hits["/good.tar.gz"] == before + 1
    size = server.sizes["/good.tar.gz"]
    assert f"{size:,} of {size:,} bytes received" in err  # progress in bytes on stderr
    assert "verified and wrote 15 file(s)" in err
    for rel, digest in CHECKSUMS.items():
        assert _sha(root / rel) == digest
    assert (root / "LICENSE").read_bytes() == (data_dir / "LICENSE").read_bytes()
    assert not (root / UNRELATED).exists() and not (root / "img").exists()
    assert not (root / PREFIX).exists()
    assert sorted(p.name for p in root.iterdir()) == ["LICENSE", "README.md", "data"]
    assert sorted(p.name for p in (root / "data").iterdir()) == [
        "berthing",
        "random",
        "turning",
        "zigzag",
    ]
    mtimes = {rel: (root / rel).stat().st_mtime_ns for rel in CHECKSUMS}

    # second run: everything verified locally, no request at all
    assert main(["--root", str(root), "--url", url]) == 0
    err = capsys.readouterr().err
    assert server.hits["/good.tar.gz"] == before + 1
    assert "all 13 recordings present and verified" in err and "nothing to download" in err
    assert {rel: (root / rel).stat().st_mtime_ns for rel in CHECKSUMS} == mtimes

    # an unreachable URL does not matter either when everything is present
    assert main(["--root", str(root), "--url", f"http://127.0.0.1:{_closed_port()}/x"]) == 0


def test_repairs_missing_and_damaged_files_only(server: Server, tmp_path: Path) -> None:
    root = tmp_path / "root"
    url = f"{server.base}/good.tar.gz"
    download(root, url=url)
    gone = "data/random/random_06-Aug-2020_16_24_25_5.csv"
    damaged = "data/berthing/berthing_12-Nov-2020_13_21_03.csv"
    (root / gone).unlink()
    (root / damaged).write_bytes(b"t [s]\n")
    untouched = {
        rel: (root / rel).stat().st_mtime_ns for rel in CHECKSUMS if rel not in (gone, damaged)
    }
    hits = server.hits["/good.tar.gz"]

    result = download(root, url=url)
    assert server.hits["/good.tar.gz"] == hits + 1
    assert set(result.written) == {gone, damaged}  # LICENSE/README already present: kept
    assert len(result.already_ok) == 11
    assert result.bytes_downloaded == server.sizes["/good.tar.gz"]
    assert _sha(root / gone) == CHECKSUMS[gone] and _sha(root / damaged) == CHECKSUMS[damaged]
    assert {rel: (root / rel).stat().st_mtime_ns for rel in untouched} == untouched


def test_force_downloads_again(server: Server, tmp_path: Path) -> None:
    root = tmp_path / "root"
    url = f"{server.base}/good.tar.gz"
    download(root, url=url)
    hits = server.hits["/good.tar.gz"]
    assert download(root, url=url).written == ()
    result = download(root, url=url, force=True)
    assert server.hits["/good.tar.gz"] == hits + 1
    assert len(result.written) == 15


def test_corrupted_archive_fails_cleanly_and_writes_nothing(
    server: Server, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "fresh"
    assert main(["--root", str(root), "--url", f"{server.base}/corrupt.tar.gz"]) == 1
    err = capsys.readouterr().err
    assert "checksum mismatch" in err
    assert "zigzag_31-Jul-2020_14_10_05.csv: expected " + CHECKSUMS[CORRUPTED] in err
    assert "berthing" not in err  # only the corrupted file is named
    assert "Traceback" not in err
    assert not root.exists()  # created for the download, removed again

    # an existing root keeps exactly what it had
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "keep.txt").write_text("mine")
    assert main(["--root", str(existing), "--url", f"{server.base}/corrupt.tar.gz"]) == 1
    capsys.readouterr()
    assert sorted(p.name for p in existing.iterdir()) == ["keep.txt"]


def test_network_errors_are_clean(
    server: Server, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "root"
    assert main(["--root", str(root), "--url", f"http://127.0.0.1:{_closed_port()}/a.tgz"]) == 1
    err = capsys.readouterr().err
    assert "error: could not download http://127.0.0.1:" in err
    assert "Connection refused" in err and "Traceback" not in err
    assert not root.exists()

    assert main(["--root", str(root), "--url", f"{server.base}/missing.tar.gz"]) == 1
    assert "HTTP 404" in capsys.readouterr().err

    assert main(["--root", str(root), "--url", f"{server.base}/notatar.tar.gz"]) == 1
    assert "corrupt or not a tar.gz" in capsys.readouterr().err

    with pytest.raises(DownloadError, match="could not download"):
        download(root, url="nonsense://x")


def test_command_line_exit_status_without_traceback(tmp_path: Path) -> None:
    root = tmp_path / "root"
    url = f"http://127.0.0.1:{_closed_port()}/archive.tar.gz"
    proc = subprocess.run(
        [sys.executable, "-m", "sweep.download", "--root", str(root), "--url", url],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "MMG_DATA_DIR": ""},
    )
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith(f"error: could not download {url}")
