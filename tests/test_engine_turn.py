"""The engine's turn has one home (coordinator/judge.py `Judge`) and two ways through it: over Python's lists up
to TURN_FEW_DRONES alive drones (`Judge._few`), in array operations above (`Judge._arrays`). Random games, each
played with the lists always and with the arrays always, write the same journal byte for byte (a property test);
the RL environments step through the same turn (tests/test_pettingzoo.py, tests/test_golden_journals.py)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from coordinator import engine as engine_module
from coordinator import judge as judge_module
from coordinator.config import replace_config
from coordinator.journal import dumps
from dronesim.local import Inputs, simulate
from dronesim.scenario import Scenario
from entities.gcs import Plan
from entities.tasks import Tasks
from schema import WorldSpec
from world.grid import build_world

QUIET = logging.getLogger("dronesim.tests.turn")
QUIET.addHandler(logging.NullHandler())
QUIET.propagate = False
PILOTS = ("dstar", "seed", "v1", "lrta")


def random_game(case: int) -> tuple[Scenario, Inputs, dict]:
    """A random scenario (world, drones, autopilots, targets) and inputs (missed turns, vanished drones)."""
    rng = np.random.default_rng(case)
    side, height = int(rng.integers(4, 11)), int(rng.integers(1, 4))
    size = (side, side, height)
    spec = WorldSpec(size=size, seed=int(rng.integers(100)))
    cells = [(x, y, z) for x in range(side) for y in range(side) for z in range(height)]
    n = int(rng.integers(1, min(40, len(cells) // 3) + 1))
    order = rng.permutation(len(cells))
    starts = [cells[i] for i in order[:n]]
    world = build_world(spec, starts)
    free = [c for c in (cells[i] for i in order[n:]) if not world.is_building(c)]
    pilots = [PILOTS[i] for i in rng.integers(len(PILOTS), size=n)] if case % 3 else ["dstar"] * n
    drones = [{"id": f"D{i + 1:02d}", "start": list(s), "autopilot": p} for i, (s, p) in enumerate(zip(starts, pilots))]
    targets = [f"D{i + 1:02d}={x},{y},{z}" for i, (x, y, z) in enumerate(free[:n])]
    scenario = Scenario.from_json({"format": "dronesim-scenario", "version": 1,
                                   "world": {"size": list(size), "seed": spec.seed}, "drones": drones,
                                   "targets": targets, "max_turns": int(rng.integers(5, 60))})
    swarm = case % 4 == 0
    ids = [d["id"] for d in drones]
    hovered: dict[int, set[str]] = {}
    for _ in range(0 if swarm else int(rng.integers(0, 4))):  # runs of missed turns (LOST after 3 in a row)
        d, first = ids[int(rng.integers(n))], int(rng.integers(1, 12))
        for t in range(first, first + int(rng.integers(1, 5))):
            hovered.setdefault(t, set()).add(d)
    vanished = {} if swarm or rng.random() < 0.5 else {int(rng.integers(2, 15)): {ids[int(rng.integers(n))]}}
    options = {"swarm": swarm, "arbiter": "pibt" if case % 5 == 1 else "lacam", "lifelong": case % 7 == 3}
    if options["lifelong"]:  # (each drone that arrives gets a new target: the tasks counted each turn)
        return scenario, Inputs(plan=Plan(()), tasks=Tasks(world, case), hovered=hovered, vanished=vanished), options
    return scenario, Inputs(plan=scenario.plan(), hovered=hovered, vanished=vanished), options


def journal(scenario: Scenario, inputs: Inputs, options: dict) -> str:
    config = replace_config(scenario.game_config(), arbiter=options["arbiter"], lifelong=options["lifelong"])
    result = simulate(config, scenario.autopilots, inputs, QUIET, swarm=options["swarm"])
    return "".join(dumps(r) + "\n" for r in result.records)


def few_drones(monkeypatch: pytest.MonkeyPatch, few: int) -> None:
    """TURN_FEW_DRONES set to `few` wherever the turn reads it (`Engine.play`'s inputs, the judge's way)."""
    for module in (engine_module, judge_module):
        monkeypatch.setattr(module, "TURN_FEW_DRONES", few)


@pytest.mark.parametrize("case", range(30))
def test_a_turn_over_lists_is_the_turn_in_arrays(case: int, monkeypatch: pytest.MonkeyPatch) -> None:
    scenario, inputs, options = random_game(case)
    few_drones(monkeypatch, 10**6)
    lists = journal(scenario, inputs, options)
    few_drones(monkeypatch, 0)
    arrays = journal(scenario, inputs, options)
    assert lists == arrays
    assert lists.count("\n") > 2  # (a game was played)


@pytest.mark.parametrize("few", [10**6, 0])
def test_a_drone_lost_after_its_move_was_taken_still_makes_it(few: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """A host vanishes after its MOVES: its drones are LOST, their moves taken still made (the cells and notes),
    over lists as in arrays; the drone still awaited hovers. (The edge the lists take their rows in play for.)"""
    from schema import Moves, Note, StepTable
    from schema.tables import code_of
    from tests.test_engine import Game, config, records

    few_drones(monkeypatch, few)
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), ("D03", (2, 2, 2))),
             hosts={"H01": ("D01", "D02"), "D03": ("D03",)})
    g.gcs()
    steps = StepTable.build(drone=[1, 2], pos=[(1, 0, 0), (4, 4, 3)], note=[code_of(Note.NONE)] * 2)
    g.feed(g.engine.receive(Moves(turn=1, sender="H01", moves=steps)))
    g.feed(g.engine.vanished("H01"))
    g.nps("D03", (2, 2, 2), Note.UNREACHABLE)
    assert records(g.effects)[-1] == {"record": "turn", "turn": 1, "lost": ["D01", "D02"],
                                      "moves": {"D01": [1, 0, 0], "D02": [4, 4, 3]}, "notes": {"D03": "UNREACHABLE"},
                                      "state": records(g.effects)[-1]["state"]}
    assert g.status("D01").pos == (1, 0, 0)


def test_a_few_moves_among_many_alive_drones_are_made() -> None:
    """`Engine.play` given fewer moves than alive drones, these more than TURN_FEW_DRONES (so the turn is the arrays'):
    the moves given are made (they were left out, and the drones hovered), the other drones hover."""
    from coordinator.config import DroneTable, GameConfig
    from dronesim.rl import local_game
    from world.grid import World

    world = World(size=(20, 20, 2), grid=np.zeros((20, 20, 2), bool))
    starts = [(x, y, 0) for x in range(0, 20, 2) for y in range(0, 14, 2)]
    assert len(starts) > judge_module.TURN_FEW_DRONES
    game = GameConfig(world=WorldSpec(size=world.size, cells=world.packed()),
                      drones=DroneTable([f"D{i:02d}" for i in range(1, len(starts) + 1)], starts))
    engine = local_game(game, world, QUIET)
    fleet = engine.fleet
    rows = [fleet.index["D01"], fleet.index["D70"]]
    before = fleet.pos.copy()
    engine.play([], [], rows, [(1, 0, 0), (18, 12, 1)], [0, 0])
    moved = np.flatnonzero((fleet.pos != before).any(axis=1)).tolist()
    assert sorted(moved) == sorted(rows) and fleet.pos[rows].tolist() == [[1, 0, 0], [18, 12, 1]]


@pytest.mark.parametrize("cooperative", [(), (0, 2)])
def test_a_restarted_game_is_a_new_game(cooperative: tuple[int, ...]) -> None:
    """`Engine.restart` (an RL environment's next episode): after turns with targets, moves and a death, the game
    restarted from new starts is the game a new engine started here from them, turn by turn (their states, each
    turn's OVER), the cooperative drones' arbitration included."""
    from coordinator.config import DroneTable, GameConfig
    from coordinator.engine import Engine
    from schema import UsageError
    from world.grid import World

    world = World(size=(6, 6, 2), grid=np.zeros((6, 6, 2), bool))
    spec = WorldSpec(size=world.size, cells=world.packed())

    def started(starts: list) -> Engine:
        game = GameConfig(world=spec, drones=DroneTable(["D01", "D02", "D03"], starts), max_turns=6)
        engine = Engine(game, QUIET, world)
        engine.verify_env = engine.journaled = engine.env_followed = False
        engine.start_here("H01", "dstar", cooperative)
        return engine

    def state(engine: Engine) -> str:
        f = engine.fleet
        return repr((engine.stage, engine.turn, engine.final, engine.end, engine.tasks, engine.intent,
                     f.pos.tolist(), f.state.tolist(), f.target.tolist(), f.note.tolist(), f.done.tolist(),
                     f.cause.tolist(), f.misses.tolist(), f.missing, f.cooperative.tolist(), f.host, f.autopilot,
                     engine.arbitration.priority.tolist(), engine.aiming.aimed.tolist(), engine.ballot.moved.tolist()))

    def turns(engine: Engine) -> list:
        out = []
        for t in range(7):
            if engine.end is not None:
                break
            alive = engine.fleet.alive_rows().tolist()
            cells = [tuple(p) for p in engine.fleet.pos[alive].tolist()]
            moves = [(x + 1, y, z) if t % 2 else (x, min(y + 1, 5), z) for x, y, z in cells]  # (off the world, at last)
            aims = ([0, 1, 2], [(5, 5, 0), (0, 5, 1), (5, 0, 1)]) if t == 0 else ([], [])
            out.append((engine.play(*aims, alive, moves, [0] * len(alive)), state(engine)))
        return out

    old = started([(0, 0, 0), (0, 2, 0), (3, 3, 0)])
    turns(old)
    new_starts = [(2, 2, 1), (4, 0, 0), (0, 5, 1)]
    old.restart(np.array(new_starts))
    fresh = started(new_starts)
    assert state(old) == state(fresh)
    assert turns(old) == turns(fresh)
    with pytest.raises(UsageError, match="started here"):
        Engine(GameConfig(world=spec, drones=DroneTable(["D01"], [(0, 0, 0)])), QUIET, world).restart([(1, 1, 1)])
