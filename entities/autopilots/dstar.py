"""D* Lite over the 6-connected 3D grid, with sensing by ASK: an autopilot that always arrives.

The world is unknown at first. Unknown cells are assumed free ("freespace assumption"); a cell the drone learns is a
building (or outside) is blocked for good. The planner is D* Lite (Koenig & Likhachev): a backward incremental
search rooted at the target, so when the drone moves only the heuristic's origin shifts (the ``km`` offset) and when
it learns a blocked cell only the affected part of the search is repaired, never a search from scratch (a new target
is the only restart).

Sensing, each step (at most two ASK round trips):

1. the in-world, not-known-blocked neighbours (needed anyway: another drone may be in one), the target if still
   unknown (a target inside a building is seen at once), and the still-unknown cells of the next ``lookahead`` cells
   of the planned path;
2. only if the first answers revealed a building the search relied on: the still-unknown cells of the repaired
   path's next ``lookahead`` cells.

Sensing along the path ahead finds walls while there is still room to turn, so the drone veers early (often at no
cost in a Manhattan world) instead of walking into dead ends. On the benchmark suite (BENCHMARKS.md) this takes the
mean path from 1.34x to 1.11x the optimum (p90 1.98x to 1.28x) for about 12 cells asked per step, 6 of them the
neighbours.

Incremental, measured on the benchmark's 64x64x16 cities: 0.04 ms a step median (0.34 ms p90), against 0.26 ms
(0.74 ms p90) for the same code searching from scratch every step (map kept).

Implementation notes (speed in pure Python):

* cells are flat indices into a grid padded by one layer of permanently blocked cells, so a neighbour is
  ``i + offset`` with no bounds test and the world's edge is just a wall;
* heap entries are single integers ``key * NP + cell`` (lazy deletion: stale entries are skipped when popped; the
  heap is compacted when it grows large);
* keys are ``(k1, tb)`` packed into one integer, with k1 = min(g, rhs) + h + km as in D* Lite. The tie-break differs
  from the paper's (smaller g first): among equal k1, *under*-consistent cells come first (tb = 0), then
  over-consistent cells nearest the drone (tb = h + 1). Diving towards the drone on ties expands about a path's
  worth of cells in open space instead of the whole box between drone and target. Correctness still holds: an
  over-consistent cell with a wrong rhs always has an inconsistent cell with a strictly smaller k1 on its true
  shortest path (consistent heuristic, integer costs), and a g that is too small always has an under-consistent cell
  with k1 <= k1(start) behind it, which the tie-break pops before the search stops.
  ``tests/test_autopilot_dstar.py`` checks the result against breadth-first search.

Cooperation (docs/cooperation.md): besides its move, each step offers the coordinator's arbiter a ranked list of
candidate cells (the decision's ``ranked``): its own cell and the neighbours it knows are free, by their distance to
the target on the known map (closer first; staying ranks between the cells that get closer and those that do not),
ties in the tie-break order below. The arbiter (PIBT) picks one of them for it, pushing other cooperative drones
aside or pushed aside itself; on its target it offers its cell first and its free neighbours after, so that it can
be pushed out of the way and come back.

It says UNREACHABLE only where the static world has no way: the target is outside the world or a building, or its
known map (buildings, never drones) has no path to it. A drone whose distance has not reached a new low for
``stuck_after`` turns (learning a wall starts the count again) says STUCK while it lasts: nothing it knows is in the
way, so other drones are, and they have not let it pass in all that time (a crowd in a corridor, a drone that never
moves). That is the arbitration's to resolve (its priority: `arbiter.STUCK`; the search, coordinator/lacam.py, finds
the way or proves there is none), never a reason for the game to give up on it. It keeps offering its candidates and
says NONE again once it gets closer.

The move it proposes (``pos``, for an arbitration that takes one move per drone) skips the other drones seen in this
step's answers: another equally short move if there is one, else the drone waits ``PATIENCE`` turns, then
side-steps. Other drones block their cell for this step only: they never enter the search and are never remembered.
"""

from __future__ import annotations

from array import array
from collections.abc import Generator, Mapping
from heapq import heapify, heappop, heappush
from typing import ClassVar

import numpy as np

from schema import Cell, CellInfo, CellKind, Note
from schema.messages import AROUND
from schema.tables import rank_steps
from world.grid import in_bounds
from world.search import breadth_first, padded_steps

from .base import Answers, Decision, Sensing

UNKNOWN, FREE, BLOCKED = 0, 1, 2
#: Farther than any cell (a C int holds it, and any distance plus one). Each pilot's g and rhs hold one int for every
#: cell of the padded world, in arrays: as lists (of references), 40 pilots over 128x128x16 were 24 million that
#: the cyclic garbage collector walked, 75 ms of CPU at a time holding the GIL (on a loaded machine 0.5-0.8 s in
#: which the swarm host's `Deciding` thread could not say it was still deciding: its drones were LOST).
INF = 1 << 30


class DStarPilot:
    """D* Lite autopilot (``--autopilot dstar``). One instance per drone; deterministic."""

    name: ClassVar[str] = "dstar"
    cooperative: ClassVar[bool] = True  # gives way to other drones (coordinator/arbiter.py)
    senses: ClassVar[bool] = True

    #: Default number of path cells ahead whose unknown cells are asked each step.
    LOOKAHEAD: ClassVar[int] = 20
    #: Turns to wait behind a drone blocking every progressing move before side-stepping.
    PATIENCE: ClassVar[int] = 2
    #: Turns without getting closer after which a drone with another one in its way ranks its candidates by
    #: the way round that drone's cell (`_detour`) ...
    DETOUR_AFTER: ClassVar[int] = 32
    #: ... or, once pushed off its target this many times, as soon as it does not get closer, if it is at most
    #: DETOUR_NEAR moves from its target and the way round is at most DETOUR_LONGER moves longer (the bounds
    #: measured with `dronesim bench swarm`: docs/cooperation.md).
    PUSHED_OFF: ClassVar[int] = 3
    DETOUR_LONGER: ClassVar[int] = 8
    DETOUR_NEAR: ClassVar[int] = 2

    def __init__(self, *, world_size: Cell, lookahead: int | None = None, rounds: int = 2,
                 known: np.ndarray | None = None, stuck_after: int | None = None) -> None:
        """`known`: the world's buildings (a bool array of `world_size`) if the drone is given the map (the benchmark's
        upper bound), else it learns them by ASK. `stuck_after`: see the module's doc (default: twice the world's
        X + Y + Z, at least 64 turns)."""
        X, Y, Z = (int(v) for v in world_size)
        self.size: Cell = (X, Y, Z)
        self.lookahead = self.LOOKAHEAD if lookahead is None else max(0, int(lookahead))
        self.rounds = max(1, min(2, int(rounds)))
        sx, sy, self._offs = padded_steps(self.size)  # strides and the neighbours' offsets, in AROUND order
        n = (X + 2) * sx
        self._sx, self._sy, self._n = sx, sy, n
        # Known map: border and every learnt building/outside cell are BLOCKED.
        grid = np.full((X + 2, Y + 2, Z + 2), BLOCKED, dtype=np.uint8)
        grid[1:-1, 1:-1, 1:-1] = UNKNOWN if known is None else np.where(known, BLOCKED, FREE)
        self._state = bytearray(grid.tobytes())
        # Padded coordinates (x+1, y+1, z+1) of every index, for the heuristic.
        dtype, code = (np.uint8, "B") if max(X, Y, Z) < 250 else (np.uint32, "I")
        flat = np.arange(n, dtype=np.int64)
        self._xs, self._ys, self._zs = (array(code, c.astype(dtype).tobytes())
                                        for c in (flat // sx, flat // sy % (Y + 2), flat % sy))
        self._K = X + Y + Z + 8  # > any h + 1: tb fits under one unit of k1
        self.stuck_after = max(64, 2 * (X + Y + Z)) if stuck_after is None else max(1, int(stuck_after))
        # The search state of the current target (set by _reset).
        self._goal, self._last = -1, -1
        self._target: Cell | None = None
        self._home = False  # the last step was on the target
        self._restart()

    def _restart(self) -> None:
        """Start the count of turns without getting closer again (a new target, or on it)."""
        self._waited = 0  # turns waited behind a drone
        self._low, self._since = INF, 0  # the smallest distance since the count started, turns since then
        #: While going round a drone (`_detour`): the cell it avoids, and each cell's distance to the target
        #: without it (those the search reached); -1 / None otherwise.
        self._avoid = -1
        self._round: dict[int, int] | None = None
        self._tried = False  # a detour was looked for since the drone last got closer

    @property
    def distance(self) -> int | None:
        """The planned number of moves from the last step's position to the target on the known map (unknown cells
        counted free); None before any target or when it is unreachable."""
        g = INF if self._goal < 0 or self._unreachable else self._g[self._last]
        return None if g >= INF else g

    # ------------------------------------------------------------------ indices

    def _index(self, c: Cell) -> int:
        return (c[0] + 1) * self._sx + (c[1] + 1) * self._sy + c[2] + 1

    def _cell(self, i: int) -> Cell:
        return (self._xs[i] - 1, self._ys[i] - 1, self._zs[i] - 1)

    # ------------------------------------------------------------------ D* Lite core

    def _reset(self, target: Cell, start: int) -> None:
        n = self._n
        self._target = target
        self._goal = goal = self._index(target)
        self._g = array("i", (INF,)) * n  # (arrays, not lists: the collector does not walk them, see INF)
        self._rhs = array("i", (INF,)) * n
        self._km, self._last, self._unreachable = 0, start, False
        self._orders: dict[tuple[int, int, int, bool], tuple[int, ...]] = {}
        self._home, self._pushed = False, 0  # _pushed: times it was pushed off its target
        self._restart()
        self._rhs[goal] = 0
        h = self._h(start, goal)
        self._heap: list[int] = [(h * self._K + h + 1) * n + goal]

    def _h(self, a: int, b: int) -> int:
        xs, ys, zs = self._xs, self._ys, self._zs
        return abs(xs[a] - xs[b]) + abs(ys[a] - ys[b]) + abs(zs[a] - zs[b])

    def _block(self, c: int, s: int) -> bool:
        """Learn that index c is a building/outside. True if the search may have to change."""
        state = self._state
        if state[c] == BLOCKED:
            return False
        state[c] = BLOCKED
        if self._goal < 0:
            return False
        g, rhs = self._g, self._rhs
        want = g[c] + 1
        g[c] = rhs[c] = INF
        if want > INF:  # the search never reached it: nothing depends on it
            return False
        for p in (c + d for d in self._offs):
            if rhs[p] == want and p != self._goal and state[p] != BLOCKED:  # re-derive rhs(p) from its neighbours
                m = min(g[p + e] for e in self._offs)
                rhs[p] = r = m + 1 if m < INF else INF
                if g[p] != r:  # inconsistent: queued with its key relative to s
                    h = self._h(p, s)
                    key = (g[p] + h + self._km) * self._K if g[p] < r else (r + h + self._km) * self._K + h + 1
                    heappush(self._heap, key * self._n + p)
        return True

    def _compute(self, s: int, t: int = -1) -> None:
        """ComputeShortestPath: make g(t) (default: g(s)) the true distance to the goal on the known map, with keys
        relative to the drone's cell s."""
        heap, g, rhs, state = self._heap, self._g, self._rhs, self._state
        xs, ys, zs = self._xs, self._ys, self._zs
        # Heuristic by table look-up: h(u) = hx[xs[u]] + hy[ys[u]] + hz[zs[u]].
        hx, hy, hz = ([abs(c - axis[s]) for c in range(n + 2)] for axis, n in zip((xs, ys, zs), self.size))
        km, K, NP, goal, offs = self._km, self._K, self._n, self._goal, self._offs
        o0, o1, o2, o3, o4, o5 = offs
        t = s if t < 0 else t
        ht = hx[xs[t]] + hy[ys[t]] + hz[zs[t]]
        while heap:
            top = heap[0]
            gt = g[t]
            if gt == rhs[t] and top >= ((gt + ht + km) * K + ht + 1) * NP:
                break
            heappop(heap)
            k, u = divmod(top, NP)
            gu = g[u]
            ru = rhs[u]
            if gu == ru:
                continue  # stale entry
            h = hx[xs[u]] + hy[ys[u]] + hz[zs[u]]
            knew = (ru + h + km) * K + h + 1 if gu > ru else (gu + h + km) * K
            if k < knew:
                heappush(heap, knew * NP + u)
                continue
            if gu > ru:  # over-consistent: settle it, relax its neighbours
                g[u] = ru
                nv = ru + 1
                for d in offs:
                    p = u + d
                    if rhs[p] > nv and state[p] != BLOCKED:
                        rhs[p] = nv
                        gp = g[p]
                        if gp != nv:
                            hp = hx[xs[p]] + hy[ys[p]] + hz[zs[p]]
                            key = (gp + hp + km) * K if gp < nv else (nv + hp + km) * K + hp + 1
                            heappush(heap, key * NP + p)
            else:  # under-consistent: raise it to infinity, re-derive it and its dependants
                g[u] = INF
                want = gu + 1
                for p in (u, u + o0, u + o1, u + o2, u + o3, u + o4, u + o5):
                    if p == goal or state[p] == BLOCKED or (p != u and rhs[p] != want):
                        continue
                    m = min(g[p + o0], g[p + o1], g[p + o2], g[p + o3], g[p + o4], g[p + o5])
                    r = m + 1 if m < INF else INF
                    rhs[p] = r
                    gp = g[p]
                    if gp != r:
                        hp = hx[xs[p]] + hy[ys[p]] + hz[zs[p]]
                        key = (gp + hp + km) * K if gp < r else (r + hp + km) * K + hp + 1
                        heappush(heap, key * NP + p)
        if len(heap) > 2 * NP:  # compact: drop entries of cells that are consistent now
            heap[:] = [e for e in heap if g[e % NP] != rhs[e % NP]]
            heapify(heap)

    # ------------------------------------------------------------------ paths and tie-breaks

    def _order(self, i: int) -> tuple[int, ...]:
        """Neighbour offsets of cell i in tie-break order, a fixed function of (cell, target): climb first when the
        target is higher, then the horizontal axis with more way to go, then the other one, descend last (flying
        high meets fewer buildings)."""
        goal, xs, ys, zs = self._goal, self._xs, self._ys, self._zs
        dx, dy, dz = xs[goal] - xs[i], ys[goal] - ys[i], zs[goal] - zs[i]
        key = ((dx > 0) - (dx < 0), (dy > 0) - (dy < 0), (dz > 0) - (dz < 0), abs(dx) >= abs(dy))
        order = self._orders.get(key)
        if order is None:
            sx, sy = self._sx, self._sy
            fx = sx if dx >= 0 else -sx
            fy = sy if dy >= 0 else -sy
            (first, a), (second, b) = ((fx, dx), (fy, dy)) if key[3] else ((fy, dy), (fx, dx))
            ranked = ([1] if dz > 0 else []) + [d for d, way in ((first, a), (second, b)) if way]
            ranked += [-1] if dz < 0 else []
            order = (*ranked, *(d for d in (1, first, second, -first, -second, -1) if d not in ranked))
            self._orders[key] = order
        return order

    def _best(self, i: int, skip: frozenset[int] | set[int] = frozenset()) -> int:
        """The neighbour of i with the smallest g (tie-break order), or -1 if none is finite."""
        g, state = self._g, self._state
        best, bg = -1, INF
        for d in self._order(i):
            p = i + d
            if g[p] < bg and state[p] != BLOCKED and p not in skip:
                best, bg = p, g[p]
        return best

    def _unknown_ahead(self, s: int) -> list[int]:
        """The unknown cells among the planned path's next `lookahead` cells after s (fewer at the goal or a dead end;
        none if the search found no path)."""
        path: list[int] = []
        g, cur = self._g, s
        while g[s] < INF and len(path) < self.lookahead and cur != self._goal:
            nxt = self._best(cur)
            if nxt < 0 or g[nxt] >= g[cur]:
                break
            path.append(nxt)
            cur = nxt
        return [p for p in path if self._state[p] == UNKNOWN]

    # ------------------------------------------------------------------ the step

    def _learn(self, answers: Mapping[Cell, CellInfo], s: int, seen: tuple[set[int], set[int]] | None = None) -> bool:
        """Record ASK answers; collect in `seen` the cells told empty and those holding another drone. True if
        something got blocked."""
        changed = False
        state, index, size = self._state, self._index, self.size
        for cell, info in answers.items():
            if not in_bounds(cell, size):
                continue
            i = index(cell)
            if info.kind is CellKind.EMPTY:
                if state[i] == UNKNOWN:
                    state[i] = FREE
                if seen is not None:
                    seen[0].add(i)
                    if info.drones and i != s:
                        seen[1].add(i)
            elif self._block(i, s):
                changed = True
        return changed

    def step(self, pos: Cell, target: Cell | None) -> Sensing:
        pos = (int(pos[0]), int(pos[1]), int(pos[2]))
        if not in_bounds(pos, self.size):
            return Decision(pos=pos, note=Note.NONE if target is None else Note.UNREACHABLE)
        s = self._index(pos)
        if target is None:
            return Decision(pos=pos, ranked=(yield from self._rest(s)))
        target = (int(target[0]), int(target[1]), int(target[2]))
        if pos == target:  # parked: it may be pushed aside, to its free neighbours
            self._restart()
            self._home = target == self._target
            return Decision(pos=pos, note=Note.REACHED, ranked=(yield from self._rest(s)))
        if not in_bounds(target, self.size):
            return Decision(pos=pos, note=Note.UNREACHABLE, ranked=(yield from self._rest(s)))
        if target != self._target:
            self._reset(target, s)
        elif self._home:
            self._pushed += 1
        self._home = False
        goal, state = self._goal, self._state
        if self._unreachable or state[goal] == BLOCKED:
            return (yield from self._give_up(pos, s))
        if s != self._last:  # the drone moved: the heuristic's origin shifts
            self._km += self._h(self._last, s)
            self._last = s
        self._compute(s)

        # Round 1: neighbours (drones), the target if unknown, unknown cells along the path ahead.
        neigh = [s + d for d in self._offs if state[s + d] != BLOCKED]
        extra = [goal] if state[goal] == UNKNOWN else []
        cells = tuple(map(self._cell, dict.fromkeys(neigh + extra + self._unknown_ahead(s))))  # each once
        sensed: set[int] = set()  # the cells told empty, and those holding another drone
        drones: set[int] = set()
        changed = self._learn((yield cells), s, (sensed, drones)) if cells else False
        if state[goal] == BLOCKED:
            return (yield from self._give_up(pos, s))
        if changed:
            self._compute(s)
            more = self._unknown_ahead(s) if self.rounds > 1 else []  # round 2: the repaired path's
            if more and self._learn((yield tuple(map(self._cell, more))), s):
                self._compute(s)
        g = self._g
        if g[s] >= INF:
            return (yield from self._give_up(pos, s))
        if g[s] < self._low:
            self._low, self._since = g[s], 0
            self._avoid, self._round, self._tried = -1, None, False
        elif changed:
            self._low, self._since = g[s], 0
        else:
            self._since += 1
        if self._avoid >= 0:  # going round: what it learnt of the walls (the search may not say) counts
            self._round = self._detour(self._avoid, s)
            if self._round is None:
                self._avoid = -1
        note = Note.STUCK if self._since >= self.stuck_after else Note.NONE
        stuck = self._since >= self.DETOUR_AFTER
        if not self._tried and (stuck or self._pushed >= self.PUSHED_OFF and self._since and g[s] <= self.DETOUR_NEAR):
            self._tried = True
            blocker = next((p for p in sorted(drones, key=lambda p: g[p]) if g[p] < g[s]), -1)
            if blocker >= 0:
                self._round = self._detour(blocker, s)
                if self._round is not None and not stuck and self._round[s] > g[s] + self.DETOUR_LONGER:
                    self._round = None
                self._avoid = blocker if self._round is not None else -1

        # Move: the best neighbour sensed empty this step and free of other drones.
        avoid = {p for p in neigh if p not in sensed} | drones
        nxt = self._best(s)
        if nxt in avoid:
            # The planned move is taken: settle the other neighbours' distances (the search
            # only guarantees the best one's), then pick among them.
            for p in neigh:
                if p not in avoid and state[p] != BLOCKED:
                    self._compute(s, p)
            nxt = self._best(s, avoid)
        if nxt < 0 or g[nxt] >= g[s]:  # every progressing move is taken by a drone: wait, then side-step
            self._waited += 1
            if nxt < 0 or g[nxt] >= INF or self._waited <= self.PATIENCE:
                nxt = s
        if nxt != s:
            self._waited = 0
        return Decision(pos=self._cell(nxt), note=note, ranked=self._ranking(s, sensed))

    def _give_up(self, pos: Cell, s: int) -> Sensing:
        """The target is unreachable, for good: the world is static, nothing new can be learnt by hovering."""
        self._unreachable = True
        return Decision(pos=pos, note=Note.UNREACHABLE, ranked=(yield from self._rest(s)))

    def _rest(self, s: int) -> Generator[tuple[Cell, ...], Answers, int]:
        """`_aside`'s candidates, its unknown neighbours asked about first (once: then they are known): a drone at
        rest (parked, without a target, or that gave its own up) may have to step aside for another, and can only
        offer the cells it knows are free (one that never asked offered its own cell alone: a drone that had to
        pass it never did)."""
        if unknown := tuple(self._cell(s + d) for d in self._offs if self._state[s + d] == UNKNOWN):
            self._learn((yield unknown), s)
        return self._aside(s)

    # ------------------------------------------------------------------ candidates for the arbiter

    def _ranking(self, s: int, sensed: set[int]) -> int:
        """The candidates offered to the arbiter (packed): s and its neighbours sensed free this step, by distance (g)
        on the known map, ties in tie-break order. The search settles g(s) and the best neighbour's; the others' may
        still be estimates: settling them all would cost a search each and steer the next steps' sensing elsewhere,
        for an order that the next step corrects anyway."""
        known, state = self._round, self._state
        get = self._g.__getitem__ if known is None else (lambda i: known.get(i, INF))
        ranked = sorted([(get(s), -1, 0)] + [(get(s + d), k, d) for k, d in enumerate(self._order(s))
                                             if s + d in sensed and state[s + d] != BLOCKED])
        return rank_steps((0, 0, 0) if d == 0 else AROUND[self._offs.index(d)] for _, _, d in ranked)

    def _detour(self, avoid: int, s: int) -> dict[int, int] | None:
        """Each cell's distance to the target on the known map (unknown cells free) with cell `avoid` taken out, by a
        breadth-first search from the target that stops once s and its neighbours are reached; None if s cannot
        reach the target without `avoid` (no way round).

        Why: two drones whose targets are next to each other in a corridor, each coming from the end where the
        other's target is, push each other off in turn for ever (PIBT's steps are greedy; the arbiter can only
        choose among the cells offered). A drone that has not got closer for DETOUR_AFTER turns and has a drone in
        its way ranks its cells by the way round that drone's cell instead, until it gets closer than it ever was
        (docs/cooperation.md)."""
        state, offs, goal = self._state, self._offs, self._goal
        if avoid == goal:
            return None
        need = {s} | {s + d for d in offs if state[s + d] != BLOCKED and s + d != avoid}
        dist = breadth_first(state, BLOCKED, offs, goal, closed=avoid, until=need)
        return dist if s in dist else None

    def _aside(self, s: int) -> int:
        """The candidates of a drone at rest (parked, without a target, or unable to reach it): its own cell, then the
        neighbours it knows are free, in the fixed order +x, -x, +y, -y, +z, -z."""
        return rank_steps([(0, 0, 0)] + [AROUND[k] for k, d in enumerate(self._offs) if self._state[s + d] == FREE])
