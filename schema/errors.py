"""The error hierarchy: local misuse (`UsageError`) is raised to the caller, and usually ends the command with a
clear message; bad remote input (`RemoteInputError`) is caught by the adapters, which log its reason, count it
(`RejectCounter`) and change nothing: a remote peer never crashes a process.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable

from .tuning import MAX_WAIT_S, REJECT_EXCERPT, REJECT_LOG_FIRST, REJECT_LOG_WINDOW, REJECT_ORIGINS


class UsageError(Exception):
    """Local misuse: a wrong argument, an unreadable file, an impossible configuration."""


def seconds(text: str) -> float:
    """argparse's type of a flag that gives a wait (a deadline, a grace, a pace, a lease): a number of seconds in
    0..`MAX_WAIT_S`, not nan nor inf (argparse ends the command with its usage and this error, status 2)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(value) and 0 <= value <= MAX_WAIT_S):
        raise argparse.ArgumentTypeError(f"{text!r}: seconds must be in 0..{MAX_WAIT_S:g} (a day)")
    return value


class RemoteInputError(Exception):
    """A message received from the network that cannot be accepted; `reason`, a short stable slug, is the
    counter key (e.g. ``malformed``, ``stale-turn``)."""

    reason = "rejected"

    def __init__(self, detail: str, *, reason: str | None = None) -> None:
        super().__init__(detail)
        if reason is not None:
            self.reason = reason


class MalformedMessage(RemoteInputError):
    """Bytes that do not decode to a valid message of the expected type."""

    reason = "malformed"


class WrongSender(RemoteInputError):
    """A message whose sender is not allowed to say it on that key."""

    reason = "wrong-sender"


@dataclasses.dataclass(frozen=True, slots=True)
class Refusal:
    """An effect of every pure core (the engine, the environment, the drone process): remote input it
    refused, having changed nothing. `what` names the input; the adapter counts and logs `err`. Refusals are
    effects like the others, in order: a refused message may still end the phase that awaited it."""

    what: str
    err: RemoteInputError


class StaleTurn(RemoteInputError):
    """A message for a turn or phase that is not the current one."""

    reason = "stale-turn"


class OutOfRange(RemoteInputError):
    """A cell, target or move outside what the world or the rules allow."""

    reason = "out-of-range"


class UnknownEntity(RemoteInputError):
    """A message naming a drone or entity that is not part of the game."""

    reason = "unknown-entity"


class RejectCounter:
    """Thread-safe count of rejected remote inputs, by reason and by origin, with a bounded log: per origin (the
    sender, or the key it came on) and reason, the first `REJECT_LOG_FIRST` rejections of each `REJECT_LOG_WINDOW`
    seconds are logged, each as a short excerpt; `flush` sums up the rest in one line once the window is over.
    Zenoh callbacks reject on their own threads, hence the lock. `wake` is called when a window starts holding
    rejections (the thread that calls `flush` may be waiting for something else)."""

    def __init__(self, logger: logging.Logger, clock: Callable[[], float] = time.monotonic, *,
                 wake: Callable[[], None] | None = None) -> None:
        self._log = logger
        self._clock = clock
        self._wake = wake
        self._lock = threading.Lock()
        self._counts: collections.Counter[str] = collections.Counter()
        self._origins: collections.Counter[str] = collections.Counter()
        self._windows: dict[tuple[str, str], _Window] = {}
        #: the windows holding rejections not logged (a summary due): `due_in` and `flush`, called by a process's
        #: loop for each event it takes, look at these alone, not at every origin's window (up to `REJECT_ORIGINS`
        #: under a flood naming a new sender each time)
        self._holding: dict[tuple[str, str], _Window] = {}

    def reject(self, where: str, err: RemoteInputError, origin: str | None = None) -> bool:
        """Count `err`, refused at `where` (a key, or what was refused), from `origin` (default: `where`; beyond
        `REJECT_ORIGINS` origins named apart, "(others)"). True if it was logged now (not held for a summary)."""
        who, now = origin or where, self._clock()
        with self._lock:
            if who not in self._origins and len(self._origins) >= REJECT_ORIGINS:
                who = OTHERS
            self._counts[err.reason] += 1
            self._origins[who] += 1
            window = self._windows.get((who, err.reason))
            if window is None or now >= window.start + REJECT_LOG_WINDOW and not window.held:
                if window is None and len(self._windows) >= REJECT_ORIGINS:  # (the windows over, holding nothing)
                    self._windows = {k: w for k, w in self._windows.items()
                                     if w.held or now < w.start + REJECT_LOG_WINDOW}
                window = self._windows[(who, err.reason)] = _Window(now)
            window.logged += 1
            first = None  # (None: logged now)
            if window.logged > REJECT_LOG_FIRST:
                window.held += 1
                window.last = (where, err)  # (formatted by `flush`: not for each of a flood's messages)
                first = window.held == 1
                if first:
                    self._holding[(who, err.reason)] = window
        if first is None:
            self._log.warning("rejected %s: %s (%s)", where, excerpt(str(err)), err.reason)
        elif first and self._wake is not None:
            self._wake()
        return first is None

    def due_in(self) -> float | None:
        """Seconds until `flush` has a summary to log (None: none held)."""
        with self._lock:
            if not self._holding:
                return None
            end = min(w.start for w in self._holding.values()) + REJECT_LOG_WINDOW
        return max(0.0, end - self._clock())

    def flush(self, everything: bool = False) -> None:
        """Log the summary of every window that is over (`everything`: of every window)."""
        now = self._clock()
        with self._lock:
            if not self._holding:
                return
            over = [(k, w) for k, w in self._holding.items() if everything or now >= w.start + REJECT_LOG_WINDOW]
            for k, _ in over:
                del self._windows[k], self._holding[k]
        for (who, reason), w in over:
            self._log.warning("rejected %d more from %s (%s) in %.1f s; the last: %s", w.held, who, reason,
                              now - w.start, excerpt(f"{w.last[0]}: {w.last[1]}"))

    @property
    def total(self) -> int:
        return sum(self.snapshot().values())

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def report(self) -> str:
        """Every rejection so far, by reason and by origin (e.g. for a process's last words)."""
        with self._lock:
            return f"{dict(self._counts)}, from {dict(self._origins.most_common())}"


#: The origin of the rejections from origins beyond the first `REJECT_ORIGINS` (`RejectCounter`).
OTHERS = "(others)"


@dataclasses.dataclass(slots=True)
class _Window:
    start: float  # when its first rejection came (the clock's seconds)
    logged: int = 0  # rejections in it
    held: int = 0  # of which not logged
    last: tuple[str, object] = ("", "")  # the last one held: where, what (the error)


def excerpt(text: str) -> str:
    """`text`, cut to `REJECT_EXCERPT` characters (saying how long it was)."""
    return text if len(text) <= REJECT_EXCERPT else f"{text[:REJECT_EXCERPT]}... ({len(text)} characters)"
