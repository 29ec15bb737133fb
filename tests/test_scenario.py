"""Scenario files (dronesim/scenario.py): loading, validation with clear UsageErrors, plan and game config."""

from __future__ import annotations

import copy
import json
import pathlib

import pytest

from coordinator.config import DroneSpec, DroneTable, GameConfig
from dronesim.local import Inputs, simulate
from dronesim.scenario import FORMAT, Scenario
from entities.environment import build_world
from entities.gcs import Plan
from schema import UsageError, WorldSpec
from world.grid import Building, World

ROOT = pathlib.Path(__file__).resolve().parent.parent
SWARM16 = ROOT / "scenarios" / "swarm16.json"


def base() -> dict:
    return {
        "format": FORMAT, "version": 1,
        "world": {"size": [8, 8, 3], "seed": 3},
        "drones": [{"id": "D01", "start": [0, 0, 0], "autopilot": "dstar"},
                   {"id": "D02", "start": [0, 2, 0], "autopilot": "v1"}],
        "targets": ["D01=7,7,0", "D02=5,3,0@3"],
        "max_turns": 50,
    }


def city() -> World:
    """8x8x3 with one 2x2 building of height 2 at (2..3, 2..3)."""
    return World.from_buildings((8, 8, 3), [Building(x=2, y=2, length=2, width=2, height=2)])


# --------------------------------------------------------------------------- the shipped scenario


def test_swarm16_loads() -> None:
    s = Scenario.load(SWARM16)
    assert len(s.drones) == 16
    assert [d.drone for d in s.drones] == [f"D{i:02d}" for i in range(1, 17)]
    assert set(s.autopilots.values()) == {"dstar", "seed", "v1"}
    assert set(s.autopilots) == {d.drone for d in s.drones}
    assert s.world == WorldSpec(size=(16, 16, 4), seed=5)
    assert s.max_turns == 120
    assert len(s.targets) == 16
    assert s.drones[0] == DroneSpec(drone="D01", start=(0, 0, 0))


def test_swarm16_plan_and_config() -> None:
    s = Scenario.load(SWARM16)
    plan = s.plan()
    assert isinstance(plan, Plan)
    assert plan.drones() == set(s.autopilots)
    assert plan.last_turn == 1
    assert plan.at(1)["D01"] == (15, 15, 1)
    cfg = s.game_config()
    assert isinstance(cfg, GameConfig)
    assert cfg.world == s.world and cfg.drones == s.drones and cfg.max_turns == 120


def test_drones_are_a_table_that_reads_as_drone_specs(tmp_path: pathlib.Path) -> None:
    """A scenario keeps its drones as columns (no `DroneSpec` a drone for the whole game); read, they are the
    same `DroneSpec`s, in the file's order, and the game's config is the one a tuple of them gives."""
    path = tmp_path / "s.json"
    path.write_text(json.dumps(mutate(lambda d: d["drones"][0].update(autopilot="v1"))))
    s = Scenario.load(path, plan=False)
    specs = (DroneSpec(drone="D01", start=(0, 0, 0)), DroneSpec(drone="D02", start=(0, 2, 0)))
    assert isinstance(s.drones, DroneTable) and s.drones.ids == ("D01", "D02")
    assert s.drones == specs and tuple(s.drones) == specs and s.drones[1] == specs[1] and s.drones[:1] == specs[:1]
    assert s.game_config() == GameConfig(world=s.world, drones=specs, max_turns=s.max_turns)
    assert s.autopilots["D01"] is s.autopilots["D02"]  # one string for each autopilot's name
    with pytest.raises(UsageError, match="outside"):
        Scenario.from_json(mutate(lambda d: d["drones"][1].update(start=[2 ** 64, 0, 0])))


# --------------------------------------------------------------------------- worlds


def test_world_by_seed() -> None:
    s = Scenario.from_json(base())
    assert s.world == WorldSpec(size=(8, 8, 3), seed=3)
    assert s.world.cells == b""


def test_seed_defaults_to_zero() -> None:
    data = base()
    data["world"] = {"size": [8, 8, 3]}
    data["targets"] = ["D01=6,6,0"]  # (7, 7, 0) is a building of seed 0's world
    assert Scenario.from_json(data).world.seed == 0


def test_world_by_relative_file(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "worlds").mkdir()
    world = city()
    world.save(tmp_path / "worlds" / "city.json")
    data = base()
    data["world"] = {"file": "worlds/city.json"}
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the file is found relative to the scenario, not the working directory
    s = Scenario.load(path)
    assert s.world.size == (8, 8, 3)
    assert s.world.cells == world.packed()
    built = build_world(s.world, (d.start for d in s.drones))
    assert built.is_building((2, 2, 0)) and built.is_building((3, 3, 1))
    assert not built.is_building((2, 2, 2))
    assert int(built.grid.sum()) == int(world.grid.sum())


def test_world_file_scenario_runs(tmp_path: pathlib.Path) -> None:
    city().save(tmp_path / "city.json")
    data = base()
    data["world"] = {"file": "city.json"}
    data["drones"] = [{"id": "D01", "start": [0, 0, 0], "autopilot": "dstar"},
                      {"id": "D02", "start": [2, 0, 0], "autopilot": "v1"}]
    data["targets"] = ["D01=7,7,0", "D02=2,5,0"]  # D02 flies straight into the building
    (tmp_path / "s.json").write_text(json.dumps(data), encoding="utf-8")
    s = Scenario.load(tmp_path / "s.json")
    result = simulate(s.game_config(), s.autopilots, Inputs(plan=s.plan()))
    deaths = {d: c for r in result.records for d, c in r.get("deaths", {}).items()}
    assert deaths == {"D02": "BUILDING"}
    assert result.over.reason.value == "ALL_REACHED"


def test_a_target_inside_a_building_is_refused_at_load(tmp_path: pathlib.Path) -> None:
    data = base()  # seed 3's generated world: (5, 2, 0) is a building cell
    data["targets"] = ["D01=7,7,0", "D02=5,2,0@3"]
    with pytest.raises(UsageError, match=r"bad target 'D02=5,2,0@3': \(5, 2, 0\) is inside a building"):
        Scenario.from_json(data)
    city().save(tmp_path / "city.json")
    data["world"] = {"file": "city.json"}
    data["targets"] = ["D01=7,7,0", "D02=3,2,1@4"]
    (tmp_path / "s.json").write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(UsageError, match=r"s\.json: bad target 'D02=3,2,1@4': \(3, 2, 1\) is inside a building"):
        Scenario.load(tmp_path / "s.json")
    data["targets"] = ["D01=7,7,0", "D02=3,2,2@4"]  # on the roof: fine
    (tmp_path / "s.json").write_text(json.dumps(data), encoding="utf-8")
    assert Scenario.load(tmp_path / "s.json").plan().at(4) == {"D02": (3, 2, 2)}


def test_start_in_a_building_of_a_file_world(tmp_path: pathlib.Path) -> None:
    city().save(tmp_path / "city.json")
    data = base()
    data["world"] = {"file": "city.json"}
    data["drones"][1]["start"] = [3, 2, 1]
    (tmp_path / "s.json").write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(UsageError, match=r"D02 starts inside a building at \(3, 2, 1\)"):
        Scenario.load(tmp_path / "s.json")
    data["drones"][1]["start"] = [3, 2, 2]  # on the roof: fine
    (tmp_path / "s.json").write_text(json.dumps(data), encoding="utf-8")
    assert Scenario.load(tmp_path / "s.json").drones[1].start == (3, 2, 2)


def test_missing_world_file(tmp_path: pathlib.Path) -> None:
    data = base()
    data["world"] = {"file": "nowhere.json"}
    (tmp_path / "s.json").write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(UsageError, match="nowhere.json"):
        Scenario.load(tmp_path / "s.json")


def test_invalid_world_file(tmp_path: pathlib.Path) -> None:
    (tmp_path / "w.json").write_text('{"format": "dronesim-world", "version": 7, "size": [4, 4, 4]}')
    data = base()
    data["world"] = {"file": "w.json"}
    with pytest.raises(UsageError, match="version"):
        Scenario.from_json(data, base=tmp_path)


# --------------------------------------------------------------------------- errors


def mutate(fn) -> dict:
    data = base()
    fn(data)
    return data


BAD = {
    "not a dict": ([1, 2], r"not a scenario"),
    "wrong format": (mutate(lambda d: d.update(format="dronesim-world")), r'"format": "dronesim-scenario"'),
    "no format": (mutate(lambda d: d.pop("format")), r"not a scenario"),
    "wrong version": (mutate(lambda d: d.update(version=2)), r'"version": 1'),
    "world not a dict": (mutate(lambda d: d.update(world=[8, 8, 3])), r'"world" must be'),
    "world size short": (mutate(lambda d: d["world"].update(size=[8, 8])), r"world size must be \[x, y, z\]"),
    "world size negative": (mutate(lambda d: d["world"].update(size=[8, -8, 3])), r"world size"),
    "seed not int": (mutate(lambda d: d["world"].update(seed="5")), r"seed must be an integer"),
    "drones missing": (mutate(lambda d: d.pop("drones")), r'"drones" must be a non-empty list'),
    "drones empty": (mutate(lambda d: d.update(drones=[])), r'"drones" must be a non-empty list'),
    "drone not a dict": (mutate(lambda d: d["drones"].append("D03")), r"drone #3 needs an id like D01"),
    "bad drone id": (mutate(lambda d: d["drones"][1].update(id="drone2")), r"drone #2 needs an id like D01"),
    "missing drone id": (mutate(lambda d: d["drones"][0].pop("id")), r"drone #1 needs an id"),
    "duplicate ids": (mutate(lambda d: d["drones"][1].update(id="D01")), r"duplicate drone ids"),
    "duplicate starts": (mutate(lambda d: d["drones"][1].update(start=[0, 0, 0])),
                         r"two drones cannot start in the same cell"),
    "start outside": (mutate(lambda d: d["drones"][1].update(start=[8, 0, 0])),
                      r"D02 starts at \(8, 0, 0\), outside the world"),
    "start negative": (mutate(lambda d: d["drones"][1].update(start=[0, -1, 0])), r"D02 start must be \[x, y, z\]"),
    "start missing": (mutate(lambda d: d["drones"][1].pop("start")), r"D02 start must be"),
    "start floats": (mutate(lambda d: d["drones"][1].update(start=[0.0, 1.0, 0.0])), r"D02 start must be"),
    "unknown autopilot": (mutate(lambda d: d["drones"][1].update(autopilot="astar")),
                          r"D02: unknown autopilot 'astar'; choose one of v1, seed, dstar"),
    "targets for unknown drone": (mutate(lambda d: d["targets"].append("D07=1,1,0")),
                                  r"targets for drones not in the scenario: D07"),
    "target not x,y,z": (mutate(lambda d: d["targets"].append("D01=1,1")), r"bad target 'D01=1,1'"),
    "target garbage": (mutate(lambda d: d["targets"].append("to the moon")), r"bad target 'to the moon'"),
    "target outside": (mutate(lambda d: d["targets"].append("D01=1,1,3")), r"outside the world"),
    "target turn 0": (mutate(lambda d: d["targets"].append("D01=1,1,1@0")), r"turns start at 1"),
    "targets not a list": (mutate(lambda d: d.update(targets="D01=1,1,1")), r'"targets" must be a list'),
    "target not a string": (mutate(lambda d: d["targets"].append([1, 1, 1])), r'"targets" must be a list'),
    "max_turns string": (mutate(lambda d: d.update(max_turns="50")), r"max_turns must be an integer, got '50'"),
    "max_turns float": (mutate(lambda d: d.update(max_turns=50.0)), r"max_turns must be an integer, got 50.0"),
    "max_turns bool": (mutate(lambda d: d.update(max_turns=True)), r"max_turns must be an integer"),
    "max_turns zero": (mutate(lambda d: d.update(max_turns=0)), r"max_turns .* must be >= 1"),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_errors_are_usage_errors(name: str) -> None:
    data, message = BAD[name]
    with pytest.raises(UsageError, match=message):
        Scenario.from_json(copy.deepcopy(data))


def _paths(value: object, path: tuple = ()) -> list[tuple]:
    """Every place in a JSON document: the paths of its dict values and list items, the root excluded."""
    if isinstance(value, dict):
        items = list(value.items())
    elif isinstance(value, list):
        items = list(enumerate(value))
    else:
        return []
    return [p for k, v in items for p in [(*path, k), *_paths(v, (*path, k))]]


JSON_KINDS = (None, True, 0, -1, 2.5, 1 << 70, "", "D01", [], [1, 2, 3], ["D01"], {}, {"id": "D01"})


@pytest.mark.parametrize("kind", JSON_KINDS, ids=repr)
def test_any_value_of_any_json_type_anywhere_is_a_usage_error_or_a_scenario(kind: object,
                                                                           tmp_path: pathlib.Path) -> None:
    """A hand-written scenario can hold anything: whatever value of whatever type replaces any part of it, reading
    it (as JSON, or from a file, which parses drone entries its own way, with or without the plan) either gives a
    scenario or refuses it with a UsageError (e.g. an unhashable drone id once raised TypeError)."""
    file = tmp_path / "s.json"
    for path in _paths(base()):
        data = base()
        node = data
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = copy.deepcopy(kind)
        file.write_text(json.dumps(data))
        for how in ("from_json", "load", "load without the plan"):
            try:
                if how == "from_json":
                    Scenario.from_json(data)
                else:
                    Scenario.load(file, plan=how == "load")
            except UsageError:
                pass
            except Exception as exc:  # named with where the value was put
                pytest.fail(f"{how}, {'/'.join(map(str, path))} = {kind!r}: {exc!r}")


@pytest.mark.parametrize("name", sorted(BAD))
def test_a_file_gives_the_errors_its_json_gives(name: str, tmp_path: pathlib.Path) -> None:
    """Loading compacts drone entries while parsing: the errors, and their order, stay from_json's."""
    data, message = BAD[name]
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data))
    with pytest.raises(UsageError, match=message):
        Scenario.load(path)


def test_load_prefixes_errors_with_the_path(tmp_path: pathlib.Path) -> None:
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(mutate(lambda d: d["drones"][1].update(autopilot="astar"))), encoding="utf-8")
    with pytest.raises(UsageError, match=r"bad\.json: D02: unknown autopilot"):
        Scenario.load(path)


def test_load_unreadable_or_not_json(tmp_path: pathlib.Path) -> None:
    with pytest.raises(UsageError, match="cannot read scenario"):
        Scenario.load(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json", encoding="utf-8")
    with pytest.raises(UsageError, match="cannot read scenario"):
        Scenario.load(tmp_path / "bad.json")


def test_load_binary_file_is_a_usage_error(tmp_path: pathlib.Path) -> None:
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(UsageError, match="cannot read scenario"):
        Scenario.load(tmp_path / "bin.json")


@pytest.mark.parametrize("pilot", [["dstar"], {"name": "dstar"}])
def test_non_string_autopilot_is_a_usage_error(pilot: object) -> None:
    with pytest.raises(UsageError, match="unknown autopilot"):
        Scenario.from_json(mutate(lambda d: d["drones"][0].update(autopilot=pilot)))


@pytest.mark.parametrize("world", [{"size": [0, 8, 3]}, {"size": [8, 8, 3], "seed": -1},
                                   {"size": [100000, 8, 3]}], ids=["size0", "seed-1", "huge"])
def test_world_spec_errors_are_usage_errors(world: dict) -> None:
    with pytest.raises(UsageError):
        Scenario.from_json(mutate(lambda d: d.update(world=world)))


# --------------------------------------------------------------------------- plan and config


def test_defaults() -> None:
    data = base()
    del data["max_turns"], data["targets"]
    for d in data["drones"]:
        d.pop("autopilot")
    s = Scenario.from_json(data)
    assert s.max_turns == 1000
    assert s.targets == ()
    assert s.autopilots == {"D01": "seed", "D02": "seed"}
    assert s.plan().items == ()


def test_plan() -> None:
    s = Scenario.from_json(base())
    plan = s.plan()
    assert plan.items == ((1, "D01", (7, 7, 0)), (3, "D02", (5, 3, 0)))
    assert plan.at(3) == {"D02": (5, 3, 0)}
    assert plan.last_turn == 3


def test_plan_default_drone_is_the_first() -> None:
    data = base()
    data["drones"] = list(reversed(data["drones"]))
    data["targets"] = ["1,1,0", "D01=2,2,0@2"]
    plan = Scenario.from_json(data).plan()
    assert plan.items == ((1, "D02", (1, 1, 0)), (2, "D01", (2, 2, 0)))


def test_game_config_with_deadlines() -> None:
    s = Scenario.from_json(base())
    cfg = s.game_config(phase_deadline=0.5, lost_after=2, gcs_deadline=1.0)
    assert cfg.world == WorldSpec(size=(8, 8, 3), seed=3)
    assert cfg.drones == (DroneSpec(drone="D01", start=(0, 0, 0)), DroneSpec(drone="D02", start=(0, 2, 0)))
    assert cfg.max_turns == 50
    assert (cfg.phase_deadline, cfg.lost_after, cfg.gcs_deadline) == (0.5, 2, 1.0)
    with pytest.raises(UsageError):
        s.game_config(lost_after=0)


def test_scenario_roundtrips_through_a_file(tmp_path: pathlib.Path) -> None:
    path = tmp_path / "s.json"
    path.write_text(json.dumps(base()), encoding="utf-8")
    assert Scenario.load(path) == Scenario.from_json(base())



def test_the_coordinators_reading_leaves_the_plan_out_and_reads_the_same_game(tmp_path) -> None:
    """The coordinator reads a scenario without its targets (the ground station flies and checks them): the
    same game, without a string per target in memory; a plan it cannot cut out safely (a bracket inside) is
    read whole, then left out."""
    data = {"format": "dronesim-scenario", "version": 1, "world": {"size": [8, 8, 3], "seed": 2},
            "drones": [{"id": "D01", "start": [0, 0, 0]}, {"id": "D02", "start": [0, 2, 0]}],
            "targets": ["D01=7,7,1", "D02=7,0,2@3"], "max_turns": 40}
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data))
    whole, game = Scenario.load(path), Scenario.load(path, plan=False)
    assert whole.targets == tuple(data["targets"]) and game.targets == ()
    assert game.game_config() == whole.game_config() and game.autopilots == whole.autopilots
    path.write_text(json.dumps({**data, "targets": ["D01=7,7,1", "D02=]"]}))
    with pytest.raises(UsageError):
        Scenario.load(path)
    assert Scenario.load(path, plan=False).game_config() == whole.game_config()
