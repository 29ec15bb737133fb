"""A game's configuration: its world, its drones and their start cells (`DroneTable`: a swarm's as columns),
its limits, deadlines and graces (`GameConfig`), checked when made. The engine, the journal's header, resume,
scenarios and the RL episodes all read a game from it."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, overload

import numpy as np

from schema import Cell, UsageError, WorldSpec
from schema.messages import is_drone_id
from schema.tuning import (
    ADMIT_DEADLINE_S,
    ENV_GRACE_S,
    GCS_GRACE_S,
    LINK_GRACE_S,
    MAX_WAIT_S,
    PHASE_CAP_S,
    PHASE_DEADLINE_S,
)
from world.grid import inside_rows, linear_rows

from .fleet import cell_of

#: The game's rules by default (the waits are in schema/tuning.py): its turn limit, and the missed drones' phases in
#: a row after which a drone is LOST.
MAX_TURNS = 1000
LOST_AFTER = 3
#: The turn limit of a game `dronesim up` starts (the Docker cluster's too: docker/compose*.yaml's MAX_TURNS), one to
#: watch.
UP_MAX_TURNS = 200
#: The size of a generated world when none is given (`--size`): nx, ny, nz.
SIZE = (10, 10, 10)


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneSpec:
    drone: str
    start: Cell


class DroneTable(Sequence[DroneSpec]):
    """A game's drones as columns (a swarm's scenario): their ids and an (n, 3) array of their start cells,
    read as the sequence of `DroneSpec`s it stands for (each made when read: they cost a hundred bytes each)."""

    __slots__ = ("ids", "starts")

    def __init__(self, ids: Sequence[str], starts: Sequence[Cell] | Sequence[int] | np.ndarray) -> None:
        """`starts`: each drone's start cell, or their coordinates in a row (x, y, z, x, y, z, ...), or an (n, 3)
        array of them."""
        self.ids = tuple(ids)
        try:
            self.starts = np.array(starts, np.int64).reshape(len(self.ids), 3)
        except OverflowError:
            raise UsageError("a start cell is outside any world") from None

    def __len__(self) -> int:
        return len(self.ids)

    @overload
    def __getitem__(self, i: int) -> DroneSpec: ...

    @overload
    def __getitem__(self, i: slice) -> tuple[DroneSpec, ...]: ...

    def __getitem__(self, i: int | slice) -> DroneSpec | tuple[DroneSpec, ...]:
        if isinstance(i, slice):
            return tuple(self)[i]
        return DroneSpec(drone=self.ids[i], start=cell_of(self.starts[i]))

    def __iter__(self) -> Iterator[DroneSpec]:
        return (DroneSpec(drone=d, start=(x, y, z)) for d, (x, y, z) in zip(self.ids, self.starts.tolist()))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Sequence) and len(other) == len(self) and all(a == b for a, b in zip(self, other))

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        return f"DroneTable({list(self)!r})"


#: The arbitrations a game may choose: the complete search (coordinator/lacam.py, the default) or PIBT alone.
ARBITERS = ("lacam", "pibt")
ARBITER = ARBITERS[0]


@dataclass(frozen=True, slots=True, kw_only=True)
class GameConfig:
    world: WorldSpec
    drones: Sequence[DroneSpec]  # a tuple, or a `DroneTable`
    max_turns: int = MAX_TURNS
    phase_deadline: float = PHASE_DEADLINE_S  # seconds for the drones and the environment
    phase_cap: float = PHASE_CAP_S  # seconds a drones' phase may last in all while a host says it is still deciding
    gcs_deadline: float | None = None  # None: the GCS paces the game (a human types)
    admit_deadline: float | None = ADMIT_DEADLINE_S  # seconds for every entity to connect (None: forever, if asked)
    lost_after: int = LOST_AFTER  # missed DRONES deadlines in a row before a drone is LOST
    env_grace: float = ENV_GRACE_S  # seconds the game waits for a vanished environment to come back
    link_grace: float = LINK_GRACE_S  # seconds the game holds for the entities after a lost link (a router restart)
    gcs_grace: float = GCS_GRACE_S  # seconds a resumed game waits for its ground station once the others are back
    arbiter: str = ARBITER  # the cooperative drones' arbitration: ARBITERS (journaled in the header if not lacam)
    #: Lifelong: the ground station gives a drone a new target each time it reaches its own (entities/tasks.py); the
    #: engine counts the tasks done and the end says how many, and how many a turn (journaled in the header if so).
    lifelong: bool = False

    def __post_init__(self) -> None:
        if self.arbiter not in ARBITERS:
            raise UsageError(f"arbiter {self.arbiter!r}: one of {', '.join(ARBITERS)}")
        if not self.drones:
            raise UsageError("a game needs at least one drone")
        # (checked as columns: a swarm's drones as records, sets and lists would double its scenario's peak)
        table = self.drones if isinstance(self.drones, DroneTable) else \
            DroneTable([d.drone for d in self.drones], [d.start for d in self.drones])
        ids, starts = table.ids, table.starts
        if problem := _ids_problem(ids):
            raise UsageError(problem)
        if np.count_nonzero(starts.view(np.uint64) >= self.world.size):  # (a negative coordinate, unsigned, is huge)
            i = int(inside_rows(starts, self.world.size).argmin())
            raise UsageError(f"{ids[i]} starts at {cell_of(starts[i])}, outside the world {self.world.size}")
        if len(starts) > 1 and len(set(linear_rows(starts, self.world.size).tolist())) != len(starts):  # (one each)
            raise UsageError("two drones cannot start in the same cell")
        if self.max_turns < 1 or self.lost_after < 1:
            raise UsageError("max_turns and lost_after must be >= 1")
        waits = [w for w in (self.phase_deadline, self.phase_cap, self.gcs_deadline, self.admit_deadline,
                             self.env_grace, self.link_grace, self.gcs_grace) if w is not None]
        if not (self.phase_deadline > 0 and self.phase_cap > 0
                and (self.gcs_deadline is None or self.gcs_deadline > 0)
                and (self.admit_deadline is None or self.admit_deadline > 0)
                and min(self.env_grace, self.link_grace, self.gcs_grace) >= 0):
            raise UsageError("deadlines must be positive (the GCS's and admission's: or none) and graces >= 0")
        if not all(w <= MAX_WAIT_S for w in waits):  # (nan and a negative one are refused above)
            raise UsageError(f"deadlines and graces must be at most {MAX_WAIT_S:g} seconds (a day), got "
                             f"{max(waits):g}")


@functools.lru_cache(maxsize=8)
def _ids_problem(ids: tuple[str, ...]) -> str:
    """What is wrong with a game's drone ids ("" if nothing): remembered for the last few sets of ids (an RL
    environment starts a game of the same drones at every reset)."""
    if bad := [d for d in ids if not is_drone_id(d)]:
        return f"{bad[0]!r} is not a drone id (D01 ... D65535)"
    if len(set(ids)) != len(ids):
        return f"duplicate drone ids in {list(ids)}"
    return ""


def starts_of(config: GameConfig) -> Iterator[tuple[str, Cell]]:
    """Each drone of `config` and its start cell (a `DroneTable`'s read as its columns)."""
    drones = config.drones
    if isinstance(drones, DroneTable):
        return zip(drones.ids, map(tuple, drones.starts.tolist()))  # type: ignore[arg-type]
    return ((d.drone, d.start) for d in drones)


def replace_config(config: GameConfig, **changes: Any) -> GameConfig:
    return dataclasses.replace(config, **changes)
