"""The error hierarchy: local misuse versus bad remote input.

`UsageError` means *this* process was called wrongly (bad flag, bad file, a programming error):
it is raised to the caller and usually ends the command with a clear message.

`RemoteInputError` means a message from the network was unacceptable. Adapters catch it, log the
reason, count it (see `RejectCounter`) and change nothing: a remote peer can never crash a process.
"""

from __future__ import annotations

import collections
import logging
import threading


class DronesimError(Exception):
    """Base class of every error this project raises on purpose."""


class UsageError(DronesimError):
    """Local misuse: a wrong argument, an unreadable file, an impossible configuration."""


class RemoteInputError(DronesimError):
    """A message received from the network that cannot be accepted.

    `reason` is a short stable slug used as the counter key (e.g. ``malformed``, ``stale-turn``).
    """

    reason = "rejected"

    def __init__(self, detail: str, *, reason: str | None = None) -> None:
        super().__init__(detail)
        if reason is not None:
            self.reason = reason
        #: Effects that still follow although this input was refused (a state machine may set it: e.g. the
        #: refused message was the last one a phase awaited, so the phase ends). The adapter carries them out.
        self.follow: list = []


class MalformedMessage(RemoteInputError):
    """Bytes that do not decode to a valid message of the expected type."""

    reason = "malformed"


class WrongSender(RemoteInputError):
    """A message whose sender is not allowed to say it on that key."""

    reason = "wrong-sender"


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
    """Thread-safe count of rejected remote inputs by reason, logging each one.

    Zenoh callbacks run on other threads, hence the lock.
    """

    def __init__(self, logger: logging.Logger) -> None:
        self._log = logger
        self._lock = threading.Lock()
        self._counts: collections.Counter[str] = collections.Counter()

    def reject(self, where: str, err: RemoteInputError) -> None:
        with self._lock:
            self._counts[err.reason] += 1
        self._log.warning("rejected %s: %s (%s)", where, err, err.reason)

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)
