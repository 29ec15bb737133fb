"""An exact search over the drones' configurations, for the puzzles small enough to search whole: breadth first
from where the drones are, every joint move of every configuration (vertex and swap conflicts forbidden), until a
configuration with every drone that has a way home at home (docs/cooperation.md, "Small puzzles: the exact search").

LaCAM (coordinator/lacam.py) finds a way lazily, one PIBT call at a time under constraints: quick where there is
room, but on a 1-wide corridor with a bay or two its proof that no way exists, or its way through a reversal,
takes every constraint of every configuration (up to 1 + m + m^2 + ... + m^n calls a configuration for n drones of
m moves each) and hundreds of turns. Where the configurations are few, a breadth-first search over them is both
quicker and better: its way is as short as any (the least makespan), and when it runs out of configurations it is a
proof that none exists. `fits` says where (`CANDIDATES`); `Exact` is the search, with a `lacam.Search`'s interface so
that `lacam.Lacam` runs either over turns within its work budget.

Pure: numpy over the world's open cells numbered 0..F-1 and their neighbours (`lacam.Graph`'s `near`, -1 for none);
a function of its arguments alone (every layout, replay and resume does the same work). Each level is expanded in
chunks of configurations whose candidates fit in the turn's work; within a level, configurations are in the order of
their codes (each drone's cell a digit in base F), so a configuration's parent is the first that reaches it.
"""

from __future__ import annotations

import numpy as np

from .compiled import scatter_library

__all__ = ["Exact", "fits", "tried", "settle", "settle_one", "CANDIDATES", "TRY"]

#: Joint moves (candidates: a configuration's drones' moves combined, before the conflicts are struck out) an exact
#: search may have to make at most, counted as the placements of the drones on the open cells times the mean moves a
#: cell to the power of the drones (an upper bound: it visits only the configurations it reaches). Beyond it, LaCAM.
CANDIDATES = 1 << 25
#: Candidates a work unit (lacam.WORK's: about what a PIBT call spends on a drone; measured, docs/cooperation.md).
A_UNIT = 128
#: Configurations (the placements of the drones on the open cells) up to which a puzzle that `fits` does not admit is
#: tried all the same, within TRY units in all (about 128 turns of lacam.WORK): in a 1-wide corridor the drones block
#: each other's moves, so the joint moves are far fewer than `fits`' bound (six drones on 13 cells: found in 71 turns,
#: where LaCAM had not in 500). A search that spends them without an end gives up (`Exact.gave_up`): LaCAM's then.
TRIED = 1 << 21
TRY = 128 * 1260  # (lacam.WORK, which imports this module, is 1260)


def fits(near: np.ndarray, drones: int, most: int = CANDIDATES) -> bool:
    """An exact search over `drones` drones on the open cells of `near` ((F, k), each cell's open neighbours, -1 for
    none) makes at most `most` candidates, and its configurations' codes fit an int64: it is searched to its end."""
    F = len(near)
    return _coded(F, drones) and _within(F, drones, (1 + float((near >= 0).sum()) / F) ** drones, most)


def tried(near: np.ndarray, drones: int, most: int = TRIED) -> bool:
    """An exact search over `drones` drones on the open cells of `near` reaches at most `most` configurations, and
    their codes fit an int64: it is worth trying within `TRY` units, where `fits` does not admit it."""
    return _coded(len(near), drones) and _within(len(near), drones, 1.0, most)


def _coded(cells: int, drones: int) -> bool:
    return 1 <= drones <= cells and drones * float(np.log2(max(cells, 2))) <= 62


def _within(cells: int, drones: int, bound: float, most: float) -> bool:
    """`bound` times the placements of `drones` drones on `cells` cells (F (F-1) ... (F-n+1)) is at most `most`."""
    for k in range(drones):
        bound *= cells - k
        if bound > most:
            return False
    return True


def whole(focus: tuple[np.ndarray, np.ndarray, object, int] | None, cfg: np.ndarray) -> np.ndarray:
    """Every drone's cell in a configuration `cfg` of a search (of every drone; or `focus`ed: its drones' rows among
    all, every drone's cells, the others standing still there)."""
    if focus is None:
        return cfg
    out = focus[1].copy()
    out[focus[0]] = cfg
    return out


def settle(plan: np.ndarray, moves: np.ndarray) -> tuple[np.ndarray, int]:
    """`plan` ((steps, drones): each drone's open cell a step) with each drone home as early as it can be, its way
    made again against the others' (a breadth-first way is as short as any in steps, not in moves: a drone one step
    from home may wander until the last, a parked one step out and back for nothing), and the units it cost. Drone by
    drone: the earliest step from which it can be in its last cell to the end, by a way through space and time that
    never meets another drone's cell, nor trades cells with one (staying preferred at each step); its way is one such,
    so the plan stays legal and as long. `moves`: each open cell's moves ((F, 1 + k): itself, then its neighbours, -1
    for none)."""
    out = plan.copy()
    units = 0
    for i in range(out.shape[1]):
        units += settle_one(out, i, moves)
    return out, units


def settle_one(out: np.ndarray, i: int, moves: np.ndarray) -> int:
    """Drone i's way in the plan `out` made again (in place), as `settle` does: the units it cost."""
    steps, F, units = len(out), len(moves), 0
    others = np.delete(out, i, axis=1)
    last = out[-1, i]
    taken = np.flatnonzero((others == last).any(axis=1))
    free_from = int(taken[-1]) + 1 if len(taken) else 0  # (from this step on, nobody else in its last cell)
    parent = np.full((steps, F), -1, np.int64)
    parent[0, out[0, i]] = out[0, i]
    arrive = 0 if free_from == 0 and out[0, i] == last else -1
    for t in range(steps - 1):
        if arrive >= 0:
            break
        cur = np.flatnonzero(parent[t] >= 0)
        src = np.tile(cur, moves.shape[1])  # (column by column: staying first)
        dst = moves[cur].T.ravel()
        ok = dst >= 0
        ok[ok] &= ~np.isin(dst[ok], others[t + 1])  # (nobody else there then)
        moved = others[t] != others[t + 1]
        for a, b in zip(others[t][moved].tolist(), others[t + 1][moved].tolist()):
            ok &= ~((src == b) & (dst == a))  # (nobody coming the other way)
        dst, first = np.unique(dst[ok], return_index=True)
        parent[t + 1, dst] = src[ok][first]
        units += 1 + len(src) // A_UNIT
        if t + 1 >= free_from and parent[t + 1, last] >= 0:
            arrive = t + 1
    if arrive < 0:
        return units  # (none sooner: its own way stays)
    way = [last]
    for t in range(arrive, 0, -1):
        way.append(int(parent[t, way[-1]]))
    out[:arrive + 1, i] = way[::-1]
    out[arrive + 1:, i] = last
    return units


def _among(codes: np.ndarray, sorted_: np.ndarray) -> np.ndarray:
    """Which of `codes` are in `sorted_` (sorted)."""
    if not len(sorted_):
        return np.zeros(len(codes), bool)
    return sorted_[np.minimum(np.searchsorted(sorted_, codes), len(sorted_) - 1)] == codes


class _Tree:
    """One breadth-first search's levels from its root: each level's codes (sorted) and each one's parent's index in
    the level before; the next level's codes and parents as its chunks come. The configurations' graph is undirected
    (every move can be undone), so a successor of a level's configuration is in the level before, that level or the
    next: those are all a new one is checked against (never everything seen: its cost would grow with each level)."""

    __slots__ = ("levels", "done", "pending", "over", "count")

    def __init__(self, root: np.ndarray) -> None:
        self.levels: list[tuple[np.ndarray, np.ndarray]] = [(root, np.array([-1]))]
        self.done = 0  # configurations of the last level expanded so far
        self.pending: list[tuple[np.ndarray, np.ndarray]] = []
        self.over = False  # no configuration is left to reach
        self.count = 1  # configurations reached

    def add(self, codes: np.ndarray, parents: np.ndarray) -> int:
        """A chunk's successors (`codes` unique and sorted, their parents' index in the last level): those not in the
        last two levels kept for the next level; how many."""
        new = ~_among(codes, self.levels[-1][0])
        if len(self.levels) > 1:
            new &= ~_among(codes, self.levels[-2][0])
        self.pending.append((codes[new], parents[new]))
        return int(new.sum())

    def close(self) -> np.ndarray:
        """The last level is expanded: the next (its configurations reached first, in the order of their codes),
        empty and `over` if there is none."""
        codes = np.concatenate([c for c, _ in self.pending]) if self.pending else np.empty(0, np.int64)
        parents = np.concatenate([p for _, p in self.pending]) if self.pending else np.empty(0, np.int64)
        self.pending, self.done = [], 0
        codes, first = np.unique(codes, return_index=True)
        if not len(codes):
            self.over = True
            return codes
        self.levels.append((codes, parents[first]))
        self.count += len(codes)
        return codes

    def reached(self, codes: np.ndarray) -> np.ndarray:
        """Which of `codes` this tree has reached (in any level)."""
        out = np.zeros(len(codes), bool)
        for level, _ in self.levels:
            out |= _among(codes, level)
        return out

    def path(self, code: int) -> list[int]:
        """The codes from the root to `code` (reached)."""
        level = next(k for k, (codes, _) in enumerate(self.levels) if _among(np.array([code]), codes)[0])
        index = int(np.searchsorted(self.levels[level][0], code))
        out = []
        for codes, parents in reversed(self.levels[:level + 1]):
            out.append(int(codes[index]))
            index = int(parents[index])
        return out[::-1]


class Exact:
    """A breadth-first search over configurations from `start` to one where each drone i with a goal (`goals[i]`
    >= 0; numbered open cells) is on it, the others anywhere: a way as short as any, or a proof that there is none.
    Where every drone has a goal, it searches from both ends (the moves are reversible: a way back from the goal
    configuration is a way to it), a level at a time of the side whose last level is the smaller, until they meet.

    Its interface is `lacam.Search`'s as `lacam.Lacam` reads it: `expand` spends work, `step` gives the drones' next
    configuration (they hold still until it is found: a turn's work is bounded, `fits` bounds the turns), `where`,
    `found`, `plan` and `t`, `unsolvable`, `focus`, `exact`, `full` (never: `fits` bounds its memory)."""

    bounded = True  # (its work is bounded: never handed back to PIBT for want of progress, `lacam.Lacam.follow`)

    def __init__(self, near: np.ndarray, cells: np.ndarray, start: np.ndarray, goals: np.ndarray,
                 focus: tuple[np.ndarray, np.ndarray, object, int] | None = None, exact: bool = True,
                 cap: int | None = None) -> None:
        """`near`: each open cell's open neighbours ((F, k), numbered, -1 for none); `cells`: their flat cells
        (`lacam.Graph.cells`); `start`: the drones' open cells (numbered); `goals`: theirs (-1: anywhere); `focus`:
        as `lacam.Search`'s (the drones searched are its rows among all, the others stand still); `exact`: the
        search is of the game's own goal (a proof when it finds none); `cap`: the units it may spend in all before it
        gives up (`gave_up`; None: no end but its own, as `fits` admits)."""
        F, n = len(near), len(start)
        self.cells, self.focus, self.exact = cells, focus, exact
        self.moves = np.ascontiguousarray(np.concatenate([np.arange(F)[:, None], near], axis=1), np.int64)  # (F, 1 +
        # k): staying first
        self.lib = scatter_library()  # (its joint moves compiled where the machine can: `_successors`)
        self.count = (self.moves >= 0).sum(axis=1)
        self.powers = F ** np.arange(n, dtype=np.int64)
        self.goals, self.aimed = goals.astype(np.int64), np.flatnonzero(goals >= 0)
        self.trees = [_Tree(self._code(start.astype(np.int64)[None, :]))]
        if len(self.aimed) == n and len(np.unique(self.goals)) == n:  # (the goal configuration, if there is one
            # -- two drones may share a target --: a search back from it too)
            self.trees.append(_Tree(self._code(self.goals[None, :])))
        self.side = 0  # the tree being expanded
        self.found: int | None = None  # once found: the way's length
        self.plan: np.ndarray | None = None  # once found: the configurations from the start to the goal (flat cells)
        self.t = 0
        self.start = cells[start]
        self.expansions = self.refining = self.refined = self.first = 0
        self.held = 2 * n
        self.cap, self.total = cap, 0  # (the units spent so far)
        self._way: np.ndarray | None = None  # the way found, each drone's settled in turn (`_settle`)
        self._settled = 0
        if self._home(start[None, :])[0]:
            self._walk([int(self.trees[0].levels[0][0][0])])
            self._settle(0, True)

    @property
    def explored(self) -> range:
        """The configurations reached (a range of their count: `lacam.Lacam.state` reads its length)."""
        return range(sum(tree.count for tree in self.trees))

    @property
    def full(self) -> bool:
        return False

    @property
    def over(self) -> bool:
        return any(tree.over for tree in self.trees)

    @property
    def unsolvable(self) -> bool:
        """Every configuration reachable from one end is searched and none is the other end (every drone with a
        goal at home)."""
        return self.found is None and self.over

    def _code(self, cfg: np.ndarray) -> np.ndarray:
        return (cfg * self.powers).sum(axis=1)

    def _cfg(self, codes: np.ndarray) -> np.ndarray:
        return (codes[:, None] // self.powers) % len(self.moves)

    def _home(self, cfg: np.ndarray) -> np.ndarray:
        return (cfg[:, self.aimed] == self.goals[self.aimed]).all(axis=1)

    def expand(self, work: int, open_: object = None, most: int = 1 << 62, first: bool = True) -> int:
        """Spend `work` units at most (a configuration at least if `first`, unless the search is over): the units
        spent."""
        spent = 0
        if self._way is not None:
            return self._settle(work, first)
        if self.cap is not None:  # (what is left of its cap)
            work = min(work, self.cap - self.total)
            if work <= 0:
                return 0
        while self.found is None and not self.over:
            tree = self.trees[self.side]
            codes = tree.levels[-1][0]
            if tree.done == len(codes):  # (its cost: the next level's unique codes, and the other tree's levels
                # each checked for a meeting, a searchsorted each)
                closing = 1 + sum(len(c) for c, _ in tree.pending) // A_UNIT + \
                    (len(self.trees[1 - self.side].levels) if len(self.trees) > 1 else 0)
                if (spent or not first) and spent + closing > work:
                    break
                spent += closing
                self._close(tree)
                continue
            cfg = self._cfg(codes[tree.done:tree.done + max(1, (work - spent) * A_UNIT)])  # (those that may fit)
            cost = np.cumsum(self.count[cfg].prod(axis=1)) // A_UNIT + 1
            take = int(np.searchsorted(cost, work - spent, side="right"))
            if not take:
                if spent or not first:
                    break
                take = 1
            spent += int(cost[take - 1])
            codes, parents = self._successors(cfg[:take])
            self.held += 2 * tree.add(codes, parents + tree.done)
            tree.done += take
            self.expansions += take
        if self._way is not None:  # (found: settled in what is left of the work)
            spent += self._settle(work - spent, False)
        self.total += spent
        return spent

    @property
    def gave_up(self) -> bool:
        """It spent its `cap` and neither found a way nor ran out of configurations."""
        return self.cap is not None and self.total >= self.cap and self.found is None and not self.over

    def _successors(self, cfg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The configurations one joint move from `cfg`'s (their codes, unique and sorted, and the index in `cfg` of
        the first that reaches each): compiled (coordinator/scatter.c, `ex_successors`) where the machine has it, the
        same configurations in the same order as Python's below, some ten times as fast."""
        if self.lib is not None and cfg.shape[1] <= 64:
            cfg = np.ascontiguousarray(cfg, np.int64)
            cap = int(self.count[cfg].prod(axis=1).sum())
            out, src = np.empty(cap, np.int64), np.empty(cap, np.int64)
            m = self.lib.ex_successors(len(cfg), cfg.shape[1], cfg.ctypes.data, self.moves.shape[1],
                                       self.moves.ctypes.data, self.powers.ctypes.data, out.ctypes.data,
                                       src.ctypes.data, cap)
            if m >= 0:
                codes, first = np.unique(out[:m], return_index=True)
                return codes, src[first]
        return self._successors_python(cfg)

    def _successors_python(self, cfg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`_successors` in Python: drone by drone, each move against the moves of the drones before it."""
        src = np.arange(len(cfg))
        nxt = np.empty((len(cfg), 0), np.int64)
        for i in range(cfg.shape[1]):  # (drone by drone: each move against the moves of the drones before it)
            options = self.moves[cfg[src, i]]
            r, c = np.nonzero(options >= 0)
            src, v = src[r], options[r, c]
            nxt = np.concatenate([nxt[r], v[:, None]], axis=1)
            ok = (nxt[:, :i] != v[:, None]).all(axis=1)  # (no two in a cell)
            ok &= ~((nxt[:, :i] == cfg[src, i][:, None]) & (v[:, None] == cfg[src, :i])).any(axis=1)  # (no swap)
            src, nxt = src[ok], nxt[ok]
        codes, first = np.unique(self._code(nxt), return_index=True)
        return codes, src[first]

    def _close(self, tree: _Tree) -> None:
        """`tree`'s level is expanded: the next; the way if it meets the other end (the goal, or the other tree),
        else the next level is of the tree whose last level is the smaller."""
        codes = tree.close()
        if len(self.trees) == 1:
            home = np.flatnonzero(self._home(self._cfg(codes)))
            if len(home):
                self._walk(tree.path(int(codes[home[0]])))
                return
        else:
            other = self.trees[1 - self.side]
            met = codes[other.reached(codes)]
            if len(met):
                ways = (tree.path(int(met[0])), other.path(int(met[0])))
                self._walk(ways[0] + ways[1][-2::-1] if self.side == 0 else ways[1] + ways[0][-2::-1])
                return
            sizes = [len(t.levels[-1][0]) for t in self.trees]
            self.side = int(sizes[1] < sizes[0])

    def _walk(self, way: list[int]) -> None:
        """The way found: the configurations of `way` (codes, from the start to the goal), to be settled (`_settle`:
        each drone home as early as it can be) before the drones take it; the trees no longer kept."""
        self._way = self._cfg(np.array(way, np.int64))
        self.found = self.first = len(way) - 1
        self.trees = [self.trees[0]]
        self.trees[0].levels, self.trees[0].pending = [], []

    def _settle(self, work: int, first: bool) -> int:
        """Settle the found way's drones one after the other (`settle_one`) within `work` units (a drone at least if
        `first`); the plan once every drone's is. The units spent."""
        way, spent = self._way, 0
        assert way is not None
        cost = len(way) * (1 + self.moves.size // A_UNIT)  # (a drone's at most: a layer of space and time a step)
        while self._settled < way.shape[1]:
            if (spent or not first) and spent + cost > work:
                return spent
            spent += settle_one(way, self._settled, self.moves)
            self._settled += 1
        self.plan, self._way = self.cells[way], None
        return spent

    def refine(self, work: int, open_: object = None, first: bool = True) -> int:
        """Nothing to refine: its way is as short as any. No units."""
        return 0

    def whole(self, cfg: np.ndarray) -> np.ndarray:
        """Every drone's cell in a configuration of the search (a focused one moves some drones only)."""
        return whole(self.focus, cfg)

    def where(self) -> np.ndarray:
        """Every drone's cells where the search has them now."""
        return self.whole(self.start if self.plan is None else self.plan[self.t])

    def step(self) -> np.ndarray:
        """The drones' next configuration: the next of the plan once found, else where they are."""
        if self.plan is not None:
            self.t = min(self.t + 1, len(self.plan) - 1)
        return self.where()
