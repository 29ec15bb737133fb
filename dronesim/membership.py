"""What every entity process does the same way: connect (admission), stay admitted when the coordinator restarts or a
link is cut, and wait for another entity's presence. Each role's protocol is a pure class (coordinator/engine.py,
entities/environment.py, entities/drone.py, entities/gcs.py); its Zenoh adapter (coordinator/node.py,
entities/*_node.py) connects with this module and screens the coordinator's messages with its `TurnClock`."""

from __future__ import annotations

import logging
import threading
import time

import zenoh

from dronesim.transport import Inbox, Presence, Received, ask
from schema import Connect, Keys, Message, Over, Refused, Status, Turn, Welcome
from schema.errors import RejectCounter, RemoteInputError, StaleTurn, UsageError


class Refusal(UsageError):
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
        raise Refusal(f"connection refused: {reply.text}")
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
            except Refusal as err:
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


def add_entity_args(parser) -> None:
    """Flags every entity process shares."""
    g = parser.add_argument_group("membership")
    g.add_argument("--connect-timeout", type=float, default=30.0,
                   help="seconds to wait for the coordinator to admit this entity (default 30)")
    g.add_argument("--grace", type=float, default=30.0,
                   help="seconds to wait for a vanished coordinator to come back (default 30)")


class TurnClock:
    """The turn an entity believes the game is at, learnt from the coordinator's TURN, STATUS and OVER.

    Once it has seen one, it refuses those messages when they cannot be current (a replayed or garbled TURN
    must not make a drone plan, nor a STATUS move the world): a TURN for a past turn or one more than a turn
    ahead, a STATUS for other than the turn just played (or a repeat of the one before), an OVER far from now,
    or a repeat (same message, phase and turn) that differs from the first (a repeat re-sent to a process that
    connected again is identical and passes). TURN(t) and STATUS(t - 1) are current while turn t is played; so
    are OVER(t - 1) after STATUS(t - 1) and OVER of any later turn (a frozen process learns the end late). Each
    must be of this entity's `game` (from its WELCOME): another game's, or an earlier coordinator's, is foreign,
    whatever its turn. (A forged message for the right turn is spoofing: the router's access control stops it.)
    With `skips_status` (the environment, which reads only the newest STATUS, when it needs one), a STATUS of any
    later turn is current too."""

    def __init__(self, turn: int | None = None, *, game: str = "", skips_status: bool = False) -> None:
        self.turn: int | None = turn or None  # the turn being played (after STATUS(t): t + 1, the next)
        self.game, self.skips_status = game, skips_status
        self._seen: dict[tuple[str, object, int], Message] = {}

    def admit(self, msg: Turn | Status | Over) -> None:
        """Check `msg` against the clock (StaleTurn if it cannot be current) and advance the clock."""
        if msg.game != self.game:
            raise StaleTurn(f"a {msg.TAG} of game {msg.game or '(none)'}, not this one ({self.game or '(none)'})",
                            reason="foreign-game")
        now = msg.turn + 1 if isinstance(msg, Status) else msg.turn
        if self.turn is not None:  # (STATUS(t) makes t + 1 "now"; the end may come at any turn)
            lo, hi = (self.turn - 1, float("inf")) if isinstance(msg, Over) else (self.turn, self.turn + 1)
            if self.skips_status and isinstance(msg, Status):
                hi = float("inf")
            if not lo <= now <= hi:
                raise StaleTurn(f"{msg.TAG} for turn {msg.turn} while the game is at turn {self.turn}")
        key = (msg.TAG, getattr(msg, "phase", None), msg.turn)
        if self._seen.get(key, msg) != msg:
            raise StaleTurn(f"a {msg.TAG} for turn {msg.turn} that contradicts the one received before",
                            reason="contradiction")
        self._seen = {k: m for k, m in self._seen.items() if k[2] >= now - 1}  # keep this turn and the last
        self._seen[key] = msg
        self.turn = now if self.turn is None else max(self.turn, now)

    def screen(self, event: object, rejects: RejectCounter) -> bool:
        """False (the rejection counted and logged) for a coordinator message that fails `admit`."""
        if isinstance(event, Received) and isinstance(event.msg, (Turn, Status, Over)):
            try:
                self.admit(event.msg)
            except RemoteInputError as err:
                rejects.reject(event.key, err)
                return False
        return True
