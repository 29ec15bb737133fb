"""What every entity process does the same way: connect (admission), stay admitted when the coordinator restarts or a
link is cut, and wait for another entity's presence. Each role's protocol is a pure class (coordinator/engine.py,
entities/environment.py, entities/drone.py, entities/gcs.py); its Zenoh adapter (coordinator/node.py,
entities/*_node.py) connects with this module and screens the coordinator's messages with its
`TurnClock` (network/clock.py)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from network.clock import TurnClock
from network.progress import Progress
from network.transport import Inbox, Presence, Received, ask_later
from schema import Connect, Message, Over, Refused, Status, Turn, Welcome
from schema.errors import RejectCounter, RemoteInputError, UsageError, seconds
from schema.tuning import CONNECT_GAP, CONNECT_TIMEOUT_S, COORDINATOR_GRACE_S, PROCESS_CHECK_S


class NotAdmitted(UsageError):
    """The coordinator refused this entity (e.g. its role is already taken)."""


@dataclass(frozen=True, slots=True)
class Answered:
    """The coordinator's answer to this entity's CONNECT, an event of its inbox (posted by the query's callback):
    a Welcome or Refused (`reply`) from the session `coordinator`, or None and why none came (`error`)."""

    reply: Message | None
    coordinator: str = ""
    error: str = ""


class Membership:
    """An entity's admission, kept through a coordinator restart or a cut link. It declares the entity's
    presence token, connects, and watches the token of the coordinator that admitted it (the session that
    answered its CONNECT: another token under the coordinator's name holds nothing): when it has gone, it
    waits up to `grace` seconds to be admitted again, connecting again as soon as a coordinator's token appears
    (the coordinator re-admits the same process, or resumes a game from its journal); only an answer ends the
    wait, never a token alone, which may be anyone's. Refused then (a drone declared LOST meanwhile), the
    entity takes no further part: it says so and leaves at OVER. Admission is events on the entity's main loop,
    never a blocking wait: the CONNECT's answer comes as an `Answered` event of the inbox, the coordinator's
    presence as `Presence` events (a signal wakes the loop at once). Feed it every `Presence` and `Answered`
    event (`on_event`); use `timeout()` for the inbox wait and `check()` when it times out."""

    def __init__(self, session: zenoh.Session, inbox: Inbox, hello: Connect, logger: logging.Logger, *,
                 connect_timeout: float, grace: float, skips_status: bool = False,
                 check: Callable[[], None] | None = None) -> None:
        """Connect, taking the inbox's events until admitted (those not about admission are held for the entity's
        loop, `Inbox.hold`); UsageError if no coordinator answered within `connect_timeout`, NotAdmitted if refused.
        `check`: called every PROCESS_CHECK_S without an event meanwhile (it raises to give up: a process the
        caller started has died)."""
        self.session, self.inbox, self.keys, self.log = session, inbox, inbox.keys, logger
        self.hello, self.grace, self.connect_timeout = hello, grace, connect_timeout
        self.token = session.liveliness().declare_token(self.keys.alive(hello.sender, hello.session))
        self.coordinator, self._present, self._asking, self._closed = "", False, False, False
        # the sessions with a coordinator's presence token, as this loop has heard them (`Presence` events): an
        # answer to CONNECT counts only from one of them, and CONNECT is sent only once one is known (so the
        # genuine answer never comes ahead of its sender's token)
        self._coordinators: set[str] = set()
        self._lost_since: float | None = None
        self._asked_at = time.monotonic()  # when the last CONNECT left: its WELCOME's turn anchors the turn clock
        self.progress = Progress.from_environment()  # for a health check (docker/healthcheck.py)
        self.progress.note("connecting", 0, "the coordinator")
        inbox.watch_presence("SRV")
        end, held, welcome = time.monotonic() + connect_timeout, [], None
        while welcome is None:
            left = max(0.0, end - time.monotonic())
            event = inbox.get(left if check is None else min(left, PROCESS_CHECK_S))
            if event is None and time.monotonic() >= end:
                raise UsageError(f"no coordinator answered on {self.keys.connect} within {connect_timeout:g} s")
            if event is None and check is not None:
                check()
            if isinstance(event, Answered):
                welcome = self._answered(event)
            elif isinstance(event, Presence) and event.entity == "SRV":
                self._seen(event)
            elif event is not None:
                held.append(event)
        inbox.hold(held)
        self.welcome: Welcome = welcome
        self.progress.note("admitted", welcome.turn)
        # the coordinator's messages pass through its clock (`screen`)
        self.clock: TurnClock = TurnClock(game=welcome.game, skips_status=skips_status, now=self._asked_at,
                                          known=welcome.turn)

    def _from_coordinator(self, replier: str) -> bool:  # (on Zenoh's thread)
        """Whether an answer to CONNECT comes from a session with a coordinator's presence token (on a plain router
        anyone may answer: a forged REFUSED must not send the entity away, nor a forged WELCOME keep it)."""
        if replier in self._coordinators:
            return True
        self.log.warning("an answer to CONNECT from session %s, which has no coordinator's presence: ignored",
                         replier or "(unknown)")
        return False

    def _connect(self) -> None:
        """Send CONNECT, `CONNECT_GAP` s after this session's last at least (later, from a timer's thread: a router
        keeps at most `CONNECT_RATE` a second from one session, `schema.acl.flood_filters`); its answer comes as an
        `Answered` event."""
        self._asking = True
        now = time.monotonic()  # (the session's inbox keeps when its next CONNECT may go, for every membership)
        wait = self.inbox.next_connect - now
        self.inbox.next_connect = max(now, self.inbox.next_connect) + CONNECT_GAP
        if wait <= 0:
            self._ask()
            return
        timer = threading.Timer(wait, self._ask)
        timer.daemon = True
        timer.start()

    def _ask(self) -> None:
        if self._closed:
            return
        self._asked_at = time.monotonic()
        ask_later(self.session, self.keys.connect, self.hello, (Welcome, Refused), self.connect_timeout,
                  lambda reply, coordinator, error: self.inbox.post(Answered(reply, coordinator, error)),
                  accept=self._from_coordinator)

    def _track(self, event: Presence) -> None:
        """Note a coordinator's token that came or went (the sessions whose answers to CONNECT count)."""
        self._present = event.alive
        if event.alive:
            self._coordinators.add(event.session)
        else:
            self._coordinators.discard(event.session)

    def _seen(self, event: Presence) -> None:
        """A coordinator's token came or went: one that appears is asked (again) if no CONNECT is out."""
        self._track(event)
        if event.alive and not self._asking:
            self._connect()

    def _answered(self, event: Answered) -> Welcome | None:
        """The CONNECT's answer: the Welcome; None if none came (asked again at once while a coordinator's token
        is there, else when one appears); NotAdmitted if refused."""
        self._asking = False
        if isinstance(event.reply, Refused):
            raise NotAdmitted(f"connection refused: {event.reply.text}")
        if not isinstance(event.reply, Welcome):
            self.log.debug("CONNECT unanswered (%s)%s", event.error, ": asking again" if self._present else "")
            if self._present:
                self._connect()
            return None
        self.log.info("%s", event.reply.text)
        self.coordinator = event.coordinator
        return event.reply

    def on_event(self, event: Presence | Answered) -> Welcome | None:
        """Track the coordinator (its `Presence`), connect again when it is back, and take the answer (`Answered`):
        the new Welcome when this entity was admitted again."""
        if isinstance(event, Answered):
            try:
                welcome = self._answered(event)
            except NotAdmitted as err:
                self._lost_since = None  # (a coordinator answered: it is back, the entity waits for its OVER)
                self.log.warning("%s: %s takes no further part and leaves at the end of the game",
                                 err, self.hello.sender)
                self.progress.note("refused", self.welcome.turn, str(err))
                return None
            if welcome is not None:
                self._lost_since = None  # (admitted again: the grace is over)
                self.welcome = welcome
                self.progress.note("admitted", welcome.turn)
                self.clock = TurnClock(welcome.turn, game=welcome.game, skips_status=self.clock.skips_status,
                                       now=self._asked_at)
            return welcome
        if event.entity != "SRV":
            return None
        self._track(event)
        if event.alive and self._lost_since is not None:
            # its grace runs on until a coordinator admits this entity again: a token alone may be anyone's (a
            # foreign one appearing just after the coordinator died kept the entities waiting without end)
            self.log.warning("the coordinator is back: connecting again")
            if not self._asking:
                self._connect()
        elif not event.alive and event.session == (self.coordinator or event.session) and self._lost_since is None:
            self._lost_since = time.monotonic()  # (the one that admitted it; any, if Zenoh did not say which)
            self.log.warning("the coordinator vanished: waiting up to %g s for it to come back", self.grace)
            self.progress.note("waiting", self.welcome.turn, "the coordinator, which vanished")
        return None

    def timeout(self) -> float | None:
        """How long the inbox may wait for the next event (None: no limit while admitted)."""
        return None if self._lost_since is None else max(0.0, self._lost_since + self.grace - time.monotonic())

    def check(self) -> None:
        """Raise a UsageError once the grace period is over."""
        if self.timeout() == 0.0:
            raise UsageError(f"the coordinator vanished and did not come back within {self.grace:g} s")

    def close(self) -> None:
        self._closed = True
        self.token.undeclare()

    def screen(self, event: object, rejects: RejectCounter) -> bool:
        """False (the rejection counted and logged) for a coordinator message that fails `admit`."""
        if isinstance(event, Received) and isinstance(event.msg, (Turn, Status, Over)):
            try:
                self.clock.admit(event.msg, time.monotonic())
            except RemoteInputError as err:
                rejects.reject(event.key, err)
                return False
            self.progress.note("over" if isinstance(event.msg, Over) else "playing", event.msg.turn)
        return True


def add_entity_args(parser) -> None:
    """Flags every entity process shares."""
    g = parser.add_argument_group("membership")
    g.add_argument("--connect-timeout", type=seconds, default=CONNECT_TIMEOUT_S,
                   help=f"seconds to wait for the coordinator to admit this entity (default {CONNECT_TIMEOUT_S:g})")
    g.add_argument("--grace", type=seconds, default=COORDINATOR_GRACE_S,
                   help=f"seconds to wait for a vanished coordinator to come back (default {COORDINATOR_GRACE_S:g})")
