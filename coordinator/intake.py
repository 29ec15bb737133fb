"""What a turn's phases take in, each item checked on its own: the ground station's targets for the GCS phase
(`Aims`), the drones' moves for the drones' phase (`Ballot`), and what came ahead of its phase, held for it
(`Ahead`). An item refused raises (a `RemoteInputError`) and
changes nothing; a batch (a DONE's targets, a MOVES's moves) is taken item by item, or for more than FEW_ROWS items
in array operations first (`in_batch`), and one `Refusal` names those refused. The engine (coordinator/engine.py)
says when a phase opens and closes; the judge (coordinator/judge.py) reads the ballot as the drones' phase closes."""

from __future__ import annotations

from collections.abc import Callable, Container

import numpy as np

from schema import Cell, Done, Message, Moves, Note, Phase
from schema.errors import OutOfRange, Refusal, RemoteInputError, StaleTurn, UnknownEntity, WrongSender
from schema.tables import code_of, drone_name
from schema.tuning import FEW_ROWS
from world.grid import in_bounds, inside_rows
from world.search import is_step, step_lengths

from .fleet import ALIVE, NOTES, STATES, Fleet, cell_of


class Aims:
    """The targets this GCS phase received for the drones of `fleet` in a world of `size`, not in force until the
    phase closes (`take_effect`): `aimed` (whose, one row per drone) and `cells` (theirs, where `aimed`)."""

    def __init__(self, fleet: Fleet, size: Cell) -> None:
        self.fleet, self.size = fleet, size
        self.aimed = np.zeros(len(fleet), bool)
        self.cells = np.zeros((len(fleet), 3), np.int32)

    def aim(self, d: str, pos: Cell) -> None:
        """Keep a target for this GCS phase, or raise (and keep nothing)."""
        i = self.fleet.index.get(d)
        if i is None:
            raise UnknownEntity(f"target for unknown drone {d}")
        if self.fleet.state[i] != ALIVE:
            raise UnknownEntity(f"target for {d}, which is {STATES[self.fleet.state[i]].value}")
        if not in_bounds(pos, self.size):
            raise OutOfRange(f"target {pos} for {d} is outside the world {self.size}")
        self.aimed[i], self.cells[i] = True, pos

    def aim_all(self, msg: Done) -> list[Refusal]:
        """A DONE's targets, each kept as if sent as a TGT (`aim`); a `Refusal` of those refused."""
        fleet, numbers, pos = self.fleet, msg.targets.numbers, msg.targets.column("pos")

        def whole() -> np.ndarray:  # `aim`'s checks, as arrays
            rows = fleet.row_of_number[numbers]
            ok = (rows >= 0) & inside_rows(pos, self.size)
            ok[ok] = fleet.state[rows[ok]] == ALIVE
            self.aimed[rows[ok]], self.cells[rows[ok]] = True, pos[ok]
            return np.flatnonzero(~ok)

        return in_batch(msg, len(msg.targets), whole, lambda j: self.aim(drone_name(int(numbers[j])), cell_of(pos[j])))

    def take_effect(self) -> np.ndarray:
        """The phase closes: the targets it received are in force (the fleet's); the rows whose target changed."""
        fleet = self.fleet
        changed = np.flatnonzero(self.aimed & (fleet.target != self.cells).any(axis=1))
        fleet.aim(changed, self.cells[changed])
        self.aimed.fill(False)
        return changed


class Ballot:
    """The moves this drones' phase took for the drones of `fleet`, one row per drone: `moved` (whose), `proposed`
    (the cells), `said` (the Note codes that came with them), `ranked` (the candidates, 0: none); `awaiting`: the
    alive drones whose move the phase still awaits."""

    def __init__(self, fleet: Fleet) -> None:
        n = len(fleet)
        self.fleet, self.turn, self.awaiting = fleet, 0, 0
        self.moved = np.zeros(n, bool)
        self.proposed = np.zeros((n, 3), np.int32)
        self.said = np.zeros(n, np.uint8)
        self.ranked = np.zeros(n, np.uint32)

    def open(self, turn: int, awaiting: int) -> None:
        """The drones' phase of `turn` opens: no move taken yet, `awaiting` drones' awaited."""
        self.moved[:] = False
        self.turn, self.awaiting = turn, awaiting

    def take(self, d: str, pos: Cell, note: Note, ranked: int) -> None:
        """Take a drone's move for this phase, or raise (and take nothing)."""
        fleet = self.fleet
        i = fleet.index.get(d)
        if i is None or fleet.state[i] != ALIVE:
            raise UnknownEntity(f"NPS from {d}, which is not an alive drone of this game")
        if self.moved[i]:
            if cell_of(self.proposed[i]) == pos and (self.said[i], self.ranked[i]) == (code_of(note), ranked):
                return  # the same again (its TURN was sent again: `Engine.connect`)
            raise StaleTurn(f"second NPS from {d} in turn {self.turn}")
        here = cell_of(fleet.pos[i])
        if not is_step(here, pos):
            # refused: the drone may still send a valid move, or hover at the deadline
            raise OutOfRange(f"{d} cannot move from {here} to {pos}: one cell per turn, 6-connectivity")
        self.proposed[i], self.moved[i], self.said[i], self.ranked[i] = pos, True, code_of(note), ranked
        self.awaiting -= 1

    def take_hosted(self, sender: str, d: str, pos: Cell, note: Note, ranked: int) -> None:
        """Take a move a swarm host sent for one of its drones, or raise (and take nothing)."""
        i = self.fleet.index.get(d)
        host = None if i is None else self.fleet.host[i]
        if host != sender:
            raise WrongSender(f"MOVES from {sender} for {d}, which {host or 'nobody'} flies")
        self.take(d, pos, note, ranked)

    def take_all(self, msg: Moves) -> list[Refusal]:
        """A swarm host's moves (not none), each taken as if sent as an NPS (`take_hosted`); a `Refusal` of those
        refused."""
        fleet, steps = self.fleet, msg.moves
        numbers, pos, notes = steps.numbers, steps.column("pos"), steps.column("note")

        def whole() -> np.ndarray:  # (the MOVES as columns of the fleet's rows: docs/performance.md, Memory)
            rows, n = fleet.row_of_number[numbers], len(fleet)  # -1, the extra row: a number not of this game
            step = np.full(n + 1, 2, np.int64)  # each row's step in this MOVES (2: none sent)
            step[rows] = step_lengths(fleet.pos[rows], pos)
            take = (step[:-1] <= 1) & (fleet.host_code == fleet.hosts.get(msg.sender, -2)) & (fleet.state == ALIVE)
            take &= ~self.moved
            item = np.zeros(n + 1, np.intp)  # each row's item in this MOVES (where it sent one)
            item[rows] = np.arange(len(rows))
            item = item[:-1]
            np.copyto(self.proposed, pos[item], where=take[:, None])
            np.copyto(self.said, notes[item], where=take)
            np.copyto(self.ranked, steps.column("ranked")[item], where=take)
            self.moved |= take
            taken = int(np.count_nonzero(take))
            self.awaiting -= taken
            return rows[:0] if taken == len(rows) else np.flatnonzero(~np.append(take, False)[rows])

        return in_batch(msg, len(steps), whole, lambda j: self.take_hosted(
            msg.sender, drone_name(int(numbers[j])), cell_of(pos[j]), NOTES[notes[j]], int(steps.column("ranked")[j])))

    def awaits(self, host: int) -> bool:
        """Whether the phase still awaits a move of an alive drone that host code `host` flies."""
        fleet = self.fleet
        return bool(np.count_nonzero((fleet.host_code == host) & (fleet.state == ALIVE) & ~self.moved))


class Ahead:
    """What came ahead of its phase, held for it: the GCS's DONEs for coming GCS phases (`dones`: turn -> DONE; it
    had nothing new to say), swarm hosts' MOVES for this turn's drones' phase (`moves`: host -> MOVES, one each; a
    host that decides from the STATUS alone sends its DONE and MOVES at once). Each is checked like any other as
    its phase opens (no round trip to the sender)."""

    def __init__(self) -> None:
        self.dones: dict[int, Done] = {}
        self.moves: dict[str, Moves] = {}

    def hold_done(self, msg: Done) -> None:
        """Keep the GCS's DONE for a coming GCS phase, or raise (and keep nothing)."""
        if msg.sender != "GCS" or msg.phase is not Phase.GCS:
            raise WrongSender(f"DONE({msg.phase.value}) ahead from {msg.sender}")
        if msg.count:
            raise StaleTurn(f"a DONE ahead for turn {msg.turn} carries its targets itself, it cannot count TGTs")
        if msg.turn in self.dones:
            if msg == self.dones[msg.turn]:
                return  # (the same again)
            raise StaleTurn(f"second DONE ahead for turn {msg.turn}")
        self.dones[msg.turn] = msg

    def done_for(self, turn: int) -> Done | None:
        """The GCS phase of `turn` opens: the DONE held for it, if any (those of earlier turns are dropped)."""
        done = self.dones.pop(turn, None)
        self.dones = {t: d for t, d in self.dones.items() if t > turn}
        return done

    def hold_moves(self, msg: Moves, hosts: Container[str]) -> None:
        """Keep a swarm host's MOVES for this turn's drones' phase (`hosts`: the game's), or raise (keeping none)."""
        if msg.sender not in hosts:
            raise WrongSender(f"MOVES ahead from {msg.sender}, which flies no drone of this game")
        if not len(msg.moves):  # (a host says it is deciding only once the phase it decides is open)
            raise StaleTurn(f"an empty MOVES from {msg.sender} before turn {msg.turn}'s drones' phase opened")
        if msg.sender in self.moves:
            raise StaleTurn(f"second MOVES ahead from {msg.sender} for turn {msg.turn}")
        self.moves[msg.sender] = msg

    def take_moves(self) -> list[Moves]:
        """The drones' phase is announced: the MOVES held for it, in the order they came."""
        held, self.moves = self.moves, {}
        return list(held.values())


def in_batch(msg: Message, n: int, whole: Callable[[], np.ndarray] | None, one: Callable[[int], None]) -> list[Refusal]:
    """Take the `n` items of `msg` (a MOVES's moves, a DONE's targets, a TGT's one) each on its own (`one(j)`
    takes item j or raises why not, changing nothing): a `Refusal` of `msg` if some were refused, the first one's
    error naming the others. A batch of more than FEW_ROWS is taken as a whole first (`whole()` takes, in array
    operations, every item `one` would take, and says which it did not), the rest one by one."""
    refused = []
    for j in range(n) if n <= FEW_ROWS or whole is None else whole().tolist():
        try:
            one(j)
        except RemoteInputError as err:
            refused.append(err)
    if not refused:
        return []
    first = refused[0]
    more = f" (and {len(refused) - 1} more: {'; '.join(map(str, refused[1:4]))})" if len(refused) > 1 else ""
    return [Refusal(f"{msg.TAG} from {msg.sender}", type(first)(f"{first}{more}"))]
