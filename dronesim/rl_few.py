"""Episodes of a few drones, drone by drone: the local backend's fast path (docs/performance.md).

An `Episode` over `LocalTurns` plays a step in some 80 numpy calls, whose fixed cost (~0.5-1 µs each) is
the whole step when there are a few drones. `FewEpisode` plays the same step over Python lists, with the
engine's turn reduced to what a policy's turn does in it: the episode's targets, every alive drone's move
(no deadline is missed, so nobody hovers by rule or is LOST), no arbitration (the policy's drones are not
cooperative), the observer's rules drone by drone (`observer.deaths`), each alive drone's note as it said
it, and the end of the game with the episode's (no drone alive, or the turn limit: every agent has ended).
tests/test_pettingzoo.py holds both to the same steps on random worlds and actions (a property test).
"""

from __future__ import annotations

import numpy as np

from coordinator.fleet import ALIVE, DEAD
from coordinator.observer import deaths
from dronesim.rl import (
    ACTIONS,
    CAUSE_TEXT,
    NONE_NOTE,
    NOTE_TEXT,
    STATE_TEXT,
    UNREACHABLE_NOTE,
    Config,
    ConfigError,
    EpisodeBase,
    Eyes,
    Layout,
    Outcome,
    checked_actions,
    done_agents,
)
from schema import Cause, Cell, Note
from schema.tables import code_of

#: The most drones a FewEpisode plays: drone D100 would sort before D11 (rows would not be the id order).
FEW_MAX = 99
_CAUSE = {c: code_of(c) for c in Cause}
_REACHED = code_of(Note.REACHED)


def _meet(pos: list[Cell], after: dict[int, Cell], moved: list[int]) -> bool:
    """Whether two drones end in one cell or two movers swap cells (from `pos` to `after`; `moved`: the rows
    whose cell changes): whether the observer could find a collision."""
    entering = {after[i]: i for i in moved}  # (used only if every drone ends in a cell of its own)
    return len(set(after.values())) < len(after) \
        or any(pos[j] == after[i] for i in moved if (j := entering.get(pos[i])) is not None)


class FewEpisode(EpisodeBase):
    """`Episode`'s surface over Python lists, for up to FEW_MAX drones: their rows (drone number - 1) are then
    the id order (the observer's priority order). The columns (arrays) are made from the lists at each read."""

    def __init__(self, config: Config, layout: Layout, max_cycles: int, eyes: Eyes | None = None) -> None:
        n = config.num_drones
        if n > FEW_MAX:
            raise ValueError(f"a FewEpisode plays up to {FEW_MAX} drones, not {n}")
        super().__init__(config, layout, max_cycles, eyes)
        self._pos: list[Cell] = list(map(tuple, layout.starts.tolist()))
        self._targets: list[Cell] = list(map(tuple, layout.targets.tolist()))
        self._state = [ALIVE] * n
        self._cause = [0] * n
        self._shown = [NONE_NOTE] * n  # each drone's note as the last STATUS says it (REACHED on its target)
        self._on = [False] * n  # an acting row was on its target at the last turn (its arrival is rewarded)
        self._acting = [True] * n
        self._rows = list(range(n))  # the rows acting, ascending
        self._alive = list(range(n))  # the rows alive, ascending
        self._say = [NONE_NOTE if r else UNREACHABLE_NOTE for r in layout.reachable.tolist()]  # notes to the engine
        self._shown = self._say[:]  # (an unreachable target is noted at the start: as it will be said)
        self.left = n
        self._finish, self._new = config.on_target == "finish", config.on_target == "new"
        self._solid = self.world.grid.tobytes()  # a building cell: solid[(x * ny + y) * nz + z] == 1

    # ------------------------------------------------------------------ columns (as Episode's)

    @property
    def pos(self) -> np.ndarray:
        return np.array(self._pos, np.int32).reshape(self.n, 3)

    @property
    def state(self) -> np.ndarray:
        return np.array(self._state, np.uint8)

    @property
    def targets(self) -> np.ndarray:
        return np.array(self._targets, np.int32).reshape(self.n, 3)

    @property
    def acting(self) -> np.ndarray:
        return np.array(self._acting, bool)

    # ------------------------------------------------------------------ reading

    def observe(self, rows) -> list[np.ndarray] | np.ndarray:
        pos, targets, alive = self._pos, self._targets, self._alive
        rows = list(rows)
        if len(rows) == self.n:  # (every row: the lists themselves)
            return self.eyes.see_few(pos, targets, pos if len(alive) == self.n else [pos[i] for i in alive])
        return self.eyes.see_few([pos[i] for i in rows], [targets[i] for i in rows], [pos[i] for i in alive])

    def infos(self, rows) -> list[dict]:
        """As `Episode.infos`."""
        pos, targets, shown, state, cause = self._pos, self._targets, self._shown, self._state, self._cause
        return [{"cell": pos[i], "target": targets[i], "note": NOTE_TEXT[shown[i]], "state": STATE_TEXT[state[i]],
                 "cause": CAUSE_TEXT[cause[i]]} for i in rows]

    # ------------------------------------------------------------------ acting

    def act(self, rows: list[int], values: list) -> Outcome:
        """As `Episode.act`."""
        if not self.left:
            raise ConfigError("step() after the end of the episode: call reset()")
        acting = self._acting
        if self.left < self.n:
            done = [i for i in rows if not acting[i]]
            if done:
                raise done_agents(done)
        action = dict(zip(rows, checked_actions(rows, values, self.config.actions)))
        t = self.cycle + 1
        pos, state, say, shown = self._pos, self._state, self._say, self._shown
        # the engine's turn: every alive drone moves (the acting ones as told, hover by default; the parked ones
        # hover), the observer judges, each alive drone's note is the one it said
        (nx, ny, nz), solid = self.world.size, self._solid
        alive = self._alive
        after: dict[int, Cell] = {}
        moved, buildings, left_world = [], set(), False
        for i in alive:
            a = action.get(i, 0)
            if a:
                x, y, z = pos[i]
                dx, dy, dz = ACTIONS[a]
                cell = x, y, z = x + dx, y + dy, z + dz
                if not (0 <= x < nx and 0 <= y < ny and 0 <= z < nz):
                    left_world = True
                elif solid[(x * ny + y) * nz + z]:
                    buildings.add(cell)
                after[i] = cell
                moved.append(i)
            else:
                after[i] = pos[i]
        if left_world or buildings or _meet(pos, after, moved):
            dead = deaths(self.world.size, {i: pos[i] for i in alive}, after, buildings)
        else:  # (most turns: nobody can die, the observer's rules need not be run)
            dead = {}
        for i in moved:
            pos[i] = after[i]
        if dead:
            for i, cause in dead.items():
                state[i], self._cause[i] = DEAD, _CAUSE[cause]
            self._alive = [i for i in alive if i not in dead]
        self.cycle = t
        # the episode's rules, for the rows acting
        rows_out = self._rows
        targets, was_on, finish = self._targets, self._on, self._finish
        nothing, arrived, died = self.rewards
        rewards, terminated, arrivals = [], [], []
        for i in rows_out:
            gone = i in dead
            if gone or pos[i] != targets[i]:
                was_on[i] = False
                shown[i] = say[i]
                rewards.append(died if gone else nothing)
                terminated.append(gone)
            else:
                shown[i] = _REACHED
                if was_on[i]:
                    rewards.append(nothing)
                    terminated.append(False)
                else:
                    was_on[i] = True
                    rewards.append(arrived)
                    terminated.append(finish)
                    arrivals.append(i)
        if t >= self.max_cycles:
            truncated = [not end for end in terminated]
            stops = len(rows_out)
        else:
            truncated = [False] * len(rows_out)
            stops = terminated.count(True)
        if self._new and arrivals:
            others = np.array(targets, np.int32)
            for i in arrivals:
                new, ok = self.layout.new_target(i, np.array(pos[i], np.int32), others)
                others[i] = new
                targets[i] = int(new[0]), int(new[1]), int(new[2])
                say[i] = NONE_NOTE if ok else UNREACHABLE_NOTE
                was_on[i] = False
        if stops:
            for i, end, cut in zip(rows_out, terminated, truncated):
                if end or cut:
                    acting[i] = False
            self._rows = [i for i in rows_out if acting[i]]
            self.left -= stops
        return Outcome(rows_out, self.observe(rows_out), rewards, terminated, truncated, self.infos(rows_out))
