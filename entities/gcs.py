"""The ground station, pure: the seed's input check (correctForm), scripted plans, the console's reading of a
line, the display, and `Station`, the protocol every ground station plays (scripted, interactive, web, benchmark;
the console's own is `entities.console`).

A plan maps turns to targets: ``9,9,0`` (D01 from turn 1), ``D02=3,4,0`` (D02 from turn 1),
``D01=5,5,0@12`` (from turn 12). A script file holds one such item per line (``#`` comments).
"""

from __future__ import annotations

import bisect
import pathlib
import re
from collections import Counter, deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from itertools import takewhile

import numpy as np

from schema import (
    Aim,
    AimTable,
    Cell,
    Done,
    DroneState,
    DroneStatus,
    EndReason,
    Intent,
    Message,
    Note,
    Over,
    Phase,
    Status,
    Turn,
    UsageError,
    Welcome,
)
from schema.tables import drone_name
from schema.tuning import ANSWER_AHEAD, DONE_RETRY_MIN_S, DONE_RETRY_S, DONE_RETRY_TURNS, FINAL_STATUS_WAIT, PUT_GAP
from world.grid import World, build_world, in_bounds

from .tasks import Tasks

_ITEM = re.compile(r"\s*(?:(?P<drone>D\d{2,5})\s*[= ]\s*)?"
                   r"(?P<cell>-?\d+\s*,\s*-?\d+\s*,\s*-?\d+)\s*(?:@\s*(?P<turn>\d+))?\s*\Z")


def correct_form(text: str, size: Cell, world: World | None = None) -> Cell:
    """The seed's CORRECTFORM: ``x,y,z`` (spaces allowed), a cell `check_cell` accepts."""
    try:
        x, y, z = (int(p) for p in text.replace(" ", ",").split(",") if p.strip())
    except ValueError:
        raise UsageError(f"{text!r} is not x,y,z") from None
    return check_cell((x, y, z), size, world)


def check_cell(cell: Cell, size: Cell, world: World | None = None) -> Cell:
    """`cell` if it is inside the world (of `size`) and, given the `world`, not a building cell (no drone can
    get there: a seed drone would wander to the turn limit looking for a way in)."""
    if not in_bounds(cell, size):
        raise UsageError(f"{cell} is outside the world: 0 <= x < {size[0]}, 0 <= y < {size[1]}, 0 <= z < {size[2]}")
    if world is not None and world.is_building(cell):
        raise UsageError(f"{cell} is inside a building: no drone can get there")
    return cell


def gcs_done(turn: int, targets: Mapping[str, Cell], intent: Intent,
             in_force: Mapping[str, Cell] | None = None) -> Done:
    """The ground station's answer in the GCS phase of `turn`: its DONE, carrying the targets
    (``GCS:D01:TGT:x:y:z``) in one message. The seed re-sent every target every turn; the coordinator
    keeps them, so only those that differ from `in_force` (the targets of the last STATUS) are sent: a
    swarm's GCS phase costs what changes, not what is."""
    keep = in_force or {}
    return Done(turn=turn, sender="GCS", phase=Phase.GCS, intent=intent,
                targets=AimTable.of(Aim(drone=d, pos=c) for d, c in sorted(targets.items()) if keep.get(d) != c))


def turns_to_answer_ahead(plan: Plan, turn: int, answered: int, *, last: int | None = None,
                          horizon: int = ANSWER_AHEAD) -> list[int]:
    """The turns after `turn` a scripted station can answer now: up to `horizon` of them, before the
    plan's next change (and before `last`), except those already answered (up to `answered`: none of them brings a
    change, so the plan is read from the first turn not answered on)."""
    return list(takewhile(lambda u: not plan.at(u) and (last is None or u < last),
                          range(max(turn, answered) + 1, turn + horizon + 1)))


def _plan_items(texts: Iterable[str], size: Cell, default_drone: str,
                world: World | None) -> Iterable[tuple[int, str, Cell]]:
    """(turn, drone, cell) of each target item in `texts`, in the order written; UsageError on a bad one
    (`correct_form`'s checks, with the `world`'s buildings if given)."""
    for text in texts:
        for item in map(str.strip, text.split(";")):
            if not item or item.startswith("#"):
                continue
            m = _ITEM.match(item)
            try:
                if not m:
                    raise UsageError("expected [Dnn=]x,y,z[@turn]")
                turn = int(m["turn"] or 1)
                if turn < 1:
                    raise UsageError("turns start at 1")
                yield turn, m["drone"] or default_drone, correct_form(m["cell"], size, world)
            except UsageError as err:
                raise UsageError(f"bad target {item!r}: {err}") from None


@dataclass(frozen=True, slots=True)
class Plan:
    """Targets by turn: ``items`` holds (turn, drone, cell), sorted."""

    items: tuple[tuple[int, str, Cell], ...]

    @classmethod
    def parse(cls, texts: Iterable[str], size: Cell, default_drone: str = "D01", world: World | None = None) -> Plan:
        # a stable sort: within a turn, the last written wins
        return cls(tuple(sorted(_plan_items(texts, size, default_drone, world), key=lambda item: item[0])))

    @staticmethod
    def drones_of(texts: Iterable[str], size: Cell, default_drone: str = "D01", world: World | None = None) -> set[str]:
        """The drones the plan `texts` gives targets to, every item checked as `parse` checks it,
        none kept (a process that needs no plan checks a swarm's thousands of targets for free)."""
        return {drone for _, drone, _ in _plan_items(texts, size, default_drone, world)}

    @classmethod
    def load(cls, path: str, size: Cell, world: World | None = None) -> Plan:
        try:
            lines = pathlib.Path(path).read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise UsageError(f"cannot read the target script {path}: {exc}") from None
        return cls.parse((ln.split("#", 1)[0] for ln in lines), size, world=world)

    def at(self, turn: int) -> dict[str, Cell]:
        """Targets that take effect at `turn` (found by bisection: `items` are sorted by turn)."""
        lo = bisect.bisect_left(self.items, (turn,))
        hi = bisect.bisect_left(self.items, (turn + 1,), lo)
        return {d: c for _, d, c in self.items[lo:hi]}

    @property
    def last_turn(self) -> int:
        return self.items[-1][0] if self.items else 0

    def drones(self) -> set[str]:
        return {d for _, d, _ in self.items}


def parse_command(line: str, size: Cell, drones: Sequence[str], world: World | None = None) -> dict[str, Cell]:
    """One interactive line: ``x,y,z`` (the only or first drone) or ``Dnn x,y,z``."""
    head = re.match(r"\s*(D\d{2,5})(?:\s*=\s*|\s+)(.*)\Z", line)  # "D02 1 2 3", "D02=1,2,3"
    drone_part, cell_part = (f"{head[1]}=", head[2]) if head else ("", line)
    line = drone_part + re.sub(r"(?<=\d)[\s,]+(?=-?\d)", ",", cell_part.strip())  # "1 2 3" -> "1,2,3"
    m = _ITEM.match(line)
    if not m or m["turn"]:
        raise UsageError(f"{line.strip()!r}: type x,y,z or Dnn x,y,z")
    drone = m["drone"] or drones[0]
    if drone not in drones:
        raise UsageError(f"unknown drone {drone}: this game flies {', '.join(drones)}")
    return {drone: correct_form(m["cell"], size, world)}


def describe(s: DroneStatus) -> str:
    """One drone's line: position, alive/dead (the seed's display), target and notes."""
    if s.state is DroneState.ALIVE:
        state = "reached its target" if s.note is Note.REACHED else (
            "target UNREACHABLE, hovering" if s.note is Note.UNREACHABLE else
            "alive, held up by other drones" if s.note is Note.STUCK else "alive")
    else:
        state = f"{s.state.value} ({s.cause.value.lower()})"
    target = "no target" if s.target is None else f"target {s.target}"
    return f"{s.drone} at {s.pos}: {state}, {target}"


def format_status(status: Status, limit: int = 16) -> str:
    lines = [f"turn {status.turn}:", *(f"  {describe(s)}" for s in status.drones[:limit])]
    if len(status.drones) > limit:
        counts = dict(Counter(s.state.value for s in status.drones))
        lines.append(f"  ... {len(status.drones) - limit} more; totals: {counts}")
    return "\n".join(lines)


class Tracks:
    """The last STATUS and each drone's path so far, kept as the game goes (memory grows with the moves
    made, not with the turns played: a long game of hovering drones costs nothing). A STATUS adds the
    rows of the drones that moved, as arrays (a swarm's turn is a few array operations); the paths are
    read from them when asked for."""

    def __init__(self) -> None:
        self.last: Status | None = None
        self._moves: list[tuple[np.ndarray, np.ndarray]] = []  # (drone numbers, their cells) per STATUS

    def add(self, status: Status) -> None:
        last, self.last = self.last, status
        numbers, pos = status.drones.numbers, status.drones.column("pos")
        if last is not None and np.array_equal(last.drones.numbers, numbers):
            moved = np.flatnonzero((pos != last.drones.column("pos")).any(axis=1))
            if len(moved):
                self._moves.append((numbers[moved], pos[moved]))
        else:
            self._moves.append((numbers.copy(), pos.copy()))

    @property
    def paths(self) -> dict[str, list[Cell]]:
        """Each drone's path, without repeats of consecutive cells."""
        paths: dict[str, list[Cell]] = {}
        for numbers, cells in self._moves:
            for n, (x, y, z) in zip(numbers.tolist(), cells.tolist()):
                path = paths.setdefault(drone_name(n), [])
                if not path or path[-1] != (x, y, z):
                    path.append((x, y, z))
        return paths


def targets_of(status: Status) -> Mapping[str, Cell]:
    """Each drone's target in force, of those that have one (read from the STATUS's columns)."""
    targets, ids = status.drones.column("target"), status.drones.ids()
    has = np.flatnonzero(targets[:, 0] >= 0)
    return {ids[i]: (x, y, z) for i, (x, y, z) in zip(has.tolist(), targets[has].tolist())}


@dataclass(frozen=True, slots=True)
class Ground:
    """What a ground station knows once admitted: the world (rebuilt with the environment's own recipe),
    the drones of the game with their starts, and its plan of targets checked against both."""

    world: World
    starts: dict[str, Cell]
    plan: Plan

    @classmethod
    def from_welcome(cls, welcome: Welcome, plan_texts: Iterable[str], script: str | None) -> Ground:
        starts = welcome.starts.cells()
        world = build_world(welcome.world, starts.values())
        return cls(world, starts, cls.plan_of(world, list(starts), plan_texts, script))

    @staticmethod
    def plan_of(world: World, drones: Sequence[str], plan_texts: Iterable[str], script: str | None) -> Plan:
        """The plan of a ground station of the game of `drones` (in order) in `world`: its `script`'s, else its
        targets', every item checked against both (UsageError; `dronesim up` checks it so before any process
        starts)."""
        size = world.size
        plan = Plan.load(script, size, world) if script else Plan.parse(plan_texts, size, drones[0], world)
        if unknown := plan.drones() - set(drones):
            raise UsageError(f"the plan names {', '.join(sorted(unknown))}; this game flies {', '.join(drones)}")
        return plan


#: End reasons whose last turn produced a STATUS (the others end a turn before its STATUS).
OBSERVED_ENDS = frozenset({EndReason.NO_DRONE_ALIVE, EndReason.ALL_REACHED, EndReason.SETTLED, EndReason.TURN_LIMIT})


@dataclass(frozen=True, slots=True)
class SendDone:
    """Publish this DONE on the ground station's key (`ahead`: before its phase has begun)."""

    msg: Done
    ahead: bool = False


@dataclass(frozen=True, slots=True)
class Show:
    """Show this text to the person at the station."""

    text: str


@dataclass(frozen=True, slots=True)
class End:
    """The game is over and the station has seen all it will see of it: the process may finish."""

    over: Over


Effect = SendDone | Show | End


class Station:
    """The ground station's side of the protocol: fed the coordinator's messages, it returns what to do. No
    network, no clock (times are seconds of any monotonic clock). Each GCS phase it answers with a DONE
    carrying the targets that change (`gcs_done`), its plan's of that turn and the person's. Who decides, and when:
    - a script (not `hold`) answers at once from its plan, intent FINAL from the plan's
      last turn (given `quit_at`: CONTINUE until that turn, then QUIT), and answers ahead the coming phases
      in which its plan has nothing new (`turns_to_answer_ahead`): the coordinator takes them without a
      round trip and without announcing them, so the station goes by STATUS;
    - a held station (`hold`: the console, the web page) keeps the phase `pending` until `answer` is called;
    - a station taking `goals` as they come (ROS 2's, `want`) answers no phase ahead and never says its plan
      is final (the game goes on to its turn limit, or until someone quits);
    - a lifelong script (`tasks`) answers each phase in it, once the STATUS of the turn before is in: its plan's
      targets, then a new target for every drone that reached its own (`entities.tasks`); it never says its
      plan is final either.
    It keeps every drone's path (`tracks`), forgets the drones that died or were lost, takes over the targets
    in force of a game it joins late, and ends (`End`) after OVER once the STATUS of the last turn is in, or
    `FINAL_STATUS_WAIT` s after OVER.

    Its DONEs may be lost on the way: a router keeps at most `PUT_RATE` puts a second from one session on its
    key (schema/acl.py `flood_filters`; a buggy or hostile second session floods it in vain). So the DONEs of its
    own making (`receive`) go out `PUT_GAP` s apart at least, queued until due (`tick`); a phase announced although
    it was answered ahead is answered again (the coordinator announces a phase whose DONE it does not hold); and
    a phase's DONE goes out again, a few turns' time later (`DONE_RETRY_TURNS`, between `DONE_RETRY_MIN_S` and
    `DONE_RETRY_S` s), then twice as long each time, until that turn's STATUS comes (the coordinator takes a repeat
    of the DONE it holds as nothing new)."""

    def __init__(self, ground: Ground, *, hold: bool = False, quit_at: int | None = None, verbose: bool = False,
                 ahead: int = ANSWER_AHEAD, goals: bool = False, tasks: Tasks | None = None) -> None:
        self.ground, self.plan = ground, ground.plan
        self.hold, self.quit_at, self.verbose = hold, quit_at, verbose
        self.scripted = not hold
        # phases a script answers ahead at most (0: none; the benchmark's switch)
        self.ahead = 0 if goals or tasks is not None else ahead
        self.goals, self.tasks = goals, tasks
        self._due: int | None = None  # lifelong: a GCS phase waiting for the STATUS of the turn before it
        self.wanted: dict[str, Cell] = {}  # the targets this station wants, of drones alive
        self.gone: set[str] = set()  # drones dead or lost: nothing more to say to them
        self.tracks = Tracks()
        self.answered = 0  # the last turn whose GCS phase this station has answered (maybe ahead)
        self._outgoing: deque[SendDone] = deque()  # DONEs not sent yet: one every PUT_GAP s (`_paced`)
        self._next_send = float("-inf")  # when the next DONE may go out
        self._unacked: tuple[SendDone, float, float] | None = None  # a phase's DONE, when it goes out again, and
        # how long after that, until its STATUS comes
        self._ahead_sent: dict[int, SendDone] = {}  # the DONEs answered ahead, until their phase (`_lost`)
        self._status_at: tuple[int, float] | None = None  # the last STATUS's turn, and when it came
        self._turn_s: float | None = None  # seconds a turn lately (smoothed), once two STATUS came
        #: DONEs sent again: "announced" (answered ahead, its phase announced all the same: lost on the way),
        #: "timed out" (a phase's DONE whose STATUS did not come in time)
        self.resent: Counter[str] = Counter()
        self.pending: int | None = None  # a held GCS phase not answered yet
        self.over: Over | None = None
        self._over_since: float | None = None  # when OVER came, while its turn's STATUS is awaited
        self._joining = True  # until the first STATUS since admission: it tells the targets in force
        self.ended = False

    @property
    def status_turn(self) -> int:
        """The turn of the last STATUS (-1 before the first)."""
        return -1 if self.tracks.last is None else self.tracks.last.turn

    def receive(self, msg: Message, now: float) -> list[Effect]:
        """A message from the coordinator (TURN, STATUS or OVER), already screened by its turn clock."""
        if self.ended:
            return []
        return self._paced(self._receive(msg, now), now)

    def _receive(self, msg: Message, now: float) -> list[Effect]:
        match msg:
            case Turn(phase=Phase.GCS):
                if self._unacked is not None and msg.turn > self._unacked[0].msg.turn:
                    self._unacked = None  # a later phase: its DONE came
                return self._gcs_phase(msg.turn)
            case Turn():  # a held phase the coordinator closed without us (its GCS deadline passed)
                if self.pending is not None and self.pending <= msg.turn:
                    self.pending = None
                if self._due is not None and self._due <= msg.turn:
                    self._due = None
                if self._unacked is not None and msg.turn >= self._unacked[0].msg.turn:
                    self._unacked = None  # its GCS phase is over
            case Status():
                self._timed(msg.turn, now)
                return self._status(msg)
            case Over():
                return self._over(msg, now)
        return []

    def admitted(self, welcome: Welcome) -> list[Effect]:
        """Admitted again (the coordinator came back): it does not know what was answered ahead."""
        self.answered, self._joining = 0, True
        self._ahead_sent.clear()
        self._outgoing.clear()
        self._unacked = None
        return []

    def wake(self, now: float) -> float | None:
        """Seconds until `tick` has something to do (None: nothing, whatever the time)."""
        if self.ended:
            return None
        since = self._over_since
        dues = [since + FINAL_STATUS_WAIT if since is not None else None,
                self._next_send if self._outgoing else None,
                self._unacked[1] if self._unacked is not None and self.over is None else None]
        return min((max(0.0, due - now) for due in dues if due is not None), default=None)

    def tick(self, now: float) -> list[Effect]:
        """What is due at `now` without a message: a DONE queued or to send again, the end once the last STATUS is
        given up."""
        if self.ended:
            return []
        effects: list[Effect] = []
        if self._unacked is not None and self.over is None and now >= self._unacked[1]:
            done, _, wait = self._unacked
            self._unacked = (done, now + 2 * wait, 2 * wait)
            self.resent["timed out"] += 1
            self._outgoing.append(done)
        effects += self._release(now)
        since = self._over_since
        return effects + ([self._end()] if since is not None and now >= since + FINAL_STATUS_WAIT else [])

    def _paced(self, effects: list[Effect], now: float) -> list[Effect]:
        """`effects` with their DONEs queued, to go out PUT_GAP s apart; a phase's DONE (not one ahead) is kept to
        go out again until its turn's STATUS (`tick`)."""
        out: list[Effect] = []
        for effect in effects:
            if isinstance(effect, SendDone):
                self._outgoing.append(effect)
                if not effect.ahead:
                    wait = DONE_RETRY_S if self._turn_s is None else (
                        min(DONE_RETRY_S, max(DONE_RETRY_MIN_S, DONE_RETRY_TURNS * self._turn_s)))
                    self._unacked = (effect, now + wait, wait)
            else:
                out.append(effect)
        return self._release(now) + out

    def _release(self, now: float) -> list[Effect]:
        """The queued DONE due now, if any (the next one PUT_GAP s later); those of turns already played are
        dropped (the coordinator would refuse them as stale)."""
        while self._outgoing and self._outgoing[0].msg.turn <= self.status_turn:
            self._outgoing.popleft()
        if not self._outgoing or now < self._next_send:
            return []
        self._next_send = now + PUT_GAP
        return [self._outgoing.popleft()]

    def want(self, targets: Mapping[str, Cell]) -> dict[str, Cell]:
        """Take `targets` for the drones still flying; returns those that changed."""
        changed = {d: c for d, c in targets.items() if d not in self.gone and self.wanted.get(d) != c}
        self.wanted.update(changed)
        return changed

    def take(self, drone: str, cell: Cell) -> None:
        """A target from outside the plan (a ROS 2 goal), for the next GCS phase; UsageError (``reason: ...``) if
        there is no such drone, it is dead or lost, or the game is over."""
        if self.over is not None:
            raise UsageError("game over: no more targets")
        if drone not in self.ground.starts:
            raise UsageError(f"unknown drone: this game flies {', '.join(self.ground.starts)}")
        if drone in self.gone:
            raise UsageError(f"dead or lost: {drone} takes no more targets")
        self.want({drone: cell})

    def answer(self, turn: int, intent: Intent, new: Mapping[str, Cell] = {}) -> list[Effect]:
        self.want(new)
        in_force = targets_of(self.tracks.last) if self.tracks.last is not None else None
        self.answered, self.pending = max(self.answered, turn), None
        return [SendDone(gcs_done(turn, self.wanted, intent, in_force))]

    def intent(self, turn: int) -> Intent:
        if self.quit_at is not None:
            return Intent.QUIT if turn >= self.quit_at else Intent.CONTINUE
        if self.goals or self.tasks is not None:
            return Intent.CONTINUE
        return Intent.FINAL if turn >= self.plan.last_turn else Intent.CONTINUE

    def _lost(self, turn: int) -> SendDone | None:
        """The DONE of `turn` answered ahead, if it was lost on its way: its phase is announced, and the coordinator
        opens a phase unannounced when it holds its DONE (a router's budget of puts a second may keep only the first
        of DONEs sent together: `schema.tuning.PUT_RATE`). It goes out again, the same (if the first came after all,
        the coordinator takes the second as nothing new)."""
        lost = self._ahead_sent.get(turn)
        for t in [t for t in self._ahead_sent if t <= turn]:
            del self._ahead_sent[t]
        if lost is None:
            return None
        if lost in self._outgoing:  # not sent yet (paced behind others; the game went faster): it goes out first
            self._outgoing.remove(lost)
            self._outgoing.appendleft(lost)
            return None
        self.resent["announced"] += 1
        return SendDone(lost.msg)

    def _gcs_phase(self, turn: int) -> list[Effect]:
        if turn <= self.answered or turn == self.pending:  # answered (maybe ahead), or held
            self.answered = max(self.answered, turn)
            again = self._lost(turn)
            return [*([again] if again is not None else []), *self._ahead(turn)]
        if self.scripted and self.quit_at is not None and turn >= self.quit_at:
            self.answered = turn
            return [SendDone(Done(turn=turn, sender="GCS", phase=Phase.GCS, intent=Intent.QUIT))]
        self.want(self.plan.at(turn))
        if self.tasks is not None:
            if self.status_turn < turn - 1:  # (its STATUS, which the draws read, is still on its way)
                self._due = turn
                return []
            return self._tasks_done(turn)
        if self.hold:
            self.pending = turn
            return []
        return self.answer(turn, self.intent(turn)) + self._ahead(turn)

    def _tasks_done(self, turn: int) -> list[Effect]:
        """A lifelong station's answer in the GCS phase of `turn`, the STATUS of the turn before in: the new targets
        of the drones that reached theirs (`Tasks.assign`), besides its plan's."""
        assert self.tasks is not None and self.tracks.last is not None
        self.want(self.tasks.assign(turn, self.tracks.last, given=self.plan.at(turn)))
        return self.answer(turn, self.intent(turn))

    def _ahead(self, turn: int) -> list[Effect]:
        """A script with nothing new in the turns after `turn` answers them now, up to `ahead` turns on: once
        topped up, one more at each STATUS (its DONEs go out `PUT_GAP` apart, so a batch would not travel together,
        and its last ones would come after their phases in a fast game)."""
        if not self.scripted:
            return []
        turns = turns_to_answer_ahead(self.plan, turn, self.answered, last=self.quit_at, horizon=self.ahead)
        self.answered = max([self.answered, *turns])
        sent = {ahead: SendDone(gcs_done(ahead, {}, self.intent(ahead)), ahead=True) for ahead in turns}
        self._ahead_sent.update(sent)
        return list(sent.values())

    def _timed(self, turn: int, now: float) -> None:
        """The time of a turn, smoothed over the last few, from the STATUS of `turn` coming at `now`."""
        last = self._status_at
        if last is not None and turn > last[0]:
            took = (now - last[1]) / (turn - last[0])
            self._turn_s = took if self._turn_s is None else self._turn_s + (took - self._turn_s) / 8
        if last is None or turn > last[0]:
            self._status_at = (turn, now)

    def _status(self, status: Status) -> list[Effect]:
        if status.turn < self.status_turn:
            return []
        if self._unacked is not None and status.turn >= self._unacked[0].msg.turn:
            self._unacked = None  # its turn was played: its DONE came
        # the coming turn was answered ahead: no TURN(GCS) comes for it, its STATUS says it has begun
        effects = self._ahead(status.turn + 1) if status.turn + 1 <= self.answered else []
        self.tracks.add(status)
        alive = status.drones.alive_mask()
        if not alive.all():
            ended = {drone_name(n) for n in status.drones.numbers[~alive].tolist()}
            self.gone |= ended
            for d in ended & self.wanted.keys():  # (not the whole dict rebuilt at every STATUS after a death)
                del self.wanted[d]
        if self._joining:  # a late joiner takes over the targets in force (after that, they are its own)
            self._joining = False
            for d, c in targets_of(status).items():
                if d not in self.gone:
                    self.wanted.setdefault(d, c)
        if self._due is not None and status.turn >= self._due - 1:  # lifelong: the phase it waited for
            due, self._due = self._due, None
            if status.turn == due - 1:
                effects += self._tasks_done(due)
        if self.verbose:
            effects.append(Show(format_status(status)))
        if self.over is not None and status.turn >= self.over.turn:
            effects.append(self._end())
        return effects

    def _over(self, over: Over, now: float) -> list[Effect]:
        if self.over is not None:
            return []
        self.over, self.pending = over, None
        if over.reason not in OBSERVED_ENDS or self.status_turn >= over.turn:
            return [self._end()]
        self._over_since = now
        return []

    def _end(self) -> End:
        assert self.over is not None
        self.ended, self._over_since = True, None
        return End(self.over)

    def opening(self) -> str:
        """The world and the drones' floors at the start."""
        world, starts = self.ground.world, self.ground.starts
        return (f"World {world.size}, {int(world.grid.sum())} building cells; the drones' floor at start:\n"
                + world.draw(starts, floors=sorted({c[2] for c in starts.values()})))

    def report(self, *, draw: bool) -> str:
        """After the game: the world with the drones' paths (if `draw`), the end, each drone's moves and state."""
        assert self.over is not None
        world, last, paths = self.ground.world, self.tracks.last, self.tracks.paths
        lines = []
        if draw and last is not None:
            trail = [c for p in paths.values() for c in p if world.contains(c)]
            targets = {s.drone: s.target for s in last.drones if s.target is not None}
            floors = sorted({c[2] for c in trail} | {t[2] for t in targets.values()})
            lines += ["\nFinal world with the drones' paths:",
                      world.draw({s.drone: s.pos for s in last.drones if s.alive and world.contains(s.pos)},
                                 targets=targets, trail=trail, floors=floors)]
        lines.append(f"\nGAME OVER at turn {self.over.turn}: {self.over.reason.value} - {self.over.text}")
        if last is not None:
            lines += [f"  {s.drone}: {len(paths[s.drone]) - 1} moves, {describe(s).split(': ', 1)[1]}"
                      for s in last.drones]
        return "\n".join(lines)
