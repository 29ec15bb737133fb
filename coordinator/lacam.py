"""A complete arbitration: a LaCAM search over the cooperative drones' configurations, run by the coordinator
over turns and committed one step a turn (docs/cooperation.md, "Completeness: the search").

PIBT (coordinator/arbiter.py) plans one step; where its condition fails (dead ends, 1-wide corridors and doors)
it can push drones to and fro for ever. LaCAM (Okumura, "LaCAM: Search-Based Algorithm for Quick Multi-Agent
Pathfinding", AAAI 2023) searches the graph of configurations (one cell a drone) depth first, generating each
node's successors lazily with PIBT under *constraints* ("drone i goes to cell v"), added one drone at a time
breadth first (the low-level search): every successor of a configuration is eventually tried, so on a finite
world the search finds a way to the goal configuration if one exists, and says so when none does. The swap
and the clear operation (Okumura, IJCAI 2023) are PIBT's own here (`arbiter.pibt`), and so is the way a
pushed drone's cells are ordered (`arbiter.candidates`).

Online, in the manner of Real-Time LaCAM (Liang et al., 2025): the search tree persists from turn to turn; each
turn spends a budget of *work units* (a PIBT call costs a unit per drone and `CALL`, over `SHARE`; a distance table
made in the turns one a level and one per `CELLS_A_UNIT` open cells: never wall-clock time, so that every layout,
replay and resume does the same work; a call or table begun only if it fits, so the longest turn is bounded; the
tables of a small world made at the game's start, `Lacam.prepare`) and the drones then take one
step along the tree from the node they are at towards the goal node if found, else towards the best node known
(the least sum of distances to the goals; a step up the tree is a move back: every transition is reversible), never
along the depth-first frontier as the search backtracks. A node's constraints pin the drones away from their goals
first, then the drones on their goals nearest to them (`Search._pins`), not all in PIBT's order. PIBT's candidates in
the whole world's search are guided by scattered paths (`Scatter`, LaCAM3's: paths that meet each other's as little as
they can in space and time, made in the search's first turns, the drones holding, where the tables are made at the
game's start; compiled where the machine can build it, coordinator/scatter.c): a drone on its path tries its next cell
first, so that the first chain spreads the drones over several doors. The search is
complete whatever the drones do meanwhile, and once it has found the goal the drones walk to it: every drone home.

State and determinism: what the search keeps is a function of the calls' arguments alone (the drones' cells,
targets, whether they cooperate, the world and the turn), never of their offers or of time, so
`coordinator/resume.py` rebuilds it by calling `Lacam.follow` with each journaled turn. The drones' offers
decide whether the step is taken: a cooperative drone only ever moves to a cell it offered (or stays); if a
step is not offered (a drone that missed its deadline offers only its own cell), the turn is PIBT's
(`arbiter.cooperate`) and the search starts again from where the drones are.

The search runs where it is affordable: at once (new targets, a new search), once the drones' distance tables (a BFS
from each target over the static world) are made (at the game's start where every cell's fits in `PRECOMPUTE`), and
never where the tables would exceed `LIMIT` entries (the 256 x 256 x 32 city: plain PIBT). Until the tables are
made, PIBT plays. A search that has not brought a new high of drones onto their targets for `STALL` turns (twice as
many each time one is so left), or that fills its memory, hands the turns back to PIBT until PIBT stalls as long;
then a search focused on the drones away from their goals starts from where the drones are (`Lacam._focus`: those
within `FOCUS` moves of them or of their goals move, the others stand still as walls; a dense endgame is a few drones
away among hundreds parked); the next after a focused one that makes no progress, fills its memory or finds no way in
its part is twice as wide, up to the whole world (and of the whole world where no focus can be made: the tables made
in the turns, a bigger world). The patience doubling, some search eventually runs as long as it needs: the whole
stays complete, for the instances whose search fits in `MEMORY` entries (a search that fills it hands back as one
without progress does, and never says an instance unsolvable; nor does a focused one).

Small puzzles (the whole world's, or a focused one's: few drones in a small part, `exact.fits`) are not LaCAM's: an
exact breadth-first search over their configurations (coordinator/exact.py) finds a way as short as any, or proves
that none exists, in a few turns where LaCAM's proof takes hundreds; it runs over turns within the same budget.
"""

from __future__ import annotations

import ctypes
import weakref
from bisect import bisect_left, insort
from collections import Counter, deque
from heapq import heappop, heappush
from itertools import chain
from typing import Any

import numpy as np

from schema import Cell
from world.search import cells_of, flat_cells, levels, padded_steps

from .arbiter import OpenCells, candidates, cooperate, offered, pibt, steps_flat, tie_breaks
from .compiled import scatter_library
from .exact import CANDIDATES, TRY, Exact, fits, tried, whole

__all__ = ["Lacam", "Search", "Graph"]

#: A PIBT call's fixed cost, in units, besides a unit a drone that chooses in it and one per FIXED drones (its arrays,
#: dictionaries, the swap's test and the node's candidates, over every drone).
CALL = 30
FIXED = 2
#: A PIBT call's units are its drones', FIXED's and CALL's divided by SHARE. The units were calibrated on Python's
#: calls (`arbiter.pibt`); compiled (`pb_choosers`, `pb_pibt`, `pb_valid`, `pb_candidates` in coordinator/scatter.c)
#: they take a seventh to an eleventh of the time: SHARE = 4 is more search a turn, eight full calls at 400 drones,
#: about 0.25 ms each (BENCHMARKS.md, "LaCAM: more search a turn, its calls' bookkeeping compiled"); without the
#: library the search's calls take 7 to 11 times as long (the same games).
SHARE = 4
#: The search's work units a turn, two full PIBT calls at 400 drones at SHARE = 1 (a PIBT call costs one a drone that
#: chooses in it — not the drones of its order's end that would stay, `_choosing` —, one per FIXED drones and CALL, over
#: SHARE; a distance table one a level of its breadth-first search and one per CELLS_A_UNIT open cells). A turn is that
#: work, or that of the tables, and at most one more PIBT call (the turn's own when the search does not play it), never
#: more: the search's calls and tables are only started within the budget (the first of a turn excepted: one call at
#: least, the drones never wait for the search), so the longest turn is bounded as the average (docs/cooperation.md,
#: "Online": 20 ms or less at 400 drones, 100 at 1000, on the benchmark's densest instances).
WORK = 2 * (400 + 400 // FIXED + CALL)
#: A breadth-first search's level costs about a unit (the arrays of its frontier); its cells about a 32nd each.
CELLS_A_UNIT = 32
#: Every open cell's distance table is made at the game's start (`Lacam.prepare`) where they hold this many entries
#: or fewer (open cells squared, int16: 8 MiB; every 32 x 32 map); elsewhere the tables are made in the turns' budget.
PRECOMPUTE = 1 << 22
#: Distance-table entries (drones x open cells) beyond which the search never runs (int16 entries: 64 MiB).
LIMIT = 1 << 25
#: Turns without a new high of drones on their targets after which a search hands back to PIBT (the first time; twice
#: as many each later time), and after which PIBT hands over to a new search (focused: `FOCUS`).
STALL = 32
#: The entries a search may hold (a configuration's cells, priorities and order: 3 a drone; a queued constraint: 2 a
#: drone it pins): 2^21, about 50 MB. A search that reaches it stops and hands back as one without progress does
#: (docs/cooperation.md, "Memory"): complete only for the instances whose search fits in it.
MEMORY = 1 << 21
#: The first radius of a focused search (`Lacam._focus`, the search after one without progress): the drones within so
#: many moves of a drone away from its goal or of that goal; twice as many each time one makes no progress.
FOCUS = 4
#: A found plan is refined (`Search.refine`) while its part beyond the refiner's root has this many steps or more.
REFINE = 8
#: Where a refining search starts (`Search.refine`): this fraction of the plan's steps left from the drones on.
AHEAD = (1, 3)
#: A refining search is given up once it has made this many PIBT calls and is behind the plan (`Search._behind`).
BEHIND = 16
#: A refining search costs, to make, a unit per BUILD open cells (its part of the world's graph, its root).
BUILD = 2
#: A refining search's nodes are numbered from its count times this (their tie-breaks differ from the others').
REFINE_NUMBERS = 1 << 20
#: Scattered paths (`Scatter`, LaCAM3's space utilisation): a drone's path may be this many steps longer than its
#: shortest way (LaCAM3's default), and the paths are planned again, each against the others', for at most this many
#: rounds (fewer once a round brings no fewer collisions).
MARGIN = 10
ROUNDS = 3
#: A scattered path's search costs a unit per POPS cells it settles (a heap pop and its neighbours' collision counts:
#: 1.3 µs a cell when set, about 0.8 since, docs/performance.md, "The scattered paths' search made cheaper"; a unit
#: is about what a PIBT call spends on a drone).
POPS = 2
#: A drone tries its next cell on its scattered path first while the node's depth is at most HORIZON times its path's
#: cells (the paths are planned for drones that move every step; in a crowd they are late, and past that, lost).
HORIZON = 2
#: The search is guided by scattered paths where every open cell's distance table is made at the game's start
#: (`PRECOMPUTE`: the 32 x 32 maps), the drones times the open cells are at most SCATTER (400 drones there) and the
#: drones are CROWD or more (measured at 400; a few dozen drones' first solution is found in a turn or two, and their
#: games are PIBT's chaos either way: a 24-drone RL episode brought one drone fewer home with it).
SCATTER = 1 << 19
CROWD = 100
#: The scattered paths are made in the search's first turns, SCATTER_WORK of their units a turn (another path only if
#: the costliest so far fits), the drones holding until they are all made: 4 or 5 turns at 400 drones on the 32 x 32
#: maps, each about as long as a turn of the search's (10 ms or so compiled, coordinator/scatter.c; 50 to 90 in
#: Python): within the 20 ms bound of a turn, where made at once their turn took 116 to 390 ms (BENCHMARKS.md, "LaCAM:
#: the scattered paths compiled and made over turns").
SCATTER_WORK = 24_000
#: Turns without progress (no new low of the drones' sum of distances to their targets) after which a small puzzle is
#: searched whole (`exact.Exact`): LaCAM first, whose first step costs no wait; where it is stuck (a corridor's
#: drones backing off in turn), the exact search. Two drones crossing a 10 x 10 x 10 world never wait for it.
EXACT_AFTER = 4
#: The endgame (`Lacam._endgame`): at most one drone in so many away from its target (and `ENDGAME_FEW` at least), and
#: no new high of drones on their targets for `ENDGAME_AFTER` turns: the whole world's search, which has not found its
#: goal, hands over to a focused search at once, without its patience's turns nor PIBT's.
ENDGAME_SHARE = 32
ENDGAME_FEW = 2
ENDGAME_AFTER = STALL // 2
#: The rungs of a focused search's ladder (`Lacam._rung_search`): a cell where a drone other than the puzzle's stands
#: costs so many moves to enter (a free cell one): a rung's part grows through free space before it takes in drones.
RUNG_PARKED = 2
#: The units an exact search of a rung may spend before it gives up (the ladder then ends): 16 turns' `WORK`.
RUNG_TRY = 16 * WORK
#: A distance that means "no way" (int16).
FAR = np.iinfo(np.int16).max
#: A priority is the node depths since the drone was last on its goal times SPAN, plus its distance at the root.
SPAN = 1 << 16


class Graph:
    """The static world's open cells, numbered 0..F-1 (`cells`: their flat cells, `world.search.flat_cells`'s padded
    numbering; `index`: the other way, -1 for a building), each one's open neighbours (`near`, (F, 6), -1 for
    none) and its connected component (`part`: the first open cell of it)."""

    __slots__ = ("cells", "index", "near", "_part", "_steps", "_open")

    def __init__(self, open_: OpenCells, size: Cell) -> None:
        bits = open_.array()
        self.cells = np.flatnonzero(bits).astype(np.int64)
        self.index = np.full(len(bits), -1, np.int64)
        self.index[self.cells] = np.arange(len(self.cells))
        self._steps = steps = np.array(padded_steps(size)[2], np.int64)
        self.near = self.index[self.cells[:, None] + steps]
        self._open = open_
        self._part: np.ndarray | None = None

    @property
    def part(self) -> np.ndarray:
        """Each open cell's connected component (its first open cell), made when first asked (a refining search's
        graph never is: `Search._refiner`)."""
        if self._part is None:
            bits = self._open.array()
            self._part = part = np.full(len(self.cells), -1, np.int64)
            for root in range(len(self.cells)):
                if part[root] < 0:  # (a breadth-first search of its component, the cells it has left open)
                    for reached in levels(bits, [int(self.cells[root])], self._steps):
                        part[self.index[reached]] = root
        return self._part

    def ways(self, here: np.ndarray, aims: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The drones' open cells (numbered; -1 off them), their targets' (-1 for none or a building), and whether
        each has a way there over the static world (both open, in one component)."""
        hc = self.index[here]
        ac = np.where(aims >= 0, self.index[np.maximum(aims, 0)], -1)
        way = (ac >= 0) & (hc >= 0)
        way[way] = self.part[ac[way]] == self.part[hc[way]]
        return hc, ac, way

    def distances(self, goal: int) -> tuple[np.ndarray, int]:
        """Each open cell's distance to open cell `goal` (numbered), FAR where none (a breadth-first search), and its
        work units (`CELLS_A_UNIT`)."""
        dist = np.full(len(self.cells), FAR, np.int16)
        depth = 0
        for depth, reached in enumerate(levels(self.index >= 0, [int(self.cells[goal])], self._steps)):
            dist[self.index[reached]] = min(depth, FAR - 1)
        return dist, depth + 1 + len(self.cells) // CELLS_A_UNIT

    def every_distance(self) -> np.ndarray:
        """Every open cell's distance to every open cell ((F, F), row: the goal; FAR where none): the breadth-first
        searches from every cell at once, bit-parallel (64 goals a word of each cell's frontier), a level at a time."""
        n, words = len(self.cells), (len(self.cells) + 63) // 64
        dist = np.full((n, n), FAR, np.int16)
        goals = np.arange(n)
        front = np.zeros((n + 1, words), np.uint64)  # (row n: no neighbour, always empty)
        front[goals, goals // 64] = np.left_shift(np.uint64(1), (goals % 64).astype(np.uint64))
        seen = front[:n].copy()
        near = np.where(self.near >= 0, self.near, n)
        dist[goals, goals] = 0
        depth = 0
        while True:
            nxt = np.bitwise_or.reduce(front[near], axis=1) & ~seen
            cells, word = np.nonzero(nxt)
            if not len(cells):
                return dist
            depth += 1
            seen |= nxt
            front[:n] = nxt
            bits = np.unpackbits(nxt[cells, word].astype("<u8").view(np.uint8).reshape(-1, 8), axis=1,
                                 bitorder="little")
            k, bit = np.nonzero(bits)
            dist[word[k] * 64 + bit, cells[k]] = min(depth, FAR - 1)


def scatter_order(n: int, r: int) -> list[int]:
    """The order in which `Scatter` plans its `n` drones' paths in round `r` (0, 1, ...): drawn from the round's number
    alone (`arbiter.tie_breaks`), the drones' numbers breaking ties."""
    draw = tie_breaks(r + 1, np.arange(n, dtype=np.int64), np.zeros((n, 1), np.int64))[:, 0]
    return np.lexsort((np.arange(n), draw)).tolist()


class Scatter:
    """Scattered paths, the guide of the search's configuration generator (LaCAM3's, Okumura, "Engineering LaCAM*",
    AAMAS 2024, after Han and Yu's space utilisation optimisation, ICRA 2022): a path for each drone from its cell to
    its goal, at most `MARGIN` steps longer than its shortest way, that meets the others' paths as little as it can in
    space and time; planned one drone after the other, each against the paths planned so far, and again for a few
    rounds (`ROUNDS`) while a round meets fewer. A drone on its path tries its path's next cell first (`table`).

    Each path is a best-first search over the open cells (each settled once), ordered by the collisions met on the way
    (another path in the cell at the same step, a path taking the same edge the other way, a drone parked there on its
    goal since an earlier step), then by the length through the cell (its distance table: the search stays within the
    margin), then by the cell's number: deterministic. The drones' order in each round is drawn from the round's number
    alone (`arbiter.tie_breaks`). A function of the drones' cells and goals alone, never of time; `advance` plans
    within a budget (a unit per `POPS` cells settled), the search makes them in its first turns, `SCATTER_WORK` units
    a turn, the drones holding, before its first PIBT call (`Search.expand`): made while the drones moved they came
    too late to guide the first chain (docs/cooperation.md, "Scattered paths"). `_plan` and `_collisions` run compiled
    (coordinator/scatter.c, `compiled.scatter_library`) where the machine can build it: the same paths and units."""

    __slots__ = ("cells", "near", "start", "goal", "dist", "margin", "rounds", "F", "occ", "moves", "parked", "paths",
                 "order", "k", "round", "last", "done", "costliest", "lib", "ctx", "_arrays", "_release", "__weakref__")

    def __init__(self, graph: Graph, start: np.ndarray, goal: np.ndarray, dist: np.ndarray, margin: int = MARGIN,
                 rounds: int = ROUNDS, compiled: bool = True) -> None:
        """`start`, `goal`: the drones' open cells (numbered, `Graph`); `dist`: their distance tables ((n, F));
        `compiled`: the search compiled (coordinator/scatter.c, `compiled.scatter_library`) where this machine has it,
        else (and with False) Python's: the same paths and units."""
        n = len(start)
        self.cells = graph.cells
        self.start, self.goal, self.dist = start.tolist(), goal.tolist(), dist
        self.margin, self.rounds = margin, rounds
        self.F = F = len(graph.cells)
        longest = int(dist[np.arange(n), start].max(initial=0)) + margin + 1
        self.paths: list[list[int]] = [[] for _ in range(n)]
        self.order = scatter_order(n, 0)
        self.k, self.round, self.last = 0, 0, -1
        self.done = n == 0
        self.costliest = 0
        self.lib = scatter_library() if compiled and n and dist.dtype == np.int16 else None  # (its tables' type)
        self.ctx: int | None = None
        if self.lib is not None:  # (its state in C; the arrays it reads kept alive as long as it lives)
            near = np.ascontiguousarray(graph.near, np.int64)
            d16 = np.ascontiguousarray(dist, np.int16)
            self._arrays = (near, d16)
            self.ctx = self.lib.sc_new(F, n, near.shape[1], longest, near.ctypes.data, d16.ctypes.data, margin)
            if self.ctx:
                self._release = weakref.finalize(self, self.lib.sc_free, ctypes.c_void_p(self.ctx))
                return
            self.lib, self.ctx = None, None  # (no memory for it: Python's)
        self.near = [[v for v in row if v >= 0] for row in graph.near.tolist()]
        self.occ = [0] * ((longest + 1) * F)  # (step, cell) -> paths there then
        self.moves: dict[int, int] = {}  # (step, cell, next cell) -> paths taking that edge then
        self.parked: list[list[int]] = [[] for _ in range(F)]  # cell -> the steps from which paths ending there stay
        # there, sorted (those before a step: `bisect_left`)

    def advance(self, work: int) -> int:
        """Plan paths within `work` units (one at least; another only if the costliest so far fits): the units spent."""
        spent = 0
        while not self.done and not (spent and spent + self.costliest > work):
            units = self._plan(self.order[self.k])
            spent += units
            self.costliest = max(self.costliest, units)
            self.k += 1
            if self.k == len(self.order):  # (a round planned)
                total = self._collisions()
                spent += len(self.start)
                self.round += 1
                self.done = total == 0 or self.round >= self.rounds or (self.round >= 2 and total >= self.last)
                self.last, self.k = total, 0
                self.order = scatter_order(len(self.start), self.round)
        if self.done and self.ctx is not None:  # (the paths out of C, its memory freed)
            self._fetch()
        return spent

    def _fetch(self) -> None:
        lib, ctx = self.lib, self.ctx
        assert lib is not None and ctx is not None
        cells = np.zeros(lib.sc_paths_length(ctx), np.int64)  # (every path at once, one after the other)
        lengths = np.zeros(len(self.paths), np.int64)
        lib.sc_paths(ctx, lengths.ctypes.data, cells.ctypes.data)
        flat, ends = cells.tolist(), np.cumsum(lengths).tolist()
        self.paths = [flat[a:b] for a, b in zip([0] + ends[:-1], ends)]
        self._release()
        self.ctx = None

    def _collisions(self) -> int:
        """The paths' collisions with each other (each pair's counted from both sides): in the same cell at the same
        step, along the same edge the other way, or through a cell where another has stopped for good."""
        if self.ctx is not None:
            assert self.lib is not None
            return int(self.lib.sc_collisions(self.ctx))
        F, occ, moves, parked = self.F, self.occ, self.moves, self.parked
        total = 0
        for path in self.paths:
            for t in range(1, len(path)):
                v, u = path[t], path[t - 1]
                total += occ[t * F + v] - 1 + moves.get(((t - 1) * F + v) * F + u, 0)
                ends = parked[v]
                if ends:
                    total += bisect_left(ends, t)
        return total

    def _enroll(self, i: int, path: list[int], sign: int) -> None:
        F, occ, moves = self.F, self.occ, self.moves
        for t, v in enumerate(path):
            occ[t * F + v] += sign
            if t + 1 < len(path):
                key = (t * F + v) * F + path[t + 1]
                moves[key] = moves.get(key, 0) + sign
        if path:
            ends = self.parked[path[-1]]
            if sign > 0:
                insort(ends, len(path) - 1)
            else:
                ends.remove(len(path) - 1)

    def _plan(self, i: int) -> int:
        """Drone i's path planned again against the others': the units it cost."""
        if self.ctx is not None:
            assert self.lib is not None
            settled = int(self.lib.sc_plan(self.ctx, i, self.start[i], self.goal[i]))
            if settled < 0:
                raise MemoryError("the scattered paths' search ran out of memory")
            return 1 + settled // POPS
        if self.paths[i]:
            self._enroll(i, self.paths[i], -1)
        s, goal, F, near, occ, moves, parked = self.start[i], self.goal[i], self.F, self.near, self.occ, self.moves, \
            self.parked
        d = self.dist[i].tolist()
        bound = d[s] + self.margin
        heap = [(0, d[s], s, 0, -1)]
        parent = [-2] * F  # each settled cell's parent (-1: none, the start; -2: not settled)
        settled, met = 0, -1
        while heap:
            c, _, v, g, p = heappop(heap)
            if parent[v] != -2:
                continue
            parent[v] = p
            settled += 1
            if v == goal:
                met = c
                break
            t = g + 1
            tF, gF = t * F, g * F
            for u in near[v]:
                du = d[u]
                if parent[u] != -2 or t + du > bound:
                    continue
                cc = c + occ[tF + u]
                if occ[gF + u]:  # (a path takes the edge the other way only if one is in u at g)
                    cc += moves.get((gF + u) * F + v, 0)
                ends = parked[u]
                if ends:
                    cc += bisect_left(ends, t)
                heappush(heap, (cc, t + du, u, t, v))
        path: list[int] = []
        if met >= 0:
            v = goal
            while v >= 0:
                path.append(v)
                v = parent[v]
            path.reverse()
        self.paths[i] = path
        self._enroll(i, path, 1)
        return 1 + settled // POPS

    def table(self) -> np.ndarray:
        """Each drone's next cell on its path from each open cell ((n, F), flat cells; -1 off its path)."""
        out = np.full((len(self.paths), self.F), -1, np.int64)
        lengths = np.array([len(p) for p in self.paths], np.int64)
        flat = np.fromiter(chain.from_iterable(self.paths), np.int64, count=int(lengths.sum()))
        step = np.ones(len(flat), bool)  # (every cell of a path but its last, then the next cell along it)
        step[np.cumsum(lengths)[lengths > 0] - 1] = False
        at = np.flatnonzero(step)
        out[np.repeat(np.arange(len(self.paths)), lengths)[at], flat[at]] = self.cells[flat[at + 1]]
        return out


class Node:
    """A configuration of the search: the drones' cells (flat), its parent in the tree, its depth, the drones'
    PIBT priorities there, its low-level search (the constraints still to try: (drones, cells) pairs), PIBT's order
    (highest priority first) and the order in which its constraints pin drones (`Search._pins`, made when needed)."""

    __slots__ = ("cfg", "parent", "depth", "prio", "tree", "order", "number", "near", "pins")

    def __init__(self, cfg: np.ndarray, parent: Node | None, prio: np.ndarray, number: int) -> None:
        self.cfg, self.parent, self.prio, self.number = cfg, parent, prio, number
        self.depth: int = 0 if parent is None else parent.depth + 1
        self.order = np.argsort(-prio, kind="stable")  # (ties: the lower row first)
        self.tree: deque[tuple[tuple[int, ...], tuple[int, ...]]] = deque([((), ())])
        self.near: list[Node] = [] if parent is None else [parent]  # its neighbours in the configurations' graph
        self.pins: list[int] | None = None  # the order in which its constraints pin drones (`Search._pins`)


def _rewire(a: Node, b: Node) -> None:
    """Edge a-b found: the depths (moves from the root) and parents of every node a shorter way now reaches
    (Dijkstra with unit costs, LaCAM*'s rewiring: the drones' way to the goal is the tree's, as short as known)."""
    if a.depth > b.depth:
        a, b = b, a
    if a.depth + 1 >= b.depth:
        return
    b.parent, b.depth = a, a.depth + 1
    queue = deque([b])
    while queue:
        u = queue.popleft()
        for v in u.near:
            if u.depth + 1 < v.depth:
                v.parent, v.depth = u, u.depth + 1
                queue.append(v)


#: A PIBT call of the search (`Search._choosers`): the drones that choose, and each drone's cell taken by the
#: constraints (-1: none); arrays where it runs compiled, lists where Python's does.
Call = tuple[np.ndarray, np.ndarray] | tuple[list[int], list[int]]
#: A focused search's drones (rows among all), every drone's cells, its part of the world and its radius.
Focus = tuple[np.ndarray, np.ndarray, OpenCells, int]


def stand_ins(graph: Graph, goal: np.ndarray, way: np.ndarray) -> np.ndarray:
    """The search's goals (numbered open cells), `goal`'s with the stand-in goal of each drone without a target it
    can reach (`way` False: its own cell) moved off the others' goals: to the nearest open cell no other drone has as
    its goal (breadth first over the open cells, in `Graph.near`'s order; drones in row order). Else the goal
    configuration would hold two drones in one cell -- a drone that gave up, parked on another's target -- and no
    search could reach it (a search with stand-ins is no proof either way: `Search.exact`)."""
    taken = Counter(goal.tolist())
    clash = [i for i in np.flatnonzero(~way).tolist() if taken[int(goal[i])] > 1]
    if not clash:
        return goal
    out = goal.copy()
    near = graph.near.tolist()
    for i in clash:
        start = int(out[i])
        if taken[start] <= 1:  # (freed by an earlier stand-in's move)
            continue
        seen, queue = {start}, deque([start])
        while queue:
            v = queue.popleft()
            if not taken[v]:
                taken[start] -= 1
                taken[v] += 1
                out[i] = v
                break
            for u in near[v]:
                if u >= 0 and u not in seen:
                    seen.add(u)
                    queue.append(u)
    return out


def pibt_compiled(lib: ctypes.CDLL, here: np.ndarray, cand: np.ndarray, order: np.ndarray | list[int],
                  taken: np.ndarray | list[int], open_: OpenCells | None, steps: np.ndarray, goal: np.ndarray,
                  aim: np.ndarray | None, shape: Cell) -> tuple[np.ndarray, list[int]] | None:
    """`arbiter.pibt` compiled (`pb_pibt` in coordinator/scatter.c, step for step): `here` (n,) and `cand` ((n, k), -1
    after the last) as arrays, `goal` the drones' targets for the swap (with `open_`; None: no swap), `aim` for a pushed
    drone's retreats (None: unknown), `shape` the padded world's. The next cells ((n,), -1 for a drone that neither
    chose nor was taken) and the drones that gave way, as Python's; None where the library cannot run it."""
    n, k = cand.shape
    here = np.ascontiguousarray(here, np.int64)
    cand = np.ascontiguousarray(cand, np.int64)
    order_a = np.array(order, np.int64)
    nxt = np.array(taken, np.int64)
    gave = np.empty(max(n, 1), np.int64)
    goal = np.ascontiguousarray(goal, np.int64)
    aim_a = None if aim is None else np.ascontiguousarray(aim, np.int64)
    bits = None if open_ is None else open_.bits
    cells = shape[0] * shape[1] * shape[2]
    got = lib.pb_pibt(n, k, here.ctypes.data, cand.ctypes.data, order_a.ctypes.data, len(order_a), nxt.ctypes.data,
                      bits, cells, steps.ctypes.data, len(steps), goal.ctypes.data,
                      None if aim_a is None else aim_a.ctypes.data, shape[1], shape[2], gave.ctypes.data)
    if got < 0:
        return None
    return nxt, gave[:got].tolist()


class Search:
    """One LaCAM search from a configuration to the goal one (`goals`, flat cells): `expand` spends work on it,
    `step` gives the drones' next configuration from the node they are at (`at`)."""

    bounded = False  # (its work is not bounded: handed back to PIBT after turns without progress, `Lacam.follow`)

    def __init__(self, graph: Graph, size: Cell, start: np.ndarray, goals: np.ndarray, aims: np.ndarray,
                 dist: np.ndarray, memory: int = MEMORY, focus: Focus | None = None, number: int = 0,
                 scatter: bool = False, exact: bool = True) -> None:
        """`exact`: every drone's goal is its target (False: some drone, without a target it can reach, has its cell
        as a stand-in goal: a search that runs out of nodes then proves nothing of the game, `unsolvable`);
        `aims`: the drones' real targets (flat, -1 for none: PIBT's swap and retreats read them); `dist`: each
        drone's distance table ((n, F), to its goal); `memory`: the entries it may hold (`MEMORY`); `focus`: a search
        over some drones only (`Lacam._focus`): their rows among all, every drone's cells (the others stay there), the
        part of the world it searches (`graph`'s open cells) and its radius; `number`: its root's number (the nodes'
        numbers draw PIBT's tie-breaks: a refining search, `refine`, draws others than the search it refines)."""
        self.graph, self.size, self.goals, self.dist, self.memory = graph, size, goals, dist, memory
        self.exact = exact
        self.focus = focus
        self.aims = aims.tolist()
        n = len(start)
        self.rows = np.arange(n)
        self.at_goal = goals.tobytes()
        prio = np.minimum(dist[self.rows, graph.index[start]].astype(np.int64), SPAN - 1)
        self.base = prio
        self.created = number + 1
        root = Node(start, None, np.where(start == goals, prio, prio + SPAN), number)
        self.at = root  # where the drones are
        self.explored: dict[bytes, Node] = {start.tobytes(): root}
        self.open: list[Node] = [root]
        self.found: Node | None = root if start.tobytes() == self.at_goal else None
        self.best, self.best_h = root, int(dist[self.rows, graph.index[start]].sum())  # the nearest node to the goal
        self.expansions = 0
        self.held = 3 * n  # the entries it holds (`MEMORY`): the root's
        self.gave: list[int] = []  # the drones that gave way in the last successor (`arbiter.pibt`)
        shape = (size[0] + 2, size[1] + 2, size[2] + 2)
        self.steps = list(padded_steps(size)[2])
        self._steps = np.array(self.steps, np.int64)
        self._lib = scatter_library()  # (PIBT's calls compiled where the machine can: `_successor`)
        # (and the nodes' candidates, `_candidates_compiled`: for int16 tables of a 3D grid's graph whose cells it may
        # index, checked once here rather than at every node)
        self._fits_c = dist.dtype == np.int16 and graph.near.shape[1] == 6 and \
            int(graph.near.max(initial=-1)) < len(graph.cells) and \
            0 <= int(graph.cells.min(initial=0)) <= int(graph.cells.max(initial=0)) < shape[0] * shape[1] * shape[2]
        self.aim_array = aims.astype(np.int64)
        self._cells = shape[0] * shape[1] * shape[2]  # (the padded world's flat cells: the compiled calls' range)
        self._cached: tuple[Node | None, np.ndarray] = (None, np.zeros((0, 0), np.int64))  # a node, its candidates
        self._listed: tuple[Node | None, list[int], list[list[int]], list[int]] = (None, [], [], [])  # (as lists)
        self._compiled_args: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (`_candidates_compiled`)
        self.aimed = (self.aims, shape)
        self.plan: np.ndarray | None = None  # once found: the drones' configurations from `at` to the goal (`refine`)
        self.t = 0  # the drones' index in `plan`
        self.refiner: Search | None = None  # a search from a configuration of `plan` ahead of the drones (`refine`)
        self.ahead = 0  # the refiner's root's index in `plan`
        self.refined = 0  # refining searches started, and the plan's length when found (`first`)
        self.first = 0
        self.refining = 0  # the refiners' PIBT calls
        self._h: np.ndarray | None = None  # the plan's configurations' sums of distances (`_behind`)
        self._h_of: np.ndarray | None = None
        self._build = len(graph.cells) // BUILD  # a refiner's units to make (its part of the world's graph)
        # with `scatter`, the scattered paths' guide (`Scatter`, made in the search's first turns, `SCATTER_WORK`
        # units a turn, the drones holding meanwhile: `expand`): each drone's next cell on its path from each open
        # cell ((n, F), flat, -1 off it), the open cells' numbering, and each path's cells (`HORIZON`)
        self.guide: tuple[np.ndarray, np.ndarray] | None = None
        self.horizon = np.zeros(n, np.int64)
        self.scattered = 0  # its units
        self._scatter = Scatter(graph, graph.index[start], graph.index[goals], dist) if scatter else None

    def _guide(self) -> int:
        """The scattered paths made further, `SCATTER_WORK` units (a path at least): the guide once they are all made.
        The units spent."""
        made = self._scatter
        assert made is not None
        spent = made.advance(SCATTER_WORK)
        self.scattered += spent
        if made.done:
            self.guide = (made.table(), self.graph.index)
            self.horizon = np.array([len(p) for p in made.paths], np.int64)
            self._scatter = None
        return spent

    @property
    def unsolvable(self) -> bool:
        """The search is over and found no way to its goal configuration (never said by a search that reached its
        memory: it stops there, `full`). No configuration sequence then brings every drone home if the search is
        `exact` and of the whole world; else the goal was stricter than the game's."""
        return self.found is None and not self.open and not self.full

    @property
    def full(self) -> bool:
        """The search holds its `memory`'s entries: it expands no more."""
        return self.held >= self.memory

    def whole(self, cfg: np.ndarray) -> np.ndarray:
        """Every drone's cell in a configuration of the search (a focused one moves some drones only)."""
        return whole(self.focus, cfg)

    def expand(self, work: int, open_: OpenCells, most: int = 1 << 62, first: bool = True) -> int:
        """Spend `work` units at most (but one PIBT call at least if `first`, unless the search is over): a call is
        made only if its units fit in what is left, and while the search has made fewer than `most` calls; the units
        spent."""
        spent, n = 0, len(self.goals)
        if self.focus is not None:
            open_ = self.focus[2]
        if self._scatter is not None:  # (the guide first: no PIBT call until it is made)
            return self._guide()
        while self.found is None and self.open and not self.full and self.expansions < most:
            node = self.open[-1]
            if not node.tree:
                self.open.pop()
                continue
            who, where = node.tree[0]
            call = self._choosers(node, who, where)
            cost = max(1, (CALL + n // FIXED + (0 if call is None else len(call[0]))) // SHARE)  # (those that
            # choose: `_choosing`)
            if (spent or not first) and spent + cost > work:
                break
            node.tree.popleft()
            self.held -= 2 * len(who)
            if len(who) < n:  # the next drone in the node's order gets each of its cells in turn, nearest first
                i = self._pin(node, len(who))
                for v in self._moves(node.cfg[i], i):
                    node.tree.append((who + (i,), where + (v,)))
                    self.held += 2 * len(who) + 2
            spent += cost
            self.expansions += 1
            nxt = None if call is None else self._successor(node, call, open_)
            if nxt is None:
                continue
            key = nxt.tobytes()
            known = self.explored.get(key)
            if known is not None:  # LaCAM*: a shorter way to it?
                if known is not node:
                    node.near.append(known)
                    known.near.append(node)
                    _rewire(node, known)
                continue
            prio = np.where(nxt == self.goals, self.base, node.prio + SPAN)
            prio[self.gave] = self.base[self.gave]  # gave way: the drones it could not push push it back
            child = Node(nxt, node, prio, self.created)
            node.near.append(child)
            self.created += 1
            self.held += 3 * n
            self.explored[key] = child
            self.open.append(child)
            if key == self.at_goal:
                self.found = child
            h = int(self.dist[self.rows, self.graph.index[nxt]].sum())
            if h < self.best_h:
                self.best, self.best_h = child, h
        return spent

    def _pin(self, node: Node, k: int) -> int:
        """The drone `node`'s constraints pin k-th (`_pins`; the drones away alone while k is below their count, the
        drones on their goals ordered only once a constraint reaches them)."""
        if node.pins is None:
            order = node.order
            node.pins = order[node.cfg[order] != self.goals[order]].tolist()
            self.held += len(node.pins)
        if k >= len(node.pins) and len(node.pins) < len(node.order):
            return self._pins(node)[k]
        return node.pins[k]

    def _pins(self, node: Node) -> list[int]:
        """The order in which `node`'s constraints pin drones: the drones away from their goals, highest priority
        first, then those on their goals, nearest (over the open cells) to a drone away first, then by priority."""
        if node.pins is None or len(node.pins) < len(node.order):
            g, order = self.graph, node.order
            away = node.cfg[order] != self.goals[order]
            first = order[away]
            self.held -= 0 if node.pins is None else len(node.pins)
            dist = np.full(len(g.cells) + 1, FAR, np.int64)  # (the last: no neighbour)
            front = g.index[node.cfg[first]]
            depth = 0
            near = np.where(g.near >= 0, g.near, len(g.cells))
            while len(front):
                front = front[dist[front] == FAR]
                dist[front] = depth
                depth += 1
                front = np.unique(near[front].ravel())
                front = front[(front < len(g.cells)) & (dist[front] == FAR)]
            rest = order[~away]
            rest = rest[np.argsort(dist[g.index[node.cfg[rest]]], kind="stable")]
            node.pins = np.concatenate([first, rest]).tolist()
            self.held += len(order)
        return node.pins

    def _moves(self, cell: int, i: int) -> list[int]:
        """Drone i's cells from `cell` (its open neighbours and itself), nearest to its goal first."""
        g = self.graph
        c = int(g.index[cell])
        near = [c] + [v for v in g.near[c].tolist() if v >= 0]
        d = self.dist[i]
        return [int(g.cells[v]) for v in sorted(near, key=lambda v: (int(d[v]), v != c, v))]

    def _choosers(self, node: Node, who: tuple[int, ...], where: tuple[int, ...]
                  ) -> Call | None:
        """The PIBT call from `node` with drones `who` sent to cells `where`: the drones that choose, highest priority
        first (`_choosing`), and each drone's cell taken by the constraints (-1: none); None if two share one. Arrays
        where the call runs compiled (`pb_choosers` in coordinator/scatter.c, the same drones), else lists."""
        n = len(node.cfg)
        taken = np.full(n, -1, np.int64)
        if who:
            taken[list(who)] = where
        if self._cached[0] is not node:  # (a node is often tried again at once, under its next constraint)
            self._cached = (node, self._candidates(node))
        cand_array = self._cached[1]
        if self._lib is not None:
            order = np.empty(n, np.int64)
            here = np.ascontiguousarray(node.cfg, np.int64)
            k = self._lib.pb_choosers(n, cand_array.shape[1], here.ctypes.data, cand_array.ctypes.data,
                                      np.ascontiguousarray(node.order, np.int64).ctypes.data, taken.ctypes.data,
                                      self._cells, order.ctypes.data)
            if k == -2:
                return None
            if k >= 0:
                return order[:k], taken
        fixed = taken[taken >= 0]
        if len(np.unique(fixed)) < len(fixed):
            return None
        _, here_list, cand, order_all = self._lists(node)
        order_list = [i for i in order_all if taken[i] < 0] if who else order_all
        return order_list[:_choosing(order_list, here_list, cand, set(where))], taken.tolist()

    def _lists(self, node: Node) -> tuple[Node | None, list[int], list[list[int]], list[int]]:
        """`node`'s cells, candidates and order as lists (Python's PIBT call, `arbiter.pibt`)."""
        if self._listed[0] is not node:
            self._listed = (node, node.cfg.tolist(), self._cached[1].tolist(), node.order.tolist())
        return self._listed

    def _successor(self, node: Node, call: Call, open_: OpenCells) -> np.ndarray | None:
        """PIBT's next configuration from `node` (`_choosers`' call); None if there is none."""
        here = node.cfg
        n = len(here)
        cand_array = self._cached[1]
        lib = self._lib
        made = None if lib is None else pibt_compiled(lib, here, cand_array, call[0], call[1], open_, self._steps,
                                                      self.aim_array, self.aim_array, self.aimed[1])
        if made is not None and lib is not None:
            nxt, gave = made
            ok = lib.pb_valid(n, np.ascontiguousarray(here, np.int64).ctypes.data, nxt.ctypes.data, self._cells)
            if ok == 0:  # (the stays filled in, the configuration checked: else, -1, numpy's below)
                return None
            if ok == 1:
                self.gave = gave
                return nxt
        else:
            _, here_list, cand, _ = self._lists(node)
            order, taken = call[0], call[1]
            chosen, gave = pibt(here_list, cand, _listed(order), _listed(taken), (open_, self.steps, self.aims),
                                self.aimed)
            made = np.array(chosen, np.int64), gave
        nxt, gave = made
        nxt = np.where(nxt < 0, here, nxt)  # (the drones of the order's end that would stay: `_choosing`)
        if len(np.unique(nxt)) < n:
            return None
        self.gave = gave
        srt = np.argsort(here)
        k = np.minimum(np.searchsorted(here[srt], nxt), n - 1)
        j = srt[k]
        if ((here[j] == nxt) & (j != self.rows) & (nxt[j] == here)).any():
            return None  # a swap
        return nxt

    def _candidates(self, node: Node) -> np.ndarray:
        """Each drone's cells from `node` in the order PIBT tries them ((n, 7), flat, -1 after the last): nearest
        to its goal first, staying before a neighbour as near (as a drone ranks), reordered by
        `arbiter.candidates` (free cells first, retreats out of the others' way, ties drawn from the node); with the
        scattered paths' guide, a drone on its path (within `HORIZON`) tries the path's next cell first (LaCAM3)."""
        g, here = self.graph, node.cfg
        c = g.index[here]
        if self._lib is not None and self._fits_c:
            made = self._candidates_compiled(node, c)
            if made is not None:
                return made
        near = np.concatenate([g.near[c], c[:, None]], axis=1)  # (n, 7): the neighbours, then the cell itself
        d = np.where(near >= 0, self.dist[self.rows[:, None], np.maximum(near, 0)], FAR).astype(np.int64)
        rank = np.where(near >= 0, d * 8 + np.array([1, 2, 3, 4, 5, 6, 0]), 1 << 40)
        sort = np.argsort(rank, axis=1, kind="stable")
        own = np.take_along_axis(np.where(near >= 0, g.cells[np.maximum(near, 0)], -1), sort, axis=1)
        cand = candidates(here, own, self.size, self.aim_array, node.number)
        if self.guide is None:
            return cand
        table, index = self.guide  # (the scattered paths: a drone on its path tries its next cell first)
        nxt = np.where(node.depth <= HORIZON * self.horizon, table[self.rows, index[here]], -1)
        hit = (cand == nxt[:, None]) & (nxt >= 0)[:, None]
        if not hit.any():
            return cand
        key = np.where(hit, -1, np.arange(cand.shape[1]))
        return np.take_along_axis(cand, np.argsort(key, axis=1, kind="stable"), axis=1)

    def _candidates_compiled(self, node: Node, c: np.ndarray) -> np.ndarray | None:
        """`_candidates` compiled (`pb_candidates` in coordinator/scatter.c, the same rows); None if it cannot run."""
        assert self._lib is not None
        g, here, n = self.graph, np.ascontiguousarray(node.cfg, np.int64), len(node.cfg)
        guide = None
        if self.guide is not None:
            table, index = self.guide
            guide = np.ascontiguousarray(np.where(node.depth <= HORIZON * self.horizon, table[self.rows, index[here]],
                                                  -1), np.int64)
        if self._compiled_args is None:  # (the graph's arrays and the tables as the library reads them, made once)
            self._compiled_args = (np.ascontiguousarray(g.near, np.int64), np.ascontiguousarray(self.dist),
                                   np.ascontiguousarray(g.cells, np.int64))
        near, dist, cells = self._compiled_args
        shape = self.aimed[1]
        out = np.empty((n, g.near.shape[1] + 1), np.int64)
        seed = node.number * 0x9E3779B97F4A7C15 % (1 << 64)  # (`arbiter.tie_breaks`' seed)
        got = self._lib.pb_candidates(n, g.near.shape[1], np.ascontiguousarray(c, np.int64).ctypes.data,
                                      near.ctypes.data, dist.ctypes.data, dist.shape[1], cells.ctypes.data,
                                      here.ctypes.data, self.aim_array.ctypes.data, 1, seed, shape[1], shape[2],
                                      self._cells, None if guide is None else guide.ctypes.data, out.ctypes.data)
        return None if got < 0 else out

    def _next(self, at: Node) -> Node:
        """The node after `at` on the way to the goal node (or, while it is not found, the best node known): one step
        along the tree (down towards it, or up when it is not below `at`); `at` once there."""
        aim = self.found if self.found is not None else self.best
        node: Node | None = aim
        while node is not None and node.depth > at.depth + 1:
            node = node.parent
        if node is not None and node.parent is at:
            return node
        if at is not aim and at.parent is not None:
            return at.parent
        return at

    def path(self, at: Node) -> np.ndarray:
        """The configurations from `at` to the goal node (found), one a step ((k, n), this search's drones)."""
        out = [at.cfg]
        while at is not self.found:
            at = self._next(at)
            out.append(at.cfg)
        return np.stack(out)

    def where(self) -> np.ndarray:
        """Every drone's cells where the search has them now (`whole`)."""
        return self.whole(self.at.cfg if self.plan is None else self.plan[self.t])

    def step(self) -> np.ndarray:
        """The drones' next configuration: one step along the tree from `at` towards the goal node (or, while the
        goal is not found, the best node known: the least sum of distances to the goals), which becomes `at`; `at`'s
        own once there. Once found, the next of `plan` (`refine`). Every drone's cells (`whole`)."""
        if self.plan is not None:
            self.t = min(self.t + 1, len(self.plan) - 1)
            return self.whole(self.plan[self.t])
        self.at = self._next(self.at)
        return self.whole(self.at.cfg)

    def refine(self, work: int, open_: OpenCells, first: bool = True) -> int:
        """Once the goal is found: the drones' way to it (`plan`) made shorter, within `work` units (`expand`'s rule),
        while they walk it — LaCAM3's refinement done as a search that starts again (Okumura, AAMAS 2024: a solution
        is improved by planning again from parts of it, the better kept). A new search (`refiner`, its tie-breaks its
        own) starts from the configuration of the plan `AHEAD` of the way from the drones to the goal (a third), with
        at most as many PIBT calls as the plan has steps from there, less one: if it finds the goal in fewer steps
        than the plan, its way replaces the plan's from there (the drones reach that configuration later than it is
        made: a refiner makes a call a turn at least, and has as many turns as calls); whether or not, the next
        starts as far ahead again.
        Each is a function of the plan alone: deterministic. `first`: a call at least (`expand`). The units spent."""
        if self.found is None:
            return 0
        if self.plan is None:  # (the tree is no longer needed: its memory freed)
            self.plan, self.t = self.path(self.at), 0
            self.first = len(self.plan) - 1
            self.found = self.at = self.best = Node(self.found.cfg, None, self.found.prio, self.found.number)
            self.explored, self.open = {}, []
        spent = 0
        while True:
            r = self.refiner
            if r is not None and self.t > self.ahead:  # (the drones are past its root: too late)
                r = self.refiner = None
            if r is None:
                ahead = self.t + (len(self.plan) - 1 - self.t) * AHEAD[0] // AHEAD[1]
                if len(self.plan) - 1 - ahead < REFINE or (spent and spent + self._build > work):
                    return spent
                made = self._refiner(ahead, (self.refined + 1) * REFINE_NUMBERS)
                if made is None:  # (its tables too big to make in a turn: the plan is walked as it is)
                    return spent
                spent += self._build
                self.refined += 1
                self.ahead = ahead
                r = self.refiner = made
            left = len(self.plan) - 1 - self.ahead  # the plan's steps after the refiner's root
            while r.found is None and r.open and not r.full and r.expansions < left - 1 and not self._behind(r):
                calls = r.expansions
                spent += r.expand(work - spent, open_, min(left - 1, calls + 1), first and not spent)
                self.refining += r.expansions - calls
                if r.expansions == calls and r.found is None and r.open and not r.full:
                    return spent  # (its next call does not fit in this turn's units)
            if r.found is not None and r.found.depth < left and self.t <= self.ahead:
                way = r.path(r.at)
                if r.focus is not None and self.focus is None:  # (its drones only: every drone's cells)
                    way = np.repeat(self.plan[self.ahead][None, :], len(way), axis=0)
                    way[:, r.focus[0]] = r.path(r.at)
                self.plan = np.concatenate([self.plan[:self.ahead], way])
            self.refiner = None

    def _refiner(self, ahead: int, number: int) -> Search | None:
        """A refining search from the plan's configuration `ahead`, its root numbered `number`: over the drones that
        move after it, the others (on their goals from there to the end of the plan) standing still, walls to it (as a
        focused search's); of every drone in a focused search (its plan holds its drones alone). Its calls cost the
        drones it moves: in the plan's second half most drones are home for good. None where its distance tables (its
        drones' over its part of the world, copied) would hold more than `PRECOMPUTE` entries: a copy longer than a
        turn (1000 drones in the 64 x 64 x 8 city: 56 MB, 150 ms); never on a 32 x 32 map."""
        assert self.plan is not None
        aims = self.aim_array
        parked = (self.plan[ahead:] == self.goals).all(axis=0)
        if self.focus is not None or not parked.any():
            return Search(self.graph, self.size, self.plan[ahead], self.goals, aims, self.dist, self.memory,
                          self.focus, number)
        g = self.graph
        free = np.flatnonzero(~parked)
        if len(free) * (len(g.cells) - int(parked.sum())) > PRECOMPUTE:  # (its tables: its drones by its part's cells)
            return None
        bits = np.zeros(len(g.index), bool)
        bits[g.cells] = True
        bits[self.plan[ahead][parked]] = False
        world = OpenCells.of(bits)
        part = g.index[np.flatnonzero(bits)]
        sub = Graph(world, self.size)
        return Search(sub, self.size, self.plan[ahead][free], self.goals[free], aims[free],
                      self.dist[np.ix_(free, part)], self.memory, (free, self.plan[ahead], world, 0), number)

    def _behind(self, r: Search) -> bool:
        """The refiner `r` has made BEHIND calls or more and its best node is farther from the goal (sum of distances)
        than the plan is after as many steps from its root as `r` made calls: unlikely to make the plan shorter."""
        if r.expansions < BEHIND or self.plan is None:
            return False
        if self._h is None or len(self._h) != len(self.plan) or self._h_of is not self.plan:
            idx = self.graph.index[self.plan]
            self._h = self.dist[self.rows[None, :], idx].astype(np.int64).sum(axis=1)
            self._h_of = self.plan
        return r.best_h > int(self._h[min(self.ahead + r.expansions, len(self.plan) - 1)])


def _pieces(seen: np.ndarray, near: np.ndarray) -> np.ndarray:
    """Each open cell of `seen` labelled with the least number of the connected piece of `seen` it is in, the others
    with len(seen) (`near`: each open cell's neighbours, len(seen) for none)."""
    n = len(seen)
    label = np.where(seen, np.arange(n), n)
    ext = np.append(label, n)
    while True:  # (each cell the least number of its piece: the pieces are small)
        low = np.minimum(label, ext[near].min(axis=1))
        low = np.where(seen, low, n)
        if (low == label).all():
            return label
        label, ext = low, np.append(low, n)


def _listed(xs: np.ndarray | list[int]) -> list[int]:
    """A call's drones or cells as a list (`Search._choosers` gives arrays where it runs compiled)."""
    return xs.tolist() if isinstance(xs, np.ndarray) else xs


def _choosing(order: list[int], here: list[int], cand: list[list[int]], fixed: set[int]) -> int:
    """How many of `order`'s drones PIBT must let choose: not the drones at its end whose first candidate is their
    own cell (drones on their goals, of the lowest priorities) and that no constraint sends another drone into
    (`fixed`: those cells). Each of those, when its turn came, would take its cell (nobody can have claimed it
    without pushing it, and then it has chosen already) and no drone after it could push it: left out, those nobody
    pushes stay, as PIBT would have them, the others are pushed as they would be (every drone before them has
    chosen the same). In a crowd's endgame most drones are such: the call costs the others."""
    k = len(order)
    while k and cand[order[k - 1]][0] == here[order[k - 1]] and here[order[k - 1]] not in fixed:
        k -= 1
    return k


class Lacam:
    """The complete arbitration (an `arbiter.Arbiter`, with state): `follow` runs the search and gives its step,
    the call checks the step against the drones' offers (PIBT, `cooperate`, when there is no step or it is not
    offered). `unsolvable`: the search proved that no way brings every drone home (the engine ends the game)."""

    complete = True

    def __init__(self, work: int = WORK, limit: int = LIMIT, stall: int = STALL, memory: int = MEMORY,
                 scatter: bool = True, small: int = CANDIDATES) -> None:
        """`scatter`: the whole world's searches guided by scattered paths (`Scatter`; False: PIBT's candidates by
        distance alone, as before); `small`: the candidates beyond which a puzzle is LaCAM's, not an exact search's
        (`exact.fits`; 0: LaCAM's always)."""
        self.work, self.limit, self.stall, self.memory, self.scatter = work, limit, stall, memory, scatter
        self.small = small
        self._scattered: bytes | None = None  # the targets the scattered paths were made for (once a world: `_start`)
        self._graph: Graph | None = None
        self._of: OpenCells | None = None
        self._tables: dict[int, np.ndarray] = {}  # goal (numbered open cell) -> its distance table
        self._table_units = 0  # the units of the costliest table made so far (in this world)
        self._every: np.ndarray | None = None  # every open cell's table (`PRECOMPUTE`), made by `prepare`
        self._search: Search | Exact | None = None
        self._key = b""  # the targets and cooperative drones the record and the search are for
        self._best, self._since = -1, 0  # most drones on their targets at once, and turns since
        self._patience = stall  # turns without a new high after which the running search hands back to PIBT
        self._handed = False  # a search handed back to PIBT (for these targets): the next starts once PIBT stalls
        self._radius = 0  # the next search's focus (`_focus`; 0: the whole world)
        self._rung = 1  # the next rung of the focused searches' ladder (`_rung_search`; 0: none, LaCAM's focus)
        self._rung_cells = 0  # the cells of the last rung's part
        self._side = 0  # the rung's next part to search: 0 the whole, or where it is too big its sides (`_sides`)
        self._seed: np.ndarray | None = None  # the drones (rows) whose puzzle the ladder solves (its first rung's)
        self._on_rung: Exact | None = None  # the exact search of a rung, while it runs
        self._tried = False  # an exact search tried for these targets gave up (`_whole`): LaCAM's from then on
        self._low, self._flat = 1 << 62, 0  # the drones' least sum of distances to their targets, turns since it
        # was (`_progress`)
        self.unsolvable = False
        self.expansions = 0  # PIBT calls of every search so far (for the benchmark)
        self.full = 0  # searches stopped at their memory (`MEMORY`)
        self.spent = 0  # the units the search spent in its last turn

    def __call__(self, size: Cell, before: np.ndarray, proposed: np.ndarray, ranked: np.ndarray,
                 cooperative: np.ndarray, priority: np.ndarray, targets: np.ndarray, open_: OpenCells | None = None,
                 salt: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        plan = self.follow(size, before, cooperative, targets, open_, salt)
        if plan is None:
            return cooperate(size, before, proposed, ranked, cooperative, priority, targets, open_, salt)
        here = flat_cells(before, size)
        wants = flat_cells(proposed, size)
        own = offered(here, ranked, wants, size)
        if not ((plan == here) | (own == plan[:, None]).any(axis=1)).all() or len(np.unique(plan)) < len(plan):
            # (the drones will not be where the search thinks, unless PIBT sends them there: it then goes on, else
            # starts again, as `follow` sees next turn from their cells alone; a step that would put two drones in one
            # cell is a bug, never played)
            return cooperate(size, before, proposed, ranked, cooperative, priority, targets, open_, salt)
        first = ranked.astype(np.int64) & 7
        yielded = plan != np.where(first > 0, here + steps_flat(size)[first], wants)
        return cells_of(plan, size), yielded, np.zeros(len(before), bool)

    def follow(self, size: Cell, before: np.ndarray, cooperative: np.ndarray, targets: np.ndarray,
               open_: OpenCells | None, salt: int | None = None) -> np.ndarray | None:
        """The drones' cells (flat, `world.search.flat_cells`) the search sends them to this turn, or None (PIBT's
        turn). A function of the arguments of this and every earlier call alone (`coordinator/resume.py`)."""
        n = len(before)
        if open_ is None or not n or not cooperative.all():
            self._search, self._key = None, b""  # a non-cooperative drone's move is its own: PIBT
            return None
        self.prepare(size, open_)
        here = flat_cells(before, size)
        aims = np.where(targets[:, 0] >= 0, flat_cells(targets, size), -1)
        key = aims.tobytes()
        if key != self._key:
            self._key, self._search, self._best, self._since, self.unsolvable = key, None, -1, 0, False
            self._patience, self._handed, self._radius, self._tried = self.stall, False, 0, False
            self._ladder()
            self._low, self._flat = 1 << 62, 0
        search = self._search
        if search is not None and not np.array_equal(search.where(), here):
            search = self._search = None
        piece = search is not None and search.focus is not None and search.plan is not None and \
            search.t == len(search.plan) - 1  # (a focused search walked: the next piece, at once)
        if piece:
            search = self._search = None
            self._ladder()  # (the next piece: its ladder)
        home = int(np.count_nonzero(here == aims))
        self._best, self._since = (home, 0) if home > self._best else (self._best, self._since + 1)
        self._progress(here, aims)
        if isinstance(search, Search) and search.focus is None and search.found is None and \
                self._graph is not None and self._whole(self._graph.near, n)[0]:
            search = self._search = None  # (LaCAM stuck on a small puzzle: the exact search, from here)
        endgame = search is not None and search.found is None and self._endgame(search, n - home)
        if search is not None and search is self._on_rung and search.unsolvable:
            self._side += 1  # (no way within the rung's part, which proves nothing: its next side or the next
            # rung, at once)
            search = self._search = self._on_rung = None
            self._handed = False
        elif search is not None and search.found is None and (
                (self._since >= self._patience and not search.bounded) or search.full or search.unsolvable or endgame):
            # no progress for long, its memory full, or no way to its goal (within its part of the world, or with a
            # drone's stand-in goal; a lifelong game's, whose ground station plays on): PIBT's turns until PIBT
            # stalls as long, then a search focused on the drones away (wider each time, the whole world at last)
            self.full += search.full
            self._radius = FOCUS if search.focus is None else 2 * search.focus[3]
            if search.focus is None:
                self._ladder()
            self._patience, self._handed, self._since = 2 * self._patience, True, 0
            if search.unsolvable and not search.exact and self._graph is not None and \
                    self._small(self._graph.near, n)[0]:  # (a stand-in's goal, stricter than the game's: the exact
                self._handed = False  # search's, not PIBT's turns, for a small puzzle)
            if endgame:
                self._handed = False  # (a focused search at once)
            search = self._search = None
        if search is None:
            if home == n:
                return None  # every drone home: nothing to search
            if n * int(open_.count()) > self.limit or (self._handed and self._since < self.stall and not piece):
                return None
            search = self._rung_search(size, here, aims) if self._radius and self._rung else None
            if search is None:
                search = self._focus(size, here, aims, self._radius) if self._radius else None
            if search is None:  # (the first search, or no focus can be made: the whole world)
                search = self._start(size, here, aims)
            if search is None:
                return None  # (its graph or tables made this turn: PIBT's turn)
            self._since = 0  # (its patience counts from its start)
        self.expansions -= search.expansions
        self.spent = search.expand(self.work, open_)  # (at least one PIBT call: the drones never wait for the search,
        # but while the scattered paths that guide it are made, `SCATTER_WORK`)
        self.expansions += search.expansions
        self.expansions -= search.refining
        self.spent += search.refine(self.work - self.spent, open_, not self.spent)  # (once found: made shorter)
        self.expansions += search.refining
        if isinstance(search, Exact) and search.gave_up:  # (LaCAM's search from the next turn, where they are)
            if search is self._on_rung:
                self._rung, self._search, self._on_rung = 0, None, None  # (the ladder ends: LaCAM's focus, at
                self._handed = False  # once)
            else:
                self._tried, self._search = True, None
        if search.unsolvable and search.focus is None and search.exact:  # (a proof: the game's own goal)
            self.unsolvable = True
        return search.step()

    def prepare(self, size: Cell, open_: OpenCells) -> None:
        """The game starts in the world of `open_`: its graph, and every open cell's distance table where they hold
        `PRECOMPUTE` entries or fewer, made now, before the turns (the engine calls it as the game starts). A
        function of the world alone: where nobody called it (a replay, a resumed game), `follow`'s first call in the
        world does, and the search takes the same decisions."""
        if open_ is self._of:
            return
        self._of, self._tables, self._table_units, self._scattered = open_, {}, 0, None
        self._graph = g = Graph(open_, size)
        self._every = g.every_distance() if len(g.cells) ** 2 <= PRECOMPUTE else None
        if self._every is not None and (self.scatter or self.small):
            scatter_library()  # (built now if it is to be, not in a turn: the scattered paths' search and the exact
            # search's joint moves, which run only where the tables are made now)

    def _focus(self, size: Cell, here: np.ndarray, aims: np.ndarray, radius: int) -> Search | Exact | None:
        """A search from `here` over the drones within `radius` moves (over the open cells) of a drone away from its
        goal or of that goal, the others standing still, walls to it (their tables made at the game's start: None
        elsewhere); the radius at least half the farthest such drone's distance, so that its shortest ways are in
        it. Where that part is the whole world, a search of the whole world (`_start`)."""
        g, every = self._graph, self._every
        assert g is not None  # (`prepare`)
        if every is None:
            return None
        hc, ac, way = g.ways(here, aims)
        if (hc < 0).any():
            return None
        goal_c = stand_ins(g, np.where(way, ac, hc), way)
        away = goal_c != hc
        if not away.any():
            return None
        radius = max(radius, (int(every[goal_c[away], hc[away]].max(initial=0)) + 1) // 2)
        seen = np.zeros(len(g.cells) + 1, bool)  # (the last: no neighbour)
        front = np.unique(np.concatenate([hc[away], goal_c[away]]))
        near = np.where(g.near >= 0, g.near, len(g.cells))
        for _ in range(radius + 1):
            if not len(front):
                break  # (every cell of the drones' components: a radius may grow without end)
            seen[front] = True
            front = np.unique(near[front].ravel())
            front = front[(front < len(g.cells)) & ~seen[front]]
        seen[:-1] &= self._piece(seen[:-1], near, hc[away])
        part = np.flatnonzero(seen[:-1])
        if len(part) == int((g.part == g.part[part[0]]).sum()):  # (every cell of its connected component: the whole
            return self._start(size, here, aims)  # world's search, its other components' drones standing still)
        free = np.flatnonzero(seen[hc])
        world = OpenCells.of(self._bits(g, part))
        sub = Graph(world, size)
        goals = sub.index[g.cells[goal_c[free]]]
        whole, cap = self._whole(sub.near, len(free))
        if whole and (goals >= 0).all():  # (a small puzzle: searched whole)
            self._search = Exact(sub.near, sub.cells, sub.index[here[free]], goals, (free, here, world, radius),
                                 cap=cap)
            return self._search
        self._search = Search(sub, size, here[free], g.cells[goal_c[free]], np.where(way, aims, -1)[free],
                              every[goal_c[free]][:, part], self.memory, (free, here, world, radius))
        return self._search

    def _endgame(self, search: Search | Exact, away: int) -> bool:
        """The whole world's search is in its endgame: a few drones away (`ENDGAME_SHARE`, `ENDGAME_FEW`) among many
        on their targets, and no new high for `ENDGAME_AFTER` turns. Its chain from the start has brought them there;
        what is left is a puzzle or two of a few drones, which a focused search solves in a few turns, while the whole
        world's spends its calls on every drone (random-32-32-20 with 400 drones, seeds 2, 3 and 5: 396 to 398 home by
        turn 105, then 32 turns of the search's patience and 32 to 64 of PIBT's before the focused search)."""
        return search.focus is None and not search.bounded and self._since >= ENDGAME_AFTER and \
            0 < away <= max(ENDGAME_FEW, len(search.goals) // ENDGAME_SHARE) and self._every is not None

    def _ladder(self) -> None:
        """The focused searches start again from the ladder's first rung (`_rung_search`), for a puzzle to choose."""
        self._rung, self._rung_cells, self._seed, self._side = 1, 0, None, 0

    def _rung_search(self, size: Cell, here: np.ndarray, aims: np.ndarray) -> Exact | None:
        """The exact search of the ladder's next rung, or None once the ladder is over (`_rung` 0: LaCAM's focus).

        The ladder solves one puzzle, its seed: the drones away that stand together (`_piece` of their cells and
        goals alone: the fewest drones away, then the fewest cells). Rung R's part: the open cells within R of a seed
        drone or of its goal, a cell where another drone stands costing `RUNG_PARKED` moves to enter (a free cell
        one), the piece the seed is in; its drones move, the seed's to their goals, every other back to its cell,
        the drones outside stand still. A puzzle in a crowd is solved by the few drones beside free space, not by
        the many in the crowd: the ball of `_focus` takes in every parked drone around and its joint moves are too
        many for an exact search, while LaCAM's constraints are slow to find the few moves that matter
        (random-32-32-20 with 400 drones, seed 5: two drones trading places in a 1-wide passage between two 2 x 2
        blocks, one with parked drones and the other with free cells: 18,539 PIBT calls in the ball of radius 4, 10
        drones on 18 cells; rung 5, 6 drones on 11 cells, found in 7 turns' units). Each rung's part is searched
        whole (`exact.Exact`, at most `RUNG_TRY` units); one that has no way within its part (no proof of anything)
        gives way to the next at once. A rung's part too big for an exact search (`_small`: a single configuration's
        joint moves could then outgrow a turn) is searched a side at a time (`_sides`: the seed's cells and one piece
        of the rest, the smallest first), each that is small enough, the next on no way: drones that must change
        their order in a 1-wide line find room on one side, where both sides' cells and parked drones together are
        too many configurations (random-32-32-20 with 400 drones, seed 5, under more search a turn: three drones
        each wanting the next one's cell in a line of 3 between two clusters of 6 and 7 cells, each with a 4-cycle;
        the whole, 8 drones on 16 cells, is 518,918,400 placements; its left side, 5 drones on 9 cells, is searched
        in 2 turns, a way of 9 steps). The ladder ends where a rung is every cell, has no side left, or gives up.
        The next puzzle climbs a ladder of its own."""
        g, every = self._graph, self._every
        assert g is not None  # (`prepare`)
        hc, ac, way = g.ways(here, aims)
        if every is None or (hc < 0).any() or not self.small:
            self._rung = 0
            return None
        goal_c = stand_ins(g, np.where(way, ac, hc), way)
        away = goal_c != hc
        F = len(g.cells)
        near = np.where(g.near >= 0, g.near, F)
        if self._seed is None:
            on = np.zeros(F, bool)
            on[np.concatenate([hc[away], goal_c[away]])] = True
            if not on.any():
                self._rung = 0
                return None
            self._seed = np.flatnonzero(away & self._piece(on, near, hc[away])[hc])
        seed = self._seed
        mine = np.zeros(len(hc), bool)
        mine[seed] = True
        enter = np.ones(F + 1, np.int64)
        enter[hc[~mine]] = RUNG_PARKED
        enter[F] = F  # (no neighbour: never entered)
        start = np.unique(np.concatenate([hc[seed], goal_c[seed]]))
        whole = int((g.part == g.part[hc[seed[0]]]).sum())  # (the seed's connected component: its part's end)
        while self._rung:
            cost = np.full(F + 1, F, np.int64)
            cost[start] = 0
            for d in range(self._rung):  # (Dijkstra by levels: every cost is a whole number of moves)
                beyond = near[np.flatnonzero(cost[:F] == d)].ravel()
                np.minimum.at(cost, beyond, d + enter[beyond])
            seen = cost[:F] <= self._rung
            seen &= self._piece(seen, near, hc[seed])
            part = np.flatnonzero(seen)
            if len(part) == whole:
                break  # (every cell)
            if not self._side and len(part) == self._rung_cells:
                self._rung += 1  # (the same part as the last rung's)
                continue
            self._rung_cells = len(part)
            world = OpenCells.of(self._bits(g, part))
            sub = Graph(world, size)
            sides = not self._small(sub.near, int(seen[hc].sum()))[0]  # (too many configurations for an exact search)
            tries = self._sides(seen, start, near) if sides else [seen]
            while self._side < len(tries):
                on = tries[self._side]
                if sides:
                    world = OpenCells.of(self._bits(g, np.flatnonzero(on)))
                    sub = Graph(world, size)
                free = np.flatnonzero(on[hc])
                goals = sub.index[g.cells[np.where(mine, goal_c, hc)[free]]]
                if (goals >= 0).all() and (not sides or self._small(sub.near, len(free))[0]):
                    self._search = self._on_rung = Exact(sub.near, sub.cells, sub.index[here[free]], goals,
                                                         (free, here, world, self._rung), cap=RUNG_TRY)
                    return self._on_rung
                self._side += 1  # (a seed drone's goal outside the part, or a side too big as well)
            if sides:
                break  # (no side left: LaCAM's focus)
            self._rung, self._side = self._rung + 1, 0
        self._rung = 0  # (LaCAM's focus)
        return None

    @staticmethod
    def _sides(seen: np.ndarray, start: np.ndarray, near: np.ndarray) -> list[np.ndarray]:
        """A rung's part (the open cells `seen`) one side at a time: the seed's cells (`start`: its drones' and their
        goals') with one connected piece of the rest each, the smallest piece first (then by its least cell)."""
        seeds = np.zeros(len(seen), bool)
        seeds[start] = True
        rest = seen & ~seeds
        label = _pieces(rest, near)
        pieces, cells = np.unique(label[rest], return_counts=True)
        return [seeds | (label == p) for _, p in sorted(zip(cells.tolist(), pieces.tolist()))]

    @staticmethod
    def _bits(g: Graph, part: np.ndarray) -> np.ndarray:
        """Every flat cell's bit, set on the open cells `part` (numbered) of `g`."""
        bits = np.zeros(len(g.index), bool)
        bits[g.cells[part]] = True
        return bits

    def _whole(self, near: np.ndarray, drones: int) -> tuple[bool, int | None]:
        """Whether a puzzle of `drones` drones on the open cells of `near` is searched whole (`exact.Exact`), and the
        units it may spend: once the drones have made no progress for `EXACT_AFTER` turns (`_progress`: where they
        do, LaCAM's way costs no wait), to its end where `exact.fits` admits it (None), `exact.TRY` where
        `exact.tried` does and no such try has given up for these targets; else LaCAM's."""
        if self._flat < EXACT_AFTER:
            return False, None
        return self._small(near, drones)

    def _small(self, near: np.ndarray, drones: int) -> tuple[bool, int | None]:
        """`_whole`'s answer, progress or not."""
        if fits(near, drones, self.small):
            return True, None
        return bool(self.small) and not self._tried and tried(near, drones), TRY

    def _progress(self, here: np.ndarray, aims: np.ndarray) -> None:
        """Count the turns since the drones' sum of distances to their targets (those they can reach) was last at a
        new low (`_flat`), where the world's every distance table is made (`prepare`)."""
        g, every = self._graph, self._every
        if g is None or every is None:
            return
        hc, ac, way = g.ways(here, aims)
        h = int(every[ac[way], hc[way]].astype(np.int64).sum())
        self._low, self._flat = (h, 0) if h < self._low else (self._low, self._flat + 1)

    @staticmethod
    def _piece(seen: np.ndarray, near: np.ndarray, away: np.ndarray) -> np.ndarray:
        """Of the open cells `seen` (a focus: within its radius of a drone away or of its goal), the connected piece
        a focused search takes first: the one with the fewest drones away (`away`: their open cells; one at least),
        then the fewest cells, then the first cell. Puzzles apart are solved one after the other, each a search of its
        own (in one, LaCAM's constraints would combine their drones' moves: random-32-32-20 with 400 drones, seed 5,
        two drones trading places at a dead end, solved in 182 calls alone, not in 5,000 beside a harder one)."""
        label = _pieces(seen, near)
        pieces, cells = np.unique(label[seen], return_counts=True)
        count = {int(p): 0 for p in pieces}
        for c in label[away].tolist():
            count[c] += 1
        best = min(zip(pieces.tolist(), cells.tolist()),
                   key=lambda pc: (not count[pc[0]], count[pc[0]], pc[1], pc[0]))[0]
        return label == best

    def _start(self, size: Cell, here: np.ndarray, aims: np.ndarray) -> Search | Exact | None:
        """A search from `here` once every drone's distance table is made, None until then: made at the game's start
        (`prepare`) in a small world, else in turns of `work` units (one at least a turn; another only if the
        costliest so far fits in what is left), the search starting on the turn after the last. A drone whose
        target is none, a building or cut off from it by the static world has its cell as its goal (it must be able
        to come back there)."""
        g = self._graph
        assert g is not None  # (`prepare`)
        hc, ac, way = g.ways(here, aims)
        if (hc < 0).any():
            return None  # a drone in a building or outside (it is dying): PIBT
        if len(np.unique(ac[way])) < np.count_nonzero(way):  # two drones share a target: no configuration has both
            self.unsolvable = True  # home (a proof without a search)
            return None
        whole, cap = self._whole(g.near, len(here))
        if whole:  # (a small puzzle searched whole: its way shortest, or a proof)
            self._search = Exact(g.near, g.cells, hc, np.where(way, ac, -1), cap=cap)
            return self._search
        goal_c = stand_ins(g, np.where(way, ac, hc), way)
        if self._every is not None:
            # the scattered paths: for the first targets in this world (at the game's start; a lifelong game's new
            # targets, a search a turn, go unguided) and where they are affordable (`SCATTER`)
            scatter = self.scatter and self._scattered in (None, self._key) and CROWD <= len(here) and \
                len(here) * len(g.cells) <= SCATTER
            if scatter:
                self._scattered = self._key
            self._search = Search(g, size, here, g.cells[goal_c], np.where(way, aims, -1), self._every[goal_c],
                                  self.memory, scatter=scatter, exact=bool(way.all()))
            return self._search
        spent = 0
        for c in dict.fromkeys(goal_c.tolist()):
            if c not in self._tables:
                if spent and spent + self._table_units > self.work:
                    return None
                self._tables[c], units = g.distances(c)
                self._table_units = max(self._table_units, units)
                spent += units
        if spent:
            return None  # (the search starts next turn: this one's work went on the tables)
        if len(self._tables) > 4 * len(here):  # (new targets keep coming: keep the tables in use)
            self._tables = {c: self._tables[c] for c in dict.fromkeys(goal_c.tolist())}
        dist = np.stack([self._tables[c] for c in goal_c.tolist()])
        self._search = Search(g, size, here, g.cells[goal_c], np.where(way, aims, -1), dist, self.memory,
                              exact=bool(way.all()))
        return self._search

    @property
    def busy(self) -> bool:
        """A search is bringing the drones home (a drone that says UNREACHABLE meanwhile is not: the engine does
        not settle the game on it)."""
        s = self._search
        return s is not None and not self.unsolvable and (s.found is None or s.plan is None or
                                                           s.t < len(s.plan) - 1)

    def state(self) -> dict[str, Any]:
        """A summary of the search (for logs and tests): nodes, PIBT calls, found, unsolvable."""
        s = self._search
        return {"nodes": 0 if s is None else len(s.explored), "held": 0 if s is None else s.held,
                "expansions": self.expansions, "full": self.full, "first": 0 if s is None else s.first,
                "plan": 0 if s is None or s.plan is None else len(s.plan) - 1, "refined": 0 if s is None else s.refined,
                "found": s is not None and s.found is not None, "unsolvable": self.unsolvable}
