"""Headless Chromium for the browser tests: Debian's /usr/bin/chromium driven by Playwright through its
executable path (Playwright never downloads a browser here; tests/setup.d/web.sh installs both). When
either is genuinely missing, the tests are skipped and the reason is printed at the end of the run."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "artifacts"  # gitignored: screenshots of the page, for a human to look at
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-default-apps", "--disable-extensions", "--no-default-browser-check",
]
_skipped: list[str] = []


def chromium_path() -> str | None:
    for candidate in (os.environ.get("DRONESIM_CHROMIUM"), shutil.which("chromium"), "/usr/bin/chromium"):
        if candidate and os.path.exists(candidate):
            return candidate
    return None


def browser_problem() -> str | None:
    if chromium_path() is None:
        return "Debian's chromium is not installed (bash tests/setup.d/web.sh installs it)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the Python package playwright is not installed (bash tests/setup.d/web.sh installs it)"
    return None


# The Playwright driver, `playwright_driver`, is in tests/conftest.py: the engine tests (tests/test_docker.py)
# drive the web page too. One a module, stopped at its end: a running sync Playwright leaves the main thread
# holding a running event loop (a second one started meanwhile fails, and so does any asyncio.run).


@pytest.fixture
def page(playwright_driver, tmp_path):
    """A fresh page in a fresh Chromium profile; console errors fail the test."""
    ctx = playwright_driver.chromium.launch_persistent_context(
        str(tmp_path / "profile"), executable_path=chromium_path(), headless=True, args=CHROMIUM_FLAGS,
        viewport={"width": 1440, "height": 900})
    pg = ctx.pages[0] if ctx.pages else ctx.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda exc: errors.append(f"page error: {exc}"))
    pg.on("console", lambda msg: errors.append(f"console {msg.type}: {msg.text}") if msg.type == "error" else None)
    pg.set_default_timeout(60_000)
    try:
        yield pg
    finally:
        ctx.close()
    # a refused target's 4xx is logged by Chromium as a failed resource load: that one is expected
    real = [e for e in errors if "status of 4" not in e]
    assert not real, real


@pytest.fixture(scope="session")
def artifacts() -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS


def pytest_terminal_summary(terminalreporter):
    for reason in sorted(set(_skipped)):
        terminalreporter.write_line(f"BROWSER TESTS SKIPPED: {reason}", yellow=True, bold=True)


def fly_to_clicked_cell(page, drone: str, cell: tuple[int, int, int]) -> None:
    """As a human would: pick the cell's floor and click the cell; the page says `drone`'s target is set
    (the drone selected in the page), and the drone arrives there."""
    x, y, z = cell
    page.click(f"#floors button[data-z='{z}']")
    page.click(f"#grid .cell[data-x='{x}'][data-y='{y}']")
    page.wait_for_selector("#message.ok")
    assert f"target of {drone} set to ({x}, {y}, {z})" in page.inner_text("#message")
    page.wait_for_selector(f"#drone-{drone} [data-status=reached]")
    assert page.inner_text(f"#drone-{drone} .pos") == f"({x}, {y}, {z})"
