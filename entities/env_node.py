"""The environment process (the seed's ENV): the Zenoh adapter of `EnvironmentProcess`
(entities/environment.py, which says what it does).

It serves ASK (ENV/ASK) and the static map (ENV/MAP), hears STATUS and OVER, the ENV phase's TURN while
someone listens to its UPD (a matching listener says when), and publishes the UPD.
"""

from __future__ import annotations

import argparse
import functools
import logging
import sys

import zenoh

from dronesim.membership import Membership, add_entity_args
from dronesim.signals import until_stopped
from dronesim.transport import (
    Asked,
    Event,
    Inbox,
    Matching,
    Outbox,
    Presence,
    Received,
    add_zenoh_args,
    session_id,
    setup_logging,
    zenoh_config,
)
from schema import Ask, Connect, Keys, MapRequest, Over, Phase, Role, Status, Turn, UsageError, encode

from .environment import Effect, EnvironmentProcess, Fail, Follow, Refusal, Reply, Report


def main(conf: zenoh.Config, *, keys: Keys, logger: logging.Logger, draw: bool = True,
         connect_timeout: float = 30.0, grace: float = 30.0) -> Over:
    with zenoh.open(conf) as session:
        inbox, out = Inbox(session, keys, logger), Outbox(session)
        inbox.subscribe(keys.status, Status)
        inbox.subscribe(keys.over, Over)
        inbox.serve(keys.ask, Ask)
        inbox.serve(keys.map, MapRequest)
        member = Membership(session, inbox, Connect(turn=0, sender="ENV", role=Role.ENV, session=session_id(session)),
                            logger, connect_timeout=connect_timeout, grace=grace)
        env = EnvironmentProcess(member.welcome)
        if draw:
            print(env.drawing(), flush=True)
        out.watch(keys.upd, inbox)  # (a first Matching event at once if someone already listens)

        def handle(event: Event | None) -> None:
            if not member.clock.screen(event, inbox.rejects):
                return
            match event:
                case None:
                    member.check()
                case Presence() as presence:
                    member.on_presence(presence)  # the world stays; the next STATUS resyncs the drones
                case Matching(matching=matching):
                    carry_out(env.listened(matching))
                case Asked(query, Ask() | MapRequest() as msg):  # the queryables serve these alone
                    carry_out(env.asked(query, msg))
                case Received(_, Status() | Turn() | Over() as msg):  # the subscriptions take these alone
                    carry_out(env.receive(msg))

        carry_out = functools.partial(_carry_out, keys=keys, inbox=inbox, out=out, moves=[])
        inbox.run(handle, timeout=member.timeout, until=lambda: env.over is not None)
        member.close()
        inbox.rejects.flush(everything=True)
        if inbox.rejects.total:
            logger.info("rejected inputs: %s", inbox.rejects.report())
    assert env.over is not None
    logger.info("OVER: %s", env.over.text)
    return env.over


def _carry_out(effects: list[Effect], *, keys: Keys, inbox: Inbox, out: Outbox, moves: list[zenoh.Subscriber]) -> None:
    """Carry out the environment's effects (`moves`: the subscription to the ENV phase, while held)."""
    for eff in effects:
        match eff:
            case Reply(zenoh.Query() as query, msg):  # the core holds the query it was given: a zenoh.Query
                query.reply(query.key_expr, encode(msg))
                query.drop()
            case Fail(zenoh.Query() as query, why):
                query.reply_err(why.encode())
                query.drop()
            case Report(msg):
                out.put(keys.upd, msg)
            case Follow(moves=True):
                moves.append(inbox.subscribe(keys.turn_of(Phase.ENV), Turn))
            case Follow(moves=False):
                inbox.unsubscribe(moves.pop())
            case Refusal(what, err):
                inbox.rejects.reject(what, err)


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim env", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--no-draw", action="store_true", help="do not print the world at start")
    add_entity_args(p)
    args = p.parse_args(argv)
    logger = setup_logging(args.log_level, "ENV")
    try:
        return until_stopped(lambda: main(zenoh_config(args), keys=Keys(args.root), logger=logger,
                                          draw=not args.no_draw, connect_timeout=args.connect_timeout,
                                          grace=args.grace), logger)
    except UsageError as err:
        logger.error("%s", err)
        return 2


if __name__ == "__main__":
    sys.exit(cli())
