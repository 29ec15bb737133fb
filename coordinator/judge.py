"""A turn's judgement (`Judge`): the moves the drones' phase took, made as the phase closes (every turn, from
messages or from `Engine.play`): arbitrated (coordinator/arbitration.py), judged by the observer's rules
(coordinator/observer.py), the notes, priorities, missed deadlines, deaths and losses, and what the turn's journal
record says of them. Over Python's lists up to TURN_FEW_DRONES alive drones, in array operations above: the same
turn (tests/test_engine_turn.py; docs/performance.md gives the lists' gain). The moves are those of the phase's
ballot (coordinator/intake.py), or given whole by `Engine.play`."""

from __future__ import annotations

import logging
from operator import itemgetter
from typing import NamedTuple

import numpy as np

from schema import Cause, Cell, DroneState
from schema.errors import UsageError
from schema.tables import code_of
from schema.tuning import FEW_ROWS, TURN_FEW_DRONES
from world.grid import World, inside_rows, linear_rows
from world.search import STEPS

from . import observer
from .arbitration import Arbitration
from .fleet import ALIVE, CAUSES, DEAD, NOTES, Fleet, cell_of
from .intake import Ballot
from .journal import TurnLog, TurnRecord

#: What `Engine.play` takes: rows, cells and Note codes as arrays, or as lists (a few drones' turn).
Rows = np.ndarray | list[int]
Cells = np.ndarray | list[Cell]
Codes = np.ndarray | list[int]
CAUSE_CODE = {c: code_of(c) for c in Cause}
_HOVER = (0, 0, 0)  # the step of a drone that stays
_NO_CELLS: set[Cell] = set()  # (`Judge.steps`: never changed)
_tuple_new = tuple.__new__  # (a NamedTuple made by its class's `__new__` without its call: a Python frame less a turn)


class Steps(NamedTuple):
    """Every alive drone's move in a turn of a few drones, read and checked in one pass (`Judge.steps`): the alive
    rows (ascending), every drone's cell before by row (the fleet's own list, which `Fleet.move` then changes), the
    alive ones' cells after, the rows that changed cell (ascending), and whether one of these left the world and the
    building cells they entered (`observer.deaths_of_moves`' `found`)."""

    rows: list[int]
    before: list[Cell]
    after: dict[int, Cell]
    moved: list[int]
    found: tuple[bool, set[Cell]]


class Moved(NamedTuple):
    """What a turn did (`Judge.rule`): the drones it moved, their rows and their cells before and after (arrays, or
    lists), and how many drones are alive after it."""

    rows: Rows
    src: Cells
    dst: Cells
    alive: int


class Judge:
    """The turn's judgement over `fleet` in `world`, its cooperative drones' moves arbitrated by `arbitration`;
    a hovering drone is LOST after `lost_after` missed deadlines in a row. The moves: those `ballot` took."""

    def __init__(self, fleet: Fleet, world: World, arbitration: Arbitration, ballot: Ballot, lost_after: int,
                 logger: logging.Logger) -> None:
        self.fleet, self.size, self.arbitration, self.ballot, self.lost_after, self._log = \
            fleet, world.size, arbitration, ballot, lost_after, logger
        self._solid = world.grid.reshape(-1)  # the buildings, flat (a view: the coordinator holds one world)
        self._solid_items = self._solid.data  # the same read item by item (`_few`): a memoryview's item is a Python
        # bool in ~25 ns, a numpy array's ~300 ns
        self._every = list(range(len(fleet)))  # every row (`steps`: compared with a caller's rows in C)
        self._alive: tuple[list[int], list[int]] = ([], [])  # the last states `steps` read and their alive rows

    def steps(self, rows: list[int], cells: list[Cell], whole: tuple[list[int], list[Cell]],
              offsets: bool = False) -> Steps | None:
        """The moves `cells` ((x, y, z) tuples) of the `rows` of a few drones, if these are every alive drone in
        ascending order (a caller that moves or hovers each, as an RL episode does), read in one pass as the judge
        reads them (`rule_steps` makes them); `whole`: the fleet's state and cells (`Fleet.whole`); `offsets`: the
        moves are each drone's step (dx, dy, dz), not its cell (the caller's pass from steps to cells is this one).
        UsageError, nothing changed, if one is not a step (6-connectivity) from its drone's cell. None: other rows
        (`rule`)."""
        states, pos = whole
        n = len(states)
        if states.count(ALIVE) == n:
            if len(rows) != n or rows != self._every:
                return None
        else:  # (the alive rows of the states of the last turn that had the same: compared in C)
            known, alive = self._alive
            if states != known:
                alive = [i for i, s in zip(self._every, states) if s == ALIVE]
                self._alive = states, alive
            if rows != alive:
                return None
        (nx, ny, nz), solid = self.size, self._solid_items
        after: dict[int, Cell] = {}
        moved: list[int] = []
        outside, buildings = False, _NO_CELLS  # (a set of its own once a drone enters a building)
        if offsets and not STEPS.issuperset(cells):  # (each step looked up in C)
            raise UsageError("a move of more than one cell (6-connectivity)")
        for i, move in zip(rows, cells):
            x, y, z = here = pos[i]
            if offsets:  # (a step other than hovering changes the drone's cell)
                if move == _HOVER:
                    after[i] = here
                    continue
                dx, dy, dz = move
                a, b, c = cell = x + dx, y + dy, z + dz
            else:
                a, b, c = cell = move
                if (a - x, b - y, c - z) not in STEPS:
                    raise UsageError("a move for a drone not alive, or of more than one cell (6-connectivity)")
                if cell == here:
                    after[i] = here
                    continue
            after[i] = cell
            moved.append(i)
            if not (0 <= a < nx and 0 <= b < ny and 0 <= c < nz):
                outside = True
            elif solid[(a * ny + b) * nz + c]:
                buildings = {*buildings, cell}
        return _tuple_new(Steps, (rows, pos, after, moved, (outside, buildings)))

    def rule_steps(self, turn: int, log: TurnLog, journaled: bool, cells: bool, steps: Steps,
                   codes: list[int]) -> Moved:
        """`rule` of the moves `steps` (`steps`), said with the Note `codes` (one per row of `steps`)."""
        fleet, rows = self.fleet, steps.rows
        notes = fleet.codes()
        if rows is self._every or len(rows) == len(notes):  # (every row: compared in C, most turns equal)
            said = [] if codes == notes else [i for i, code, was in zip(rows, codes, notes) if code != was]
            says = codes
        elif len(rows) > 1 and itemgetter(*rows)(notes) == tuple(codes):  # (the rows' notes picked in C: most turns
            said, says = [], codes  # the same as said)
        else:
            said, says = [], [0] * len(notes)
            for i, code in zip(rows, codes):
                says[i] = code
                if code != notes[i]:
                    said.append(i)
        return self._settle(rows, rows, steps.before, steps.after, steps.moved, steps.found, said, says, rows, [],
                            turn, log, journaled, cells)

    def rule(self, turn: int, log: TurnLog, journaled: bool, cells: bool,
             took: dict[int, tuple[Cell, int]] | None = None,
             whole: tuple[list[int], list[Cell]] | None = None) -> Moved:
        """The turn's moves take effect as the drones' phase closes (every turn, from messages or from `play`):
        the moves taken (the others hover), arbitrated, the observer's judgement, the notes, priorities, missed
        deadlines and the turn's journal record. The drones that moved: their rows, cells before and after.
        The moves taken: `took` (row -> its cell and note code), or None: the phase's (`ballot`). Up to
        TURN_FEW_DRONES alive drones, the turn is played over Python's lists (`_few`), else in array operations
        (`_arrays`): the same turn (tests/test_engine_turn.py). `whole`: the fleet's state and cells as lists
        (`Fleet.whole`), if the caller read them this turn. `turn`, `log`: the turn and its journal record;
        `journaled`: whether the record says what each drone did; `cells`: whether the moved drones' cells are
        wanted (if not, the lists' way leaves them out)."""
        fleet, ballot = self.fleet, self.ballot
        # (the states as a list for a small fleet; its cells only once the lists' way is taken: more alive drones
        # than TURN_FEW_DRONES play in arrays, which would read `pos` back from the tuples every turn)
        states = whole[0] if whole else fleet.states() if fleet.small else None
        if states is not None and states.count(ALIVE) == len(states):  # (every drone alive: most turns, in C)
            alive = list(range(len(states)))
        elif states is not None:
            alive = []
            for i, s in enumerate(states):  # (loops, not comprehensions, in the few drones' turn: Python 3.11
                if s == ALIVE:  # calls a function for each comprehension, a few drones' whole work)
                    alive.append(i)
        else:
            alive = fleet.alive_rows().tolist()
        if len(alive) > TURN_FEW_DRONES:
            if took is not None:  # (a turn of `play`'s with a few moves: they are the phase's, as the arrays read it)
                ballot.moved[:] = False
                for i, (cell, code) in took.items():
                    ballot.proposed[i], ballot.said[i], ballot.moved[i], ballot.ranked[i] = cell, code, True, 0
            return self._arrays(turn, log, journaled)
        every = alive  # the rows in play: the alive ones, and any whose move was taken before it was LOST
        if took is None:
            rows = np.flatnonzero(ballot.moved).tolist()
            proposed = map(tuple, fleet.column(ballot.proposed, rows))
            took = dict(zip(rows, zip(proposed, fleet.column(ballot.said, rows))))
            if not took.keys() <= set(alive):  # (it moves, as in the arrays: `_arrays`)
                every = sorted({*alive, *took})
        where = whole[1] if whole else fleet.cells() if fleet.small else None  # (the states are read above)
        return self._few(alive, every, took, where, turn, log, journaled, cells)

    def _few(self, alive: list[int], every: list[int], took: dict[int, tuple[Cell, int]],
             whole: list[Cell] | None, turn: int, log: TurnLog, journaled: bool, cells: bool) -> Moved:
        """The turn over lists: `alive`, the alive rows (ascending); `every`, the rows in play (those and any whose
        move was taken); `took`, the moves taken; `whole`: every drone's cell (None: those of `every` read here)."""
        fleet = self.fleet
        pos: list[Cell] | dict[int, list[int]] = \
            dict(zip(every, fleet.column(fleet.pos, every))) if whole is None else whole
        before: dict[int, Cell] = {}
        after: dict[int, Cell] = {}
        moved: list[int] = []
        for i in every:
            x, y, z = pos[i]
            here = before[i] = (x, y, z)
            move = took.get(i)
            cell = after[i] = here if move is None else move[0]
            if cell != here:
                moved.append(i)
        if fleet.cooperating and True in fleet.column(fleet.cooperative, alive):
            rows = np.array(alive)
            final = self.arbitration.decide(fleet, rows, np.array([before[i] for i in alive]),
                                            np.array([after[i] for i in alive]),
                                            np.where(self.ballot.moved[rows], self.ballot.ranked[rows], 0), turn, log)
            after.update(zip(alive, map(tuple, final.tolist())))
            moved = [i for i in every if after[i] != before[i]]
        notes = fleet.codes() if fleet.small else dict(zip(took, fleet.column(fleet.note, [*took])))
        said = []  # (in any order: the journal's is its own)
        says = {}
        for i, (_, code) in took.items():
            if code != notes[i]:
                said.append(i)
                says[i] = code
        hovered = [i for i in alive if i not in took] if len(alive) != len(took) else []  # (as the arrays count:
        # a LOST drone's move taken counts)
        return self._settle(alive, every, before, after, moved, None, said, says, [*took], hovered, turn, log,
                            journaled, cells)

    def _settle(self, alive: list[int], every: list[int], before: dict[int, Cell] | list[Cell],
                after: dict[int, Cell], moved: list[int], found: tuple[bool, set[Cell]] | None, said: list[int],
                says: list[int] | dict[int, int], taken: list[int], hovered: list[int], turn: int, log: TurnLog,
                journaled: bool, cells: bool) -> Moved:
        """A few drones' turn made (`_few`, `rule_steps`): `alive`, `every`, `before`, `after` as in `_few`
        (`before` may also be every drone's cell by row: the fleet's list, `steps`'); `moved`, the rows that changed
        cell; `found`: whether one of them left the world and the building cells they entered (None: not known);
        `said`, the rows whose note changed, to `says[i]`; `taken`, the rows whose move was taken; `hovered`, the
        alive rows whose move was not."""
        fleet = self.fleet
        if not moved:  # where the drones were, alive and apart, they still are
            dead: dict[int, Cause] = {}
        elif every is alive:
            dead = observer.deaths_of_moves(self.size, self._solid_items, before, after, moved, found)
        else:
            live = set(alive)
            dead = observer.deaths_of_moves(self.size, self._solid_items, {i: before[i] for i in alive},
                                            {i: after[i] for i in alive}, [i for i in moved if i in live])
        src = [before[i] for i in moved] if cells else []  # (`before` may be the fleet's list, which the moves change)
        fleet.move(moved, after)
        if said:
            _set_rows(fleet.note, said, [says[i] for i in said])
        if fleet.cooperating:  # (priorities are the arbitration's: none without cooperation)
            self.arbitration.age(fleet, np.array(alive, np.intp))
        if dead:
            self._died(dead, after, turn)
        lost = 0
        if hovered or fleet.missing:  # misses in a row: a move starts the count again
            lost = self._missed(alive, taken, hovered, turn, log)
        if journaled:  # what the turn did, drone by drone
            self._journal_few(log, moved, after, said, says, hovered, dead)
        left = len(alive) - len(dead) - lost
        if not cells:  # (nobody reads the moves' cells: `Engine._drones_finish`)
            return _tuple_new(Moved, (moved, [], [], left))
        return _tuple_new(Moved, (moved, src, [after[i] for i in moved], left))

    def _journal_few(self, log: TurnLog, moved: list[int], after: dict[int, Cell], said: list[int],
                     says: list[int] | dict[int, int], hovered: list[int], dead: dict[int, Cause]) -> None:
        ids = self.fleet.ids
        if moved:
            log.moves([ids[i] for i in moved], [list(after[i]) for i in moved])
        if said:
            log.notes([ids[i] for i in said], [NOTES[says[i]] for i in said])
        if hovered:
            log.hovered([ids[i] for i in hovered])
        if dead:
            log.deaths([ids[i] for i in sorted(dead)], [dead[i] for i in sorted(dead)])

    def _missed(self, alive: list[int], took: list[int], hovered: list[int], turn: int, log: TurnLog) -> int:
        """The misses in a row after a turn (`_few`): 0 for a drone whose move was taken, one more for an alive
        one that hovered; LOST after `lost_after`. How many were LOST."""
        fleet, n = self.fleet, len(self.fleet)
        took_mask, alive_mask = np.zeros(n, bool), np.zeros(n, bool)
        took_mask[took], alive_mask[alive] = True, True
        fleet.count_misses(took_mask, alive_mask)
        lost = [i for i in hovered if fleet.misses[i] >= self.lost_after and fleet.state[i] == ALIVE]
        for i in lost:  # (not one that died this turn)
            self.lose(i, turn, log)
        return len(lost)

    def _died(self, dead: dict[int, Cause], at: dict[int, Cell], turn: int) -> None:
        fleet, rows = self.fleet, sorted(dead)
        _set_rows(fleet.state, rows, [DEAD] * len(rows))
        _set_rows(fleet.cause, rows, [CAUSE_CODE[dead[i]] for i in rows])
        for i in rows:
            self._log.warning("turn %d: %s died (%s) at %s", turn, fleet.ids[i], dead[i].value, at[i])

    def _arrays(self, turn: int, log: TurnLog, journaled: bool) -> Moved:
        """The turn in array operations, of the phase's moves. Its masks are over every row, dead or alive, as the
        observer's (`observer.judge`)."""
        fleet, ids, ballot = self.fleet, self.fleet.ids, self.ballot
        alive, took = fleet.state == ALIVE, ballot.moved  # (a drone not alive has no move taken)
        before = fleet.pos.copy()
        hovering = np.count_nonzero(alive) - np.count_nonzero(took)  # (most turns: none, whose bookkeeping is skipped)
        after = np.where(took[:, None], ballot.proposed, before)
        if np.count_nonzero(fleet.cooperative & alive):
            rows = alive.nonzero()[0]
            after[rows] = self.arbitration.decide(fleet, rows, before[rows], after[rows],
                                                  np.where(ballot.moved[rows], ballot.ranked[rows], 0), turn, log)
        moved = (after != before).any(axis=1)
        any_moved = np.count_nonzero(moved) > 0
        if any_moved:  # a cell outside the world is the observer's to judge (OUTSIDE), never a building
            inside = inside_rows(after, self.size)
            building = moved & inside & self._solid[np.where(inside, linear_rows(after, self.size), 0)]
            cause = observer.judge(self.size, before, after, building, alive)
        else:  # where the drones were, alive and apart, they still are
            cause = np.zeros(len(fleet), np.uint8)
        fleet.pos[:] = after
        says = took & (ballot.said != fleet.note)  # (most turns: the notes said before)
        said = says.nonzero()[0]
        if len(said):
            np.copyto(fleet.note, ballot.said, where=says)
        if fleet.cooperating:  # (priorities are the arbitration's: none without cooperation)
            self.arbitration.age(fleet, alive)
        hovered = (alive & ~took).nonzero()[0] if hovering else said[:0]
        if hovering or fleet.missing:  # misses in a row: a move starts the count again
            fleet.count_misses(took, alive)
        lost = hovered[fleet.misses[hovered] >= self.lost_after] if hovering else hovered
        died = cause != 0
        dead = died.nonzero()[0]
        if len(dead):
            fleet.state[died] = DEAD
            np.copyto(fleet.cause, cause, where=died)
        for i in dead.tolist():
            self._log.warning("turn %d: %s died (%s) at %s", turn, ids[i], CAUSES[fleet.cause[i]].value,
                              cell_of(fleet.pos[i]))
        for i in lost.tolist():
            if fleet.state[i] == ALIVE:
                self.lose(i, turn, log)
        rows = moved.nonzero()[0]
        if journaled:  # what the turn did, drone by drone
            if any_moved:
                log.moves([ids[i] for i in rows.tolist()], after[rows].tolist())
            if len(said):
                log.notes([ids[i] for i in said.tolist()], [NOTES[c] for c in fleet.note[said].tolist()])
            if len(hovered):
                log.hovered([ids[i] for i in hovered.tolist()])
            if len(dead):
                log.deaths([ids[i] for i in dead.tolist()], [CAUSES[c] for c in fleet.cause[dead].tolist()])
        return Moved(rows, before[rows], after[rows], int(np.count_nonzero(fleet.state == ALIVE)))

    def replay(self, r: TurnRecord, alive: np.ndarray) -> None:
        """A journaled turn made again (`Engine.resume`) as this judge made it, from its record `r` (the `alive`
        rows: those before it): the arbitration's search followed, the moves, notes, priorities, misses, deaths and
        losses the record says."""
        fleet, row = self.fleet, self.fleet.index
        self.arbitration.follow(fleet, alive, r.turn)  # (before the moves, as the arbitration ran)
        for d, p in r.moves.items():
            fleet.pos[row[d]] = p
        for d, n in r.notes.items():
            fleet.note[row[d]] = code_of(n)
        if fleet.cooperating:  # the arbitration's priorities (as a turn keeps them)
            self.arbitration.age(fleet, alive, [row[d] for d in r.gave_way])
        hovered = np.isin(alive, [row[d] for d in r.hovered])
        took, live = np.zeros(len(fleet), bool), np.zeros(len(fleet), bool)
        took[alive[~hovered]], live[alive] = True, True
        fleet.count_misses(took, live)
        for d, cause in r.deaths.items():
            fleet.end(row[d], DroneState.DEAD, cause)
        for d in r.lost:
            fleet.end(row[d], DroneState.LOST, Cause.LOST)

    def lose(self, i: int, turn: int, log: TurnLog) -> None:
        """Drone row `i` is LOST in `turn` (its record `log`)."""
        d = self.fleet.ids[i]
        self.fleet.end(i, DroneState.LOST, Cause.LOST)
        log.lost(d)
        self._log.warning("turn %d: %s is LOST at %s", turn, d, cell_of(self.fleet.pos[i]))


def _set_rows(column: np.ndarray, rows: list[int], values: list) -> None:
    """column[rows] = values, a few rows one by one (a selection by a list costs as much as FEW_ROWS rows)."""
    if len(rows) <= FEW_ROWS:
        for i, v in zip(rows, values):
            column[i] = v
    else:
        column[rows] = values
