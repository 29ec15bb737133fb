"""Shared fixtures: the canonical sample messages (one list, as in the mqtt5 test suites), their golden
bytes, and a quiet logger for the pure state machines."""

from __future__ import annotations

import asyncio
import json
import logging

import pytest

from schema.samples import SAMPLES, VECTORS_PATH

SAMPLE_NAMES = sorted(SAMPLES)


def golden_vectors() -> dict[str, str]:
    return json.loads(VECTORS_PATH.read_text(encoding="utf-8"))


@pytest.fixture(params=SAMPLE_NAMES)
def sample_name(request: pytest.FixtureRequest) -> str:
    """The name of each canonical sample in turn."""
    return request.param


@pytest.fixture
def sample(sample_name: str):
    """Each canonical sample message in turn."""
    return SAMPLES[sample_name]


@pytest.fixture(scope="session")
def vectors() -> dict[str, str]:
    """schema/vectors.json: sample name -> golden hex bytes."""
    return golden_vectors()


@pytest.fixture
def golden(sample_name: str, vectors: dict[str, str]) -> bytes:
    """The golden bytes of the current sample."""
    return bytes.fromhex(vectors[sample_name])


@pytest.fixture
def logger() -> logging.Logger:
    log = logging.getLogger("dronesim.tests")
    log.addHandler(logging.NullHandler())
    return log


@pytest.fixture(scope="module")
def playwright_driver():
    """A module's one Playwright driver (a second sync Playwright started while one runs fails), for the browser
    tests (tests/e2e/) and the engine test of the web page; skipped, saying why, without a browser.

    Stopped at the end of the module, not of the session: a started sync Playwright runs its asyncio loop in a
    greenlet of the main thread, so that until it stops the main thread holds a running event loop
    (`asyncio.get_running_loop()` returns it) and any later test's `asyncio.run` fails with "cannot be called
    from a running event loop" (MAVSDK's, in tests/test_mavlink_clients.py, after tests/e2e/ in a whole run)."""
    from tests.e2e.conftest import _skipped, browser_problem

    problem = browser_problem()
    if problem:
        _skipped.append(problem)
        pytest.skip(f"browser tests skipped: {problem}")
    from playwright.sync_api import sync_playwright

    pw = sync_playwright().start()
    try:
        yield pw
    finally:
        pw.stop()
    with pytest.raises(RuntimeError):  # (stopped: the main thread's running loop is gone with it)
        asyncio.get_running_loop()
