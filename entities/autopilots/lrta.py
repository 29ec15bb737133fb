"""LRTA*: a cooperative autopilot cheap enough for ten thousand drones (``--autopilot lrta``).

Korf's Learning Real-Time A* ("Real-time heuristic search", Artificial Intelligence 42, 1990) with a lookahead
of one move, over the 6-connected grid. A drone keeps no map and no search: only the values it has *learned*.
A cell's value is h(c) = what the drone learned for it, else the Manhattan distance from c to the target
(admissible on the grid: no way is shorter). Each turn, from `pos` towards `target`:

1. it senses its six neighbours and its target by ASK (a swarm host answers from its chart: no round trip);
   a neighbour is *free* if it is told EMPTY (a building, outside the world or no answer: not free);
2. it learns: h(pos) = max(h(pos), 1 + min h(free neighbour)) (stored only where it exceeds the Manhattan
   distance: the learned values are sparse, a few cells around the buildings it met);
3. it ranks its own cell and its free neighbours for the coordinator's arbiter (PIBT, coordinator/arbiter.py,
   docs/cooperation.md): by h, smallest first; staying (with the value just learned) before any neighbour of
   equal h; among neighbours of equal h, the one nearer the target as the crow flies (squared Euclidean
   distance) first, then in AROUND order (+x, -x, +y, -y, +z, -z): a total order. Nearer as the crow flies:
   of two cells that get closer, the one along the axis with more way to go (paths go diagonally,
   staircase-wise, rather than one axis after the other, which would put crowds in the same lanes); of two
   that do not, the one to the side rather than straight back (a drone facing a building goes round it).
   After learning, the best neighbour is always strictly below staying, so a drone that gets its first choice
   always moves. Its move (`pos`, for an arbitration that takes one move per drone) is its first choice.

A drone at rest (on its target, without one, or that cannot reach it) offers its own cell first, then its
free neighbours in AROUND order, so that it can be pushed aside and come back.

Unreachable targets are said (Note.UNREACHABLE), not waited on for ever: at once when the target is told to
be a building or is outside the world, or when the drone is boxed in; and, for a target walled in, once the
value learned where it stands exceeds its Manhattan distance by more than `slack` moves (default
``max(64, 2 (X + Y + Z))``): since h never exceeds the true distance on the static map, a value above the
number of cells of the world proves the target unreachable; the slack is a judgement well below that (a way
that long round the buildings is taken as none). Such a drone keeps moving and learning (it may still find the
way) and says NONE again once its value falls back under the bound (only a new target lowers it).

Other drones never enter the values: they are the arbiter's business (a cell held by a drone is still offered;
PIBT pushes or waits). So the learned values stay admissible, and one drone alone is LRTA*: complete on a
finite graph where its target is reachable (Korf), whatever the others do to it in between as long as it
gets its first choice often enough (the drone of highest priority always does, docs/cooperation.md).

Two forms, the same decisions (a property test flies both over random worlds and compares every move, note
and ranking): `LrtaPilot`, one per drone in plain Python; `LrtaSwarm`, one for a whole swarm host over
arrays (`autopilots.SWARMS`), about 2 µs a drone a turn.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import repeat
from typing import ClassVar

import numpy as np

from entities.world import linear_rows
from schema import Cell, CellInfo, CellKind, Note
from schema.messages import AROUND
from schema.tables import code_of

from .base import NO_ANSWER, Decision, Sensing, SwarmSensing, in_bounds, swarm_numbers, swarm_rows

#: A ranking key is h * _H + tie * _TIE + the step's index in RANK_STEPS (0-5 the neighbours in AROUND order,
#: 6 staying); tie is 0 for staying and 1 + the neighbour's squared Euclidean distance to the target (below 2**36
#: in a world of sides up to 2**16) for a neighbour.
_TIE = 8
_H = 1 << 40
_STAY = 6
_AXIS = tuple(next(a for a in range(3) if d[a]) for d in AROUND)
_NONE, _REACHED, _UNREACHABLE = (code_of(n) for n in (Note.NONE, Note.REACHED, Note.UNREACHABLE))


def default_slack(size: Cell) -> int:
    """Moves beyond the Manhattan distance after which a drone says its target is unreachable."""
    return max(64, 2 * (size[0] + size[1] + size[2]))


def _manhattan(a: Cell, b: Cell) -> int:
    return abs(a[0] - b[0]) + abs(a[1] - b[1]) + abs(a[2] - b[2])


def _pack(order: Sequence[int]) -> int:
    """Step indices (into RANK_STEPS) as `schema.tables.rank_steps` packs them (code = index + 1)."""
    value = 0
    for i, k in enumerate(order):
        value |= (k + 1) << 3 * i
    return value


class LrtaPilot:
    """LRTA* for one drone (see the module). Deterministic; its memory is the values it learned for its
    current target."""

    name: ClassVar[str] = "lrta"
    cooperative: ClassVar[bool] = True
    senses: ClassVar[bool] = True

    def __init__(self, *, world_size: Cell, slack: int | None = None) -> None:
        self.size: Cell = (int(world_size[0]), int(world_size[1]), int(world_size[2]))
        if min(self.size) < 1:
            raise ValueError(f"world size must be positive, got {world_size!r}")
        self.slack = default_slack(self.size) if slack is None else max(0, int(slack))
        self._target: Cell | None = None
        self._learned: dict[Cell, int] = {}

    @property
    def learned(self) -> dict[Cell, int]:
        """The values learned for the current target (cell -> h), those above the Manhattan distance."""
        return dict(self._learned)

    def h(self, cell: Cell) -> int:
        """The drone's value of `cell` for its current target (its Manhattan distance unless learned)."""
        assert self._target is not None
        return self._learned.get(cell, _manhattan(cell, self._target))

    def step(self, pos: Cell, target: Cell | None) -> Sensing:
        pos = (int(pos[0]), int(pos[1]), int(pos[2]))
        if target is not None:
            target = (int(target[0]), int(target[1]), int(target[2]))
        around = [(pos[0] + dx, pos[1] + dy, pos[2] + dz) for dx, dy, dz in AROUND]
        asked = [c for c in around if in_bounds(c, self.size)]
        if target is not None and target != pos and in_bounds(target, self.size) and target not in asked:
            asked.append(target)
        answers: Mapping[Cell, CellInfo] = (yield tuple(asked)) if asked else {}
        free = [k for k, c in enumerate(around) if in_bounds(c, self.size) and _empty(answers.get(c))]
        aside = _pack([_STAY, *free])
        if target is None:
            return Decision(pos=pos, ranked=aside)
        if target != self._target:
            self._target, self._learned = target, {}
        if pos == target:
            return Decision(pos=pos, note=Note.REACHED, ranked=aside)
        told = answers.get(target)
        if not in_bounds(target, self.size) or (told is not None and told.kind is not CellKind.EMPTY) or not free:
            return Decision(pos=pos, note=Note.UNREACHABLE, ranked=aside)
        values = {k: self.h(around[k]) for k in free}
        here = max(self.h(pos), 1 + min(values.values()))
        base = _manhattan(pos, target)
        if here > base:
            self._learned[pos] = here
        keys = [(here * _H + _STAY, _STAY)]
        for k, v in values.items():
            c = around[k]
            euclid = (c[0] - target[0]) ** 2 + (c[1] - target[1]) ** 2 + (c[2] - target[2]) ** 2
            keys.append((v * _H + (1 + euclid) * _TIE + k, k))
        order = [k for _, k in sorted(keys)]
        note = Note.UNREACHABLE if here > base + self.slack else Note.NONE
        return Decision(pos=pos if order[0] == _STAY else around[order[0]], note=note, ranked=_pack(order))


def _empty(info: CellInfo | None) -> bool:
    return info is not None and info.kind is CellKind.EMPTY


_STEPS = np.array(AROUND, dtype=np.int64)  # (6, 3)
_AXES = np.array(_AXIS, dtype=np.int64)
_SIGNS = np.array([sum(d) for d in AROUND], dtype=np.int64)  # +1 or -1: the step's way along its axis
_COLUMNS = np.arange(6, dtype=np.int64)
_SHIFTS = np.arange(7, dtype=np.int64) * 3
_FAR = np.iinfo(np.int64).max


class LrtaSwarm:
    """`LrtaPilot` for a whole swarm host's drones at once, over arrays: the same decisions and the same learned
    values. The values of every drone are one dict: (the drone's current trip × world cells + the cell's grid
    index) -> h, where a trip is numbered anew each time the drone's target changes (the values of a former
    target are never read again)."""

    def __init__(self, *, world_size: Cell, drones: Sequence[int], slack: int | None = None) -> None:
        self.size: Cell = (int(world_size[0]), int(world_size[1]), int(world_size[2]))
        self.slack = default_slack(self.size) if slack is None else max(0, int(slack))
        self._drones = swarm_numbers(drones)
        n = len(self._drones)
        self._cells = self.size[0] * self.size[1] * self.size[2]
        self._target = np.full((n, 3), -1, dtype=np.int64)
        self._trip = np.arange(n, dtype=np.int64)  # each drone's current trip
        self._trips = n  # trips numbered so far
        self._learned: dict[int, int] = {}
        self._learns = np.zeros(n, dtype=bool)  # learned something on its current trip

    def learned(self, drone: int) -> dict[Cell, int]:
        """Drone number `drone`'s learned values for its current target (as `LrtaPilot.learned`)."""
        row = int(self._rows([drone])[0])
        first = int(self._trip[row]) * self._cells
        _, ny, nz = self.size
        return {(i // (ny * nz), i // nz % ny, i % nz): v for k, v in self._learned.items()
                if first <= k < first + self._cells for i in (k - first,)}

    def _rows(self, drones: Sequence[int] | np.ndarray) -> np.ndarray:
        return swarm_rows(self._drones, drones)

    def step(self, drones: np.ndarray, pos: np.ndarray, target: np.ndarray) -> SwarmSensing:
        """This turn's moves of the drones numbered `drones` at `pos` ((n, 3)) towards `target` ((n, 3),
        (-1, -1, -1) for none): yields once the cells it senses, receives their kinds, returns (new cells
        (n, 3), note codes (n,), rankings (n,) uint32 as `schema.tables.rank_steps` packs them).

        The hot path of a swarm host (about 2 µs a drone): the neighbours' Manhattan distances follow from the
        drone's own (one more or one less, by the side of the target they lie on), and the learned values are
        looked up only for the drones that learned something on their current trip (`_learns`)."""
        size = self.size
        n = len(drones)
        rows = self._rows(drones)
        pos = np.asarray(pos, dtype=np.int64).reshape(n, 3)
        target = np.asarray(target, dtype=np.int64).reshape(n, 3)
        has = target[:, 0] >= 0
        changed = has & (self._target[rows] != target).any(axis=1)
        if changed.any():  # a new trip: the values learned for the former target are left behind
            fresh = np.flatnonzero(changed)
            self._trip[rows[fresh]] = self._trips + np.arange(len(fresh))
            self._trips += len(fresh)
            self._target[rows[fresh]] = target[fresh]
            self._learns[rows[fresh]] = False
        # Sense: the six neighbours (inside the world) and the target (inside, not where the drone is).
        limit = np.array(size, dtype=np.int64)
        inside = np.empty((n, 6), dtype=bool)
        inside[:, 0::2] = pos < limit - 1  # +x, +y, +z
        inside[:, 1::2] = pos > 0  # -x, -y, -z
        around = pos[:, None, :] + _STEPS  # (n, 6, 3)
        here = has & (pos == target).all(axis=1)
        t_in = has & ((target >= 0) & (target < limit)).all(axis=1)
        ask_t = t_in & ~here
        asked = np.concatenate([around[inside], target[ask_t]])
        kinds = (yield asked) if len(asked) else np.zeros(0, dtype=np.uint8)
        m = int(np.count_nonzero(inside))
        free = np.zeros((n, 6), dtype=bool)
        free[inside] = kinds[:m] == CellKind.EMPTY
        told = kinds[m:]
        t_blocked = np.zeros(n, dtype=bool)
        t_blocked[ask_t] = (told != CellKind.EMPTY) & (told != NO_ANSWER)  # no answer: not known blocked
        boxed = ~free.any(axis=1)

        rest = ~has | here | ~t_in | t_blocked | boxed
        go = np.flatnonzero(~rest)
        # At rest: its own cell, then the free neighbours in AROUND order.
        keys = np.full((n, 7), _FAR, dtype=np.int64)
        keys[:, :6][free] = np.broadcast_to(_COLUMNS, (n, 6))[free]
        keys[:, 6] = -1
        note = np.full(n, _NONE, dtype=np.uint8)
        note[here] = _REACHED
        note[has & ~here & (~t_in | t_blocked | boxed)] = _UNREACHABLE
        if len(go):
            p, t, f = pos[go], target[go], free[go]
            k = len(go)
            gap = np.abs(t - p)  # (k, 3)
            manh_p = gap.sum(axis=1)
            side = np.sign(t - p)  # each neighbour is one closer if it steps towards the target, else one farther
            values = np.empty((k, 7), dtype=np.int64)
            values[:, 0] = manh_p
            values[:, 1:] = manh_p[:, None] + np.where(side[:, _AXES] == _SIGNS, -1, 1)
            cell_keys = None
            learner = self._learns[rows[go]]
            if learner.any():  # the drones that learned on this trip: their values, where they learned one
                sub = np.flatnonzero(learner)
                cell_keys = (self._trip[rows[go[sub]]] * self._cells)[:, None] + linear_rows(
                    np.concatenate([p[sub, None, :], around[go[sub]]], axis=1).reshape(-1, 3), size).reshape(-1, 7)
                wanted = np.concatenate([np.ones((len(sub), 1), dtype=bool), f[sub]], axis=1)
                found = np.fromiter(map(self._learned.get, cell_keys[wanted].tolist(), repeat(-1)), dtype=np.int64,
                                    count=int(wanted.sum()))
                part = values[sub]
                part[wanted] = np.where(found >= 0, found, part[wanted])
                values[sub] = part
            h_nb = np.where(f, values[:, 1:], _FAR)
            h_here = np.maximum(values[:, 0], 1 + h_nb.min(axis=1))
            learn = h_here > manh_p
            if learn.any():
                at = np.flatnonzero(learn)
                spots = self._trip[rows[go[at]]] * self._cells + linear_rows(p[at], size)
                self._learned.update(zip(spots.tolist(), h_here[at].tolist()))
                self._learns[rows[go[at]]] = True
            tie = 1 + ((around[go] - t[:, None, :]) ** 2).sum(axis=2)
            ranking = np.where(f, np.where(f, h_nb, 0) * _H + tie * _TIE + _COLUMNS, _FAR)
            keys[go, :6] = ranking
            keys[go, 6] = h_here * _H + _STAY
            note[go] = np.where(h_here > manh_p + self.slack, _UNREACHABLE, _NONE)
        order = np.argsort(keys, axis=1, kind="stable")
        valid = np.take_along_axis(keys, order, axis=1) != _FAR
        ranked = (np.where(valid, order + 1, 0) << _SHIFTS).sum(axis=1).astype(np.uint32)
        new = pos.copy()
        if len(go):
            first = order[go, 0]
            moving = first < _STAY
            new[go[moving]] += _STEPS[first[moving]]
        return new, note, ranked
