"""Multi-agent reinforcement learning on the game, with no RL library: the episode's rules as arrays.

`dronesim.pettingzoo` wraps this in PettingZoo's API; this module needs numpy and the project alone. An
episode is a game of the project's own engine (coordinator/engine.py), the policy playing the ground station
(the targets) and one swarm host flying every drone (their moves); each step is one turn: a DONE with the
targets that change, a MOVES with every alive drone's move, then the observer's STATUS, from which the
observations, rewards and terminations are read. Where the turn is played is the backend's business
(`Turns`): `LocalTurns` feeds the engine in this process, `dronesim.rl_zenoh` sends the same messages to
the real processes; both get the same STATUS, so an episode does not depend on the backend. The rules
(the seed's observer's, and `on_target`: "finish", "stay" or "new") are in docs/rl.md.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import logging
import math
from dataclasses import dataclass
from itertools import chain
from pathlib import Path
from typing import NamedTuple, Protocol

import numpy as np

from coordinator.config import DroneTable, GameConfig
from coordinator.engine import Engine
from coordinator.fleet import ALIVE, CAUSES, NOTES, STATES
from coordinator.stages import Stage
from entities.autopilots import COOPERATIVE
from schema import (
    AimTable,
    Cell,
    Connect,
    Done,
    Intent,
    Moves,
    Note,
    Over,
    Phase,
    Role,
    Status,
    StepTable,
    UsageError,
    WorldSpec,
)
from schema.messages import AROUND
from schema.tables import MAX_DRONE, code_of, drone_name
from schema.tuning import EYES_CUBE_GATHER, EYES_ONE_BY_ONE, PHASE_DEADLINE_S, RL_WAIT_S
from world.grid import Regions, World, checked_int, inside_rows, pick_cell

#: The actions: hover, then one cell along +x, -x, +y, -y, +z, -z (the engine's 6-connectivity).
ACTIONS: tuple[Cell, ...] = ((0, 0, 0), *AROUND)
#: On a world one cell high (a MovingAI map), the first five alone: hover, +x, -x, +y, -y (POGEMA's five;
#: ±z would only leave the world).
FLAT_ACTIONS = 5
_DELTAS = np.array(ACTIONS, np.int32)
#: What happens when a drone reaches its target (docs/rl.md).
ON_TARGET = ("finish", "stay", "new")
BACKENDS = ("local", "zenoh")
RENDER_MODES = ("human", "ansi", "rgb_array")
#: The swarm host that flies every drone of an episode (the policy).
HOST = "H01"
#: The name the swarm host gives as its autopilot (journaled in the header).
PILOT = "policy"
#: The note codes an episode tells the engine (its drones' targets reachable or not).
UNREACHABLE_NOTE, NONE_NOTE = code_of(Note.UNREACHABLE), code_of(Note.NONE)
_NO_AIMS = AimTable(AimTable.empty(0))  # a DONE that changes no target
_NO_ROWS, _NO_CELLS = np.zeros(0, np.intp), np.zeros((0, 3), np.int32)  # (read-only: nothing to hold)
_NO_ROWS.flags.writeable = _NO_CELLS.flags.writeable = False


class Seen(enum.IntEnum):
    """What an observation says of a cell around the drone."""

    FREE = 0
    BUILDING = 1
    DRONE = 2  # another alive drone (a finished one parked on its target too)
    OUTSIDE = 3  # beyond the world's bounds
    UNKNOWN = 4  # in the observation's cube but beyond the radius (a sphere): not sensed


_FREE, _DRONE, _UNKNOWN = int(Seen.FREE), int(Seen.DRONE), int(Seen.UNKNOWN)  # (an enum's member is slow to get)


class ConfigError(UsageError, ValueError):
    """A bad configuration or call: an unknown key, a value out of range, a world too small for the drones,
    an action outside the space, a step after the end."""


class BackendError(RuntimeError):
    """The backend cannot play the turn: a process of the game died, or it did not answer in time."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Config:
    """An environment's configuration: `Config.of(**keywords)` checks every key and value."""

    num_drones: int = 8
    size: Cell = (16, 16, 8)  # a generated world's size (with `seed`)
    seed: int = 0  # the first episode's seed (worlds, starts, targets); reset(seed=...) overrides it
    world: World | None = None  # a given world (a `World`, a world file's or a MovingAI .map's path) instead
    max_cycles: int = 128  # steps before every agent still acting is truncated
    obs_radius: int = 2  # cells sensed within this Euclidean distance, in a cube of side 2 r + 1
    on_target: str = "finish"
    reward_target: float = 1.0
    reward_death: float = -1.0
    step_cost: float = 0.0  # subtracted from every acting agent's reward at every step
    render_mode: str | None = None
    backend: str = "local"
    connect: str | None = None  # zenoh backend: a router's endpoint to join (default: start one in-process)
    deadline: float = RL_WAIT_S  # zenoh backend: seconds any wait may last (start of a game, a turn, the end)

    @classmethod
    def of(cls, **config: object) -> Config:
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(config) - set(names))
        if unknown:
            raise ConfigError(f"unknown configuration key(s) {', '.join(unknown)}; the keys are {', '.join(names)}")
        world = config.get("world")
        if isinstance(world, (str, Path)):
            try:
                config["world"] = World.load(world)
            except UsageError as err:
                raise ConfigError(str(err)) from None
        if world is not None and "size" in config:
            raise ConfigError("give a world or a size, not both (a world has its own size)")
        return cls(**config)  # type: ignore[arg-type]

    @property
    def actions(self) -> int:
        """How many actions the agents have: `FLAT_ACTIONS` on a world one cell high, else all of `ACTIONS`."""
        return FLAT_ACTIONS if self.size[2] == 1 else len(ACTIONS)

    def __post_init__(self) -> None:
        n = int_in(self.num_drones, "num_drones", 1, MAX_DRONE)
        if self.world is not None and not isinstance(self.world, World):
            raise ConfigError(f"world must be a World or a world file's path, got {self.world!r}")
        given: object = self.world.size if self.world is not None else self.size
        try:
            size = tuple(checked_int(v, "size", ConfigError) for v in given)  # type: ignore[attr-defined]
        except TypeError:
            raise ConfigError(f"size must be 3 integers (nx, ny, nz), got {self.size!r}") from None
        if len(size) != 3 or min(size) < 1 or max(size) > 65536:
            raise ConfigError(f"size must be 3 integers in 1..65536, got {self.size!r}")
        object.__setattr__(self, "size", size)
        cells = math.prod(size) if self.world is None else int(np.count_nonzero(~self.world.grid))
        if cells < 2 * n:
            raise ConfigError(f"the world has {cells} free cells, too few for {n} drones (a start and a target each)")
        int_in(self.seed, "seed", 0)
        int_in(self.max_cycles, "max_cycles", 1)
        int_in(self.obs_radius, "obs_radius", 0, 8)
        for name in ("reward_target", "reward_death", "step_cost"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(value):
                raise ConfigError(f"{name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        _choice(self.on_target, ON_TARGET, "on_target")
        _choice(self.backend, BACKENDS, "backend")
        if self.render_mode is not None:
            _choice(self.render_mode, RENDER_MODES, "render_mode")
        if self.connect is not None and (self.backend != "zenoh" or not isinstance(self.connect, str)):
            raise ConfigError("connect (a router's endpoint, e.g. tcp/127.0.0.1:7447) is for backend='zenoh'")
        if isinstance(self.deadline, bool) or not isinstance(self.deadline, (int, float)) or not self.deadline > 0:
            raise ConfigError(f"deadline must be a positive number of seconds, got {self.deadline!r}")


def int_in(value: object, name: str, low: int, high: int | None = None) -> int:
    """`value` as an int in low..high (None: no bound above); ConfigError if it is not."""
    v = checked_int(value, name, ConfigError)
    if v < low or high is not None and v > high:
        raise ConfigError(f"{name} must be {f'>= {low}' if high is None else f'in {low}..{high}'}, got {value}")
    return v


def _choice(value: object, choices: tuple[str, ...], what: str) -> None:
    if value not in choices:
        raise ConfigError(f"{what} must be one of {', '.join(map(repr, choices))}, got {value!r}")


# --------------------------------------------------------------------------- an episode's layout


def clear_cells(grid: np.ndarray) -> np.ndarray:
    """Which cells are free with the neighbours an agent's actions reach free and inside the world (bool, the
    grid's shape): the 6 neighbours, or on a world one cell high the 4 of its floor (`FLAT_ACTIONS`)."""
    free = np.pad(~grid, 1)
    clear = free[1:-1, 1:-1, 1:-1].copy()
    for axis in range(3 if grid.shape[2] > 1 else 2):
        for shift in (1, -1):
            clear &= np.roll(free, shift, axis=axis)[1:-1, 1:-1, 1:-1]
    return clear


class Terrain(Regions):
    """What drawing an episode's layout needs of its world, computed once per world (an environment keeps it
    while its episodes share a world, a given one): the free cells, the clear ones (`clear_cells`), the packed
    grid, and the components of the free cells reached from the starts so far, with each one's cells
    (`Regions`)."""

    def __init__(self, world: World) -> None:
        super().__init__(world)
        self.free = np.flatnonzero(~world.grid.ravel())
        self.clear_mask = clear_cells(world.grid).ravel()
        self.clear = np.flatnonzero(self.clear_mask)
        self.spec = WorldSpec(size=world.size, cells=world.packed())  # the world as every backend's game gives it

    def fits(self, world: World) -> bool:
        return world is self.world or world == self.world


@dataclass(frozen=True, slots=True)
class Layout:
    """One episode's world, starts and first targets, and the generator that draws its later targets."""

    world: World
    starts: np.ndarray  # (n, 3) int32, drone i + 1's start
    targets: np.ndarray  # (n, 3) int32
    reachable: np.ndarray  # (n,) bool: the target is in the start's component
    terrain: Terrain
    comp: np.ndarray  # (n,) each start's component (`Terrain.label`)
    rng: np.random.Generator
    clear: np.ndarray  # (n,) bool: the start is clear (`clear_cells`: no action kills at the first step)

    @classmethod
    def draw(cls, config: Config, seed: int, terrain: Terrain | None = None) -> Layout:
        """The layout of an episode (docs/rl.md, "Layout and seeds"): starts among the clear cells, where there are
        fewer than the drones every clear cell and the others among the free cells; each target a free cell of
        its start's component that no start or other target holds, or if none is left any such free cell, and
        unreachable. `terrain`: the world's, if the caller has it (an environment's previous episode)."""
        rng = np.random.default_rng(seed)
        world = config.world if config.world is not None else World.generate(config.size, rng, keep_free=())
        if terrain is None or not terrain.fits(world):
            terrain = Terrain(world)
        n = config.num_drones
        free, clear = terrain.free, terrain.clear
        if len(free) < 2 * n:
            raise ConfigError(f"the world of seed {seed} has {len(free)} free cells, too few for {n} drones "
                              "(a start and a target each)")
        if len(clear) >= n:  # room around: no death at the first move
            start_lin = clear[(rng.random(n) * len(clear)).astype(np.intp)]
            if n > 1 and len(np.unique(start_lin)) < n:  # (two drones drew one cell: draw them all without it)
                start_lin = rng.choice(clear, n, replace=False)
        else:  # every clear cell, then free ones (`clear` says which starts are clear)
            rest = rng.choice(np.flatnonzero(~world.grid.ravel() & ~terrain.clear_mask), n - len(clear),
                              replace=False)
            start_lin = rng.permutation(np.concatenate([clear, rest]))
        starts = np.array(np.unravel_index(start_lin, world.size), np.int32).T.copy()  # (n, 3), C order
        comp = terrain.labels(start_lin, starts)
        taken = np.zeros(world.grid.size, bool)
        taken[start_lin] = True
        targets = np.empty((n, 3), np.int32)
        reachable = np.ones(n, bool)
        nx, ny, nz = world.size
        for i, c in enumerate(comp.tolist()):
            cell = pick_cell(rng, terrain.members(c), taken)
            if cell < 0:
                cell, reachable[i] = pick_cell(rng, free, taken), False  # any free cell: unreachable
            taken[cell] = True
            targets[i] = cell // (ny * nz), cell // nz % ny, cell % nz
        return cls(world=world, starts=starts, targets=targets, reachable=reachable, terrain=terrain, comp=comp,
                   rng=rng, clear=terrain.clear_mask[start_lin])

    def new_target(self, i: int, here: np.ndarray, others: np.ndarray) -> tuple[np.ndarray, bool]:
        """A new target for drone row `i` at `here` (the lifelong variant): a free cell of its start's
        component other than `here` and the other targets (`others`, (n, 3)), drawn from the episode's
        generator; (the cell, whether it is reachable)."""
        size, comp = self.world.size, int(self.comp[i])
        cells = self.terrain.members(comp)
        used = {tuple(c) for c in others.tolist()} | {tuple(here.tolist())}
        label = self.terrain.label
        # a free cell is left if its component has more cells than every used cell (the usual case, at once), else
        # than its own used cells (counted only then: a drone's arrival in a swarm's step costs no pass over all)
        if len(cells) > len(used) or len(cells) > sum(
                1 for c in used if all(0 <= v < n for v, n in zip(c, size))
                and label[np.ravel_multi_index(c, size)] == comp):
            while True:
                cell = np.array(np.unravel_index(int(cells[self.rng.integers(len(cells))]), size), np.int32)
                if tuple(cell.tolist()) not in used:
                    return cell, True
        return self.targets[i].copy(), bool(self.reachable[i])  # nowhere else to go: the same target

    def game(self, max_turns: int, phase_deadline: float = PHASE_DEADLINE_S) -> GameConfig:
        """The engine's game for this layout (the world given cell by cell: every backend builds the same)."""
        drones = DroneTable(drone_names(len(self.starts)), self.starts)
        return GameConfig(world=self.terrain.spec, drones=drones, max_turns=max_turns, phase_deadline=phase_deadline)


@functools.lru_cache(maxsize=8)
def drone_names(n: int) -> tuple[str, ...]:
    """The ids of an episode's drones, D01 ... (the same at every reset: made once)."""
    return tuple(drone_name(i) for i in range(1, n + 1))


# --------------------------------------------------------------------------- backends


class Board(NamedTuple):
    """Every drone's state after a turn as the observer's STATUS says it, row i for drone i + 1: its cell
    ((n, 3) int32), state, note (REACHED on its target) and cause of death (fleet codes, uint8). (A named
    tuple: made at every step, where a frozen dataclass costs three times as much.)"""

    pos: np.ndarray
    state: np.ndarray
    note: np.ndarray
    cause: np.ndarray

    @classmethod
    def of_status(cls, status: Status, n: int) -> Board:
        """The board a STATUS of `n` drones D01..Dn says (its rows are in id text order: D10 < D100 < D11)."""
        rows = status.drones.rows
        if len(rows) != n:
            raise BackendError(f"the STATUS of turn {status.turn} holds {len(rows)} drones, not {n}")
        rows = rows[np.argsort(rows["drone"], kind="stable")]
        if not np.array_equal(rows["drone"], np.arange(1, n + 1)):
            raise BackendError("the STATUS does not hold this episode's drones")
        return cls(rows["pos"].astype(np.int32), *(rows[k].copy() for k in ("state", "note", "cause")))


class Turns(Protocol):
    """Where an episode's turns are played (rows are drone number - 1): `start` a game (ending any running
    one: the board of turn 0), `play` its turns, `stop` it (the ground station quits), `close` the backend."""

    def start(self, game: GameConfig, world: World) -> Board: ...

    def play(self, turn: int, aim_rows: np.ndarray, aims: np.ndarray, move_rows: np.ndarray, moves: np.ndarray,
             notes: np.ndarray) -> tuple[Board, Over | None]:
        """Turn `turn`: the ground station sets the targets `aims` of `aim_rows`, then the swarm host moves
        `move_rows` (every alive drone, ascending) to `moves` with `notes` (Note codes); the turn's board and,
        if the game ended with it, the OVER."""

    def stop(self) -> None: ...

    def close(self) -> None: ...


def hellos(game: GameConfig, session: str = "") -> tuple[Connect, ...]:
    """The ground station's and the swarm host's CONNECT (the policy plays both)."""
    drones = tuple(sorted((d.drone for d in game.drones), key=lambda d: int(d[1:])))
    return (Connect(turn=0, sender="GCS", role=Role.GCS, session=session),
            Connect(turn=0, sender=HOST, role=Role.DRONE, drones=drones, autopilot=PILOT, session=session))


def turn_messages(turn: int, aim_rows: np.ndarray, aims: np.ndarray, move_rows: np.ndarray, moves: np.ndarray,
                  notes: np.ndarray) -> tuple[Done, Moves | None]:
    """A turn's messages (see `Turns.play`): the ground station's DONE carrying the targets, the host's MOVES
    (None: no drone alive)."""
    targets = AimTable.build(drone=aim_rows + 1, pos=aims) if len(aim_rows) else _NO_AIMS
    done = Done(turn=turn, sender="GCS", phase=Phase.GCS, intent=Intent.CONTINUE, targets=targets)
    if not len(move_rows):
        return done, None
    steps = StepTable.build(drone=(move_rows + 1).astype(np.uint16), pos=moves, note=notes)
    return done, Moves(turn=turn, sender=HOST, moves=steps)


def local_game(game: GameConfig, world: World, logger: logging.Logger) -> Engine:
    """The engine of an episode's game in this process, started (`Engine.start_here`: the policy is its ground
    station and the host flying every drone, the engine judges the moves from its own copy of the world, as the
    coordinator does), without a journal."""
    engine = Engine(game, logger, world)
    engine.verify_env = engine.journaled = engine.env_followed = False
    engine.start_here(HOST, PILOT)
    return engine


#: A game's fields but its drones (`LocalTurns._same`).
_GAME_BUT_DRONES = tuple(f.name for f in dataclasses.fields(GameConfig) if f.name != "drones")


class LocalTurns:
    """The engine in this process, its turns played from arrays (`Engine.play`: the same turn as from the
    messages the processes would send, none of them built) and read from its fleet. No environment process:
    the engine judges the moves from its own copy of the world, as the coordinator does."""

    def __init__(self) -> None:
        # Deaths are the engine's warnings, and an episode's everyday business: only its errors are said.
        self.log = logging.Logger("dronesim.rl.engine", logging.ERROR)
        self.engine: Engine | None = None
        self._rows: np.ndarray | None = None  # the engine's row of each of ours (None: the same)

    def start(self, game: GameConfig, world: World) -> Board:
        engine = self.engine
        if engine is not None and self._same(engine, world, game):  # (the last episode's game again: restarted)
            starts = np.array([d.start for d in game.drones], np.int32).reshape(-1, 3)  # (ours: D1, D2, ...)
            if self._rows is not None:  # (the engine's rows: in id text order)
                starts[self._rows] = starts.copy()
            engine.restart(starts)
        else:
            engine = local_game(game, world, self.log)
        fleet = engine.fleet
        rows = fleet.row_of_number[1:len(fleet) + 1].astype(np.intp)  # engine rows are in id text order
        self._rows = None if np.array_equal(rows, np.arange(len(fleet))) else rows
        self.engine = engine
        return self._board()

    def few(self, layout: Layout, max_turns: int) -> Engine:
        """The engine of an episode of up to FEW_MAX drones (dronesim/rl_few.py; its rows, D01 ... D99, are ours):
        the last episode's restarted (`Engine.restart`) when it played the same world, drones and turn limit, else
        a new one."""
        engine = self.engine
        config = None if engine is None else engine.config
        if config is None or engine is None or engine.world is not layout.world or \
                len(engine.fleet) != len(layout.starts) or config.max_turns != max_turns or \
                config.phase_deadline != PHASE_DEADLINE_S:
            engine = self.engine = local_game(layout.game(max_turns), layout.world, self.log)
        else:
            engine.restart(layout.starts)
        self._rows = None
        return engine

    @staticmethod
    def _same(engine: Engine, world: World, game: GameConfig) -> bool:
        """Whether `engine` plays `game` in `world` but for its drones' starts (restarted, it plays it)."""
        theirs = engine.config
        return engine.world is world and all(getattr(game, f) == getattr(theirs, f) for f in _GAME_BUT_DRONES) \
            and tuple(d.drone for d in game.drones) == tuple(d.drone for d in theirs.drones)

    def _board(self) -> Board:
        """The fleet's columns (in our row order): with the engine's order ours, its columns themselves, valid
        until the next turn changes them (the episode reads a board before it plays the next turn)."""
        fleet, rows = self.engine.fleet, self._rows  # type: ignore[union-attr]
        board = Board(fleet.pos, fleet.state, fleet.notes(), fleet.cause)
        return board if rows is None else Board(*(column[rows] for column in board))

    def play(self, turn: int, aim_rows: np.ndarray, aims: np.ndarray, move_rows: np.ndarray, moves: np.ndarray,
             notes: np.ndarray) -> tuple[Board, Over | None]:
        engine = self.engine
        if engine is None or engine.stage is Stage.OVER:
            raise BackendError("no game is running")
        if engine.turn != turn:
            raise BackendError(f"turn {turn} cannot be played: the game is at turn {engine.turn}")
        rows = self._rows
        if rows is not None:
            aim_rows, move_rows = rows[aim_rows], rows[move_rows]
        try:
            over = engine.play(aim_rows, aims, move_rows, moves, notes)
        except UsageError as err:  # our own input: a bug, never the policy's doing
            raise BackendError(f"the engine refused turn {turn}: {err}") from err
        return self._board(), over

    def stop(self) -> None:
        self.engine = None

    close = stop


# --------------------------------------------------------------------------- observations and rendering


class Eyes:
    """Each drone's observation: the cells of the cube of side 2 r + 1 around it (in C order of the offsets
    (dx, dy, dz), each -r..r), those beyond the radius UNKNOWN, its own cell FREE; then the offset from it
    to its target (dx, dy, dz)."""

    def __init__(self, world: World, radius: int) -> None:
        self.radius = r = radius
        pad = r + 1  # a dead drone may stand one cell outside the world
        static = np.pad(np.where(world.grid, Seen.BUILDING, Seen.FREE).astype(np.int32), pad,
                        constant_values=Seen.OUTSIDE)
        # the padded world flat, as the observations' codes, after a FREE cell and before an UNKNOWN one: one gather
        # (`np.take`, indices clipped to the ends) reads a whole observation, the cells beyond the radius UNKNOWN
        # (the last), the drone's own FREE (the first) and the target's offset's three UNKNOWN till written
        self._flat = np.concatenate([[_FREE], static.ravel(), [_UNKNOWN]]).astype(np.int32)
        self._items = self._flat.data  # (the same, item by item: `see_few`)
        self._sx, self._sy = static.shape[1] * static.shape[2], static.shape[2]
        self._strides = np.array([self._sx, self._sy, 1], np.int64)
        self._origin = (self._sx + self._sy + 1) * pad + 1  # where the world's cell (0, 0, 0) is
        span = np.arange(-r, r + 1)
        cube = np.stack(np.meshgrid(span, span, span, indexing="ij"), axis=-1).reshape(-1, 3)
        self.cells = len(cube)
        ball = np.flatnonzero((cube ** 2).sum(axis=1) <= r * r)  # the cells of the cube sensed
        far = 1 << 40  # (beyond either end of the flat world from any cell: clipped to it)
        # each cell of an observation, from the cube's first cell (`_shift` before the drone's): a gather from a
        # slice of the flat world that starts there (no index array added to: a slice costs less than an addition)
        self._shift = r * (self._sx + self._sy + 1)
        self._index = np.full(self.cells + 3, far, np.int64)
        self._index[ball] = cube[ball] @ self._strides + self._shift  # (the drone's own cell: `_shift`, FREE or
        # marked a drone by `see_few`, which writes FREE there then)
        # (many drones: a gather of their sensed cells alone, placed in rows of UNKNOWN: a gather of the cube's every
        # cell, clipped, costs more per drone)
        self._ball, self._offsets, self._centre = ball, (cube[ball] @ self._strides).astype(np.intp), self.cells // 2
        self._blank = np.full((0, self.cells + 3), _UNKNOWN, np.int32)  # rows to start observations from
        self.world = world

    def fits(self, world: World, radius: int) -> bool:
        """Whether these eyes see `world` with `radius` (an episode reuses its predecessor's when they do)."""
        return radius == self.radius and (world is self.world or world == self.world)

    @staticmethod
    def bounds_for(size: Cell, radius: int) -> tuple[np.ndarray, np.ndarray]:
        """The observation space's bounds (low, high) in a world of `size` with `radius`: a cell's code, then
        an offset per axis (a dead drone may stand one cell outside the world: up to the size itself)."""
        cells = (2 * radius + 1) ** 3
        extent = np.array(size, np.int32)
        return (np.concatenate([np.zeros(cells, np.int32), -extent]),
                np.concatenate([np.full(cells, max(Seen), np.int32), extent]))

    def see(self, pos: np.ndarray, targets: np.ndarray, drones: np.ndarray | None = None) -> np.ndarray:
        """The observations ((m, cells + 3) int32) of drones at `pos` ((m, 3)) with `targets`, among the
        alive drones at `drones` ((k, 3), inside the world; None: the drones at `pos`, all alive). One gather
        of every drone's observation from the padded world, with the drones marked in it for the while."""
        cells = self._flat
        base = pos @ self._strides + self._origin
        at = base if drones is None else drones @ self._strides + self._origin
        cells[at] = _DRONE
        try:
            window = cells[base[:, None] + self._offsets]
        finally:
            cells[at] = _FREE  # an alive drone's cell is free in the static world
        return self._rows(window, targets - pos)

    def _rows(self, window: np.ndarray, offsets: np.ndarray | list[Cell]) -> np.ndarray:
        """Observations from each drone's sensed cells (`window`, (m, the ball's cells)) and target offsets."""
        m, n = len(window), self.cells
        if len(self._blank) < m:
            self._blank = np.full((m, n + 3), _UNKNOWN, np.int32)
        out = self._blank[:m].copy()  # UNKNOWN beyond the radius
        out[:, self._ball] = window
        out[:, self._centre] = _FREE
        out[:, n:] = offsets
        return out

    def see_few(self, pos: list[Cell], targets: np.ndarray, drones: list[Cell]) -> list[np.ndarray] | np.ndarray:
        """`see` of drones given as cells (lists of (x, y, z)), with fewer array operations: for up to
        EYES_ONE_BY_ONE drones, their observations one by one (a list of arrays), else as `see`'s rows, in one
        gather (of each drone's whole cube up to EYES_CUBE_GATHER drones, of the sensed cells alone above).
        `targets`: the drones' targets, (m, 3) intp (an array: its offsets are one subtraction, where a list of
        tuples would be converted item by item)."""
        if len(pos) <= EYES_ONE_BY_ONE:
            return self._one_by_one(pos, targets, drones)
        cells, o, n = self._flat, self._origin, self.cells
        here = cells_array(pos)
        base = here @ self._strides + o
        at = base if drones is pos else cells_array(drones) @ self._strides + o
        cells[at] = _DRONE  # the drones marked in the world for the while
        try:
            if len(pos) > EYES_CUBE_GATHER:  # their sensed cells in one gather, placed in rows of UNKNOWN (`see`'s)
                return self._rows(cells[base[:, None] + self._offsets], targets - here)
            # every observation in one gather, as a lone one's (the cube's every cell, clipped: beyond, UNKNOWN)
            rows = cells.take((base - self._shift)[:, None] + self._index, mode="clip")
        finally:
            cells[at] = _FREE  # an alive drone's cell is free in the static world
        rows[:, n // 2] = _FREE  # (its own cell: marked, or where it died)
        rows[:, n:] = targets - here
        return rows

    def _one_by_one(self, pos: list[Cell], targets: np.ndarray, drones: list[Cell]) -> list[np.ndarray]:
        """`see_few`'s observations of up to EYES_ONE_BY_ONE drones, one by one (a list of arrays)."""
        cells, sx, sy, o = self._flat, self._sx, self._sy, self._origin
        # the drones marked in the world for the while (a lone drone that sees itself: its own cell reads FREE), item
        # by item through a memoryview (a numpy item costs ~3 times as much)
        alone = len(drones) == 1 and pos == drones
        at = [] if alone else [x * sx + y * sy + z + o for x, y, z in drones]
        items = self._items
        for k in at:
            items[k] = _DRONE
        try:
            index, n, first = self._index, self.cells, o - self._shift
            out = []
            for (x, y, z), (a, b, c) in zip(pos, targets.tolist()):
                one = cells[x * sx + y * sy + z + first:].take(index, mode="clip")  # (beyond: the last, UNKNOWN)
                one[n], one[n + 1], one[n + 2] = a - x, b - y, c - z  # (three items: half a slice's cost)
                if not alone:  # (its own cell: marked, or where it died; a lone alive drone's reads FREE)
                    one[n // 2] = _FREE
                out.append(one)
            return out
        finally:
            for k in at:
                items[k] = _FREE  # an alive drone's cell is free in the static world


def cells_array(cells: list[Cell]) -> np.ndarray:
    """Cells ((x, y, z) tuples) as an (n, 3) intp array, read from their items in one pass (~2.5 times cheaper than
    `np.array` of the tuples, which numpy parses one by one)."""
    return np.fromiter(chain.from_iterable(cells), np.intp, 3 * len(cells)).reshape(-1, 3)


#: rgb_array colours.
_FREE_RGB, _BUILDING_RGB, _GRID_RGB, _TARGET_RGB = (245, 245, 245), (90, 90, 100), (200, 200, 200), (240, 180, 0)


def drone_colours(n: int) -> np.ndarray:
    """A distinct-ish colour per drone (golden-angle hues), (n, 3) uint8."""
    hue = (np.arange(n) * 0.618033988749895) % 1.0
    k = (np.array([5.0, 3.0, 1.0])[None, :] + hue[:, None] * 6) % 6
    rgb = 1 - np.clip(np.minimum(k, 4 - k), 0, 1) * 0.85
    return (rgb * 200).astype(np.uint8)


def floors_image(world: World, drones: np.ndarray, colours: np.ndarray, targets: np.ndarray,
                 max_pixels: int = 1024) -> np.ndarray:
    """The world floor by floor as an image (H, W, 3) uint8: floors side by side in a grid of panels
    (z = 0 top-left, rows of panels left to right), one square of pixels per cell, row = x and column = y
    as in the text drawing; buildings dark, targets gold, each drone its colour (`colours`, one row each)."""
    nx, ny, nz = world.size
    across = math.ceil(math.sqrt(nz))
    down = math.ceil(nz / across)
    scale = max(1, min(16, max_pixels // max(across * (ny + 1), down * (nx + 1))))
    image = np.full((down * (nx + 1) * scale + scale, across * (ny + 1) * scale + scale, 3), _GRID_RGB, np.uint8)
    for z in range(nz):
        floor = np.full((nx, ny, 3), _FREE_RGB, np.uint8)
        floor[world.grid[:, :, z]] = _BUILDING_RGB
        for cells, colour in ((targets, None), (drones, colours)):
            on = (cells[:, 2] == z) & inside_rows(cells, world.size) if len(cells) else np.zeros(0, bool)
            floor[cells[on, 0], cells[on, 1]] = _TARGET_RGB if colour is None else colour[on]
        r0 = (z // across) * (nx + 1) * scale + scale
        c0 = (z % across) * (ny + 1) * scale + scale
        image[r0:r0 + nx * scale, c0:c0 + ny * scale] = np.repeat(np.repeat(floor, scale, 0), scale, 1)
    return image


# --------------------------------------------------------------------------- the episode


class Outcome(NamedTuple):
    """One step's result for the rows that acted (rows: drone number - 1, ascending)."""

    rows: list[int]
    observations: np.ndarray | list[np.ndarray]  # (m, cells + 3) int32, or m such rows
    rewards: list[float]
    terminated: list[bool]
    truncated: list[bool]
    infos: list[dict]


class EpisodeBase:
    """What `Episode` and `FewEpisode` share: the configuration, the eyes, the step's rewards, the end and the
    drawings, from the world and the columns `pos`, `state`, `targets`, `acting` (`columns`)."""

    left: int  # the rows still acting

    def __init__(self, config: Config, layout: Layout, max_cycles: int, eyes: Eyes | None) -> None:
        self.config, self.layout, self.max_cycles = config, layout, max_cycles
        self.world = layout.world
        self.eyes = eyes if eyes is not None and eyes.fits(self.world, config.obs_radius) \
            else Eyes(self.world, config.obs_radius)
        self.n = config.num_drones
        self.cycle = 0
        # a step's reward by (arrived, dead): nothing, arrived, dead (each a sum, as written: 0.0 - 0.0 is not -0.0)
        cost = config.step_cost
        self.rewards = (0.0 + 0.0 - cost, config.reward_target + 0.0 - cost, 0.0 + config.reward_death - cost)

    @property
    def ended(self) -> bool:
        return not self.left

    def columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every drone's cell ((n, 3) int32), state (uint8), target ((n, 3) int32) and whether it acts (bool)."""
        return self.pos, self.state, self.targets, self.acting  # type: ignore[attr-defined]

    def ansi(self) -> str:
        pos, state, targets_, acting_ = self.columns()
        alive = np.flatnonzero(state == ALIVE)
        drones = dict(zip((drone_name(i + 1) for i in alive.tolist()), map(tuple, pos[alive].tolist())))
        acting = np.flatnonzero(acting_)
        targets = dict(zip((drone_name(i + 1) for i in acting.tolist()), map(tuple, targets_[acting].tolist())))
        head = f"turn {self.cycle}: {len(acting)} acting, {len(alive)} alive of {self.n}"
        return head + "\n\n" + self.world.draw(drones, targets=targets)

    def state_grid(self) -> np.ndarray:
        """The world as observation codes (nx, ny, nz) int8: FREE, BUILDING, and DRONE where an alive drone is."""
        grid = np.where(self.world.grid, Seen.BUILDING, Seen.FREE).astype(np.int8)
        pos, state, _, _ = self.columns()
        alive = pos[state == ALIVE]
        grid[tuple(alive.T)] = Seen.DRONE
        return grid

    def rgb(self) -> np.ndarray:
        pos, state, targets, acting = self.columns()
        alive = state == ALIVE
        return floors_image(self.world, pos[alive], drone_colours(self.n)[alive], targets[acting])


def done_agents(rows: list[int]) -> ConfigError:
    return ConfigError("actions for agents that are done: " + ", ".join(f"drone_{r + 1}" for r in rows))


class Episode(EpisodeBase):
    """One episode's state and rules over a backend's turns; rows are drone number - 1."""

    def __init__(self, config: Config, layout: Layout, turns: Turns, max_cycles: int, eyes: Eyes | None = None) -> None:
        super().__init__(config, layout, max_cycles, eyes)
        self.turns, n = turns, self.n
        self.targets = layout.targets.copy()
        self.reachable = layout.reachable.copy()
        self.over: Over | None = None
        board = turns.start(layout.game(max_cycles, phase_deadline=config.deadline), self.world)
        self.pos, self.state, self.note, self.cause = board  # (the fleet's columns, as the STATUS says them)
        if not (self.state == ALIVE).all():
            raise BackendError("a drone was not alive at the start")
        self.acting = np.ones(n, bool)  # rows still acting (PettingZoo's agents)
        self.left = n  # how many
        #: Every row acting and alive (no agent has ended yet): the step then needs no row selection.
        self.everyone = True
        self._all = np.arange(n)
        self._rows_all = list(range(n))  # (read-only)
        self.on = np.zeros(n, bool)  # rows on their target at the last STATUS
        self.aim_next = self._all  # rows whose target the next DONE carries (all, at turn 1)
        self._say = self._notes()  # each row's note to the engine (whether its target is reachable)
        self.note = np.where(layout.reachable, self.note, UNREACHABLE_NOTE).astype(np.uint8)  # (as said at turn 1)
        self._reward = np.array(self.rewards, np.float64)

    def _notes(self) -> np.ndarray:
        return np.where(self.reachable, NONE_NOTE, UNREACHABLE_NOTE).astype(np.uint8)

    # ------------------------------------------------------------------ reading

    def observe(self, rows: np.ndarray | range, whole: bool = True) -> np.ndarray:
        """The observations of `rows`; `whole`: whether they are every drone, all alive (as at the start)."""
        if whole:
            return self.eyes.see(self.pos, self.targets)
        return self.eyes.see(self.pos[rows], self.targets[rows], self.pos[self.state == ALIVE])

    def infos(self, rows: np.ndarray | range) -> list[dict]:
        """Each row's info: its cell, target, note (as the STATUS says: reached, unreachable or none), state
        and cause of death (none while alive)."""
        columns: tuple[np.ndarray, ...] = (self.pos, self.targets, self.note, self.state, self.cause)
        if len(rows) < self.n:
            columns = tuple(c[rows] for c in columns)
        return [{"cell": tuple(p), "target": tuple(t), "note": NOTE_TEXT[nt], "state": STATE_TEXT[s],
                 "cause": CAUSE_TEXT[c]} for p, t, nt, s, c in zip(*(c.tolist() for c in columns))]

    # ------------------------------------------------------------------ acting

    def act(self, given: list[int], values: list) -> Outcome:
        """One turn: the action `values[k]` for row `given[k]` (the other acting rows hover); ConfigError (and no
        turn played) after the end, for a row no longer acting or an action outside the space."""
        if self.ended:
            raise ConfigError("step() after the end of the episode: call reset()")
        at = np.array(given, np.intp)
        if not self.everyone:
            done = at[~self.acting[at]]
            if len(done):
                raise done_agents(done.tolist())
        actions = np.zeros(self.n, np.intp)
        actions[at] = checked_actions(given, values, self.config.actions)
        t = self.cycle + 1
        aim = self.aim_next
        everyone = self.everyone
        if everyone:  # (the whole arrays: no row selection)
            alive, dest, note = self._all, self.pos + _DELTAS[actions], self._say
        else:
            alive = np.flatnonzero(self.state == ALIVE)
            dest = self.pos[alive] + np.where(self.acting[alive, None], _DELTAS[actions[alive]], 0)
            note = self._say[alive]
        board, over = self.turns.play(t, aim, self.targets[aim] if len(aim) else _NO_CELLS, alive, dest, note)
        self.cycle, self.over = t, over
        self.pos, self.state, self.note, self.cause = board
        cfg = self.config
        if everyone:
            rows, state, pos, targets, was_on = self._all, self.state, self.pos, self.targets, self.on
        else:
            rows = np.flatnonzero(self.acting)
            state, pos, targets, was_on = self.state[rows], self.pos[rows], self.targets[rows], self.on[rows]
        dead = state != ALIVE
        died = np.count_nonzero(dead)
        on = (pos == targets).all(axis=1)
        if died:
            on &= ~dead
        arrived = on > was_on
        rewards = self._reward[arrived + 2 * dead] if died else self._reward[arrived.view(np.uint8)]  # (most: none)
        terminated = dead | arrived if cfg.on_target == "finish" else dead
        truncated = ~terminated if t >= self.max_cycles else np.zeros(len(rows), bool)
        ended = terminated | truncated
        stops = int(np.count_nonzero(ended))
        if over is not None and stops < len(rows):
            raise BackendError(f"the game ended at turn {t} ({over.reason.value}: {over.text})")
        if everyone:
            self.on = on
        else:
            self.on[rows] = on
        self.aim_next = rows[arrived] if cfg.on_target == "new" else _NO_ROWS
        if len(self.aim_next):
            for i in self.aim_next.tolist():
                self.targets[i], self.reachable[i] = self.layout.new_target(i, self.pos[i], self.targets)
                self.on[i] = bool((self.targets[i] == self.pos[i]).all())  # (nowhere else to go: no new arrival)
            self._say = self._notes()
        observations = self.observe(rows, everyone and not died)  # (the dead are not seen)
        infos = self.infos(rows)
        if stops:
            self.acting[rows[ended]] = False
            self.left -= stops
            self.everyone = False
        if self.ended and over is None:
            self.turns.stop()  # the drones left (parked on their targets) need no more turns
        return Outcome(self._rows_all if everyone else rows.tolist(), observations, rewards.tolist(),
                       terminated.tolist(), truncated.tolist(), infos)


#: The infos' texts of the fleet's note, state and cause codes.
NOTE_TEXT = tuple(n.value.lower() for n in NOTES)
STATE_TEXT = tuple(s.value.lower() for s in STATES)
CAUSE_TEXT = tuple(c.value.lower() for c in CAUSES)


class Expert:
    """One of the project's autopilots per drone (D* by default) choosing each acting drone's action: an expert
    for imitation learning, or a baseline. It senses as a drone process does (the episode's world answers its
    ASK). A cooperative autopilot's drones give way to each other as a game's do: their decisions (each one's
    move, note and ranked candidates) are a turn of the expert's own game of the episode's alive drones
    (`Engine.play`), whose arbitration (the search, coordinator/lacam.py, and PIBT) gives each its cell; a drone
    that no longer acts (parked on its target) is in that game as a drone that does not cooperate. The game
    follows the episode turn by turn, and starts again from the episode's cells when they are not its own (a
    new episode, or another policy's steps)."""

    def __init__(self, autopilot: str = COOPERATIVE) -> None:
        from entities.autopilots import pilot_class

        self.autopilot = autopilot
        self.cooperative = pilot_class(autopilot).cooperative
        self._episode: EpisodeBase | None = None
        self._pilots: dict[str, object] = {}
        self._game: Engine | None = None
        self._rows: list[int] = []  # the episode's rows in the game (the alive drones when it started), in order
        self._acting: list[int] = []  # those acting then (the game's cooperative drones)
        self._log = logging.Logger("dronesim.rl.expert", logging.ERROR)

    def actions(self, episode: EpisodeBase) -> dict[int, int]:
        """row -> action of every acting drone of `episode` at its current turn."""
        from entities.autopilots import make_autopilot
        from entities.autopilots.base import drive, fly_round
        from entities.environment import Environment

        if episode is not self._episode:  # a new episode: fresh pilots (they remember the world they saw)
            self._episode, self._pilots, self._game = episode, {}, None
        pos, state, targets, acting_ = episode.columns()
        alive = np.flatnonzero(state == ALIVE).tolist()
        here = {drone_name(i + 1): c for i, c in zip(alive, map(tuple, pos[alive].tolist()))}
        env = Environment(episode.world, here)
        acting = {i: drone_name(i + 1) for i in alive if acting_[i]}
        steps = {}
        for i, d in acting.items():
            if d not in self._pilots:
                self._pilots[d] = make_autopilot(self.autopilot, world_size=episode.world.size)
            steps[d] = self._pilots[d].step(here[d], tuple(targets[i].tolist()))  # type: ignore[attr-defined]
        decided = drive(fly_round(steps), env.oracle)
        wants = {d: decided[d].pos if d in decided else c for d, c in here.items()}
        if self.cooperative:
            wants = self._arbitrated(episode, alive, acting, decided, wants)
        return {i: _ACTION_OF[tuple(w - h for w, h in zip(wants[d], here[d]))] for i, d in acting.items()}

    def _arbitrated(self, episode: EpisodeBase, alive: list[int], acting: dict[int, str], decided: dict,
                    wants: dict[str, Cell]) -> dict[str, Cell]:
        """`wants` after a turn of the expert's game (`Expert`'s doc), which then stands where the drones go."""
        pos, _, targets, _ = episode.columns()
        game = self._game
        if game is None or game.stage is not Stage.GCS or self._rows != alive or self._acting != [*acting] or \
                not np.array_equal(
                game.fleet.pos[[game.fleet.index[drone_name(k + 1)] for k in range(len(alive))]], pos[alive]):
            game = self._start(episode, alive, acting)
        rows = [game.fleet.index[drone_name(k + 1)] for k in range(len(alive))]
        names = [drone_name(i + 1) for i in alive]
        moves = [decided[d] if d in decided else None for d in names]
        game.play(rows, targets[alive], rows, [wants[d] for d in names],
                  [0 if m is None else code_of(m.note) for m in moves], [0 if m is None else m.ranked for m in moves])
        after = game.fleet.pos[rows].tolist()
        return {d: (x, y, z) for d, (x, y, z) in zip(names, after)}

    def _start(self, episode: EpisodeBase, alive: list[int], acting: dict[int, str]) -> Engine:
        """The expert's game of `episode`'s alive drones where they are (the k-th named drone_name(k + 1))."""
        pos, _, targets, _ = episode.columns()
        drones = DroneTable([drone_name(k + 1) for k in range(len(alive))], pos[alive])
        config = GameConfig(world=WorldSpec(size=episode.world.size, cells=episode.world.packed()), drones=drones,
                            max_turns=1 << 30)
        game = Engine(config, self._log, episode.world)
        game.verify_env = game.journaled = game.env_followed = False
        game.start_here(HOST, self.autopilot, [game.fleet.index[drone_name(k + 1)] for k, i in enumerate(alive)
                                               if i in acting])
        self._game, self._rows, self._acting = game, alive, [*acting]
        return game


_ACTION_OF = {a: k for k, a in enumerate(ACTIONS)}
_BOOLS = frozenset({bool, np.bool_})
_INTEGERS = frozenset({int, np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64})
_VALID = {k: frozenset(range(k)) for k in (FLAT_ACTIONS, len(ACTIONS))}
_MEANING = ("0 hover", "1 +x", "2 -x", "3 +y", "4 -y", "5 +z", "6 -z")


def checked_actions(rows: list[int], values: list, count: int = len(ACTIONS)) -> list:
    """The actions `values` (`values[k]` for row `rows[k]`) as integers, if each is an integer in 0..count - 1
    (a Python or numpy integer, or a 0-d integer array); else ConfigError for the first that is not."""
    if len(values) == 1:  # (one agent: no sets made)
        if type(values[0]) is int and 0 <= values[0] < count:
            return values
    elif set(map(type, values)) <= _INTEGERS and set(values) <= _VALID[count]:  # (the usual case: plain integers)
        return values
    for row, a in zip(rows, values):
        if type(a) in _BOOLS or not isinstance(a, (int, np.integer, np.ndarray)) or np.ndim(a) != 0 \
                or not np.issubdtype(np.asarray(a).dtype, np.integer) or not 0 <= int(a) < count:
            raise ConfigError(f"action {a!r} for drone_{row + 1} is outside Discrete({count}): "
                              + ", ".join(_MEANING[:count]))
    return [int(a) for a in values]
