"""The drone process's protocol (a lone drone, the seed's D01, or a swarm host flying several): a pure state machine,
no network and no clock. Its Zenoh adapter (entities/drone_node.py) feeds it its `Input`s, in batches of everything
queued (`DroneProcess.receive`), and carries out the `Effect`s it returns.

Deciding. Each DRONES phase it flies every hosted drone's autopilot together (`fly_pilots`: every drone's questions
of a round at once), or a swarm host's drones with the autopilot's one pilot over arrays (`fly_swarm`, when it has
that form). Each round of questions is answered from the chart where it can; the rest goes out in ASKs (one per
Ask.MAX_CELLS cells, together), and the plan goes on when every answer is in. Then a lone drone publishes its NPS, a
swarm host the MOVES of all its drones in one message. A TURN that repeats the last one gets the same moves again. A
later TURN or an OVER received while a turn is being decided ends that turn's decision without publishing it, and a
batch acts only on its latest TURN: a process that was frozen or slow catches up instead of planning turns that are
long gone.

Sensing without a round trip. The process keeps a chart of the kinds the environment told it (buildings never move,
so a cell's kind holds for the whole game). Once admitted, with an environment present (a query sent before one
serves goes unanswered), it asks for the environment's static map (ENV/MAP, `_poll_map`) and the static world around
its drones' starts; until the map comes, once it has sent its moves, it asks ahead (an ASK for turn 0, answered at
once) for the never-told cells around where its drones are going (`_prefetch`). A question about charted cells is
answered from the chart plus the drones in them, which the turn's orders list (every alive drone's cell at the start
of the turn): exactly the CellInfo the environment would give for that turn. A question the chart cannot answer yet
waits while cells asked ahead are on their way (they usually answer it: the first turn's sensing then asks nothing,
and a swarm's environment never decodes a turn's thousands of cells) and is asked once none is. The autopilots see
only the cells they ask for, so decisions, and journals, do not change. Without a chart (`chart=False`,
`dronesim drone --no-chart`, to measure it) nothing is asked ahead or charted: every question goes to the environment.

The environment away. An ASK nobody answered is asked again as soon as an environment is present (at once if one
is), for up to `patience` seconds from the first miss; after that, or once the turn is superseded, the drones decide
without those answers.
"""

from __future__ import annotations

import functools
import itertools
import logging
from collections.abc import Callable, Generator, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from schema import Ans, Ask, Cell, CellInfo, CellKind, MapRequest, Moves, Nps, Over, Phase, StepTable, Turn, WorldMap
from schema.errors import OutOfRange, Refusal, RemoteInputError
from schema.messages import _KINDS, AROUND, OrderTable, Welcome
from schema.tables import drone_number
from schema.tuning import (
    ASK_AHEAD_MAX_DRONES,
    ASK_AHEAD_REACH,
    CHART_FEW_CELLS,
    COORDINATOR_GRACE_S,
    MAP_TRIES,
    PREFETCH_CHUNK,
    SWARM_MIN,
)
from world.grid import World, inside_rows, linear_rows

from .autopilots import make_autopilot, make_swarm, pilot_class
from .autopilots.base import NO_ANSWER, Answers, Decision, fly_pilots, fly_swarm

# --------------------------------------------------------------------------- effects and inputs


@dataclass(frozen=True, slots=True)
class SendMoves:
    """Publish a lone drone's NPS (on its NPS key) or a swarm host's MOVES (on its MOVES key)."""

    msg: Nps | Moves


@dataclass(frozen=True, slots=True)
class Query:
    """Send an ASK (ENV/ASK) or a MapRequest (ENV/MAP); once the query is finished, feed back `Answer(ref, ...)`."""

    ref: int
    msg: Ask | MapRequest


@dataclass(frozen=True, slots=True)
class Timer:
    """Feed back `Expired(ref)` in `seconds` (it replaces any timer set before)."""

    ref: int
    seconds: float


Effect = SendMoves | Query | Timer | Refusal


@dataclass(frozen=True, slots=True)
class Answer:
    """`Query(ref)` is finished: its replies, each the decoded message or the RemoteInputError of an error reply or a
    malformed one; none if nobody answered in time."""

    ref: int
    replies: tuple[Ans | WorldMap | RemoteInputError, ...]


@dataclass(frozen=True, slots=True)
class EnvPresence:
    """An environment process's presence token appeared (`alive`) or went away."""

    session: str
    alive: bool


@dataclass(frozen=True, slots=True)
class Expired:
    """The timer `Timer(ref)` ran out."""

    ref: int


Input = Turn | Over | Answer | EnvPresence | Expired
#: A turn's plan (`fly_pilots` or `fly_swarm`): it yields questions, and returns the turn's moves.
Plan = Generator[Any, Any, "StepTable | dict[str, Decision]"]


# --------------------------------------------------------------------------- the process


@dataclass(slots=True, eq=False)
class _Round:
    """One round of a plan's questions: its parts (a drone's cells, or a chunk of a swarm's) asked by ASK, the answers
    so far, and how the answers become the plan's reply."""

    parts: dict[str, tuple[Cell, ...]]
    answers: dict[str, Answers]
    reply: Callable[[dict[str, Answers]], object]
    asking: set[int] = field(default_factory=set)  # refs of its ASKs on their way
    unanswered: list[str] = field(default_factory=list)  # parts nobody answered (the environment is away)
    timer: int | None = None  # the timer of its patience, once a part went unanswered


@dataclass(eq=False)
class _Deciding:
    """The turn being decided: its plan and the round of questions it waits on."""

    turn: Turn
    key: tuple
    plan: Plan
    round: _Round | None = None
    offline: bool = False  # no more ASKs: what the chart cannot answer gets no answer (patience over, or superseded)
    question: object = None  # the plan's next question, held while what was asked ahead is on its way (never None)

    @functools.cached_property
    def occupancy(self) -> dict[Cell, tuple[str, ...]]:
        return occupancy_of(self.turn.orders)


class DroneProcess:
    """A drone process's protocol: feed it inputs, carry out the effects it returns (see the module)."""

    def __init__(self, welcome: Welcome, *, drones: Sequence[str], autopilot: str, logger: logging.Logger,
                 host: str | None = None, swarm_min: int = SWARM_MIN, patience: float = COORDINATOR_GRACE_S,
                 chart: bool = True) -> None:
        self.sender = host or drones[0]
        self.host = host
        self.log = logger
        self.patience = patience
        self.welcome = welcome
        size = welcome.world.size
        self.swarm = make_swarm(autopilot, world_size=size, drones=[drone_number(d) for d in drones],
                                least=swarm_min) if host else None
        # (each made as its drone is first flown: a D* pilot of a big world costs milliseconds, which a host flying
        # hundreds spends deciding its first turn, while it says so, rather than before it can hear one)
        self.pilots: dict[str, Any] = {} if self.swarm else Pilots(autopilot, size)
        if self.swarm:
            logger.info("flying %d drones with the %s autopilot's swarm form", len(drones), autopilot)
        self.chart = Chart(size)
        # False: every question goes to the environment (a benchmark's switch), or the autopilot asks none
        self.charting = chart and pilot_class(autopilot).senses
        self.over: Over | None = None
        self._numbers = np.array(sorted(drone_number(d) for d in drones))
        self._mine = set(drones)
        self._refs = itertools.count(1)
        self._queries: dict[int, tuple[Ask | MapRequest, tuple[str, ...]]] = {}  # ref -> (query, parts asked)
        self._map_asked: list[int] = []  # the turns in which the map was asked
        self._map_settled = False  # charted, or refused: not asked again
        self._env: set[str] = set()  # the sessions of the environment processes present
        self._deciding: _Deciding | None = None
        self._done: tuple[tuple, StepTable | dict[str, Decision]] | None = None  # the last turn decided: key, moves

    def deciding(self) -> int | None:
        """The turn being decided (None: none); another thread may read it (entities/drone_node.py `Deciding`)."""
        d = self._deciding
        return None if d is None else d.turn.turn

    # ------------------------------------------------------------------ inputs

    def start(self) -> list[Effect]:
        """Once admitted (this process exists once admitted), before the game: ask for the map and the static world
        around the starts, now if an environment is present, else when one appears (`receive` calls it again)."""
        if not (self.charting and self._env) or self._map_asked or self._done or self._deciding:
            return []
        return self._prefetch(0, sorted({c for d, c in self.welcome.starts.cells().items() if d in self._mine}))

    def receive(self, inputs: Iterable[Input]) -> list[Effect]:
        """Everything queued, in order of arrival: it acts only on the latest DRONES TURN among them."""
        effects: list[Effect] = []
        latest: Turn | None = None
        for item in inputs:
            match item:
                case Turn(phase=Phase.DRONES):
                    latest = item
                case Over():
                    if self.over is None:
                        self.log.info("OVER: %s", item.text)
                    self.over = item
                case Answer(ref, replies):
                    effects += self._answered(ref, replies)
                case EnvPresence(session, alive):
                    (self._env.add if alive else self._env.discard)(session)
                    effects += self.start() if alive else []
                case Expired(ref):
                    self._expired(ref)
        if self.over is not None:
            self._deciding = None  # the game is over: nothing more to decide or to say
            return effects
        if latest is not None:
            effects += self._turn(latest)
        return effects + self._advance()

    # ------------------------------------------------------------------ turns

    def _plan(self, turn: Turn) -> tuple[tuple, Plan]:
        """The key of `turn`'s orders for this process's drones (a repeat has the same) and its plan."""
        if self.swarm is not None:  # one pilot over arrays, reading its drones' rows of the orders
            rows = turn.orders.rows[np.isin(turn.orders.numbers, self._numbers)]
            return (turn.turn, rows.tobytes()), fly_swarm(self.swarm, rows)
        orders = turn.orders.orders(self._mine)
        return (turn.turn, orders), fly_pilots(self.pilots, orders, host=self.host)

    def _turn(self, turn: Turn) -> list[Effect]:
        key, plan = self._plan(turn)
        if (deciding := self._deciding) is not None:
            if deciding.key == key:
                return []  # a repeat of the TURN being decided: its moves go out when decided
            self._finish_offline(deciding)  # superseded: decided without asking anything more, and not sent
        if self._done is not None and self._done[0] == key:  # a repeat of the last TURN: the same moves
            self._deciding = None
            return self._messages(turn, self._done[1])
        self._deciding = _Deciding(turn, key, plan)
        return self._poll_map(turn.turn) if self.charting else []

    def _advance(self) -> list[Effect]:
        """Take the turn being decided as far as the answers in hand allow; once decided, send its moves."""
        d = self._deciding
        effects: list[Effect] = []
        if d is None or (moves := self._run(d, effects)) is None:
            return effects
        self._deciding = None
        self._done = (d.key, moves)
        effects += self._messages(d.turn, moves)
        if self.charting and not self.chart.complete:  # around where its drones mean to be: their next
            effects += self._prefetch(d.turn.turn, sorted(set(_cells_of(moves))))  # sensing, asked ahead
        return effects

    def _run(self, d: _Deciding, effects: list[Effect]) -> StepTable | dict[str, Decision] | None:
        """Drive `d`'s plan with the answers in hand (asking for the others): its moves, or None while it waits."""
        while True:
            r = d.round
            if r is not None and (r.asking or (r.unanswered and not self._settle_unanswered(d, r, effects))):
                return None  # answers on their way, or an environment awaited
            try:  # the plan's next question (`r`'s answers given), or its moves
                if d.question is not None:
                    question, d.question = d.question, None
                else:
                    question = next(d.plan) if r is None else d.plan.send(r.reply(r.answers))
            except StopIteration as stop:
                return stop.value
            d.round = r = self._pose(d, question)
            if r.parts and not d.offline and self._asked_ahead():  # the chart cannot answer it yet, but
                d.question, d.round = question, None  # cells asked ahead are on their way: it waits for them
                return None
            if d.offline:
                r.answers.update({p: {} for p in r.parts})
            else:
                effects += self._ask(d.turn.turn, r, list(r.parts))

    def _asked_ahead(self) -> bool:
        """Is an ASK sent ahead (for the static world, answered at once) on its way while an environment is present?
        (Not the map: nobody may serve it, and it is not waited for.)"""
        return bool(self._env) and any(not parts and isinstance(q, Ask) for q, parts in self._queries.values())

    def _finish_offline(self, d: _Deciding) -> None:
        """Let a superseded plan end (the autopilots' memory stays as it would be): the questions the chart cannot
        answer get no answer, nothing more is asked, and its moves are not sent."""
        d.offline = True
        if (r := d.round) is not None:  # what it waits for gets no answer (`_settle_unanswered`)
            r.asking.clear()
            r.unanswered = [p for p in r.parts if p not in r.answers]
        self._run(d, [])

    def _messages(self, turn: Turn, moves: StepTable | dict[str, Decision]) -> list[Effect]:
        """A turn's moves as messages: a swarm host's MOVES (none if it has no drone left), a lone drone's NPS."""
        if isinstance(moves, StepTable):
            return [SendMoves(Moves(turn=turn.turn, sender=self.sender, moves=moves))] if moves else []
        return [SendMoves(Nps(turn=turn.turn, sender=d, pos=dec.pos, note=dec.note, ranked=dec.ranked))
                for d, dec in moves.items()]

    # ------------------------------------------------------------------ questions

    def _pose(self, d: _Deciding, question: Any) -> _Round:
        """A plan's question as a round: what the chart answers, and the parts left to ask."""
        if isinstance(question, np.ndarray):  # a swarm pilot's cells: their kinds
            kinds = self.chart.kinds(question)
            missing = np.flatnonzero(kinds == Chart.UNKNOWN)
            wanted = list(map(tuple, question[missing].tolist()))
            asked = list(dict.fromkeys(wanted))
            parts = {f"{self.sender}#{i}": tuple(asked[i:i + Ask.MAX_CELLS])
                     for i in range(0, len(asked), Ask.MAX_CELLS)}

            def kinds_of(answers: dict[str, Answers]) -> np.ndarray:
                told = {c: info.kind for got in answers.values() for c, info in got.items()}
                kinds[missing] = [told.get(c, NO_ANSWER) for c in wanted]
                return kinds

            return _Round(parts, {}, kinds_of)
        # one pilot per drone: each drone's cells as CellInfo, from the chart when it knows them all
        kind = self.chart.kind
        answers: dict[str, Answers] = {}
        asking: dict[str, tuple[Cell, ...]] = {}
        for drone, wanted in question.items():
            infos: dict[Cell, CellInfo] = {}
            for c in wanted:
                if (k := kind(c)) is None:  # the chart cannot answer it: the drone's cells are asked
                    asking[drone] = wanted
                    break
                infos[c] = CellInfo(pos=c, kind=k, drones=d.occupancy.get(c, ()))
            else:
                answers[drone] = infos
        return _Round(asking, answers, lambda got: got)

    def _ask(self, turn: int, r: _Round, names: list[str]) -> list[Query]:
        """ASKs for the parts `names` of round `r`, batched up to Ask.MAX_CELLS cells (a part whole)."""
        batches: list[list[str]] = []
        size = Ask.MAX_CELLS
        for name in names:
            if size + len(r.parts[name]) > Ask.MAX_CELLS:
                batches.append([])
                size = 0
            batches[-1].append(name)
            size += len(r.parts[name])
        queries = [self._query(Ask(turn=turn, sender=self.sender, cells=tuple(c for p in b for c in r.parts[p])),
                               tuple(b)) for b in batches]
        r.asking.update(q.ref for q in queries)
        return queries

    def _settle_unanswered(self, d: _Deciding, r: _Round, effects: list[Effect]) -> bool:
        """Parts of `r` nobody answered: given no answer once `d` is offline (True: the plan goes on), else asked again
        now that an environment is present, or left until one is (False)."""
        if d.offline:
            r.answers.update({p: {} for p in r.unanswered})
            r.unanswered = []
            return True
        if r.timer is None:
            r.timer = next(self._refs)
            effects.append(Timer(r.timer, self.patience))
            self.log.warning("no environment answered %s: waiting for it", ", ".join(r.unanswered))
        if self._env:
            names, r.unanswered = r.unanswered, []
            effects += self._ask(d.turn.turn, r, names)
        return False

    def _expired(self, ref: int) -> None:
        """Patience is over: the turn being decided goes on without the answers it still waits for."""
        d = self._deciding
        if d is not None and d.round is not None and d.round.timer == ref:
            self.log.error("no environment answered %s within %g s", ", ".join(d.round.unanswered) or "an ASK",
                           self.patience)
            d.offline = True

    def _query(self, msg: Ask | MapRequest, parts: tuple[str, ...] = ()) -> Query:
        ref = next(self._refs)
        self._queries[ref] = (msg, parts)
        return Query(ref, msg)

    def _answered(self, ref: int, replies: tuple) -> list[Effect]:
        """A query is finished: learn what it told, and hand the answers to the round that asked."""
        asked = self._queries.pop(ref, None)
        if asked is None:
            return []
        msg, parts = asked
        if isinstance(msg, MapRequest):
            return self._map_answered(replies)
        effects: list[Effect] = []
        cells = msg.asked()
        got: dict[Cell, CellInfo] | None = None  # None: nobody answered
        for reply in replies:
            try:
                reply = _reply(reply)
                reply.check_fits(cells)
                if self.charting:
                    self.chart.learn(cells, reply.kinds)
                got = dict(zip(cells, reply.infos(cells))) if parts else {}
            except RemoteInputError as err:
                effects.append(Refusal(f"ANS for {', '.join(parts) or 'cells asked ahead'}", err))
                got = got or {}
        d = self._deciding
        if d is not None and (r := d.round) is not None and ref in r.asking:
            r.asking.discard(ref)
            if got is None:
                r.unanswered += parts
            else:
                r.answers.update({part: {c: got[c] for c in r.parts[part] if c in got} for part in parts})
        return effects

    # ------------------------------------------------------------------ the chart

    def _poll_map(self, turn: int) -> list[Effect]:
        """Ask for the environment's map if it was never asked, or if nobody answered it in an earlier turn (up to
        MAP_TRIES times: the environment may still be building its world); `turn`: the turn being played (0 before
        the game)."""
        asked = self._map_asked
        if (self._map_settled or len(asked) >= MAP_TRIES or asked and turn <= asked[-1]
                or any(isinstance(q, MapRequest) for q, _ in self._queries.values())):  # (or it is on its way)
            return []
        asked.append(turn)
        return [self._query(MapRequest(turn=0, sender=self.sender))]

    def _map_answered(self, replies: tuple) -> list[Effect]:
        if not replies:
            return []  # nobody answered: asked again in a later turn
        self._map_settled = True
        try:
            self.chart.learn_map(_reply(replies[0]))
        except RemoteInputError as err:
            return [Refusal("MAP", err)]
        self.log.info("charted the environment's map: %d cells", len(self.chart))
        return []

    def _prefetch(self, turn: int, around: list[Cell]) -> list[Effect]:
        """Ask now, for the static world (turn 0: answered at once), the kinds of the cells around `around` that this
        process has not been told yet (nothing once the whole map is charted); `turn`: as for `_poll_map`."""
        effects = self._poll_map(turn)
        cells = self.chart.unknown(around)
        if cells and len(around) <= ASK_AHEAD_MAX_DRONES:  # a few drones: ask farther at once, and again only
            cells = self.chart.unknown(around, reach=ASK_AHEAD_REACH)  # every few turns (a swarm: its next ring)
        chunk = min(PREFETCH_CHUNK, Ask.MAX_CELLS)
        return effects + [self._query(Ask(turn=0, sender=self.sender, cells=cells[i:i + chunk]))
                          for i in range(0, len(cells), chunk)]


class Pilots(dict):
    """One autopilot per drone, each made when first asked for (`make_autopilot`)."""

    def __init__(self, autopilot: str, size: Cell) -> None:
        super().__init__()
        self.autopilot, self.size = autopilot, size

    def __missing__(self, drone: str) -> Any:
        pilot = self[drone] = make_autopilot(self.autopilot, world_size=self.size)
        return pilot


def _reply(reply: Ans | WorldMap | RemoteInputError) -> Any:
    """A query's reply: the message, or the RemoteInputError of an error reply or a malformed one raised."""
    if isinstance(reply, RemoteInputError):
        raise reply
    return reply


def _cells_of(moves: StepTable | dict[str, Decision]) -> Iterable[Cell]:
    """Where a turn's moves take the drones."""
    if isinstance(moves, StepTable):
        return map(tuple, moves.column("pos").tolist())
    return (dec.pos for dec in moves.values())


@functools.cache
def _ball(reach: int) -> np.ndarray:
    """The offsets within `reach` steps of a cell (6-connectivity), itself excluded, nearest first (the neighbours in
    AROUND order)."""
    r = range(-reach, reach + 1)
    farther = [o for n in range(2, reach + 1) for o in itertools.product(r, r, r) if sum(map(abs, o)) == n]
    return np.asarray([*AROUND, *farther], dtype=np.int64)


def occupancy_of(orders: OrderTable) -> dict[Cell, tuple[str, ...]]:
    """Which drones are in which cell at the start of a turn: the orders list every alive drone."""
    cells: dict[Cell, list[str]] = {}
    for d, (x, y, z) in zip(orders.ids(), orders.column("pos").tolist()):
        cells.setdefault((x, y, z), []).append(d)
    return {c: tuple(sorted(ds)) for c, ds in cells.items()}


class Chart:
    """The kinds of the cells the environment told this process: one byte per cell of the world, 255 until told.
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
        kinds = np.frombuffer(self._kinds, dtype=np.uint8)
        kinds[:] = CellKind.EMPTY  # in place: no temporary array of the world's size (an np.where of the enum is int64)
        kinds[grid.ravel()] = CellKind.BUILDING
        self.complete = True

    def _at(self, cell: Cell) -> int | None:
        x, y, z = cell
        nx, ny, nz = self.size
        return (x * ny + y) * nz + z if 0 <= x < nx and 0 <= y < ny and 0 <= z < nz else None

    def kind(self, cell: Cell) -> CellKind | None:
        """The cell's kind, None if never told."""
        if (i := self._at(cell)) is None:
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
        if len(cells) <= CHART_FEW_CELLS:  # a few: cell by cell (numpy's fixed cost dominates)
            for cell, k in zip(cells, kinds):
                if (i := self._at(cell)) is not None:
                    self._kinds[i] = k
            return
        inside, at = self._linear(np.asarray(cells, dtype=np.int64).reshape(-1, 3))
        np.frombuffer(self._kinds, dtype=np.uint8)[at] = np.frombuffer(kinds, dtype=np.uint8)[inside]

    def unknown(self, around: Sequence[Cell], reach: int = 1) -> tuple[Cell, ...]:
        """The cells within `reach` steps (6-connectivity) of the `around` cells whose kind was never told, once each,
        in order (by default their neighbours, in AROUND order)."""
        if reach == 1 and len(around) * 6 <= CHART_FEW_CELLS:  # a few: cell by cell
            near = ((x + dx, y + dy, z + dz) for x, y, z in around for dx, dy, dz in AROUND)
            return tuple(dict.fromkeys(c for c in near if self.kind(c) is None))
        ball = (np.asarray(around, dtype=np.int64).reshape(-1, 1, 3) + _ball(reach)).reshape(-1, 3)
        inside, at = self._linear(ball)
        fresh = np.frombuffer(self._kinds, dtype=np.uint8)[at] == self.UNKNOWN
        return tuple(dict.fromkeys(map(tuple, ball[inside][fresh].tolist())))
