"""The ground station's pure parts: the seed's input check (correctForm), scripted plans, the display.

A plan maps turns to targets: ``9,9,0`` (D01 from turn 1), ``D02=3,4,0`` (D02 from turn 1),
``D01=5,5,0@12`` (from turn 12). A script file holds one such item per line (``#`` comments).
"""

from __future__ import annotations

import bisect
import pathlib
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from dronesim.schema import (
    Aim, Cell, Done, DroneState, DroneStatus, Intent, Note, Phase, Status, UsageError, Welcome, is_drone_id,
)

from .environment import build_world
from .world import World

_ITEM = re.compile(r"\s*(?:(?P<drone>D\d{2,4})\s*[= ]\s*)?(?P<cell>-?\d+\s*,\s*-?\d+\s*,\s*-?\d+)\s*(?:@\s*(?P<turn>\d+))?\s*\Z")


def correct_form(text: str, size: Cell) -> Cell:
    """The seed's CORRECTFORM: ``x,y,z`` (spaces allowed) must name a cell inside the world."""
    parts = [p.strip() for p in text.replace(" ", ",").split(",") if p.strip()]
    try:
        cell = tuple(int(p) for p in parts)
    except ValueError:
        raise UsageError(f"{text!r} is not x,y,z") from None
    if len(cell) != 3:
        raise UsageError(f"{text!r} is not x,y,z")
    if not all(0 <= c < s for c, s in zip(cell, size)):
        raise UsageError(f"{cell} is outside the world: 0 <= x < {size[0]}, 0 <= y < {size[1]}, 0 <= z < {size[2]}")
    return cell  # type: ignore[return-value]


def gcs_done(turn: int, targets: Mapping[str, Cell], intent: Intent,
             in_force: Mapping[str, Cell] | None = None) -> Done:
    """The ground station's answer in the GCS phase of `turn`: its DONE, carrying the targets
    (``GCS:D01:TGT:x:y:z``) in one message. The seed re-sent every target every turn; the coordinator
    keeps them, so only those that differ from `in_force` (the targets of the last STATUS) are sent: a
    swarm's GCS phase costs what changes, not what is."""
    keep = in_force or {}
    return Done(turn=turn, sender="GCS", phase=Phase.GCS, intent=intent,
                targets=tuple(Aim(drone=d, pos=c) for d, c in sorted(targets.items()) if keep.get(d) != c))


#: How many GCS phases a scripted ground station answers ahead, when its plan has nothing new for
#: them (the coordinator holds up to coordinator.engine.AHEAD_MAX): two keeps the ground station off
#: the turn's critical path even when its answer takes as long as the drones' phase.
ANSWER_AHEAD = 2


def turns_to_answer_ahead(plan: "Plan", turn: int, answered: int, *, last: int | None = None,
                          horizon: int = ANSWER_AHEAD) -> list[int]:
    """The turns after `turn` a scripted station can answer now: up to `horizon` of them, before the
    plan's next change (and before `last`), except those already answered (up to `answered`)."""
    out = []
    for u in range(turn + 1, turn + horizon + 1):
        if plan.at(u) or (last is not None and u >= last):
            break
        if u > answered:
            out.append(u)
    return out


def _plan_items(texts: Iterable[str], size: Cell, default_drone: str) -> Iterable[tuple[int, str, Cell]]:
    """(turn, drone, cell) of each target item in `texts`, in the order written; UsageError on a bad one."""
    for text in texts:
        for chunk in text.split(";"):
            if not chunk.strip() or chunk.strip().startswith("#"):
                continue
            m = _ITEM.match(chunk)
            if not m:
                raise UsageError(f"bad target {chunk.strip()!r}: expected [Dnn=]x,y,z[@turn]")
            turn = int(m["turn"] or 1)
            if turn < 1:
                raise UsageError(f"bad target {chunk.strip()!r}: turns start at 1")
            yield turn, m["drone"] or default_drone, correct_form(m["cell"], size)


@dataclass(frozen=True, slots=True)
class Plan:
    """Targets by turn: ``items`` holds (turn, drone, cell), sorted."""

    items: tuple[tuple[int, str, Cell], ...]

    @classmethod
    def parse(cls, texts: Iterable[str], size: Cell, default_drone: str = "D01") -> "Plan":
        items = sorted(_plan_items(texts, size, default_drone), key=lambda item: item[0])
        return cls(tuple(items))  # a stable sort: within a turn, the last written wins

    @staticmethod
    def drones_of(texts: Iterable[str], size: Cell, default_drone: str = "D01") -> set[str]:
        """The drones the plan `texts` gives targets to, every item checked as `parse` checks it,
        none kept (a process that needs no plan checks a swarm's thousands of targets for free)."""
        return {drone for _, drone, _ in _plan_items(texts, size, default_drone)}

    @classmethod
    def load(cls, path: str, size: Cell) -> "Plan":
        try:
            lines = pathlib.Path(path).read_text(encoding="utf-8").splitlines()
        except OSError as exc:
            raise UsageError(f"cannot read the target script {path}: {exc}") from None
        return cls.parse((ln.split("#", 1)[0] for ln in lines), size)

    def at(self, turn: int) -> dict[str, Cell]:
        """Targets that take effect at `turn` (found by bisection: `items` are sorted by turn)."""
        lo = bisect.bisect_left(self.items, (turn,))
        hi = bisect.bisect_left(self.items, (turn + 1,), lo)
        return {d: c for _, d, c in self.items[lo:hi]}

    @property
    def last_turn(self) -> int:
        return self.items[-1][0] if self.items else 0

    def drones(self) -> set[str]:
        return {d for _, d, _ in self.items}


def parse_command(line: str, size: Cell, drones: Iterable[str]) -> dict[str, Cell]:
    """One interactive line: ``x,y,z`` (the only or first drone) or ``Dnn x,y,z``."""
    drones = list(drones)
    head = re.match(r"\s*(D\d{2,4})(?:\s*=\s*|\s+)(.*)\Z", line)  # "D02 1 2 3", "D02=1,2,3"
    drone_part, cell_part = (head[1], head[2]) if head else ("", line)
    cell_part = re.sub(r"(?<=\d)[\s,]+(?=-?\d)", ",", cell_part.strip())  # "1 2 3" -> "1,2,3"
    line = f"{drone_part}={cell_part}" if drone_part else cell_part
    m = _ITEM.match(line)
    if not m or m["turn"]:
        raise UsageError(f"{line.strip()!r}: type x,y,z or Dnn x,y,z")
    drone = m["drone"] or drones[0]
    if not is_drone_id(drone) or drone not in drones:
        raise UsageError(f"unknown drone {drone}: this game flies {', '.join(drones)}")
    return {drone: correct_form(m["cell"], size)}


def describe(s: DroneStatus) -> str:
    """One drone's line: position, alive/dead (the seed's display), target and notes."""
    if s.state is DroneState.ALIVE:
        state = "reached its target" if s.note is Note.REACHED else (
            "target UNREACHABLE, hovering" if s.note is Note.UNREACHABLE else "alive")
    else:
        state = f"{s.state.value} ({s.cause.value.lower()})"
    target = "no target" if s.target is None else f"target {s.target}"
    return f"{s.drone} at {s.pos}: {state}, {target}"


def format_status(status: Status, limit: int = 16) -> str:
    lines = [f"turn {status.turn}:"]
    shown = status.drones[:limit]
    lines += [f"  {describe(s)}" for s in shown]
    if len(status.drones) > limit:
        counts: dict[str, int] = {}
        for s in status.drones:
            counts[s.state.value] = counts.get(s.state.value, 0) + 1
        lines.append(f"  ... {len(status.drones) - limit} more; totals: {counts}")
    return "\n".join(lines)


class Tracks:
    """The last STATUS and each drone's path so far, kept as the game goes (memory grows with the moves
    made, not with the turns played: a long game of hovering drones costs nothing)."""

    def __init__(self) -> None:
        self.last: Status | None = None
        self.paths: dict[str, list[Cell]] = {}

    def add(self, status: Status) -> None:
        """Extend the paths with `status` (read from its columns: after the first STATUS, only the drones
        that moved since the last one are looked at)."""
        last, self.last = self.last, status
        table = status.drones
        pos = table.column("pos")
        rows = np.arange(len(table))
        if last is not None and np.array_equal(last.drones.numbers, table.numbers):
            rows = np.flatnonzero((pos != last.drones.column("pos")).any(axis=1))
        ids = table.ids()
        for i, (x, y, z) in zip(rows.tolist(), pos[rows].tolist()):
            path = self.paths.setdefault(ids[i], [])
            if not path or path[-1] != (x, y, z):
                path.append((x, y, z))


def trails(history: Iterable[Status]) -> dict[str, list[Cell]]:
    """Each drone's path through the STATUS history, without repeats of consecutive cells."""
    tracks = Tracks()
    for st in history:
        tracks.add(st)
    return tracks.paths


def targets_of(status: Status) -> Mapping[str, Cell]:
    """Each drone's target in force, of those that have one (read from the STATUS's columns)."""
    table = status.drones
    targets = table.column("target")
    ids = table.ids()
    has = np.flatnonzero(targets[:, 0] >= 0)
    return {ids[i]: (x, y, z) for i, (x, y, z) in zip(has.tolist(), targets[has].tolist())}


@dataclass(frozen=True, slots=True)
class Ground:
    """What a ground station knows once admitted: the world (rebuilt with the environment's own recipe),
    the drones of the game, and its plan of targets checked against both."""

    world: World
    drones: list[str]
    plan: Plan

    @classmethod
    def from_welcome(cls, welcome: Welcome, plan_texts: Iterable[str], script: str | None) -> "Ground":
        size = welcome.world.size
        starts = welcome.starts.cells()
        drones = list(starts)
        plan = Plan.load(script, size) if script else Plan.parse(plan_texts, size, default_drone=drones[0])
        unknown = plan.drones() - set(drones)
        if unknown:
            raise UsageError(f"the plan names {', '.join(sorted(unknown))}; this game flies {', '.join(drones)}")
        return cls(build_world(welcome.world, starts.values()), drones, plan)
