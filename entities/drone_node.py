"""A drone process (the seed's D01), or a swarm host flying several drones in one process.

Each DRONES phase it runs every hosted drone's autopilot together (`fly_round`): all pending ASKs of
a round go out as concurrent queries to ENV/ASK, then each drone publishes its NPS. It exits on OVER.
"""

from __future__ import annotations

import argparse
import logging
import sys

import zenoh

from dronesim.entity import admit
from dronesim.schema import (
    Ans, Ask, Connect, Keys, Nps, Over, Phase, RemoteInputError, Role, Turn, UsageError, decode, drone_id, encode,
    is_drone_id,
)
from dronesim.transport import Inbox, Outbox, Received, add_zenoh_args, setup_logging, zenoh_config

from .autopilots import REGISTRY, fly_round, make_autopilot, pilot_class
from .autopilots.base import Answers


def main(conf: zenoh.Config, *, drones: tuple[str, ...], autopilot: str, keys: Keys, logger: logging.Logger,
         host: str | None = None, connect_timeout: float = 30.0, ask_timeout: float = 5.0) -> Over:
    sender = host or drones[0]
    with zenoh.open(conf) as session:
        token = session.liveliness().declare_token(keys.alive(sender))
        inbox = Inbox(session, keys, logger)
        inbox.subscribe(keys.turn, Turn)
        inbox.subscribe(keys.over, Over)
        cooperative = pilot_class(autopilot).cooperative
        welcome = admit(session, keys, Connect(turn=0, sender=sender, role=Role.DRONE, drones=drones,
                                               autopilot=autopilot, cooperative=cooperative),
                        logger, timeout=connect_timeout)
        pilots = {d: make_autopilot(autopilot, world_size=welcome.world.size) for d in drones}
        out = Outbox(session)
        querier = session.declare_querier(keys.ask, timeout=ask_timeout,
                                          consolidation=zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE))
        mine = set(drones)

        def ask_all(turn: int, pending: dict[str, tuple]) -> dict[str, Answers]:
            handlers = {d: querier.get(payload=encode(Ask(turn=turn, sender=d, cells=cells)))
                        for d, cells in pending.items()}
            answers: dict[str, Answers] = {}
            for d, handler in handlers.items():
                answers[d] = {}
                for reply in handler:
                    if reply.ok is None:
                        logger.warning("%s: ASK refused: %s", d, reply.err.payload.to_bytes().decode(errors="replace"))
                        continue
                    try:
                        ans = decode(reply.ok.payload.to_bytes(), Ans)
                    except RemoteInputError as err:
                        inbox.rejects.reject(f"ANS for {d}", err)
                        continue
                    answers[d] = {c.pos: c for c in ans.cells}
            return answers

        over: Over | None = None
        while over is None:
            match inbox.get():
                case Received(_, Turn(phase=Phase.DRONES) as turn):
                    orders = [o for o in turn.orders if o.drone in mine]
                    steps = {o.drone: pilots[o.drone].step(o.pos, o.target) for o in orders}
                    decisions = fly_round(steps, lambda pending: ask_all(turn.turn, pending))
                    for d, dec in decisions.items():
                        out.put(keys.nps(d), Nps(turn=turn.turn, sender=d, pos=dec.pos, note=dec.note))
                case Received(_, Over() as over):
                    logger.info("OVER: %s", over.text)
        querier.undeclare()
        token.undeclare()
        return over


def parse_drones(text: str) -> tuple[str, ...]:
    """``D01`` / ``D01,D02`` / ``D01-D08`` / ``1-8``."""
    ids: list[str] = []
    for part in text.split(","):
        part = part.strip()
        if "-" in part:
            a, b = (int(p.strip().lstrip("D")) for p in part.split("-", 1))
            ids += [drone_id(n) for n in range(a, b + 1)]
        elif part:
            ids.append(part if is_drone_id(part) else drone_id(int(part)))
    if not ids or len(set(ids)) != len(ids):
        raise UsageError(f"bad drone list {text!r}")
    return tuple(ids)


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim drone", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--id", default="D01", help="drone id(s): D01, or D01-D08 for a swarm host (default D01)")
    p.add_argument("--host", help="swarm host id Hnn (required when flying several drones)")
    p.add_argument("--autopilot", default="seed", choices=sorted(REGISTRY), help="default: seed")
    p.add_argument("--connect-timeout", type=float, default=30.0, help="seconds to wait for the coordinator")
    args = p.parse_args(argv)
    try:
        drones = parse_drones(args.id)
        if len(drones) > 1 and not args.host:
            raise UsageError("several drones in one process need --host Hnn")
        logger = setup_logging(args.log_level, args.host or drones[0])
        main(zenoh_config(args), drones=drones, autopilot=args.autopilot, keys=Keys(args.root), logger=logger,
             host=args.host, connect_timeout=args.connect_timeout)
    except UsageError as err:
        print(f"dronesim drone: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(cli())
