"""The environment process (the seed's ENV): the Zenoh adapter of `EnvironmentProcess`
(entities/environment.py, which says what it does).

It serves ASK (ENV/ASK) and the static map (ENV/MAP) and hears OVER. It reads the newest STATUS before each query
(Zenoh keeps it: nothing wakes the process for one), or takes every STATUS once the core follows them, and the ENV
phase's TURN while someone listens to its UPD (a matching listener says when); it publishes the UPD.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable

import zenoh

from network.membership import Answered, Membership, add_entity_args
from network.signals import closing, until_stopped
from network.transport import (
    Asked,
    Event,
    Inbox,
    Matching,
    Outbox,
    Presence,
    Received,
    add_zenoh_args,
    open_session,
    session_id,
    setup_logging,
    zenoh_config,
)
from schema import Ask, Connect, Keys, MapRequest, Over, Phase, Role, Status, Turn, UsageError, encode
from schema.tuning import CONNECT_TIMEOUT_S, COORDINATOR_GRACE_S

from .environment import Effect, EnvironmentProcess, Fail, Follow, Refusal, ReplyToQuery, Report


def main(conf: zenoh.Config, *, keys: Keys, logger: logging.Logger, draw: bool = True,
         connect_timeout: float = CONNECT_TIMEOUT_S, grace: float = COORDINATOR_GRACE_S, follow: bool = False) -> Over:
    with open_session(conf) as session:
        inbox = Inbox(session, keys, logger)
        newest = inbox.newest(keys.status, Status)  # (handed to the core before each query, unless followed)
        inbox.subscribe(keys.over, Over)
        inbox.serve(keys.ask, Ask)
        inbox.serve(keys.map, MapRequest)
        member = Membership(session, inbox, Connect(turn=0, sender="ENV", role=Role.ENV, session=session_id(session)),
                            logger, connect_timeout=connect_timeout, grace=grace, skips_status=True)
        env = EnvironmentProcess(member.welcome, follow=follow)
        if draw:
            print(env.drawing(), flush=True)
        effects = Effects(inbox, Outbox(session), newest)
        effects.run(env.start())

        def handle(event: Event | None) -> None:
            if not member.screen(event, inbox.rejects):
                return
            match event:
                case None:
                    member.check()
                case Presence() | Answered():
                    member.on_event(event)  # the world stays; the next STATUS resyncs the drones
                case Matching(matching=matching):
                    effects.run(env.listened(matching))
                case Asked(query, Ask() | MapRequest() as msg):  # the queryables serve these alone
                    if not effects.follows(keys.status) and (status := newest()) is not None:
                        handle(status)  # the newest STATUS, if one came since the last query
                    effects.run(env.asked(query, msg))
                case Received(_, Status() | Turn() | Over() as msg):  # the subscriptions take these alone
                    effects.run(env.receive(msg))

        effects.out.watch(keys.upd, inbox)  # (a first Matching event at once if someone already listens)
        inbox.run(handle, timeout=member.timeout, until=lambda: env.over is not None)
        closing(env.over)  # (a signal from now on: the game's status, not 143)
        for event in inbox.drain():  # the queries still queued at the end get their answer
            handle(event)
        member.close()
        inbox.rejects.flush(everything=True)
        if inbox.rejects.total:
            logger.info("rejected inputs: %s", inbox.rejects.report())
    assert env.over is not None
    logger.info("OVER: %s", env.over.text)
    return env.over


class Effects:
    """Carries out the environment's effects. As it starts following STATUS, the newest one (`newest`: one that came
    before the subscription) is queued first."""

    def __init__(self, inbox: Inbox, out: Outbox, newest: Callable[[], Received | None]) -> None:
        self.inbox, self.out, self.keys, self.newest = inbox, out, inbox.keys, newest
        self._subs: dict[str, zenoh.Subscriber] = {}  # the keys followed: STATUS, the ENV phase's TURN

    def follows(self, key: str) -> bool:
        return key in self._subs

    def run(self, effects: list[Effect]) -> None:
        for eff in effects:
            match eff:
                case ReplyToQuery(zenoh.Query() as query, msg):  # the core holds the query it was given: a zenoh.Query
                    query.reply(query.key_expr, encode(msg))
                    query.drop()
                case Fail(zenoh.Query() as query, why):
                    query.reply_err(why.encode())
                    query.drop()
                case Report(msg):
                    self.out.put(self.keys.upd, msg)
                case Follow(moves, status):
                    self._follow(self.keys.turn_of(Phase.ENV), Turn, moves)
                    if self._follow(self.keys.status, Status, status) and (newest := self.newest()) is not None:
                        self.inbox.post(newest)
                case Refusal(what, err):
                    self.inbox.rejects.reject(what, err)

    def _follow(self, key: str, kind: type[Status] | type[Turn], on: bool) -> bool:
        """Subscribe to `key` (`on`) or stop, if not done already; whether it subscribed now."""
        if on == self.follows(key):
            return False
        if on:
            self._subs[key] = self.inbox.subscribe(key, kind)
        else:
            self.inbox.unsubscribe(self._subs.pop(key))
        return on


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim env", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--no-draw", action="store_true", help="do not print the world at start")
    p.add_argument("--follow-status", action="store_true",
                   help="take every STATUS as it comes, not only the newest when a query needs it (to measure that)")
    add_entity_args(p)
    args = p.parse_args(argv)
    logger = setup_logging(args.log_level, "ENV")
    try:
        return until_stopped(lambda: main(zenoh_config(args), keys=Keys(args.root), logger=logger,
                                          draw=not args.no_draw, connect_timeout=args.connect_timeout,
                                          grace=args.grace, follow=args.follow_status), logger)
    except UsageError as err:
        logger.error("%s", err)
        return 2


if __name__ == "__main__":
    sys.exit(cli())
