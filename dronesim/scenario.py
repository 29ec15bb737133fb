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
is alive, or at ``max_turns``. ``"lifelong": true`` (or ``{"seed": n}``) makes it a lifelong game: the ground
station gives each drone a new target each time it reaches its own, drawn with the world's seed (or n;
entities/tasks.py), and the game goes on to ``max_turns``, whose end says the tasks done.

A MovingAI instance (world/movingai.py) becomes a scenario with `movingai_scenario` (``dronesim up
--world room.map --scen room.scen --agents 200``).
"""

from __future__ import annotations

import json
import pathlib
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass

from coordinator.config import MAX_TURNS, DroneSpec, DroneTable, GameConfig
from entities.autopilots import COOPERATIVE, DEFAULT, REGISTRY
from entities.gcs import Plan
from schema import Cell, RemoteInputError, UsageError, WorldSpec, is_drone_id
from world.grid import World, build_world, checked_int, json_problem
from world.movingai import read_scen

FORMAT = "dronesim-scenario"


def swarm_hosts(autopilots: dict[str, str]) -> dict[str, tuple[str, tuple[str, ...]]]:
    """The swarm layout: one host per autopilot (H01, H02, ... in the autopilots' name order) ->
    (autopilot, its drones in id order)."""
    return {f"H{n:02d}": (pilot, tuple(d for d in sorted(autopilots) if autopilots[d] == pilot))
            for n, pilot in enumerate(sorted(set(autopilots.values())), 1)}


@dataclass(frozen=True, slots=True, kw_only=True)
class Scenario:
    world: WorldSpec
    drones: Sequence[DroneSpec]  # a `DroneTable` (a tuple will do)
    autopilots: dict[str, str]  # drone -> autopilot name
    targets: tuple[str, ...]
    max_turns: int = MAX_TURNS
    lifelong: int | None = None  # a lifelong game: the seed of its targets' draws (None: not lifelong)

    def game_config(self, **deadlines: object) -> GameConfig:
        """The game, with `deadlines` (GameConfig's fields; ``lifelong=True``: lifelong, as the scenario may say)."""
        lifelong = bool(deadlines.pop("lifelong", False)) or self.lifelong is not None
        return GameConfig(world=self.world, drones=self.drones, max_turns=self.max_turns, lifelong=lifelong,
                          **deadlines)  # type: ignore[arg-type]

    def plan(self) -> Plan:
        return Plan.parse(self.targets, self.world.size, default_drone=self.drones[0].drone)

    @classmethod
    def load(cls, path: str | pathlib.Path, *, plan: bool = True) -> Scenario:
        """The scenario in `path`; without `plan`, its targets are neither kept nor checked (the coordinator's
        reading: the ground station flies the plan, and checks it)."""
        path = pathlib.Path(path)
        try:
            data = _parse(path, plan)
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:  # (ValueError: not JSON, or an
            # integer of more than 4300 digits; RecursionError: nested too deeply)
            raise UsageError(f"cannot read scenario {path}: {json_problem(exc)}") from None
        try:
            return cls.from_json(data, base=path.parent, plan=plan)
        except UsageError as err:
            raise UsageError(f"{path}: {err}") from None

    @classmethod
    def from_json(cls, data: object, base: pathlib.Path = pathlib.Path("."), *, plan: bool = True) -> Scenario:
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
                spec = WorldSpec(size=_cell(w.get("size"), "world size"), seed=checked_int(w.get("seed", 0), "seed"))
        except RemoteInputError as err:  # WorldSpec's own checks: sizes 1..65536, seed >= 0
            raise UsageError(f"bad world: {err}") from None
        drones_raw = data.get("drones")
        if not isinstance(drones_raw, list) or not drones_raw:
            raise UsageError('"drones" must be a non-empty list')
        ids: list[str] = []
        starts: list[int] = []  # x, y, z of each drone in a row
        autopilots: dict[str, str] = {}
        for i, d in enumerate(drones_raw):
            drone, x, y, z, pilot = d if isinstance(d, _Entry) else _entry(d, i + 1)
            if world_file is not None and world_file.is_building((x, y, z)):
                raise UsageError(f"{drone} starts inside a building at {(x, y, z)}")
            ids.append(drone)
            starts += x, y, z
            autopilots[drone] = pilot
        drones = DroneTable(ids, starts)
        targets = data.get("targets", []) if plan else []
        if not isinstance(targets, list) or not all(isinstance(t, str) for t in targets):
            raise UsageError('"targets" must be a list of "[Dnn=]x,y,z[@turn]" strings')
        scenario = cls(world=spec, drones=drones, autopilots=autopilots, targets=tuple(targets),
                       max_turns=checked_int(data.get("max_turns", MAX_TURNS), "max_turns"),
                       lifelong=_lifelong(data.get("lifelong", False), spec.seed))
        scenario.game_config()  # validates ids, starts
        # targets are checked against the world's buildings too: built here (as every process builds it) only
        # when there are targets and the world is generated
        world = world_file or (build_world(spec, (d.start for d in drones)) if targets else None)
        if unknown := Plan.drones_of(scenario.targets, spec.size, scenario.drones[0].drone, world) - set(autopilots):
            raise UsageError(f"targets for drones not in the scenario: {', '.join(sorted(unknown))}")
        return scenario


def movingai_scenario(map_path: str | pathlib.Path, scen_path: str | pathlib.Path, agents: int | None = None,
                      autopilot: str = COOPERATIVE, max_turns: int = MAX_TURNS) -> dict:
    """The scenario (its JSON form, for `Scenario.from_json` or a file) of the first `agents` agents of a
    MovingAI .scen (all of them: None) on its .map. UsageError if either is unreadable or they disagree."""
    if agents is not None and agents < 1:  # (a negative one sliced off the last agents)
        raise UsageError(f"the number of agents must be >= 1 (or all of them), got {agents}")
    world = World.load(map_path)
    try:
        entries = read_scen(pathlib.Path(scen_path).read_text(encoding="utf-8"))[:agents]  # (all of them: None)
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"cannot read {scen_path}: {exc}") from None
    if agents is not None and len(entries) < agents:
        raise UsageError(f"{scen_path} has {len(entries)} agents, {agents} asked")
    if not entries:
        raise UsageError(f"{scen_path} has no agents")
    for a in entries:
        if (a.width, a.height) != world.size[:2]:
            raise UsageError(f"{scen_path} is for a {a.width} x {a.height} map, {map_path} is {world.size[0]} x "
                             f"{world.size[1]}")
    ids = [f"D{n:02d}" for n in range(1, len(entries) + 1)]
    return {"format": FORMAT, "version": 1, "world": {"file": str(pathlib.Path(map_path).resolve())},
            "drones": [{"id": d, "start": [*a.start, 0], "autopilot": autopilot} for d, a in zip(ids, entries)],
            "targets": [f"{d}={a.goal[0]},{a.goal[1]},0" for d, a in zip(ids, entries)], "max_turns": max_turns}


#: The key "targets" and its list, up to the first closing bracket (no backslash inside): a valid plan is a
#: list of plain strings. Emptied, the document is the same JSON but for it, or no JSON at all (a bracket
#: inside: then the whole document is read as it is).
_TARGETS = re.compile(r'"targets"\s*:\s*\[[^\]\\]*\]')


def _parse(path: pathlib.Path, plan: bool) -> object:
    """The JSON of the scenario in `path`; without `plan`, its target list is emptied before it is parsed (5
    targets a drone take more memory than the drone itself), when that can be done safely."""
    text = path.read_text(encoding="utf-8")
    if not plan:
        text, cut = _TARGETS.subn('"targets": []', text, count=1)  # (the whole text is not kept meanwhile)
        if cut:
            try:
                return json.loads(text, object_hook=_compact)
            except json.JSONDecodeError:
                text = path.read_text(encoding="utf-8")
    return json.loads(text, object_hook=_compact)


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
    """A checked drone entry of a scenario: (drone id, x, y, z of its start, autopilot name)."""

    __slots__ = ()


def _entry(d: object, n: int = 0) -> _Entry:
    """The n-th drone entry of a scenario, checked: its id, autopilot and start."""
    if not isinstance(d, dict) or not is_drone_id(d.get("id")):
        raise UsageError(f"drone #{n} needs an id like D01")
    pilot = d.get("autopilot", DEFAULT)
    if not isinstance(pilot, str) or pilot not in REGISTRY:
        raise UsageError(f"{d['id']}: unknown autopilot {pilot!r}; choose one of {', '.join(REGISTRY)}")
    return _Entry((d["id"], *_cell(d.get("start"), f"{d['id']} start"), sys.intern(pilot)))  # (one name string for all)


def _lifelong(v: object, world_seed: int) -> int | None:
    """A scenario's "lifelong": false (not lifelong: None), true (the world's seed draws its targets) or
    {"seed": n}."""
    if v is False or v is True:
        return world_seed if v else None
    if isinstance(v, dict) and set(v) == {"seed"}:
        seed = checked_int(v["seed"], "lifelong seed")
        if seed >= 0:
            return seed
    raise UsageError(f'"lifelong" must be true, false or {{"seed": n}} with n >= 0, got {v!r}')


def _cell(v: object, what: str) -> Cell:
    if not isinstance(v, list) or len(v) != 3 or not all(type(c) is int and c >= 0 for c in v):
        raise UsageError(f"{what} must be [x, y, z] with non-negative integers, got {v!r}")
    return (v[0], v[1], v[2])
