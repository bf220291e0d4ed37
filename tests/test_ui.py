"""The MLflow UI in a real headless browser, on the smoke sweep's store.

``python -m sweep.ui`` starts the MLflow UI on a free loopback port; headless Chromium (Debian's
``chromium`` package, driven by Playwright for Python with that executable: no browser download)
opens the address it prints. The first screen must be the runs table with the sweep's parent
run; expanded, it lists the two jobs by objective, training set and seed; the parent's overview
shows the answer and the J2 table. Screenshots are saved under ``test-artifacts/ui/`` so that a
failure can be looked at. Without Chromium or Playwright the test is skipped and says why.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration  # a real browser

ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts" / "ui"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
#: flags for a closed network and a root user (see the machine notes)
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def ui(smoke) -> Iterator[str]:
    """The runs-table address printed by ``python -m sweep.ui`` (server torn down after)."""
    if CHROMIUM is None:
        pytest.skip("no Chromium on this machine: apt-get install chromium (see the README)")
    pytest.importorskip("playwright.sync_api", reason="Playwright for Python is not installed")
    cwd, _ = smoke
    port = _free_port()
    log = (cwd / "ui.log").open("w+")
    proc = subprocess.Popen(
        [sys.executable, "-m", "sweep.ui", "--tracking-uri", f"sqlite:///{cwd}/mlflow.db",
         "--port", str(port), "--no-browser"],
        cwd=cwd, stdout=log, stderr=subprocess.STDOUT, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        t0 = time.time()
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if proc.poll() is not None or time.time() - t0 > 120:
                log.seek(0)
                raise AssertionError(f"the MLflow UI did not start: {log.read()[-3000:]}")
            time.sleep(0.5)
        log.seek(0)
        match = re.search(r"MLflow UI: (\S+)", log.read())
        assert match, "sweep.ui printed no address"
        yield match.group(1)
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        log.close()


def test_the_ui_opens_on_the_runs_table_and_the_parent_shows_the_tables(ui: str) -> None:
    from playwright.sync_api import sync_playwright

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    assert "workflowType=machine_learning" in ui and "viewStateShareKey=mmg-sweep-tables" in ui
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1900, "height": 1000})
        try:
            page.goto(ui, wait_until="load")
            page.get_by_text("ci-smoke").first.wait_for(timeout=90_000)
            page.screenshot(path=str(ARTIFACTS / "1-runs-table.png"))
            body = page.inner_text("body")
            assert "Runs" in body and "Detect Issues" not in body  # not the GenAI overview
            # the sweep's saved view: objective, training set, seed and the test J as columns
            headers = set(page.locator("[role=columnheader]").all_inner_texts())
            for column in ("objective", "train", "seed", "test/J2/total", "test/J1/total"):
                assert column in headers, (column, headers)
            name_cells = page.locator("[role=gridcell][col-id='attributes.`Run Name`']")
            parent = name_cells.filter(has_text="ci-smoke").first
            parent.locator("button[data-component-id*='runnamecellrenderer']").click()
            for child in ("J1-R-seed0", "J2-R-seed0"):  # objective, training set, seed
                page.get_by_text(child).first.wait_for(timeout=30_000)
            page.screenshot(path=str(ARTIFACTS / "2-parent-expanded.png"))
            parent.get_by_role("link", name="ci-smoke").click()
            page.get_by_text("Best generalisation").first.wait_for(timeout=30_000)
            page.screenshot(path=str(ARTIFACTS / "3-parent-overview.png"), full_page=True)
            text = page.inner_text("body")
            assert re.search(r"Best generalisation \(J2, whole test set\): J[12]-R", text)
            j2 = text.split("J2 on the test set", 1)[1].split("J1 on the test set", 1)[0]
            for row in ("EFD", "J1-R", "J2-R"):
                assert re.search(rf"{row}\s+\d", j2), row  # the table's rows, with numbers
            assert "Test-B-S" in j2 and "Total" in j2
        except Exception:
            page.screenshot(path=str(ARTIFACTS / "failure.png"), full_page=True)
            raise
        finally:
            browser.close()
