"""A drone process (the seed's D01), or a swarm host flying several drones in one process.

Each DRONES phase it runs every hosted drone's autopilot together (`fly_pilots`): all pending ASKs of
a round go out as concurrent queries to ENV/ASK, then a lone drone publishes its NPS, a swarm host the
MOVES of all its drones in one message. A swarm host of an autopilot that has a swarm form flies its
drones with that one pilot over arrays instead (`fly_swarm`). It exits on OVER.

Sensing without a round trip: the process keeps a chart of the kinds the environment told it (buildings
never move, so a cell's kind holds for the whole game). As soon as it is admitted it asks the environment
for its static map (ENV/MAP, the query a ground station draws with; asked again each turn until a reply
comes, as the environment may still be building its world); until then, once it has sent its moves, it
asks, for the static world (an ASK for turn 0, answered at once), the never-told cells around where its
drones are going (within three steps for a few drones, so that it asks only every few turns; the next ring
for a swarm). When an autopilot asks, each cell whose kind is charted is answered from the chart plus the
drones in it, which the turn's orders list (every alive drone's cell at the start of the turn): exactly
the CellInfo the environment would give for that turn. Other cells are asked as usual. The autopilots
see only the cells they ask for, so decisions, and journals, do not change.
"""

from __future__ import annotations

import argparse
import functools
import logging
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence

import numpy as np
import zenoh

from dronesim.entity import Membership, add_entity_args, await_presence
from dronesim.schema import (
    Ans, Ask, Cell, CellInfo, CellKind, Connect, Keys, MapRequest, Moves, Nps, OrderTable, Over, Phase,
    RemoteInputError, Role, StepTable, Turn, UsageError, WorldMap, decode, drone_id, encode, is_drone_id,
)
from dronesim.schema.errors import OutOfRange
from dronesim.schema.messages import _KINDS, AROUND, unchecked
from dronesim.schema.tables import drone_number
from dronesim.transport import (
    Event, Inbox, Outbox, Presence, Received, add_zenoh_args, inline_for, session_id, setup_logging, zenoh_config,
)

from .autopilots import REGISTRY, SWARM_MIN, make_autopilot, make_swarm, pilot_class
from .autopilots.base import NO_ANSWER, Answers, fly_pilots, fly_swarm
from .world import World, inside_rows, linear_rows


def main(conf: zenoh.Config, *, drones: tuple[str, ...], autopilot: str, keys: Keys, logger: logging.Logger,
         host: str | None = None, connect_timeout: float = 30.0, grace: float = 30.0,
         ask_timeout: float = 5.0, swarm_min: int = SWARM_MIN) -> Over:
    sender = host or drones[0]
    with zenoh.open(conf) as session:
        inbox = Inbox(session, keys, logger)
        inbox.subscribe(keys.turn_of(Phase.DRONES), Turn)
        inbox.subscribe(keys.over, Over)
        hello = Connect(turn=0, sender=sender, role=Role.DRONE, drones=drones, autopilot=autopilot,
                        cooperative=pilot_class(autopilot).cooperative, session=session_id(session))
        member = Membership(session, inbox, hello, logger, connect_timeout=connect_timeout, grace=grace)
        size = member.welcome.world.size
        # A swarm host flies its drones with one pilot over arrays when the autopilot has that form.
        swarm = make_swarm(autopilot, world_size=size, drones=[drone_number(d) for d in drones],
                           least=swarm_min) if host else None
        pilots = {} if swarm else {d: make_autopilot(autopilot, world_size=size) for d in drones}
        if swarm:
            logger.info("flying %d drones with the %s autopilot's swarm form", len(drones), autopilot)
        numbers = np.array(sorted(drone_number(d) for d in drones))
        out = Outbox(session)
        asker = Asker(session, keys, inbox, logger, sender=sender, timeout=ask_timeout, patience=grace,
                      size=size)
        mine = set(drones)
        senses = pilot_class(autopilot).senses
        if senses:  # the static world around the starts, asked now: the first turn's sensing needs no ASK
            asker.prefetch(0, sorted({c for d, c in member.welcome.starts.cells().items() if d in mine}))
        done: tuple[tuple, StepTable | dict] | None = None  # the last turn's orders and moves (a repeated TURN gets them again)
        over: Over | None = None
        backlog: list = []  # events taken from the inbox while waiting for the environment

        def superseded(turn: int) -> bool:
            """Has the game moved past `turn` (a later TURN, or OVER, is queued)? Then stop planning it."""
            backlog.extend(inbox.drain())
            return any(isinstance(e, Received) and (isinstance(e.msg, Over) or
                                                    (isinstance(e.msg, Turn) and e.msg.turn > turn))
                       for e in backlog)

        def act(turn: Turn) -> None:
            """The DRONES phase of `turn`: decide (unless it is a repeat) and send the moves."""
            nonlocal done
            give_up = functools.partial(superseded, turn.turn)
            if swarm:  # one pilot over arrays, reading its drones' rows of the orders
                rows = turn.orders.rows[np.isin(turn.orders.numbers, numbers)]
                key: tuple = (turn.turn, rows.tobytes())
                decide = functools.partial(fly_swarm, swarm, rows, lambda cells: asker.kinds(
                    turn.turn, cells, give_up=give_up))
            else:
                orders = turn.orders.orders(mine)
                key = (turn.turn, orders)
                decide = functools.partial(fly_pilots, pilots, orders, lambda pending: asker.ask_all(
                    turn.turn, pending, functools.cache(lambda: occupancy_of(turn.orders)), give_up=give_up),
                    host=host)
            fresh = done is None or done[0] != key  # a repeated TURN gets the same moves again
            if fresh:
                decided = decide()
                if superseded(turn.turn):
                    return  # too late: the game has moved on (the queued events come next)
                done = (key, decided)
            moves = done[1]
            if isinstance(moves, StepTable):  # a swarm host: one message for all its drones
                if moves:
                    out.put(keys.moves(host), Moves(turn=turn.turn, sender=host, moves=moves))
                cells = map(tuple, moves.column("pos").tolist())
            else:
                for d, dec in moves.items():
                    out.put(keys.nps(d), Nps(turn=turn.turn, sender=d, pos=dec.pos, note=dec.note))
                cells = (dec.pos for dec in moves.values())
            if fresh and senses and not asker.chart.complete:  # around where its drones mean to be:
                asker.prefetch(turn.turn, sorted(set(cells)))  # their next sensing, asked ahead

        def handle(event: Event | None) -> None:
            """Work through everything already queued, acting only on the latest DRONES phase: a process
            that was frozen or slow catches up instead of planning turns that are long gone."""
            nonlocal over
            if event is None:
                member.check()
                return
            events = [event, *inbox.drain()]
            while events:
                backlog.clear()
                latest: Turn | None = None
                for ev in events:
                    if not member.clock.screen(ev, inbox.rejects):
                        continue
                    match ev:
                        case Presence() as presence:
                            member.on_presence(presence)
                        case Received(_, Turn(phase=Phase.DRONES) as turn):
                            latest = turn
                        case Received(_, Over() as end):
                            over = end
                if over is not None:
                    logger.info("OVER: %s", over.text)
                    return
                if latest is not None and latest.turn == member.clock.turn:
                    act(latest)
                events = [*backlog, *inbox.drain()]  # what came while it decided

        # In a small game, a TURN is handled on Zenoh's thread when the drones can decide without asking the
        # environment (see Inbox.run): every answer then comes from the chart, and nothing waits for a reply.
        small = inline_for(len(drones))
        inbox.run(handle, timeout=member.timeout, until=lambda: over is not None,
                  inline=lambda event: small(event) and asker.offline)
        asker.close()
        member.close()
        return over


class Asker:
    """ASK queries to the environment for every drone of this process: all the cells the drones of one
    round want go out together (one query per Ask.MAX_CELLS cells, concurrently), and each drone gets
    the answers for its own cells. A query nobody answered (the environment is restarting) is asked
    again once the environment is back, so the decision does not change."""

    def __init__(self, session: zenoh.Session, keys: Keys, inbox: Inbox, logger: logging.Logger, *,
                 sender: str, timeout: float, patience: float, size: Cell) -> None:
        self.session, self.keys, self.inbox, self.log = session, keys, inbox, logger
        self.sender = sender
        self.patience = patience
        self.querier = session.declare_querier(keys.ask, timeout=timeout,
                                               consolidation=zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE))
        self.chart = Chart(size)
        self._ahead: list[tuple[Ask, object]] = []  # static ASKs (turn 0) sent ahead, and their reply handlers
        self._map_asked: list[int] = []  # the turns in which the map was asked
        self._map = None  # the reply handler of the MAP query on its way

    @property
    def offline(self) -> bool:
        """Does it answer everything from its chart, with no reply to wait for (the whole map charted)?"""
        return self.chart.complete and not self._ahead

    def _ask_map(self, turn: int):
        self._map_asked.append(turn)
        return self.session.get(self.keys.map, payload=encode(MapRequest(turn=0, sender=self.sender)),
                                timeout=self.patience)

    def _poll_map(self, turn: int) -> None:
        """Chart the whole static world if the environment's map has come (never waiting for it); the
        first call asks for it."""
        if not self._map_asked:
            self._map = self._ask_map(turn)
        if self._map is None:
            return
        try:
            reply = self._map.try_recv()
        except zenoh.ZError:  # finished without a reply: nobody served the map yet (the environment may
            # still be starting): ask again in a later turn, a few times
            if turn > self._map_asked[-1]:
                self._map = self._ask_map(turn) if len(self._map_asked) < MAP_TRIES else None
            return
        if reply is None:
            return  # on its way
        self._map = None
        try:
            if reply.ok is None:
                raise RemoteInputError(f"MAP refused: {reply.err.payload.to_bytes().decode(errors='replace')}",
                                       reason="error-reply")
            self.chart.learn_map(decode(reply.ok.payload.to_bytes(), WorldMap))
            self.log.info("charted the environment's map: %d cells", len(self.chart))
        except RemoteInputError as err:
            self.inbox.rejects.reject("MAP", err)

    def prefetch(self, turn: int, around: Iterable[Cell]) -> None:
        """Ask now, for the static world (turn 0: answered at once), the kinds of the cells around
        `around` that this process has not been told yet (nothing once the whole map is charted);
        `turn`: the turn being played (0 before the game)."""
        self._poll_map(turn)
        if self.chart.complete:
            return
        around = list(around)
        cells = self.chart.unknown(around)
        if cells and len(around) <= FAR_MAX:  # a few drones: ask farther at once, and again only every
            cells = self.chart.unknown(around, reach=FAR)  # few turns (a swarm asks its next ring each turn)
        for i in range(0, len(cells), PREFETCH_CHUNK):
            ask = Ask(turn=0, sender=self.sender, cells=cells[i:i + PREFETCH_CHUNK])
            self._ahead.append((ask, self.querier.get(payload=encode(ask))))

    def _absorb(self) -> None:
        """Learn the kinds asked ahead (waiting for answers still on their way, which is rare)."""
        for ask, handler in self._ahead:
            self._collect(["(ahead)"], handler, ask, infos=False)
        self._ahead.clear()

    def _batches(self, pending: dict[str, tuple]) -> list[list[str]]:
        batches: list[list[str]] = [[]]
        size = 0
        for d, cells in pending.items():
            if size + len(cells) > Ask.MAX_CELLS and batches[-1]:
                batches.append([])
                size = 0
            batches[-1].append(d)
            size += len(cells)
        return batches

    def ask_all(self, turn: int, pending: dict[str, tuple], occupancy: Callable[[], Mapping[Cell, tuple]], *,
                give_up: Callable[[], bool] = lambda: False) -> dict[str, Answers]:
        """Answers for every drone's cells, as the environment would give them at the start of `turn`:
        for a cell whose kind this process was told (buildings never move), the kind and the drones in
        it (`occupancy`: every alive drone's cell, from the turn's orders), without a round trip; for
        the others, an ASK. While the environment is away it waits for it (up to `patience`), checking
        `give_up` at least every second (the game may have ended meanwhile)."""
        self._absorb()
        self._poll_map(turn)
        answers: dict[str, Answers] = {}
        kind, missing = self.chart.kind, {}
        for d, cells in pending.items():
            kinds = [kind(c) for c in cells]
            if None in kinds:
                missing[d] = cells
            else:
                occupied = occupancy()
                answers[d] = {c: _cell_info(c, k, occupied.get(c, ())) for c, k in zip(cells, kinds)}
        pending = missing
        end = time.monotonic() + self.patience
        while pending:
            batches = self._batches(pending)
            asks = [Ask(turn=turn, sender=self.sender, cells=tuple(c for d in b for c in pending[d])) for b in batches]
            handlers = [self.querier.get(payload=encode(ask)) for ask in asks]
            unanswered: dict[str, tuple] = {}
            for batch, handler, ask in zip(batches, handlers, asks):
                got = self._collect(batch, handler, ask)
                for d in batch:
                    if got is None:
                        unanswered[d] = pending[d]
                    else:
                        answers[d] = {c: got[c] for c in pending[d] if c in got}
            if unanswered and give_up():
                answers.update({d: {} for d in unanswered})
                unanswered = {}
            elif unanswered and time.monotonic() < end:
                self.log.warning("no environment answered %s: waiting for it", ", ".join(unanswered))
                while not await_presence(self.session, self.keys.alive_of("ENV"),
                                         min(1.0, end - time.monotonic())):
                    if give_up() or time.monotonic() >= end:
                        break
            elif unanswered:
                self.log.error("no environment answered %s within %g s", ", ".join(unanswered), self.patience)
                answers.update({d: {} for d in unanswered})
                unanswered = {}
            pending = unanswered
        return answers

    def kinds(self, turn: int, cells: np.ndarray, *, give_up: Callable[[], bool] = lambda: False) -> np.ndarray:
        """The kind of each cell of an (n, 3) array, as the environment would give it for `turn` (uint8,
        `NO_ANSWER` for a cell it did not answer): from the chart, and by ASK for the cells never told."""
        self._absorb()
        self._poll_map(turn)
        kinds = self.chart.kinds(cells)
        missing = np.flatnonzero(kinds == Chart.UNKNOWN)
        if len(missing):
            asked = list(dict.fromkeys(map(tuple, cells[missing].tolist())))
            chunks = {f"{self.sender}#{i}": tuple(asked[i:i + Ask.MAX_CELLS]) for i in range(0, len(asked), Ask.MAX_CELLS)}
            answers = self.ask_all(turn, chunks, dict, give_up=give_up)
            told = {c: info.kind for got in answers.values() for c, info in got.items()}
            kinds[missing] = [told.get(c, NO_ANSWER) for c in map(tuple, cells[missing].tolist())]
        return kinds

    def _collect(self, batch: list[str], handler, ask: Ask, *, infos: bool = True) -> Answers | None:
        """The answer to `ask` (its kinds learnt by the chart; with `infos`, as {cell: CellInfo}); None if
        nobody answered (no queryable, or zenoh's own timeout)."""
        result: Answers | None = None
        for reply in handler:
            if reply.ok is None:
                why = reply.err.payload.to_bytes().decode(errors="replace")
                if why != "Timeout":
                    self.log.warning("%s: ASK refused: %s", ", ".join(batch), why)
                    result = result or {}
                continue
            try:
                ans = decode(reply.ok.payload.to_bytes(), Ans)
                asked = ask.asked()
                ans.check_fits(asked)
                self.chart.learn(asked, ans.kinds)
                result = dict(zip(asked, ans.infos(asked))) if infos else {}
            except RemoteInputError as err:
                self.inbox.rejects.reject(f"ANS for {', '.join(batch)}", err)
                result = result or {}
        return result

    def close(self) -> None:
        self.querier.undeclare()
        self._map = None


SMALL = 48  # up to this many cells, the chart works cell by cell rather than with numpy
FAR, FAR_MAX = 3, 32  # up to FAR_MAX drones, a process asks ahead for every cell within FAR steps
#: MAP queries a drone process sends (at most one per turn while none is answered) before it gives up on the map.
MAP_TRIES = 10
#: Cells per ASK sent ahead: nothing waits for these answers, so a swarm's thousands of cells go in
#: several concurrent queries and the environment never holds one huge request (or answer) at once.
PREFETCH_CHUNK = 512


@functools.cache
def _ball(reach: int) -> np.ndarray:
    """The offsets within `reach` steps of a cell (6-connectivity), itself excluded, nearest first (the
    neighbours in AROUND order)."""
    r = range(-reach, reach + 1)
    farther = [(dx, dy, dz) for dx in r for dy in r for dz in r if 1 < abs(dx) + abs(dy) + abs(dz) <= reach]
    return np.asarray([*AROUND, *sorted(farther, key=lambda o: abs(o[0]) + abs(o[1]) + abs(o[2]))],
                      dtype=np.int64)


_cell_info = unchecked(CellInfo)


def occupancy_of(orders: OrderTable) -> dict[Cell, tuple[str, ...]]:
    """Which drones are in which cell at the start of a turn: the orders list every alive drone."""
    cells: dict[Cell, list[str]] = {}
    for d, (x, y, z) in zip(orders.ids(), orders.column("pos").tolist()):
        cells.setdefault((x, y, z), []).append(d)
    return {c: tuple(sorted(ds)) for c, ds in cells.items()}


class Chart:
    """The kinds of the cells this process has been told by the environment (buildings never move,
    so what it is told once holds for the whole game): one byte per cell of the world, 255 until told.
    Cells outside the world are OUTSIDE (their kind follows from the world's size)."""

    UNKNOWN = 255

    def __init__(self, size: Cell) -> None:
        self.size = size
        self._kinds = bytearray([self.UNKNOWN]) * (size[0] * size[1] * size[2])
        self.complete = False  # every cell's kind is known (the environment's map was charted)

    def __len__(self) -> int:
        return len(self._kinds)

    def learn_map(self, world_map: WorldMap) -> None:
        """Every cell's kind, from the environment's static map (RemoteInputError if it is another world's)."""
        if world_map.size != self.size:
            raise OutOfRange(f"a MAP of a {world_map.size} world, this game's is {self.size}")
        grid = World.from_packed(world_map.size, world_map.buildings).grid  # the format's one reader
        kinds = np.where(grid.ravel(), np.uint8(CellKind.BUILDING), np.uint8(CellKind.EMPTY))
        np.frombuffer(self._kinds, dtype=np.uint8)[:] = kinds
        self.complete = True

    def _at(self, cell: Cell) -> int | None:
        x, y, z = cell
        nx, ny, nz = self.size
        return (x * ny + y) * nz + z if 0 <= x < nx and 0 <= y < ny and 0 <= z < nz else None

    def kind(self, cell: Cell) -> CellKind | None:
        """The cell's kind, None if never told."""
        i = self._at(cell)
        if i is None:
            return CellKind.OUTSIDE
        k = self._kinds[i]
        return None if k == self.UNKNOWN else _KINDS[k]

    def _linear(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(inside mask, linear index of each inside cell) of an (n, 3) array of cells."""
        inside = inside_rows(cells, self.size)
        return inside, linear_rows(cells[inside], self.size)

    def kinds(self, cells: np.ndarray) -> np.ndarray:
        """The kind of each cell of an (n, 3) integer array (uint8; UNKNOWN if never told)."""
        inside, at = self._linear(cells)
        kinds = np.full(len(cells), CellKind.OUTSIDE, dtype=np.uint8)
        kinds[inside] = np.frombuffer(self._kinds, dtype=np.uint8)[at]
        return kinds

    def learn(self, cells: Sequence[Cell], kinds: bytes) -> None:
        if len(cells) <= SMALL:  # a few: cell by cell (numpy's fixed cost dominates)
            for cell, k in zip(cells, kinds):
                i = self._at(cell)
                if i is not None:
                    self._kinds[i] = k
            return
        inside, at = self._linear(np.asarray(cells, dtype=np.int64).reshape(-1, 3))
        np.frombuffer(self._kinds, dtype=np.uint8)[at] = np.frombuffer(kinds, dtype=np.uint8)[inside]

    def unknown(self, around: Sequence[Cell], reach: int = 1) -> tuple[Cell, ...]:
        """The cells within `reach` steps (6-connectivity) of the `around` cells whose kind was never
        told, once each, in order (by default their neighbours, in AROUND order)."""
        if reach == 1 and len(around) * 6 <= SMALL:  # a few: cell by cell
            out: dict[Cell, None] = {}
            for x, y, z in around:
                for dx, dy, dz in AROUND:
                    c = (x + dx, y + dy, z + dz)
                    i = self._at(c)
                    if i is not None and self._kinds[i] == self.UNKNOWN:
                        out[c] = None
            return tuple(out)
        ball = (np.asarray(around, dtype=np.int64).reshape(-1, 1, 3) + _ball(reach)).reshape(-1, 3)
        inside, at = self._linear(ball)
        fresh = np.frombuffer(self._kinds, dtype=np.uint8)[at] == self.UNKNOWN
        return tuple(dict.fromkeys(map(tuple, ball[inside][fresh].tolist())))


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
    p.add_argument("--swarm-pilot-min", type=int, default=SWARM_MIN, metavar="N",
                   help="a swarm host flies its drones with the autopilot's swarm form (one pilot over arrays, same "
                        f"decisions) when it has one and flies at least N drones (default {SWARM_MIN})")
    add_entity_args(p)
    args = p.parse_args(argv)
    try:
        drones = parse_drones(args.id)
        if len(drones) > 1 and not args.host:
            raise UsageError("several drones in one process need --host Hnn")
        logger = setup_logging(args.log_level, args.host or drones[0])
        main(zenoh_config(args), drones=drones, autopilot=args.autopilot, keys=Keys(args.root), logger=logger,
             host=args.host, connect_timeout=args.connect_timeout, grace=args.grace, swarm_min=args.swarm_pilot_min)
    except UsageError as err:
        print(f"dronesim drone: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(cli())
