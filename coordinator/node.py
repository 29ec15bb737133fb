"""The coordinator process (the seed's SRV with its observer OBS): the Zenoh adapter of `Engine`.

It serves admission (queryable SRV/CONNECT), publishes TURN/STATUS/OVER, listens to TGT, DONE, NPS,
MOVES and UPD, watches liveliness tokens, enforces phase deadlines and writes the journal.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time

import zenoh

from dronesim.schema import (
    Connect, Done, Keys, Message, Moves, Nps, Over, Phase, RejectCounter, Refused, RemoteInputError, Status,
    StatusRequest, Target, Turn, Upd, UsageError, drone_id, encode,
)
from dronesim.schema.errors import WrongSender
from dronesim.schema.messages import WorldSpec
from dronesim.transport import (
    Asked, Event, Inbox, Outbox, Presence, Received, add_zenoh_args, inline_for, session_id, setup_logging,
    zenoh_config,
)

from .engine import DroneSpec, Engine, GameConfig, Publish, Record, Refusal, Reply, Stage
from .journal import JournalWriter, read, repair_tail

#: How long the coordinator waits, after OVER, for entities to leave before it closes anyway.
LINGER_S = 5.0


def _key_of(keys: Keys, msg: Message) -> str:
    match msg:
        case Turn():
            return keys.turn_of(msg.phase)
        case Status():
            return keys.status
        case Over():
            return keys.over
    raise AssertionError(f"the coordinator does not publish {msg.TAG}")


#: Seconds a CONNECT may wait for its sender's presence token to be seen.
PRESENCE_WAIT_S = 5.0


class Admissions:
    """Presence tokens, and the CONNECTs waiting for theirs.

    A CONNECT names its sender and session; it is admitted only once the presence token of that same
    (sender, session) is seen. Under the router's access control only the real principal may declare
    that token, so a process cannot take another's seat by writing its name in a CONNECT (defence in
    depth: the coordinator cannot see who sent a query). The token may arrive just after the query
    (another path), hence the short wait; a CONNECT without one is refused."""

    def __init__(self) -> None:
        self.present: set[tuple[str, str]] = set()
        self._waiting: list[tuple[float, zenoh.Query, Connect]] = []

    def connect(self, query: zenoh.Query, msg: Connect) -> list[tuple[zenoh.Query, Connect]]:
        if (msg.sender, msg.session) in self.present:
            return [(query, msg)]
        self._waiting.append((time.monotonic() + PRESENCE_WAIT_S, query, msg))
        return []

    def presence(self, entity: str, session: str, alive: bool) -> list[tuple[zenoh.Query, Connect]]:
        if not alive:
            self.present.discard((entity, session))
            return []
        self.present.add((entity, session))
        ready = [(q, m) for _, q, m in self._waiting if (m.sender, m.session) == (entity, session)]
        self._waiting = [w for w in self._waiting if (w[2].sender, w[2].session) != (entity, session)]
        return ready

    def due_in(self) -> float | None:
        return max(0.0, min(w[0] for w in self._waiting) - time.monotonic()) if self._waiting else None

    def expired(self) -> list[tuple[zenoh.Query, Connect]]:
        now = time.monotonic()
        gone = [(q, m) for due, q, m in self._waiting if due <= now]
        self._waiting = [w for w in self._waiting if w[0] > now]
        return gone


def _soonest(*delays: float | None) -> float | None:
    known = [d for d in delays if d is not None]
    return min(known) if known else None


class Executor:
    """Carries out the engine's effects in order; with `pace`, a new turn starts at most every `pace`
    seconds (the effects from its TURN on are held until then: a watchable speed, not a synchronisation)."""

    def __init__(self, keys: Keys, out: Outbox, writer: JournalWriter, rejects: RejectCounter, status: bytes,
                 pace: float = 0.0) -> None:
        self.keys, self.out, self.writer, self.rejects, self.pace = keys, out, writer, rejects, pace
        self._held: list = []
        self._due = 0.0
        self._turn = 0  # the last turn whose first TURN went out
        self._last = float("-inf")  # when it went out
        # the last STATUS that went out, encoded (served on OBS/LAST); before the first, the state the game
        # starts (or resumes) from, which that first STATUS will say
        self.last_status = status

    def run(self, effects: list) -> None:
        for eff in effects:
            if self._held:
                self._held.append(eff)
                continue
            match eff:
                case Publish(Turn() as turn) if self.pace and turn.turn > self._turn:
                    self._turn = turn.turn
                    due = self._last + self.pace
                    if time.monotonic() < due:
                        self._held, self._due = [eff], due
                        continue
                    self._last = time.monotonic()
                    self.out.put(self.keys.turn_of(turn.phase), turn)
                case Publish(Turn(phase=Phase.ENV)) if not self.out.matching(self.keys.turn_of(Phase.ENV)):
                    pass  # nobody follows the ENV phase (the environment does when someone wants its UPD)
                case Publish(msg, data):
                    data = encode(msg) if data is None else data
                    if isinstance(msg, Status):
                        self.last_status = data
                    self.out.put(_key_of(self.keys, msg), msg, data)
                case Reply(query, msg):
                    query.reply(query.key_expr, encode(msg))
                    query.drop()  # the final answer: the asker stops waiting now
                case Record(data):
                    self.writer.append(data)
                case Refusal(what, err):
                    self.rejects.reject(what, err)

    def due_in(self) -> float | None:
        """Seconds until held effects are due (None: nothing held)."""
        return max(0.0, self._due - time.monotonic()) if self._held else None

    def release(self) -> None:
        held, self._held = self._held, []
        self._last = time.monotonic()
        first, rest = held[0], held[1:]
        self.out.put(self.keys.turn_of(first.msg.phase), first.msg)
        self.run(rest)


def main(conf: zenoh.Config, game: GameConfig, *, keys: Keys, journal: str | None,
         logger: logging.Logger, resume: bool = False, pace: float = 0.0, verify_env: bool = False) -> Over:
    """Run one game to its end (or, with `resume`, the rest of the journal's game); return the OVER message."""
    if resume and not journal:
        raise UsageError("--resume needs --journal")
    if resume and os.path.exists(journal) and os.path.getsize(journal) > 0:
        repair_tail(journal)
        engine = Engine.resume(game, list(read(journal)), logger)
    else:
        if resume:  # e.g. a container restarted before the game began: nothing to resume yet
            logger.info("no journal at %s yet: starting a new game", journal)
        engine = Engine(game, logger)
    engine.verify_env = verify_env
    engine.journaled = journal is not None
    with zenoh.open(conf) as session, JournalWriter(journal) as writer:
        inbox = Inbox(session, keys, logger)
        out = Outbox(session)
        inbox.serve(keys.connect, Connect)
        inbox.subscribe(keys.any_tgt, Target)
        inbox.subscribe(keys.gcs_done, Done)
        inbox.subscribe(keys.any_nps, Nps)
        inbox.subscribe(keys.any_moves, Moves)
        if verify_env:  # the environment's report of each ENV phase, checked against the engine's world
            inbox.subscribe(keys.upd, Upd)
        inbox.watch_presence()
        token = session.liveliness().declare_token(keys.alive("SRV", session_id(session)))
        admissions = Admissions()
        present = admissions.present  # (entity, session) of every presence token

        def refuse(query: zenoh.Query, msg: Connect, why: str) -> None:
            inbox.rejects.reject(f"CONNECT from {msg.sender}", WrongSender(why))
            query.reply(query.key_expr, encode(Refused(turn=engine.turn, sender="SRV", text=why)))
            query.drop()
        logger.info("coordinator ready on %s/**: waiting for ENV, GCS and %s",
                    keys.root, ", ".join(d.drone for d in game.drones))

        effects = Executor(keys, out, writer, inbox.rejects, encode(engine.status()), pace)
        run = effects.run

        def last_status(query: zenoh.Query, _msg: StatusRequest) -> bool:
            """OBS/LAST, answered on Zenoh's thread (it reads one reference): the last STATUS published."""
            query.reply(query.key_expr, effects.last_status)
            query.drop()
            return True

        inbox.serve(keys.last_status, StatusRequest, inline=last_status)
        phase = engine.clock()
        started = time.monotonic()

        def timeout() -> float | None:
            limit = engine.deadline()
            left = None if limit is None else max(0.0, started + limit - time.monotonic())
            return _soonest(left, effects.due_in(), admissions.due_in())

        def handle(event: Event | None) -> None:
            nonlocal phase, started
            match event:
                case None if effects.due_in() == 0:
                    effects.release()
                case None if admissions.due_in() == 0:
                    for query, msg in admissions.expired():
                        refuse(query, msg, f"no presence token of {msg.sender} (session {msg.session or '?'}): "
                                           "a process connects under its own name only")
                case None:
                    run(engine.expire(*phase))
                case Asked(query, Connect() as msg):
                    for query, msg in admissions.connect(query, msg):
                        run(engine.connect(msg, query))
                case Received(_, msg):
                    try:
                        run(engine.receive(msg))
                    except RemoteInputError as err:  # counted and logged; the engine changed nothing
                        inbox.rejects.reject(f"{msg.TAG} from {msg.sender}", err)
                        run(err.follow)
                case Presence(entity, sid, alive):
                    for query, msg in admissions.presence(entity, sid, alive):
                        run(engine.connect(msg, query))
                    if not alive:
                        run(engine.vanished(entity, sid))
            if engine.clock() != phase:
                phase = engine.clock()
                started = time.monotonic()

        # A small game's messages are handled on Zenoh's thread when nothing else is under way (see Inbox.run).
        inbox.run(handle, timeout=timeout, until=lambda: engine.stage is Stage.OVER,
                  inline=inline_for(len(game.drones)))
        # Let OVER reach everyone: wait (on events, bounded) until the admitted entities have left.
        end = time.monotonic() + LINGER_S
        while {e for e, _ in present} - {"SRV"} and time.monotonic() < end:
            event = inbox.get(end - time.monotonic())
            match event:
                case Presence(entity, sid, False):
                    present.discard((entity, sid))
                case Asked(query, Connect() as msg):
                    run(engine.connect(msg, query))
        token.undeclare()
        if inbox.rejects.total:
            logger.info("rejected inputs: %s", inbox.rejects.snapshot())
    assert engine.end is not None
    return engine.end


def parse_starts(text: str, count: int) -> tuple[DroneSpec, ...]:
    """``--starts "0,0,0;0,2,0"`` or, by default, drones in a row along y from (0,0,0), every other cell."""
    if text:
        cells = [tuple(int(v) for v in part.split(",")) for part in text.split(";") if part.strip()]
        if len(cells) != count or any(len(c) != 3 for c in cells):
            raise UsageError(f"--starts needs {count} cells x,y,z separated by ';'")
    else:
        cells = [(0, 2 * i, 0) for i in range(count)]
    return tuple(DroneSpec(drone=drone_id(i + 1), start=c) for i, c in enumerate(cells))  # type: ignore[arg-type]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="dronesim coordinator", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--seed", type=int, default=0, help="world seed (default 0)")
    p.add_argument("--size", default="10,10,10", help="world size nx,ny,nz (default 10,10,10)")
    p.add_argument("--world", help="a world file (JSON) instead of a generated world")
    p.add_argument("--scenario", help="a scenario file (world, drones, starts, max turns): overrides those flags")
    p.add_argument("--drones", type=int, default=1, help="number of drones D01..Dnn (default 1)")
    p.add_argument("--starts", default="", help='start cells "x,y,z;x,y,z" (default: a row along y)')
    p.add_argument("--max-turns", type=int, default=1000)
    p.add_argument("--phase-deadline", type=float, default=5.0, help="seconds for drones and ENV per phase")
    p.add_argument("--gcs-deadline", type=float, default=0.0, help="seconds for the GCS phase (0: wait)")
    p.add_argument("--admit-deadline", type=float, default=0.0, help="seconds to wait for entities (0: forever)")
    p.add_argument("--lost-after", type=int, default=3, help="missed deadlines before a drone is LOST")
    p.add_argument("--gcs-grace", type=float, default=30.0, metavar="SECONDS",
                   help="with --resume: how long the game waits for its ground station once the environment "
                        "and the drones are back (default 30)")
    p.add_argument("--journal", help="append the game's journal to this file")
    p.add_argument("--pace", type=float, default=0.0, metavar="SECONDS",
                   help="start a turn at most every SECONDS (default 0: as fast as the entities answer)")
    p.add_argument("--verify-env", action="store_true",
                   help="check the environment's UPD of every ENV phase against the coordinator's world "
                        "(a mismatch is logged and counted as a rejected input)")
    p.add_argument("--resume", action="store_true",
                   help="restart a game from its --journal: the entities connect again and it plays on "
                        "(a missing or empty journal starts a new game)")
    return p


def parse_size(text: str) -> tuple[int, int, int]:
    try:
        size = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise UsageError(f"bad size {text!r}: expected nx,ny,nz") from None
    if len(size) == 1:
        size = size * 3
    if len(size) != 3 or min(size) < 1:
        raise UsageError(f"bad size {text!r}: expected three positive integers")
    return size  # type: ignore[return-value]


def game_config(args: argparse.Namespace) -> GameConfig:
    from dronesim.entities.world import World

    deadlines = dict(phase_deadline=args.phase_deadline, gcs_deadline=args.gcs_deadline or None,
                     admit_deadline=args.admit_deadline or None, lost_after=args.lost_after, gcs_grace=args.gcs_grace)
    if args.scenario:
        from dronesim.scenario import Scenario

        return Scenario.load(args.scenario).game_config(**deadlines)

    if args.world:
        world = World.load(args.world)
        spec = WorldSpec(size=world.size, cells=world.packed())
    else:
        spec = WorldSpec(size=parse_size(args.size), seed=args.seed)
    drones = parse_starts(args.starts, args.drones)
    if args.world:
        for d in drones:
            if world.is_building(d.start):
                raise UsageError(f"{d.drone} would start inside a building at {d.start}")
    return GameConfig(world=spec, drones=drones, max_turns=args.max_turns, **deadlines)


def cli(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logger = setup_logging(args.log_level, "SRV")
    try:
        over = main(zenoh_config(args), game_config(args), keys=Keys(args.root), journal=args.journal, logger=logger,
                    resume=args.resume, pace=args.pace, verify_env=args.verify_env)
    except UsageError as err:
        logger.error("%s", err)
        return 2
    print(f"OVER at turn {over.turn}: {over.reason.value}: {over.text}", file=sys.stderr)
    return 0
