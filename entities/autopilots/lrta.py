"""LRTA*: a cooperative autopilot cheap enough for ten thousand drones (``--autopilot lrta``).

Korf's Learning Real-Time A* ("Real-time heuristic search", Artificial Intelligence 42, 1990) with a lookahead
of one move, and of a cube in a depression (below), over the 6-connected grid. A drone keeps no map and no
search: only the values it has *learned*. A cell's value is h(c) = what the drone learned for it, else the
Manhattan distance from c to the target (admissible on the grid: no way is shorter). Each turn, from `pos`
towards `target`:

1. it senses its six neighbours and its target by ASK (a swarm host answers from its chart: no round trip);
   a neighbour is *free* if it is told EMPTY (a building, outside the world or no answer: not free);
2. it learns: h(pos) = max(h(pos), 1 + min h(free neighbour)) (stored only where it exceeds the Manhattan
   distance: the learned values are sparse, a few cells around the buildings it met);
3. it ranks its own cell and its free neighbours for the coordinator's arbiter (PIBT, coordinator/arbiter.py,
   docs/cooperation.md): by h, smallest first; staying (with the value just learned) before any neighbour of
   equal h; among neighbours of equal h, those on its *cruise* first: it climbs first and descends last (a level
   step while below the target's altitude, and a step down before it is in the target's column, come after the
   others); then the one nearer the target as the crow flies (squared Euclidean distance), then in AROUND order
   (+x, -x, +y, -y, +z, -z): a total order. The cruise: a city's buildings are boxes standing on the ground, so
   the higher of its altitude and its target's meets fewer of them, and the air above the target is free down to
   it; without it, a drone from high up that went down early met the low streets' dead ends (docs/cooperation.md
   measures it). Nearer as the crow flies: of two cells that get closer, the one along the axis with more way to
   go (paths go diagonally, staircase-wise, rather than one axis after the other, which would put crowds in the
   same lanes); of two that do not, the one to the side rather than straight back (a drone facing a building goes
   round it). After learning, the best neighbour is always strictly below staying, so a drone that gets its first
   choice always moves. Its move (`pos`, for an arbitration that takes one move per drone) is its first choice.

In a depression (it learned a value where it stood the turn before: a wall across its straight line), a drone
looks further: it senses the cube of `lookahead` cells around it (Chebyshev radius; 1: the 26 cells around; 0:
it does not) instead of its six neighbours, and revalues every free cell of the cube at once before step 2
(`Lookahead`): h(c) = max(h(c), the shortest way inside the cube's free cells from c to the target, if it is in
the cube, or to a cell just outside the cube, plus that cell's h). The way out of a depression crosses the
cube's border somewhere, so the values stay admissible; and the depression fills a cube at a time instead of a
cell at a time (Koenig and Sun's LSS-LRTA*, "Comparing real-time and incremental heuristic search for real-time
situated agents", JAAMAS 2009, with the sensed cube as the local search space).

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
arrays (`autopilots.SWARMS`), about 2 µs a drone a turn. Both revalue a cube with the same `Lookahead`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np

from schema import Cell, CellInfo, CellKind, Note
from schema.messages import AROUND
from schema.tables import code_of
from world.grid import in_bounds, linear_rows

from .base import NO_ANSWER, Decision, Sensing, SwarmBase, SwarmSensing

#: A ranking key is h * _H + off * _OFF + tie * _TIE + the step's index in RANK_STEPS (0-5 the neighbours in
#: AROUND order, 6 staying); off is 1 for a step off the cruise (see the module), else 0; tie is 0 for staying
#: and 1 + the neighbour's squared Euclidean distance to the target (below 2**36 in a world of sides up to 2**16)
#: for a neighbour. Learned values are kept below _CAP, so that keys stay below 2**63.
_TIE = 8
_OFF = 1 << 40
_H = 1 << 41
_CAP = 1 << 21
_STAY = 6
_AXIS = tuple(next(a for a in range(3) if d[a]) for d in AROUND)
_NONE, _REACHED, _UNREACHABLE = (code_of(n) for n in (Note.NONE, Note.REACHED, Note.UNREACHABLE))


#: The cube a drone in a depression senses and revalues: its Chebyshev radius (see the module; each radius
#: measured in docs/cooperation.md).
LOOKAHEAD = 1
_FAR_H = 1 << 50  # a value no way reaches (outside the world, a cell not yet reached by the revaluation)


def default_slack(size: Cell) -> int:
    """Moves beyond the Manhattan distance after which a drone says its target is unreachable."""
    return max(64, 2 * (size[0] + size[1] + size[2]))


def _manhattan(a: Cell, b: Cell) -> int:
    return abs(a[0] - b[0]) + abs(a[1] - b[1]) + abs(a[2] - b[2])


def _pack(order: Sequence[int]) -> int:
    """Step indices (into RANK_STEPS) as `schema.tables.rank_steps` packs them (code = index + 1)."""
    return sum((k + 1) << 3 * i for i, k in enumerate(order))


class Lookahead:
    """The cube of Chebyshev radius `radius` a drone in a depression senses, and its revaluation (radius 0: no
    cube, the one-move lookahead only). Cells are indexed in the *padded* cube (radius + 1, C order over the
    offsets); `inner` are the cube's own."""

    def __init__(self, radius: int) -> None:
        self.radius = r = int(radius)
        if r < 0:
            raise ValueError(f"a lookahead radius is at least 0 (0: the one-move lookahead only), got {radius!r}")
        side = 2 * r + 3
        span = np.arange(-r - 1, r + 2, dtype=np.int64)
        self.offsets = np.stack(np.meshgrid(span, span, span, indexing="ij"), axis=-1).reshape(-1, 3)
        self.inner = np.flatnonzero(np.abs(self.offsets).max(axis=1) <= r)
        strides = np.array([dx * side * side + dy * side + dz for dx, dy, dz in AROUND], dtype=np.int64)
        self._next = self.inner[:, None] + strides  # (inner, 6): padded indices of each inner cell's neighbours
        self.cube = self.offsets[self.inner]  # (inner, 3): the cube's own offsets
        at = {tuple(o): i for i, o in enumerate(self.cube.tolist())}
        self.center = at[(0, 0, 0)]
        self.around = np.array([at[d] for d in AROUND if d in at], dtype=np.int64)  # inner indices, AROUND order
        #: inner indices of the cells sensed besides the six neighbours (the center is where the drone is)
        self.extra = np.setdiff1d(np.arange(len(self.inner)), [self.center, *self.around.tolist()])
        self.sensed = self.cube[self.extra]  # (extra, 3): their offsets

    def revalue(self, pos: np.ndarray, target: np.ndarray, free: np.ndarray, h: np.ndarray) -> np.ndarray:
        """The new values of the inner cells of `k` drones' cubes ((k, inner) int64): for a free cell, the
        greater of its value and its shortest way through free inner cells to the target (0 there) or to a
        padded border cell (plus that cell's value); an unfree cell, or one with no way out, keeps its value.

        `pos`, `target`: (k, 3); `free`: (k, inner) bool, the drone's own cell free; `h`: (k, padded) the
        drones' values of every padded cell (`_FAR_H` outside the world)."""
        cells = pos[:, None, :] + self.cube
        goal = free & (cells == target[:, None, :]).all(axis=2)
        old = h[:, self.inner]
        way = np.where(goal, 0, _FAR_H)
        relax = free & ~goal
        padded = h.copy()
        for _ in range(len(self.inner)):  # Bellman-Ford over unit steps: a fixed point within `inner` rounds
            padded[:, self.inner] = way
            better = np.where(relax, np.minimum(way, padded[:, self._next].min(axis=2) + 1), way)
            if np.array_equal(better, way):
                break
            way = better
        return np.where(free & (way < _FAR_H), np.maximum(old, way), old)


class LrtaPilot:
    """LRTA* for one drone (see the module). Deterministic; its memory is the values it learned for its
    current target."""

    name: ClassVar[str] = "lrta"
    cooperative: ClassVar[bool] = True
    senses: ClassVar[bool] = True

    def __init__(self, *, world_size: Cell, slack: int | None = None, lookahead: int = LOOKAHEAD) -> None:
        self.size: Cell = (int(world_size[0]), int(world_size[1]), int(world_size[2]))
        self.slack = default_slack(self.size) if slack is None else max(0, int(slack))
        self.look = Lookahead(lookahead)
        self._target: Cell | None = None
        self._learned: dict[Cell, int] = {}
        self._deep = False  # it learned where it stood last turn: it senses and revalues a cube

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
        deep, self._deep = self._deep and target is not None and target == self._target and target != pos, False
        cube = [(pos[0] + x, pos[1] + y, pos[2] + z) for x, y, z in self.look.cube.tolist()] if deep else []
        sensed = [cube[i] for i in self.look.extra.tolist()] if deep else []
        asked = [c for c in [*around, *sensed] if in_bounds(c, self.size)]
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
        if deep:
            self._revalue(pos, target, cube, answers)
        values = {k: self.h(around[k]) for k in free}
        here = min(_CAP, max(self.h(pos), 1 + min(values.values())))
        base = _manhattan(pos, target)
        if here > base:
            self._learned[pos] = here
            self._deep = self.look.radius > 0
        keys = [(here * _H + _STAY, _STAY)]
        below, column = pos[2] < target[2], pos[:2] == target[:2]
        for k, v in values.items():
            c = around[k]
            euclid = (c[0] - target[0]) ** 2 + (c[1] - target[1]) ** 2 + (c[2] - target[2]) ** 2
            off = k < 4 and below or k == 5 and not column  # level before climbing, down before its column
            keys.append((v * _H + off * _OFF + (1 + euclid) * _TIE + k, k))
        order = [k for _, k in sorted(keys)]
        note = Note.UNREACHABLE if here > base + self.slack else Note.NONE
        return Decision(pos=pos if order[0] == _STAY else around[order[0]], note=note, ranked=_pack(order))

    def _revalue(self, pos: Cell, target: Cell, cube: list[Cell], answers: Mapping[Cell, CellInfo]) -> None:
        """Revalue the cube around `pos` (`Lookahead.revalue`) and keep the values it raised."""
        look = self.look
        free = np.array([[c == pos or _empty(answers.get(c)) for c in cube]])
        padded = [(pos[0] + x, pos[1] + y, pos[2] + z) for x, y, z in look.offsets.tolist()]
        h = np.array([[self.h(c) if in_bounds(c, self.size) else _FAR_H for c in padded]], dtype=np.int64)
        old, new = h[0, look.inner].tolist(), look.revalue(np.array([pos]), np.array([target]), free, h)[0].tolist()
        self._learned.update((c, min(_CAP, v)) for c, o, v in zip(cube, old, new) if v > o)


def _empty(info: CellInfo | None) -> bool:
    return info is not None and info.kind is CellKind.EMPTY


_STEPS = np.array(AROUND, dtype=np.int64)  # (6, 3)
_AXES = np.array(_AXIS, dtype=np.int64)
_SIGNS = np.array([sum(d) for d in AROUND], dtype=np.int64)  # +1 or -1: the step's way along its axis
_COLUMNS = np.arange(6, dtype=np.int64)
_SHIFTS = np.arange(7, dtype=np.int64) * 3
_FAR = np.iinfo(np.int64).max


class LrtaSwarm(SwarmBase):
    """`LrtaPilot` for a whole swarm host's drones at once, over arrays: the same decisions and the same learned
    values. The values of every drone are one dict: (the drone's current trip × world cells + the cell's grid
    index) -> h, where a trip is numbered anew each time the drone's target changes (the values of a former
    target are never read again, and dropped once the dict has doubled since they were last dropped: its size
    stays within twice the current trips' values, at a constant cost a value, amortised)."""

    #: Values kept before the first drop of former trips' values (`_forget`).
    FORGET_AFTER: ClassVar[int] = 1 << 16

    def __init__(self, *, world_size: Cell, drones: Sequence[int], slack: int | None = None,
                 lookahead: int = LOOKAHEAD) -> None:
        super().__init__(world_size=world_size, drones=drones)
        self.slack = default_slack(self.size) if slack is None else max(0, int(slack))
        self.look = Lookahead(lookahead)
        n = len(self._drones)
        self._target = np.full((n, 3), -1, dtype=np.int64)
        self._trip = np.arange(n, dtype=np.int64)  # each drone's current trip
        self._trips = n  # trips numbered so far
        self._learned: dict[int, int] = {}
        self._forget_at = self.FORGET_AFTER  # the dict's size at which former trips' values are dropped
        self._learns = np.zeros(n, dtype=bool)  # learned something on its current trip
        self._deep = np.zeros(n, dtype=bool)  # learned where it stood last turn: senses and revalues a cube

    @property
    def kept(self) -> int:
        """How many learned values the swarm keeps (its drones' current trips', and former trips' not yet dropped)."""
        return len(self._learned)

    def learned(self, drone: int) -> dict[Cell, int]:
        """Drone number `drone`'s learned values for its current target (as `LrtaPilot.learned`)."""
        return self._memory_of(self._learned, int(self._trip[int(self._rows([drone])[0])]))

    def step(self, drones: np.ndarray, pos: np.ndarray, target: np.ndarray) -> SwarmSensing:
        """`SwarmPilot.step`, with the rankings. The hot path of a swarm host (about 2 µs a drone): the neighbours'
        Manhattan distances follow from the drone's own (one more or one less, by the side of the target they lie
        on), and the learned values are looked up only for the drones that learned something on their current trip
        (`_learns`)."""
        size = self.size
        n = len(drones)
        rows, pos, target = self._orders(drones, pos, target)
        has = target[:, 0] >= 0
        changed = has & (self._target[rows] != target).any(axis=1)
        if changed.any():  # a new trip: the values learned for the former target are left behind
            fresh = np.flatnonzero(changed)
            self._trip[rows[fresh]] = self._trips + np.arange(len(fresh))
            self._trips += len(fresh)
            self._target[rows[fresh]] = target[fresh]
            self._learns[rows[fresh]] = False
            if len(self._learned) >= self._forget_at:
                self._forget()
        # Sense: the six neighbours (inside the world) and the target (inside, not where the drone is).
        limit = np.array(size, dtype=np.int64)
        inside = np.empty((n, 6), dtype=bool)
        inside[:, 0::2] = pos < limit - 1  # +x, +y, +z
        inside[:, 1::2] = pos > 0  # -x, -y, -z
        around = pos[:, None, :] + _STEPS  # (n, 6, 3)
        here = has & (pos == target).all(axis=1)
        deep = self._deep[rows] & has & ~changed & ~here
        self._deep[rows] = False
        t_in = has & ((target >= 0) & (target < limit)).all(axis=1)
        ask_t = t_in & ~here
        extra = pos[deep][:, None, :] + self.look.sensed  # (d, extra, 3)
        extra_in = ((extra >= 0) & (extra < limit)).all(axis=2)
        asked = np.concatenate([around[inside], target[ask_t], extra[extra_in]])
        kinds = (yield asked) if len(asked) else np.zeros(0, dtype=np.uint8)
        m = int(np.count_nonzero(inside))
        mt = m + int(np.count_nonzero(ask_t))  # the neighbours', then the targets', then the cubes' answers
        free = np.zeros((n, 6), dtype=bool)
        free[inside] = kinds[:m] == CellKind.EMPTY
        told = kinds[m:mt]
        cube_free = np.zeros((len(extra), len(self.look.inner)), dtype=bool)  # a row for each deep drone
        if len(extra):
            cube_free[:, self.look.center] = True
            cube_free[:, self.look.around] = free[deep]
            extra_free = np.zeros(extra_in.shape, dtype=bool)
            extra_free[extra_in] = kinds[mt:] == CellKind.EMPTY
            cube_free[:, self.look.extra] = extra_free
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
            manh_p = np.abs(t - p).sum(axis=1)
            side = np.sign(t - p)  # each neighbour is one closer if it steps towards the target, else one farther
            values = np.empty((k, 7), dtype=np.int64)
            values[:, 0] = manh_p
            values[:, 1:] = manh_p[:, None] + np.where(side[:, _AXES] == _SIGNS, -1, 1)
            if deep[go].any():  # cube_free's rows are the deep drones' in order
                at = go[deep[go]]
                self._revalue(at, rows, pos, target, cube_free[np.searchsorted(np.flatnonzero(deep), at)])
            learner = self._learns[rows[go]]
            if learner.any():  # the drones that learned on this trip: their values, where they learned one
                sub = np.flatnonzero(learner)
                cells = np.concatenate([p[sub, None, :], around[go[sub]]], axis=1)  # (sub, 7, 3)
                cell_keys = self._keys(self._trip[rows[go[sub]]], cells)
                wanted = np.concatenate([np.ones((len(sub), 1), dtype=bool), f[sub]], axis=1)
                found = self._lookup(self._learned, cell_keys[wanted])
                part = values[sub]
                part[wanted] = np.where(found >= 0, found, part[wanted])
                values[sub] = part
            h_nb = np.where(f, values[:, 1:], _FAR)
            h_here = np.minimum(_CAP, np.maximum(values[:, 0], 1 + h_nb.min(axis=1)))
            learn = h_here > manh_p
            if learn.any():
                at = np.flatnonzero(learn)
                spots = self._trip[rows[go[at]]] * self._cells + linear_rows(p[at], size)
                self._learned.update(zip(spots.tolist(), h_here[at].tolist()))
                self._learns[rows[go[at]]] = True
                self._deep[rows[go[at]]] = self.look.radius > 0
            tie = 1 + ((around[go] - t[:, None, :]) ** 2).sum(axis=2)
            off = (p[:, 2] < t[:, 2])[:, None] & (_COLUMNS < 4)  # level steps below the target's altitude
            off[:, 5] = (p[:, :2] != t[:, :2]).any(axis=1)  # down before the target's column
            keys[go, :6] = np.where(f, np.where(f, h_nb, 0) * _H + off * _OFF + tie * _TIE + _COLUMNS, _FAR)
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

    def _forget(self) -> None:
        """Drop the values of former trips (see the class)."""
        keys = np.fromiter(self._learned.keys(), dtype=np.int64, count=len(self._learned))
        values = np.fromiter(self._learned.values(), dtype=np.int64, count=len(self._learned))
        keep = np.isin(keys // self._cells, self._trip[self._learns])
        self._learned = dict(zip(keys[keep].tolist(), values[keep].tolist()))
        self._forget_at = max(self.FORGET_AFTER, 2 * len(self._learned))

    def _revalue(self, at: np.ndarray, rows: np.ndarray, pos: np.ndarray, target: np.ndarray,
                 cube_free: np.ndarray) -> None:
        """Revalue the cubes of the drones at `at` (indices into this step's arrays; each learned on its trip;
        `cube_free` their cubes' free cells) with `Lookahead.revalue`, and keep the values it raised."""
        look, size = self.look, self.size
        p, t = pos[at], target[at]
        cells = p[:, None, :] + look.offsets  # (k, padded, 3)
        inside = ((cells >= 0) & (cells < np.array(size))).all(axis=2)
        keys = self._keys(self._trip[rows[at]], np.where(inside[..., None], cells, 0))
        found = self._lookup(self._learned, keys[inside])
        h = np.full(inside.shape, _FAR_H, dtype=np.int64)
        h[inside] = np.where(found >= 0, found, np.abs(cells - t[:, None, :]).sum(axis=2)[inside])
        old = h[:, look.inner]
        new = look.revalue(p, t, cube_free, h)
        raised = new > old
        self._learned.update(zip(keys[:, look.inner][raised].tolist(), np.minimum(_CAP, new[raised]).tolist()))
