"""The ground station's link to the game, shared by every face of it (terminal, web page): `listen` and `join`
connect a station, `play` feeds it every event on the main thread (Zenoh's callbacks only decode and queue) and
carries out its effects through `publisher`."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import zenoh

from network.membership import Answered, Membership
from network.transport import Inbox, Outbox, Presence, Received, session_id
from schema import Connect, Keys, Over, Phase, Role, Status, Turn, Welcome

from .gcs import Effect, End, SendDone, Show


class Core(Protocol):
    """What `play` drives: a station's protocol (`entities.gcs.Station`, the web page's `GroundState`)."""

    def wake(self, now: float) -> float | None: ...
    def admitted(self, welcome: Welcome) -> Sequence[object]: ...
    def receive(self, msg: Any, now: float) -> Sequence[object]: ...
    def tick(self, now: float) -> Sequence[object]: ...


def listen(session: zenoh.Session, keys: Keys, logger: logging.Logger, *, every_phase: bool = False) -> Inbox:
    """An inbox of what a ground station hears: TURN (of its phase, or of every phase), STATUS and OVER."""
    inbox = Inbox(session, keys, logger)
    inbox.subscribe(keys.turn if every_phase else keys.turn_of(Phase.GCS), Turn)
    inbox.subscribe(keys.status, Status)
    inbox.subscribe(keys.over, Over)
    return inbox


def join(session: zenoh.Session, inbox: Inbox, logger: logging.Logger, *, connect_timeout: float,
         grace: float) -> Membership:
    hello = Connect(turn=0, sender="GCS", role=Role.GCS, session=session_id(session))
    return Membership(session, inbox, hello, logger, connect_timeout=connect_timeout, grace=grace)


def publisher(out: Outbox, keys: Keys, logger: logging.Logger,
              show: Callable[[str], None]) -> Callable[[Effect], None]:
    """Carries out a station's effects: a DONE is published, a text shown."""
    def perform(effect: Effect) -> None:
        match effect:
            case SendDone(msg, ahead):
                out.put(keys.gcs_done, msg)
                logger.debug("answered turn %d%s: %d targets, %s", msg.turn, " ahead" if ahead else "",
                             len(msg.targets), msg.intent.value)
            case Show(text):
                show(text)
    return perform


def play(core: Core, inbox: Inbox, member: Membership, perform: Callable[[Any], None],
         other: Callable[[object], None] = lambda event: None) -> Over:
    """Feed `core` every event, on this thread, until it ends; `other` takes the events posted by this
    process (the web page's commands). Returns the game's OVER."""
    while True:
        waits = [w for w in (core.wake(time.monotonic()), member.timeout()) if w is not None]
        event = inbox.get(min(waits) if waits else None)
        if not member.screen(event, inbox.rejects):
            continue
        now = time.monotonic()
        effects: Sequence[object] = []
        match event:
            case None:
                member.check()
            case Presence() | Answered():
                if (welcome := member.on_event(event)) is not None:
                    effects = core.admitted(welcome)
            case Received(_, msg):
                effects = core.receive(msg, now)
            case _:
                other(event)
        for effect in [*effects, *core.tick(now)]:
            perform(effect)
            if isinstance(effect, End):
                return effect.over
