"""The environment process (the seed's ENV): the Zenoh adapter of `Environment`.

It answers ASK (queryable ENV/ASK) from the world as it stands at the start of the turn, applies the
coordinator's moves in the ENV phase and publishes the changed cells (UPD, which the coordinator checks
against its own copy of the world without waiting for it), serves the static map (ENV/MAP) and takes
the drones' positions from STATUS.

It follows STATUS only while it needs the drones' positions (see `Following`): drone processes chart the
static map and compose their answers themselves, so in most games nobody asks the environment about the
drones, and it spends nothing per turn. An ASK about the drones makes it follow again: it subscribes to
STATUS and asks the coordinator for the last one (OBS/LAST), which the ASK waits for.

A STATUS is checked whole on arrival (a malformed one is refused and changes nothing), but its drones
are put on the map only when the environment needs their positions: for an ASK of the turn, or to apply
the ENV phase's moves.

An ASK for turn t is answered once STATUS(t-1) has been applied; one that arrives earlier (possible
when messages take different routes) waits for it, one for a past turn gets an error reply. An ASK for
turn 0 asks the static world: the kinds of the cells (buildings never move), no drones, answered at once.
"""

from __future__ import annotations

import argparse
import logging
import sys

import zenoh

from dronesim.entity import Membership, add_entity_args
from dronesim.schema import (
    Ans, Ask, Connect, Keys, MapRequest, Over, Phase, RemoteInputError, Role, Status, StatusRequest, Turn, Upd,
    UsageError, WorldMap, encode, is_drone_id,
)
from dronesim.schema.messages import is_host_id, unchecked
from dronesim.schema.errors import StaleTurn, WrongSender
from dronesim.transport import (
    Asked, Inbox, Matching, Outbox, Presence, Received, add_zenoh_args, session_id, setup_logging, zenoh_config,
)

from .environment import Environment, Following, build_world

_ans = unchecked(Ans)


def main(conf: zenoh.Config, *, keys: Keys, logger: logging.Logger, draw: bool = True,
         connect_timeout: float = 30.0, grace: float = 30.0) -> Over:
    with zenoh.open(conf) as session:
        inbox = Inbox(session, keys, logger)
        out = Outbox(session)
        inbox.subscribe(keys.over, Over)
        inbox.serve(keys.ask, Ask)
        inbox.serve(keys.map, MapRequest)
        member = Membership(session, inbox, Connect(turn=0, sender="ENV", role=Role.ENV, session=session_id(session)),
                            logger, connect_timeout=connect_timeout, grace=grace)
        welcome = member.welcome
        starts = welcome.starts.cells()
        world = build_world(welcome.world, starts.values())
        env = Environment(world, starts)
        if draw:
            print(f"World {world.size} seed {welcome.world.seed}, {len(world.buildings)} buildings, "
                  f"{int(world.grid.sum())} building cells:", flush=True)
            print(world.draw(env.drones), flush=True)
        ready = 1  # the turn whose ASKs can be answered now (STATUS(ready - 1) is the last one taken)
        waiting: list[tuple[zenoh.Query, Ask]] = []
        applied = False  # the ENV phase of turn `ready` is done
        early: Turn | None = None
        over: Over | None = None
        unsynced: Status | None = None  # the last STATUS, until the drones' positions are needed
        taken: int | None = None  # the turn of the last STATUS taken
        following = Following()
        statuses = None  # the subscription to STATUS, held while `following` wants it
        env_phase = None  # the subscription to the ENV phase, held while someone listens to the UPD

        def sync() -> None:
            """The drones where the last STATUS has them."""
            nonlocal unsynced
            if unsynced is not None:
                env.sync(unsynced)
                unsynced = None

        def follow() -> None:
            """Subscribe to STATUS, or stop, as `following` says. Starting again after turns unseen, the
            environment also asks the coordinator for the last STATUS (OBS/LAST): the turn an ASK waits for
            may have ended before the subscription began."""
            nonlocal statuses
            wanted = following.wanted(bool(waiting))
            if wanted and statuses is None:
                logger.info("following STATUS: the drones' positions are needed (turn %d)", ready)
                member.clock.lose_track()
                statuses = inbox.subscribe(keys.status, Status)
                inbox.fetch(keys.last_status, StatusRequest(turn=0, sender="ENV"), Status, timeout=grace)
            elif not wanted and statuses is not None:
                logger.info("no longer following STATUS: nobody asked about the drones for %d turns", following.turns)
                inbox.unsubscribe(statuses)
                statuses = None

        def listened(matching: bool) -> None:
            """The ENV phase's moves make the UPD report. Nobody listening, the environment does not even
            subscribe to them (the coordinator then sends none): the drones' cells come from STATUS alone
            (the same cells), and thousands of moves a turn in a swarm go nowhere."""
            nonlocal env_phase
            following.listened = matching
            if matching and env_phase is None:
                env_phase = inbox.subscribe(keys.turn_of(Phase.ENV), Turn)
            elif not matching and env_phase is not None:
                inbox.unsubscribe(env_phase)
                env_phase = None
            follow()

        out.watch(keys.upd, inbox)  # (a first Matching event at once if someone already listens)

        def apply(turn: Turn) -> None:
            nonlocal applied
            applied = True
            sync()
            changed = env.move(turn.moves)
            if out.matching(keys.upd):  # the report costs a record per cell: only for someone listening
                out.put(keys.upd, Upd(turn=turn.turn, sender="ENV", cells=env.answer(changed)))

        def answer(query: zenoh.Query, ask: Ask) -> None:
            # built right: not checked again (the asker does); turn 0 asks the static world (kinds only)
            if ask.turn != 0:
                sync()
            kinds, drones = env.survey(ask.cells, ask.around, drones=ask.turn != 0)
            query.reply(query.key_expr, encode(_ans(ask.turn, "ENV", kinds, drones)))
            query.drop()

        def refuse(query: zenoh.Query, why: str) -> None:
            query.reply_err(why.encode())
            query.drop()

        while over is None:
            event = inbox.get(member.timeout())
            if not member.clock.screen(event, inbox.rejects):
                continue
            try:
                match event:
                    case None:
                        member.check()
                    case Presence() as presence:
                        member.on_presence(presence)  # the world stays; the next STATUS resyncs the drones
                    case Matching(matching=matching):
                        listened(matching)
                    case Asked(query, Ask() as ask):
                        if not (is_drone_id(ask.sender) or is_host_id(ask.sender)):
                            refuse(query, "only drones ask")
                            raise WrongSender(f"ASK from {ask.sender}")
                        if ask.turn != 0:
                            following.asked()
                        if ask.turn == ready or ask.turn == 0:
                            answer(query, ask)
                        elif ask.turn > ready:
                            waiting.append((query, ask))
                        else:
                            refuse(query, f"ASK for turn {ask.turn}, the world is at turn {ready}")
                            raise StaleTurn(f"ASK for past turn {ask.turn} from {ask.sender}")
                        follow()
                    case Asked(query, MapRequest()):
                        query.reply(query.key_expr, encode(WorldMap(turn=ready - 1, sender="ENV", size=world.size,
                                                                    buildings=world.packed())))
                        query.drop()
                    case Received(_, Turn(phase=Phase.ENV) as turn):
                        if turn.turn == ready and not applied:
                            apply(turn)
                        elif turn.turn == ready + 1 and applied:
                            early = turn  # STATUS(t-1) travels on another key and has not arrived yet
                        elif turn.turn == ready - 1:  # after its own STATUS: the drones are already there
                            logger.debug("ENV phase of turn %d after its STATUS: nothing to apply", turn.turn)
                        else:
                            raise StaleTurn(f"ENV phase of turn {turn.turn} while the world is at turn {ready}")
                    case Received(_, Status() as status) if status.turn == taken:
                        pass  # the same STATUS again (from OBS/LAST and from the subscription)
                    case Received(_, Status() as status):
                        following.status()
                        unsynced, taken = status, status.turn
                        ready, applied = status.turn + 1, False
                        still = []
                        for query, ask in waiting:
                            if ask.turn == ready:
                                answer(query, ask)
                            elif ask.turn > ready:
                                still.append((query, ask))
                            else:
                                refuse(query, "stale turn")
                        waiting = still
                        if early is not None and early.turn == ready:
                            apply(early)
                        early = None
                        follow()
                    case Received(_, Over() as over):
                        logger.info("OVER: %s", over.text)
            except RemoteInputError as err:
                inbox.rejects.reject("ENV", err)
        for query, _ in waiting:
            refuse(query, "the game is over")
        member.close()
        return over


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim env", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--no-draw", action="store_true", help="do not print the world at start")
    add_entity_args(p)
    args = p.parse_args(argv)
    logger = setup_logging(args.log_level, "ENV")
    try:
        main(zenoh_config(args), keys=Keys(args.root), logger=logger, draw=not args.no_draw,
             connect_timeout=args.connect_timeout, grace=args.grace)
    except UsageError as err:
        logger.error("%s", err)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(cli())
