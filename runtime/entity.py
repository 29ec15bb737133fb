"""What every entity process does the same way: connect (admission), watch for OVER, and decide
how a run ends. The role-specific loops live in entities/*_node.py."""

from __future__ import annotations

import logging

import zenoh

from dronesim.schema import Connect, Keys, Refused, RemoteInputError, UsageError, Welcome
from dronesim.transport import request


class Refusal(UsageError):
    """The coordinator refused this entity (e.g. its role is already taken)."""


def admit(session: zenoh.Session, keys: Keys, hello: Connect, logger: logging.Logger, *,
          timeout: float) -> Welcome:
    """Send CONNECT, wait for the coordinator's answer (retrying until `timeout` if it is not up yet)."""
    import time

    end = time.monotonic() + timeout
    while True:
        try:
            reply = request(session, keys.connect, hello, (Welcome, Refused), timeout=max(0.1, end - time.monotonic()))
            break
        except (TimeoutError, RemoteInputError) as err:
            if time.monotonic() >= end:
                raise UsageError(f"no coordinator answered on {keys.connect}: {err}") from None
            # No queryable yet: wait for the coordinator's presence token instead of polling blindly.
            _await_token(session, keys.alive("SRV"), end - time.monotonic())
    match reply:
        case Refused(text=text):
            raise Refusal(f"connection refused: {text}")
        case Welcome():
            logger.info("%s", reply.text)
            return reply
    raise AssertionError(reply)


def _await_token(session: zenoh.Session, key: str, timeout: float) -> None:
    import threading

    seen = threading.Event()
    sub = session.liveliness().declare_subscriber(key, lambda s: seen.set(), history=True)
    try:
        seen.wait(max(0.0, timeout))
    finally:
        sub.undeclare()
