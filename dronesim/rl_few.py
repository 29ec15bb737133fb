"""Episodes of a few drones, drone by drone: the local backend's fast path (docs/performance.md).

An `Episode` reads and writes its columns in some 40 numpy calls a step, whose fixed cost (~0.5-1 µs each) is
the whole step when there are a few drones. `FewEpisode` keeps the episode's rules (rewards, terminations, new
targets, observations, infos) over Python lists instead, and plays each turn through the engine's own
(`Engine.play` with lists: the engine's turn over lists up to TURN_FEW_DRONES alive drones, coordinator/engine.py),
reading the cells and states the turn left back from the engine's fleet.
tests/test_pettingzoo.py holds both to the same steps on random worlds and actions (a property test).
"""

from __future__ import annotations

from operator import eq

import numpy as np

from coordinator.fleet import ALIVE
from dronesim.rl import (
    ACTIONS,
    CAUSE_TEXT,
    NONE_NOTE,
    NOTE_TEXT,
    STATE_TEXT,
    UNREACHABLE_NOTE,
    BackendError,
    Config,
    ConfigError,
    EpisodeBase,
    Eyes,
    Layout,
    LocalTurns,
    Outcome,
    checked_actions,
    done_agents,
)
from schema import Cell, Note
from schema.tables import code_of

#: The most drones a FewEpisode plays: drone D100 would sort before D11 (rows would not be the id order).
FEW_MAX = 99
_REACHED = code_of(Note.REACHED)
_tuple_new = tuple.__new__  # (a step's Outcome made without its class's `__new__`'s call: a Python frame less)


class FewEpisode(EpisodeBase):
    """`Episode`'s surface over Python lists, for up to FEW_MAX drones: their rows (drone number - 1) are then
    the id order (the observer's priority order). The columns (arrays) are made from the lists at each read."""

    def __init__(self, config: Config, layout: Layout, max_cycles: int, turns: LocalTurns,
                 eyes: Eyes | None = None) -> None:
        n = config.num_drones
        if n > FEW_MAX:
            raise ValueError(f"a FewEpisode plays up to {FEW_MAX} drones, not {n}")
        super().__init__(config, layout, max_cycles, eyes)
        self.engine = turns.few(layout, max_cycles)  # (its rows: ours, D01 ... D99; the last episode's, restarted)
        self._pos: list[Cell] = self.engine.fleet.cells()  # (the engine's fleet's: `act`)
        self._targets: list[Cell] = list(map(tuple, layout.targets.tolist()))
        self._goals = layout.targets.astype(np.intp)  # (the same, as an array: the observations' offsets)
        self._state = [ALIVE] * n
        self._cause = [0] * n
        self._on = [False] * n  # an acting row was on its target at the last turn (its arrival is rewarded)
        self._acting = [True] * n
        self._rows = list(range(n))  # the rows acting, ascending
        self._alive = list(range(n))  # the rows alive, ascending
        self._aim = list(range(n))  # the rows whose target the next turn tells the engine (all, at the first)
        self._say = [NONE_NOTE if r else UNREACHABLE_NOTE for r in layout.reachable.tolist()]  # notes to the engine
        self._shown = self._say[:]  # each drone's note as the last STATUS says it (REACHED on its target; an
        # unreachable target is noted at the start: as it will be said)
        self.left = n
        self._finish, self._new = config.on_target == "finish", config.on_target == "new"
        self._actions = config.actions  # (a property: read once)

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
        pos, alive = self._pos, self._alive
        rows = list(rows)
        if len(rows) == self.n:  # (every row: the lists themselves)
            return self.eyes.see_few(pos, self._goals, pos if len(alive) == self.n else [pos[i] for i in alive])
        # (most steps, the alive drones act: one list of their cells is `see_few`'s drones too)
        cells = [pos[i] for i in rows]
        return self.eyes.see_few(cells, self._goals[rows], cells if rows == alive else [pos[i] for i in alive])

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
        if self.left < self.n and rows != self._rows:  # (most steps, every agent acting acts: compared in C)
            done = [i for i in rows if not acting[i]]
            if done:
                raise done_agents(done)
        values = checked_actions(rows, values, self._actions)
        t = self.cycle + 1
        state, say, shown, alive = self._state, self._say, self._shown, self._alive
        # the turn, the engine's: every alive drone moves (the acting ones as told, hover by default; the parked
        # ones hover), saying whether its target is reachable
        if rows != alive:  # (most steps: every alive drone told, in row order)
            action = dict(zip(rows, values))
            values = [action.get(i, 0) for i in alive]
        notes = say if len(alive) == self.n else [say[i] for i in alive]  # (the engine reads them, keeps none)
        aim, targets = self._aim, self._targets
        # (the actions' steps: the judge's pass over them makes them cells, `Engine.play`'s offsets)
        over = self.engine.play(aim, [targets[i] for i in aim] if aim else [], alive, [ACTIONS[a] for a in values],
                                notes, offsets=True)
        self._aim = []
        # what the turn did: each drone is where the engine's fleet says (its own list of cells, read, never
        # changed here), and those it says are no longer alive died there
        fleet = self.engine.fleet  # (its rows are ours)
        self._pos = pos = fleet.cells()
        states = fleet.states()
        dead: set[int] | tuple[()] = ()  # (a set once one died: most steps none)
        if states.count(ALIVE) < len(alive):
            dead = {i for i in alive if states[i] != ALIVE}
            for i in dead:
                state[i], self._cause[i] = states[i], int(fleet.cause[i])
            self._alive = [i for i in alive if i not in dead]
        self.cycle = t
        # the episode's rules, for the rows acting
        rows_out = self._rows
        targets, was_on, finish = self._targets, self._on, self._finish
        nothing, arrived, died = self.rewards
        rewards, terminated, arrivals = [], [], []
        if not dead and len(rows_out) == self.n and not any(map(eq, pos, targets)):
            # (most steps: every drone acting and alive, none on its target: the rules below for every row at once)
            was_on[:] = [False] * self.n
            shown[:] = say
            rewards, terminated = [nothing] * self.n, [False] * self.n
        else:
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
        if over is not None and stops < len(rows_out):
            raise BackendError(f"the game ended at turn {t} ({over.reason.value}: {over.text})")
        if self._new and arrivals:
            others = self._goals  # (each new target written in it as it is drawn)
            for i in arrivals:
                new, ok = self.layout.new_target(i, np.array(pos[i], np.int32), others)
                others[i] = new
                targets[i] = int(new[0]), int(new[1]), int(new[2])
                say[i] = NONE_NOTE if ok else UNREACHABLE_NOTE
                was_on[i] = targets[i] == pos[i]  # (nowhere else to go: no new arrival)
            self._aim = arrivals
        if stops:
            for i, end, cut in zip(rows_out, terminated, truncated):
                if end or cut:
                    acting[i] = False
            self._rows = [i for i in rows_out if acting[i]]
            self.left -= stops
        seen = self.eyes.see_few(pos, self._goals, pos) if len(rows_out) == len(self._alive) == self.n else \
            self.observe(rows_out)  # (every drone acting and alive: `observe`'s lists themselves, without its call)
        return _tuple_new(Outcome, (rows_out, seen, rewards, terminated, truncated, self.infos(rows_out)))
