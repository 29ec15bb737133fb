"""Lifelong games (issue 37): a drone that reaches its target gets a new one from the ground station
(entities/tasks.py), the engine counts the tasks done, the end and `dronesim replay` say how many and how many a
turn, and the journal replays, verifies and resumes like any other."""

from __future__ import annotations

import json
import logging
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from coordinator import node
from coordinator.config import DroneSpec, GameConfig
from coordinator.journal import dumps, header_config, read, tracks
from coordinator.resume import restore
from dronesim import replay, up
from dronesim.local import Inputs, Result, simulate
from dronesim.scenario import Scenario
from entities.gcs import Ground, Plan, SendDone, Station
from entities.tasks import Tasks
from schema import Cell, DroneState, DroneStatus, EndReason, Intent, Note, Phase, Status, Turn, UsageError, WorldSpec
from schema.tables import code_of
from world.grid import World, build_world

QUIET = logging.getLogger("dronesim.tests.lifelong")
QUIET.addHandler(logging.NullHandler())
QUIET.propagate = False

SPEC = WorldSpec(size=(12, 12, 2), seed=3)
STARTS = [(0, y, 0) for y in range(0, 12, 2)] + [(11, y, 1) for y in range(0, 12, 3)]
DRONES = tuple(DroneSpec(drone=f"D{k + 1:02d}", start=s) for k, s in enumerate(STARTS))
WORLD = build_world(SPEC, STARTS)
TURNS = 120


def play(seed: int = 5, turns: int = TURNS, autopilot: str = "dstar") -> Result:
    config = GameConfig(world=SPEC, drones=DRONES, max_turns=turns, lifelong=True)
    return simulate(config, {d.drone: autopilot for d in DRONES}, Inputs(plan=Plan(()), tasks=Tasks(WORLD, seed)),
                    QUIET)


@pytest.fixture(scope="module")
def game() -> Result:
    return play()


def journal(tmp_path: pathlib.Path, result: Result) -> pathlib.Path:
    path = tmp_path / "lifelong.jsonl"
    path.write_text("".join(dumps(r) + "\n" for r in result.records), encoding="utf-8")
    return path


def story(records: list[dict]) -> list[tuple[int, str, Cell, Cell, Cell | None]]:
    """Every target given after turn 1: (turn, drone, the target, where the drone was at the end of the turn
    before, its former target)."""
    pos = {d.drone: d.start for d in DRONES}
    target: dict[str, Cell | None] = dict.fromkeys(pos)
    out = []
    for r in records:
        if r["record"] != "turn":
            continue
        for d, c in r.get("targets", {}).items():
            if r["turn"] > 1:
                out.append((r["turn"], d, tuple(c), pos[d], target[d]))
            target[d] = tuple(c)
        assert len(set(t for t in target.values() if t is not None)) == \
            sum(t is not None for t in target.values()), f"two drones share a target at turn {r['turn']}"
        for d, c in r.get("moves", {}).items():
            pos[d] = tuple(c)
    return out


# --------------------------------------------------------------------------- the game


def test_a_drone_gets_a_new_target_on_arrival_and_only_then(game: Result) -> None:
    given = story(game.records)
    assert len(given) > 50  # (the drones arrive again and again)
    for turn, d, new, was, old in given:
        assert was == old, f"{d} got a new target at turn {turn} away from its target {old} (at {was})"
        assert new != was and not WORLD.is_building(new)
    first = game.records[1]
    assert first["turn"] == 1 and set(first["targets"]) == {d.drone for d in DRONES}  # every drone, at turn 1
    assert "intent" not in json.dumps(game.records)  # CONTINUE throughout: never FINAL
    assert not any(r.get("deaths") for r in game.records)
    assert game.final is not None and not (game.final.drones.column("note") == code_of(Note.UNREACHABLE)).any()


def test_the_tasks_are_counted_in_the_end_the_over_record_and_replay(game: Result, tmp_path: pathlib.Path) -> None:
    over = game.records[-1]
    assert game.over.reason is EndReason.TURN_LIMIT and over["reason"] == "TURN_LIMIT" and over["turn"] == TURNS
    tasks = over["tasks"]
    assert tasks == game.tasks > 50
    # every arrival but those of the last turn brought a new target: the targets given are the drones' first ones,
    # plus one per task done, less the drones on their target at the end
    assert game.final is not None
    on = int(np.count_nonzero(game.final.drones.column("note") == code_of(Note.REACHED)))
    assert sum(len(r.get("targets", {})) for r in game.records if r["record"] == "turn") == len(DRONES) + tasks - on
    assert game.over.text.startswith(f"{tasks} tasks done in {TURNS} turns, {tasks / TURNS:.3f} a turn; ")
    config, _ = header_config(game.records[0])
    assert config.lifelong and game.records[0]["lifelong"] is True
    tr, last = tracks(config, game.records)
    assert last == TURNS and sum(t.tasks for t in tr.values()) == tasks  # the journal's own count agrees
    out = subprocess.run([sys.executable, "-m", "dronesim", "replay", str(journal(tmp_path, game)), "--verify"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"lifelong: {tasks} tasks done in {TURNS} turns, {tasks / TURNS:.3f} a turn" in out.stdout
    assert "verified" in out.stdout


def test_the_same_seed_plays_the_same_game_another_seed_another(game: Result) -> None:
    assert play().records == game.records
    other = play(seed=6)
    assert other.records[1]["targets"] != game.records[1]["targets"]


def test_a_resumed_lifelong_game_counts_on_from_its_journal(game: Result) -> None:
    config, _ = header_config(game.records[0])
    for k in (10, 60):
        engine = restore(config, game.records[:k + 1], QUIET)  # the header and turns 1..k
        tr, _ = tracks(config, game.records[:k + 1])
        assert engine.turn == k and engine.tasks == sum(t.tasks for t in tr.values())
    with pytest.raises(UsageError, match="another game"):  # a lifelong journal is not an ordinary game's
        restore(GameConfig(world=SPEC, drones=DRONES, max_turns=TURNS), game.records[:11], QUIET)


def test_lrta_swarms_play_lifelong_too() -> None:
    config = GameConfig(world=SPEC, drones=DRONES, max_turns=60, lifelong=True)
    pilots = {d.drone: "lrta" for d in DRONES}
    one = simulate(config, pilots, Inputs(plan=Plan(()), tasks=Tasks(WORLD, 5)), QUIET)
    hosted = simulate(config, pilots, Inputs(plan=Plan(()), tasks=Tasks(WORLD, 5)), QUIET, swarm=True, swarm_min=1)
    assert one.records == hosted.records and one.tasks > 10


# --------------------------------------------------------------------------- the draws


def status(turn: int, *rows: tuple[str, Cell, Cell | None, Note], dead: str = "") -> Status:
    return Status(turn=turn, sender="OBS", drones=tuple(
        DroneStatus(drone=d, pos=p, state=DroneState.DEAD if d == dead else DroneState.ALIVE, target=t, note=n)
        for d, p, t, n in rows))


def test_tasks_go_to_the_drones_on_their_target_or_without_one() -> None:
    world = World.from_buildings((3, 5, 1), [])
    tasks = Tasks(world, 1)
    st = status(4, ("D01", (0, 0, 0), (0, 0, 0), Note.REACHED), ("D02", (1, 1, 0), (2, 4, 0), Note.NONE),
                ("D03", (2, 2, 0), None, Note.NONE), ("D04", (2, 3, 0), (2, 3, 0), Note.REACHED),
                dead="D04")
    new = tasks.assign(5, st)
    assert set(new) == {"D01", "D03"}  # on its target, without one; not D02 (on its way), not D04 (dead)
    assert new["D01"] != (0, 0, 0) and (2, 4, 0) not in new.values() and new["D01"] != new["D03"]
    assert all(not world.is_building(c) for c in new.values())
    assert tasks.assign(5, st) == new and Tasks(world, 1).assign(5, st) == new  # a function of seed, turn, STATUS
    assert tasks.assign(5, st, given={"D01"}).keys() == {"D03"}  # a plan's target comes first


def test_a_new_target_is_in_the_drones_own_part_of_the_world() -> None:
    grid = np.zeros((5, 5, 1), bool)
    grid[2, :, 0] = True  # a wall across: x < 2 and x > 2 are cut off from each other
    world = World.from_grid(grid)
    tasks = Tasks(world, 7)
    for turn in range(1, 30):
        new = tasks.assign(turn, status(turn - 1, ("D01", (0, 0, 0), None, Note.NONE),
                                        ("D02", (4, 4, 0), None, Note.NONE)))
        assert new["D01"][0] < 2 < new["D02"][0]
    others = [(x, y, 0) for x in (0, 1) for y in range(5) if (x, y) != (1, 0)]
    full = status(0, *((f"D{k + 1:02d}", c, c, Note.NONE) for k, c in enumerate(others)),
                  ("D10", (1, 0, 0), (1, 0, 0), Note.REACHED))
    assert tasks.assign(1, full) == {}  # every other cell of its part is someone's target: it keeps its own


# --------------------------------------------------------------------------- the ground station


def station(seed: int = 5) -> Station:
    starts = {"D01": (0, 0, 0), "D02": (0, 2, 0)}
    world = World.from_buildings((10, 10, 5), [])
    return Station(Ground(world, starts, Plan(())), tasks=Tasks(world, seed))


def gcs(t: int) -> Turn:
    return Turn(turn=t, sender="SRV", phase=Phase.GCS)


def dones(effects: list) -> list[tuple[int, dict, Intent, bool]]:
    return [(e.msg.turn, {a.drone: a.pos for a in e.msg.targets}, e.msg.intent, e.ahead)
            for e in effects if isinstance(e, SendDone)]


def test_a_lifelong_station_answers_each_phase_once_the_status_before_it_is_in() -> None:
    s = station()  # (each message a second after the last: its DONEs go out `PUT_GAP` s apart at least)
    assert s.receive(gcs(1), 1.0) == []  # STATUS(0) not in yet: the draws read it
    st0 = status(0, ("D01", (0, 0, 0), None, Note.NONE), ("D02", (0, 2, 0), None, Note.NONE))
    (turn, first, intent, ahead), = dones(s.receive(st0, 2.0))
    assert (turn, intent, ahead) == (1, Intent.CONTINUE, False) and first.keys() == {"D01", "D02"}
    assert first == station().tasks.assign(1, st0)  # (what the in-process game draws)
    st1 = status(1, ("D01", (1, 0, 0), first["D01"], Note.NONE), ("D02", (0, 3, 0), first["D02"], Note.NONE))
    assert dones(s.receive(st1, 3.0)) == []  # nothing answered ahead
    assert dones(s.receive(gcs(2), 4.0)) == [(2, {}, Intent.CONTINUE, False)]
    home = first["D02"]
    st2 = status(2, ("D01", (2, 0, 0), first["D01"], Note.NONE), ("D02", home, home, Note.REACHED))
    s.receive(st2, 5.0)
    (turn, new, intent, _), = dones(s.receive(gcs(3), 6.0))
    assert turn == 3 and new.keys() == {"D02"} and new["D02"] not in (home, first["D01"])
    # a phase the coordinator closed without it (its deadline) is not answered when its STATUS comes late
    assert s.receive(gcs(5), 7.0) == [] and s.receive(Turn(turn=5, sender="SRV", phase=Phase.DRONES), 8.0) == []
    assert dones(s.receive(status(4, ("D01", (2, 0, 0), first["D01"], Note.NONE),
                                  ("D02", home, new["D02"], Note.NONE)), 9.0)) == []


# --------------------------------------------------------------------------- configuration


def scenario_json(lifelong: object) -> dict:
    return {"format": "dronesim-scenario", "version": 1, "world": {"size": [12, 12, 2], "seed": 3},
            "drones": [{"id": d.drone, "start": list(d.start), "autopilot": "dstar"} for d in DRONES],
            "max_turns": 40, "lifelong": lifelong}


def test_a_scenario_says_lifelong_with_the_worlds_seed_or_its_own() -> None:
    assert Scenario.from_json(scenario_json(True)).lifelong == 3
    assert Scenario.from_json(scenario_json({"seed": 9})).lifelong == 9
    assert Scenario.from_json(scenario_json(False)).lifelong is None
    assert Scenario.from_json(scenario_json(True)).game_config().lifelong
    assert not Scenario.from_json(scenario_json(False)).game_config().lifelong
    assert Scenario.from_json(scenario_json(False)).game_config(lifelong=True).lifelong
    for bad in (1, "yes", {"seed": -1}, {"seed": 1, "x": 2}):
        with pytest.raises(UsageError, match="lifelong"):
            Scenario.from_json(scenario_json(bad))


def test_the_commands_play_lifelong() -> None:
    args = node.build_parser().parse_args(["--lifelong", "--drones", "2"])
    assert node.game_config(args).lifelong
    assert not node.game_config(node.build_parser().parse_args(["--drones", "2"])).lifelong
    up_args = up.build_parser().parse_args(["--lifelong", "--seed", "4", "--drones", "2", "--autopilot", "dstar"])
    procs = dict(up.commands(up_args, "tcp/127.0.0.1:7447"))
    assert "--lifelong" in procs["SRV"]
    gcs_argv = procs["GCS"]
    assert gcs_argv[gcs_argv.index("--lifelong") + 1] == "4"


# --------------------------------------------------------------------------- real processes


@pytest.mark.integration
def test_a_lifelong_scenario_over_the_network_is_the_in_process_game(tmp_path: pathlib.Path) -> None:
    from tests.harness import embedded_router, play_scenario

    path = tmp_path / "lifelong.json"
    path.write_text(json.dumps(scenario_json({"seed": 5})), encoding="utf-8")
    with embedded_router() as locator:
        a, _, _ = play_scenario(locator, tmp_path, path, "processes")
        b, _, _ = play_scenario(locator, tmp_path, path, "swarm", "--swarm-pilot-min", "1")
    assert a.read_bytes() == b.read_bytes()
    mine = play(seed=5, turns=40)
    assert a.read_text(encoding="utf-8") == "".join(dumps(r) + "\n" for r in mine.records)
    records = list(read(a))
    config, autopilots = header_config(records[0])
    assert replay.verify(str(a), records, config, autopilots) is None
    assert records[-1]["tasks"] == mine.tasks > 0



def test_the_benchmark_measures_tasks_per_turn(capsys: pytest.CaptureFixture) -> None:
    from benchmarks import lifelong

    assert lifelong.main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert "| warehouse-32 | 40 | 1 | 60 |" in out and "tasks a turn (the same game in every run" in out
