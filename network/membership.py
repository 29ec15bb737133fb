"""What every entity process does the same way: connect (admission), stay admitted when the coordinator restarts or a
link is cut, and wait for another entity's presence. Each role's protocol is a pure class (coordinator/engine.py,
entities/environment.py, entities/drone.py, entities/gcs.py); its Zenoh adapter (coordinator/node.py,
entities/*_node.py) connects with this module and screens the coordinator's messages with its
`TurnClock` (network/clock.py)."""

from __future__ import annotations

import logging
import threading
import time

import zenoh

from network.clock import TurnClock
from network.transport import Inbox, Presence, Received, ask
from schema import Connect, Keys, Over, Refused, Status, Turn, Welcome
from schema.errors import RejectCounter, RemoteInputError, UsageError
from schema.tuning import CONNECT_TIMEOUT_S, COORDINATOR_GRACE_S


class NotAdmitted(UsageError):
    """The coordinator refused this entity (e.g. its role is already taken)."""


def admit(session: zenoh.Session, keys: Keys, hello: Connect, logger: logging.Logger, *,
          timeout: float) -> tuple[Welcome, str]:
    """Send CONNECT and wait for the coordinator's answer (waiting for it to appear, until `timeout`): its
    Welcome, and the session id of the coordinator that admitted this entity."""
    end = time.monotonic() + timeout
    while True:
        try:
            reply, coordinator = ask(session, keys.connect, hello, (Welcome, Refused),
                                     timeout=max(0.1, end - time.monotonic()))
            break
        except (TimeoutError, RemoteInputError) as err:
            if time.monotonic() >= end:
                raise UsageError(f"no coordinator answered on {keys.connect}: {err}") from None
            # No queryable yet: wait for the coordinator's presence token instead of polling blindly.
            await_presence(session, keys.alive_of("SRV"), end - time.monotonic())
    if isinstance(reply, Refused):
        raise NotAdmitted(f"connection refused: {reply.text}")
    assert isinstance(reply, Welcome)
    logger.info("%s", reply.text)
    return reply, coordinator


def await_presence(session: zenoh.Session, key: str, timeout: float) -> bool:
    """Block until a liveliness token matching `key` exists (True) or `timeout` passes (False)."""
    seen = threading.Event()
    sub = session.liveliness().declare_subscriber(key, lambda s: seen.set(), history=True)
    try:
        return seen.wait(max(0.0, timeout))
    finally:
        sub.undeclare()


class Membership:
    """An entity's admission, kept through a coordinator restart or a cut link. It declares the entity's
    presence token, connects, and watches the token of the coordinator that admitted it (the session that
    answered its CONNECT: another token under the coordinator's name holds nothing): when it has gone, it
    waits up to `grace` seconds for a coordinator to appear and then connects again (the coordinator re-admits
    the same process, or resumes a game from its journal). Refused then (a drone declared LOST meanwhile), the
    entity takes no further part: it says so and leaves at OVER. Feed it every `Presence` event of the inbox;
    use `timeout()` for the inbox wait and `check()` when it times out."""

    def __init__(self, session: zenoh.Session, inbox: Inbox, hello: Connect, logger: logging.Logger, *,
                 connect_timeout: float, grace: float, skips_status: bool = False) -> None:
        self.session, self.keys, self.log = session, inbox.keys, logger
        self.hello, self.grace, self.connect_timeout = hello, grace, connect_timeout
        self.token = session.liveliness().declare_token(self.keys.alive(hello.sender, hello.session))
        inbox.watch_presence("SRV")
        self.welcome, self.coordinator = admit(session, self.keys, hello, logger, timeout=connect_timeout)
        # the coordinator's messages pass through its clock (`screen`)
        self.clock = TurnClock(game=self.welcome.game, skips_status=skips_status)
        self._lost_since: float | None = None

    def on_presence(self, event: Presence) -> Welcome | None:
        """Track the coordinator; returns the new Welcome when this entity was admitted again."""
        if event.entity != "SRV":
            return None
        if event.alive and self._lost_since is not None:
            self._lost_since = None
            self.log.warning("the coordinator is back: connecting again")
            try:
                self.welcome, self.coordinator = admit(self.session, self.keys, self.hello, self.log,
                                                      timeout=self.connect_timeout)
            except NotAdmitted as err:
                self.log.warning("%s: %s takes no further part and leaves at the end of the game",
                                 err, self.hello.sender)
                return None
            self.clock = TurnClock(self.welcome.turn, game=self.welcome.game, skips_status=self.clock.skips_status)
            return self.welcome
        if not event.alive and event.session == (self.coordinator or event.session) and self._lost_since is None:
            self._lost_since = time.monotonic()  # (the one that admitted it; any, if Zenoh did not say which)
            self.log.warning("the coordinator vanished: waiting up to %g s for it to come back", self.grace)
        return None

    def timeout(self) -> float | None:
        """How long the inbox may wait for the next event (None: no limit while the coordinator is there)."""
        return None if self._lost_since is None else max(0.0, self._lost_since + self.grace - time.monotonic())

    def check(self) -> None:
        """Raise a UsageError once the grace period is over."""
        if self.timeout() == 0.0:
            raise UsageError(f"the coordinator vanished and did not come back within {self.grace:g} s")

    def close(self) -> None:
        self.token.undeclare()

    def screen(self, event: object, rejects: RejectCounter) -> bool:
        """False (the rejection counted and logged) for a coordinator message that fails `admit`."""
        if isinstance(event, Received) and isinstance(event.msg, (Turn, Status, Over)):
            try:
                self.clock.admit(event.msg)
            except RemoteInputError as err:
                rejects.reject(event.key, err)
                return False
        return True


def add_entity_args(parser) -> None:
    """Flags every entity process shares."""
    g = parser.add_argument_group("membership")
    g.add_argument("--connect-timeout", type=float, default=CONNECT_TIMEOUT_S,
                   help=f"seconds to wait for the coordinator to admit this entity (default {CONNECT_TIMEOUT_S:g})")
    g.add_argument("--grace", type=float, default=COORDINATOR_GRACE_S,
                   help=f"seconds to wait for a vanished coordinator to come back (default {COORDINATOR_GRACE_S:g})")
