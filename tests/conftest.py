"""Shared fixtures: the canonical sample messages (one list, as in the mqtt5 test suites), their golden
bytes, and a quiet logger for the pure state machines."""

from __future__ import annotations

import importlib
import importlib.util
import json
import logging
import pathlib
import sys
import types

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent


def _ensure_coordinator_importable() -> None:
    """`coordinator/` has no ``__init__.py``; setuptools' editable finder cannot resolve a namespace
    sub-package under a mapped regular package, so ``import dronesim.coordinator`` may fail in an
    editable install. Register the folder as a namespace package then (test-side only)."""
    try:
        importlib.import_module("dronesim.coordinator.engine")
        return
    except ModuleNotFoundError:
        pass
    import dronesim

    pkg = types.ModuleType("dronesim.coordinator")
    pkg.__path__ = [str(ROOT / "coordinator")]  # type: ignore[attr-defined]
    pkg.__package__ = "dronesim.coordinator"
    sys.modules["dronesim.coordinator"] = pkg
    dronesim.coordinator = pkg  # type: ignore[attr-defined]
    importlib.import_module("dronesim.coordinator.engine")


_ensure_coordinator_importable()

from dronesim.schema.samples import SAMPLES, VECTORS_PATH  # noqa: E402

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
