"""dronesim: a distributed, deterministic, turn-based multi-drone simulator over Eclipse Zenoh."""

from __future__ import annotations

import os
from pathlib import Path

__version__ = "0.1.0"

#: The folder holding the packages dronesim/, schema/, coordinator/, entities/ and benchmarks/: the
#: repository's root in a clone, site-packages once installed.
SOURCE_ROOT = Path(__file__).resolve().parent.parent


def child_env(**extra: str) -> dict[str, str]:
    """The environment for a child `python -m dronesim ...`: it imports the very code its parent runs
    (a clone runs without installing, and a worktree never picks up another checkout's install)."""
    path = os.environ.get("PYTHONPATH", "")
    parts = [str(SOURCE_ROOT), *(p for p in path.split(os.pathsep) if p and p != str(SOURCE_ROOT))]
    return dict(os.environ, PYTHONPATH=os.pathsep.join(parts), **extra)
