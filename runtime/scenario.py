"""Scenario files: a run described, shared and replayed — world, drones, targets per turn, limits.

```json
{"format": "dronesim-scenario", "version": 1,
 "world": {"size": [16, 16, 4], "seed": 5},            // or {"file": "city.json"} (relative to the scenario)
 "drones": [{"id": "D01", "start": [0, 0, 0], "autopilot": "dstar"},
            {"id": "D02", "start": [0, 2, 0], "autopilot": "v1"}],
 "targets": ["D01=15,15,0", "D02=9,2,0@4"],             // [Dnn=]x,y,z[@turn], as --targets
 "max_turns": 200}
```
The game ends when every drone has reached its last target (or said it is unreachable), when no drone
is alive, or at ``max_turns``.
"""

from __future__ import annotations

import json
import pathlib
from dataclasses import dataclass

from dronesim.coordinator.engine import DroneSpec, GameConfig
from dronesim.entities.autopilots import REGISTRY
from dronesim.entities.gcs import Plan
from dronesim.entities.world import World
from dronesim.schema import Cell, RemoteInputError, UsageError, WorldSpec, is_drone_id

FORMAT = "dronesim-scenario"


def swarm_hosts(autopilots: dict[str, str]) -> dict[str, tuple[str, tuple[str, ...]]]:
    """The swarm layout: one host per autopilot (H01, H02, ... in the autopilots' name order) ->
    (autopilot, its drones in id order)."""
    return {f"H{n:02d}": (pilot, tuple(d for d in sorted(autopilots) if autopilots[d] == pilot))
            for n, pilot in enumerate(sorted(set(autopilots.values())), 1)}


@dataclass(frozen=True, slots=True, kw_only=True)
class Scenario:
    world: WorldSpec
    drones: tuple[DroneSpec, ...]
    autopilots: dict[str, str]  # drone -> autopilot name
    targets: tuple[str, ...]
    max_turns: int = 1000

    def game_config(self, **deadlines: object) -> GameConfig:
        return GameConfig(world=self.world, drones=self.drones, max_turns=self.max_turns, **deadlines)  # type: ignore[arg-type]

    def plan(self) -> Plan:
        return Plan.parse(self.targets, self.world.size, default_drone=self.drones[0].drone)

    @classmethod
    def load(cls, path: str | pathlib.Path) -> "Scenario":
        path = pathlib.Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"), object_hook=_compact)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise UsageError(f"cannot read scenario {path}: {exc}") from None
        try:
            return cls.from_json(data, base=path.parent)
        except UsageError as err:
            raise UsageError(f"{path}: {err}") from None

    @classmethod
    def from_json(cls, data: object, base: pathlib.Path = pathlib.Path(".")) -> "Scenario":
        if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != 1:
            raise UsageError(f'not a scenario: expected "format": "{FORMAT}", "version": 1')
        w = data.get("world")
        if not isinstance(w, dict):
            raise UsageError('"world" must be {"size": [...], "seed": n} or {"file": "..."}')
        world_file: World | None = None
        try:
            if "file" in w:
                world_file = World.load(base / str(w["file"]))
                spec = WorldSpec(size=world_file.size, cells=world_file.packed())
            else:
                spec = WorldSpec(size=_cell(w.get("size"), "world size"), seed=_int(w.get("seed", 0), "seed"))
        except RemoteInputError as err:  # WorldSpec's own checks: sizes 1..65536, seed >= 0
            raise UsageError(f"bad world: {err}") from None
        drones_raw = data.get("drones")
        if not isinstance(drones_raw, list) or not drones_raw:
            raise UsageError('"drones" must be a non-empty list')
        drones, autopilots = [], {}
        for i, d in enumerate(drones_raw):
            drone, pilot = d if isinstance(d, _Entry) else _entry(d, i + 1)
            if world_file is not None and world_file.is_building(drone.start):
                raise UsageError(f"{drone.drone} starts inside a building at {drone.start}")
            drones.append(drone)
            autopilots[drone.drone] = pilot
        targets = data.get("targets", [])
        if not isinstance(targets, list) or not all(isinstance(t, str) for t in targets):
            raise UsageError('"targets" must be a list of "[Dnn=]x,y,z[@turn]" strings')
        scenario = cls(world=spec, drones=tuple(drones), autopilots=autopilots, targets=tuple(targets),
                       max_turns=_int(data.get("max_turns", 1000), "max_turns"))
        scenario.game_config()  # validates ids, starts
        unknown = Plan.drones_of(scenario.targets, spec.size, default_drone=scenario.drones[0].drone) - set(autopilots)
        if unknown:
            raise UsageError(f"targets for drones not in the scenario: {', '.join(sorted(unknown))}")
        return scenario


def _compact(obj: dict) -> object:
    """json.loads' object_hook: a valid drone entry (a dict with an "id") becomes its `_Entry` as soon as it
    is parsed (a swarm's file is thousands of them, which as dicts and lists fragmented the process's
    memory); anything else stays as it is, for `Scenario.from_json` to check in its place."""
    if "id" in obj:
        try:
            return _entry(obj)
        except UsageError:
            pass
    return obj


class _Entry(tuple):
    """A checked drone entry of a scenario: (DroneSpec, autopilot name)."""

    __slots__ = ()


def _entry(d: object, n: int = 0) -> _Entry:
    """The n-th drone entry of a scenario, checked: its id, autopilot and start."""
    if not isinstance(d, dict) or not is_drone_id(d.get("id")):
        raise UsageError(f"drone #{n} needs an id like D01")
    pilot = d.get("autopilot", "seed")
    if not isinstance(pilot, str) or pilot not in REGISTRY:
        raise UsageError(f"{d['id']}: unknown autopilot {pilot!r}; choose one of {', '.join(REGISTRY)}")
    return _Entry((DroneSpec(drone=d["id"], start=_cell(d.get("start"), f"{d['id']} start")), pilot))


def _int(v: object, what: str) -> int:
    if type(v) is not int:
        raise UsageError(f"{what} must be an integer, got {v!r}")
    return v


def _cell(v: object, what: str) -> Cell:
    if not isinstance(v, list) or len(v) != 3 or not all(type(c) is int and c >= 0 for c in v):
        raise UsageError(f"{what} must be [x, y, z] with non-negative integers, got {v!r}")
    return (v[0], v[1], v[2])
