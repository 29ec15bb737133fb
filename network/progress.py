"""Where a process stands in its game, for a health check in another process (docker/healthcheck.py reads it).

A process notes each step (`Progress.note`: a stage, the turn, whom it waits for); the file named by
``DRONESIM_PROGRESS`` (the image sets it; unset, nothing is written) then holds the last step and since when it
stands there, replaced atomically, and rewritten only when the step changes. What each stage means to the
health check is docker/healthcheck.py's business (docs/docker.md, Health checks).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from pathlib import Path

#: The environment variable naming the file (unset: no file).
PROGRESS_ENV = "DRONESIM_PROGRESS"


class Progress:
    """The last step of this process, written to `path` when it changes (no `path`: nothing is written)."""

    def __init__(self, path: str | os.PathLike[str] | None, clock: Callable[[], float] = time.time) -> None:
        self.path, self.clock = (Path(path) if path else None), clock
        self._step: tuple[str, int, str] | None = None

    @classmethod
    def from_environment(cls) -> Progress:
        return cls(os.environ.get(PROGRESS_ENV) or None)

    def note(self, stage: str, turn: int, waiting: str = "") -> None:
        """This process is at `stage` of `turn`, waiting for `waiting` (who, in words; "" if nobody in
        particular). Written only when the step differs from the last one: `since` is when it began."""
        step = (stage, turn, waiting)
        if self.path is None or step == self._step:
            return
        self._step = step
        data = {"stage": stage, "turn": turn, "waiting": waiting, "since": self.clock(), "pid": os.getpid()}
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            tmp.write_text(json.dumps(data))
            tmp.replace(self.path)
        except OSError:  # a report for the health check must never stop the game
            self._step = None


def read_progress(path: str | os.PathLike[str]) -> dict | None:
    """The last step written to `path`; None if there is none (or it cannot be read)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None
