"""The environment, without a network: its state (ASK answers, moves and UPD, sync from STATUS, building
the world) and its protocol (`EnvironmentProcess`, driven by messages, returning effects)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from entities.environment import (
    Environment,
    EnvironmentProcess,
    Fail,
    Follow,
    Refusal,
    ReplyToQuery,
    Report,
    build_world,
)
from schema import (
    Ans,
    Ask,
    CellInfo,
    CellKind,
    DroneState,
    DroneStatus,
    EndReason,
    MapRequest,
    Move,
    MoveTable,
    OutOfRange,
    Over,
    Phase,
    Start,
    StartTable,
    Status,
    StatusTable,
    Turn,
    UnknownEntity,
    Upd,
    Welcome,
    WorldMap,
    WorldSpec,
)
from schema.errors import StaleTurn, WrongSender
from world.grid import Building, World

SIZE = (4, 4, 3)


def world() -> World:
    # one building: x 1..2, y 1, z 0..1
    return World.from_buildings(SIZE, [Building(x=1, y=1, length=2, width=1, height=2)])


def env(**drones) -> Environment:
    return Environment(world(), drones or {"D01": (0, 0, 0), "D02": (3, 3, 0)})


def info(pos, kind=CellKind.EMPTY, *drones) -> CellInfo:
    return CellInfo(pos=pos, kind=kind, drones=tuple(drones))


def move(drone, src, dst) -> Move:
    return Move(drone=drone, src=src, dst=dst)


def test_answer_in_order_of_the_question() -> None:
    e = env()
    cells = ((1, 1, 0), (0, 0, 0), (-1, 0, 0), (1, 1, 2), (3, 3, 0), (0, 0, 3), (4, 0, 0))
    assert e.answer(cells) == (
        info((1, 1, 0), CellKind.BUILDING),
        info((0, 0, 0), CellKind.EMPTY, "D01"),
        info((-1, 0, 0), CellKind.OUTSIDE),
        info((1, 1, 2), CellKind.EMPTY),
        info((3, 3, 0), CellKind.EMPTY, "D02"),
        info((0, 0, 3), CellKind.OUTSIDE),
        info((4, 0, 0), CellKind.OUTSIDE),
    )
    assert e.answer(()) == ()
    assert e.answer([(0, 0, 0), (0, 0, 0)]) == (info((0, 0, 0), CellKind.EMPTY, "D01"),) * 2


def test_answer_lists_several_drones_sorted() -> None:
    e = Environment(world(), {"D03": (0, 0, 0), "D01": (0, 0, 0)})
    assert e.what_inside((0, 0, 0)) == info((0, 0, 0), CellKind.EMPTY, "D01", "D03")


def test_apply_returns_sorted_changed_cells_with_occupants() -> None:
    e = env()
    changed = e.apply(MoveTable.of([move("D02", (3, 3, 0), (3, 2, 0)), move("D01", (0, 0, 0), (1, 0, 0))]))
    assert changed == (
        info((0, 0, 0)),
        info((1, 0, 0), CellKind.EMPTY, "D01"),
        info((3, 2, 0), CellKind.EMPTY, "D02"),
        info((3, 3, 0)),
    )
    assert e.drones == {"D01": (1, 0, 0), "D02": (3, 2, 0)}
    assert e.what_inside((1, 0, 0)).drones == ("D01",)
    assert e.what_inside((0, 0, 0)).drones == ()


def test_apply_into_a_building_reports_it() -> None:
    e = env()
    e.apply(MoveTable.of([move("D01", (0, 0, 0), (0, 1, 0))]))
    changed = e.apply(MoveTable.of([move("D01", (0, 1, 0), (1, 1, 0))]))
    assert changed == (info((0, 1, 0)), info((1, 1, 0), CellKind.BUILDING, "D01"))


def test_apply_swap_and_shared_cell() -> None:
    e = Environment(world(), {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (0, 2, 0)})
    changed = e.apply(MoveTable.of([move("D01", (0, 0, 0), (1, 0, 0)), move("D02", (1, 0, 0), (0, 0, 0)),
                       move("D03", (0, 2, 0), (0, 2, 1))]))
    assert changed == (info((0, 0, 0), CellKind.EMPTY, "D02"), info((0, 2, 0)),
                       info((0, 2, 1), CellKind.EMPTY, "D03"), info((1, 0, 0), CellKind.EMPTY, "D01"))
    changed = e.apply(MoveTable.of([move("D02", (0, 0, 0), (0, 1, 0)), move("D01", (1, 0, 0), (0, 0, 0))]))
    assert changed == (info((0, 0, 0), CellKind.EMPTY, "D01"), info((0, 1, 0), CellKind.EMPTY, "D02"),
                       info((1, 0, 0)))
    e.apply(MoveTable.of([move("D02", (0, 1, 0), (0, 0, 0))]))
    assert e.what_inside((0, 0, 0)).drones == ("D01", "D02")


@pytest.mark.parametrize("dst", [(-1, 0, 0), (0, -1, 0), (0, 0, -1)])
def test_drones_leaving_the_world_are_removed(dst) -> None:
    e = env()
    changed = e.apply(MoveTable.of([move("D01", (0, 0, 0), dst)]))
    assert changed == (info((0, 0, 0)),), "only in-world cells are reported"
    assert "D01" not in e.drones
    assert e.drones == {"D02": (3, 3, 0)}
    assert e.what_inside(dst).kind is CellKind.OUTSIDE
    with pytest.raises(UnknownEntity):
        e.apply(MoveTable.of([move("D01", (0, 0, 0), (1, 0, 0))]))


def test_leaving_through_the_far_faces() -> None:
    e = env()
    assert e.apply(MoveTable.of([move("D02", (3, 3, 0), (4, 3, 0))])) == (info((3, 3, 0)),)
    assert e.drones == {"D01": (0, 0, 0)}


def test_no_moves_change_nothing() -> None:
    e = env()
    assert e.apply(MoveTable.of([])) == ()
    assert e.drones == {"D01": (0, 0, 0), "D02": (3, 3, 0)}


@pytest.mark.parametrize("bad,error", [
    (move("D02", (3, 2, 0), (3, 1, 0)), OutOfRange),  # wrong source
    (move("D09", (2, 2, 2), (2, 2, 1)), UnknownEntity),  # not in the world
])
def test_a_bad_move_is_refused_whole(bad: Move, error: type) -> None:
    e = env()
    before = (dict(e.drones), e.answer([(0, 0, 0), (1, 0, 0), (3, 3, 0), (3, 2, 0)]))
    with pytest.raises(error, match=bad.drone):
        e.apply(MoveTable.of([move("D01", (0, 0, 0), (1, 0, 0)), bad]))  # the good move comes first
    assert (dict(e.drones), e.answer([(0, 0, 0), (1, 0, 0), (3, 3, 0), (3, 2, 0)])) == before


def status(*items) -> Status:
    return Status(turn=4, sender="OBS", drones=StatusTable.of(
        [DroneStatus(drone=d, pos=p, state=s) for d, p, s in items]))


def test_sync_takes_alive_drones_and_removes_dead_and_lost() -> None:
    e = Environment(world(), {"D01": (0, 0, 0), "D02": (3, 3, 0), "D03": (2, 2, 2), "D04": (0, 3, 0)})
    e.sync(status(("D01", (0, 1, 0), DroneState.ALIVE),
                  ("D02", (1, 1, 0), DroneState.DEAD),
                  ("D03", (2, 2, 2), DroneState.LOST),
                  ("D04", (-1, 3, 0), DroneState.DEAD)))
    assert e.drones == {"D01": (0, 1, 0)}
    assert e.what_inside((0, 0, 0)).drones == ()
    assert e.what_inside((0, 1, 0)).drones == ("D01",)
    assert e.what_inside((1, 1, 0)) == info((1, 1, 0), CellKind.BUILDING)
    assert e.what_inside((2, 2, 2)).drones == ()


def test_sync_ignores_alive_drones_outside_the_world() -> None:
    e = env()
    e.sync(status(("D01", (5, 0, 0), DroneState.ALIVE), ("D02", (3, 3, 1), DroneState.ALIVE)))
    assert e.drones == {"D02": (3, 3, 1)}


def test_constructor_copies_the_drones() -> None:
    drones = {"D01": (0, 0, 0)}
    e = Environment(world(), drones)
    e.apply(MoveTable.of([move("D01", (0, 0, 0), (1, 0, 0))]))
    assert drones == {"D01": (0, 0, 0)}


# --------------------------------------------------------------------------- build_world


@pytest.mark.parametrize("seed", range(25))
def test_seeded_generation_keeps_starts_free(seed: int) -> None:
    starts = [(0, 0, 0), (1, 0, 0), (5, 5, 0), (9, 9, 9), (4, 4, 3)]
    w = build_world(WorldSpec(size=(10, 10, 10), seed=seed), starts)
    for s in starts:
        assert not w.is_building(s), (seed, s)
    assert w == build_world(WorldSpec(size=(10, 10, 10), seed=seed), starts), "same seed, same world"


def test_seeded_generation_has_buildings_and_depends_on_the_seed() -> None:
    worlds = [build_world(WorldSpec(size=(10, 10, 10), seed=s), [(0, 0, 0)]) for s in range(6)]
    assert all(w.grid.any() for w in worlds)
    assert len({w.packed() for w in worlds}) > 1
    assert all(w.size == (10, 10, 10) for w in worlds)


def test_seeded_generation_is_the_world_generator() -> None:
    spec = WorldSpec(size=(8, 6, 5), seed=42)
    expected = World.generate((8, 6, 5), np.random.default_rng(42), keep_free=((0, 0, 0),))
    assert build_world(spec, [(0, 0, 0)]) == expected


def test_cells_spec_gives_exactly_that_world() -> None:
    grid = np.zeros((3, 2, 2), dtype=bool)
    grid[0, 0, 0] = grid[2, 1, 1] = grid[1, 0, 1] = True
    packed = np.packbits(grid.ravel(order="C")).tobytes()
    w = build_world(WorldSpec(size=(3, 2, 2), seed=99, cells=packed), [(0, 1, 0)])
    assert w.size == (3, 2, 2)
    assert np.array_equal(w.grid, grid)
    assert w.packed() == packed
    assert w.is_building((0, 0, 0)) and not w.is_building((0, 0, 1))


def test_cells_spec_round_trips_a_generated_world() -> None:
    gen = build_world(WorldSpec(size=(10, 10, 10), seed=5), [(0, 0, 0)])
    again = build_world(WorldSpec(size=(10, 10, 10), cells=gen.packed()), [])
    assert np.array_equal(again.grid, gen.grid)


def test_survey_answers_as_answer_does() -> None:
    """The ANS form (kind bytes and occupied cells) says what `answer` says, cell by cell."""
    e = Environment(World.generate((6, 6, 4), np.random.default_rng(5)), {"D01": (0, 0, 0), "D02": (2, 3, 1)})
    cells = tuple((x, y, z) for x in range(-1, 7) for y in (0, 3, 6) for z in (-1, 0, 1, 4))
    kinds, drones = e.survey(cells)
    assert Ans(turn=1, sender="ENV", kinds=kinds, drones=drones).infos(cells) == e.answer(cells)
    assert drones == ((cells.index((0, 0, 0)), "D01"), (cells.index((2, 3, 1)), "D02"))
    assert e.survey(()) == (b"", ())
    ask = Ask(turn=1, sender="H01", cells=cells[:5], around=((1, 0, 0), (2, 3, 0), (5, 5, 3)))
    kinds, drones = e.survey(ask.cells, ask.around)
    assert Ans(turn=1, sender="ENV", kinds=kinds, drones=drones).infos(ask.asked()) == e.answer(ask.asked())


# --------------------------------------------------------------------------- the protocol (EnvironmentProcess)


def process(follow: bool = False) -> EnvironmentProcess:
    """An environment process welcomed into a game on `world()` (drones D01 at (0,0,0), D02 at (3,3,0))."""
    starts = StartTable.of([Start(drone=d, pos=c) for d, c in {"D01": (0, 0, 0), "D02": (3, 3, 0)}.items()])
    return EnvironmentProcess(Welcome(turn=0, sender="SRV", entity="ENV", text="", starts=starts,
                                      world=WorldSpec(size=SIZE, cells=world().packed())), follow=follow)


def ask(turn: int, *cells, sender: str = "D01") -> Ask:
    return Ask(turn=turn, sender=sender, cells=cells or ((0, 0, 0),))


def env_phase(turn: int, *moves: Move) -> Turn:
    return Turn(turn=turn, sender="SRV", phase=Phase.ENV, moves=MoveTable.of(list(moves)))


def status_of(turn: int, **cells) -> Status:
    return Status(turn=turn, sender="OBS", drones=StatusTable.of(
        [DroneStatus(drone=d, pos=c, state=DroneState.ALIVE) for d, c in sorted(cells.items())]))


def replied(effects, query) -> Any:  # (an Ans or a WorldMap, as the query asked)
    (eff,) = [e for e in effects if getattr(e, "query", None) == query]
    assert isinstance(eff, ReplyToQuery), effects
    return eff.msg


def refused(effects, query, error: type) -> str:
    """The error reply to `query`, and the refusal counted with it, of type `error`."""
    fails = [e for e in effects if isinstance(e, Fail) and e.query == query]
    counted = [e for e in effects if isinstance(e, Refusal)]
    assert len(fails) == 1 and len(counted) == 1 and isinstance(counted[0].err, error), effects
    return fails[0].why


def test_an_ask_of_the_turn_is_answered_from_the_world_at_its_start() -> None:
    p = process()
    ans = replied(p.asked("q", ask(1, (0, 0, 0), (1, 1, 0), (3, 3, 0), (5, 0, 0))), "q")
    assert ans == Ans(turn=1, sender="ENV", kinds=bytes([CellKind.EMPTY, CellKind.BUILDING, CellKind.EMPTY,
                                                          CellKind.OUTSIDE]), drones=((0, "D01"), (2, "D02")))


def test_an_ask_for_turn_0_asks_the_static_world_and_is_answered_at_once() -> None:
    p = process()
    p.receive(status_of(3, D01=(0, 0, 0), D02=(3, 3, 0)))
    ans = replied(p.asked("q", ask(0, (0, 0, 0), (1, 1, 0))), "q")
    assert ans.turn == 0 and ans.kinds == bytes([CellKind.EMPTY, CellKind.BUILDING]) and ans.drones == ()


def test_an_early_ask_waits_for_the_status_of_the_turn_before() -> None:
    p = process()
    assert p.asked("q2", ask(2, (1, 0, 0))) == [Follow(moves=False, status=True)], \
        "turn 2's world is not known yet: every STATUS is followed from now on"
    assert p.asked("q3", ask(3, (1, 0, 0))) == []
    effects = p.receive(status_of(1, D01=(1, 0, 0), D02=(3, 3, 0)))
    assert replied(effects, "q2").drones == ((0, "D01"),), "answered from STATUS(1)"
    assert all(getattr(e, "query", None) != "q3" for e in effects), "turn 3 still waits"
    assert replied(p.receive(status_of(2, D01=(2, 0, 0), D02=(3, 3, 0))), "q3").drones == ()


def test_an_ask_for_a_past_turn_is_refused_and_counted() -> None:
    p = process()
    p.receive(status_of(4, D01=(0, 0, 0), D02=(3, 3, 0)))
    assert "past turn 4" in refused(p.asked("q", ask(4)), "q", StaleTurn)
    assert replied(p.asked("q5", ask(5)), "q5").turn == 5


def test_a_waiting_ask_the_game_went_past_is_refused() -> None:
    p = process()
    p.asked("q", ask(3))
    assert "turn 3" in refused(p.receive(status_of(5, D01=(0, 0, 0), D02=(3, 3, 0))), "q", StaleTurn)


@pytest.mark.parametrize("sender", ["GCS", "ENV", "SRV"])
def test_only_drones_and_swarm_hosts_ask(sender) -> None:
    p = process()
    assert "only drones ask" in refused(p.asked("q", ask(1, sender=sender)), "q", WrongSender)
    assert replied(p.asked("h", ask(1, sender="H01")), "h").drones == ((0, "D01"),)


def test_the_map_is_the_static_world() -> None:
    p = process()
    msg = replied(p.asked("q", MapRequest(turn=0, sender="GCS")), "q")
    assert isinstance(msg, WorldMap) and msg.size == SIZE and msg.buildings == world().packed()


def test_the_env_phase_is_followed_and_reported_only_while_someone_listens_to_the_upd() -> None:
    p = process()
    assert p.listened(False) == [], "nobody listened before either"
    assert p.listened(True) == [Follow(moves=True, status=True)]
    assert p.listened(True) == []
    (report,) = p.receive(env_phase(1, move("D01", (0, 0, 0), (1, 0, 0))))
    assert report == Report(Upd(turn=1, sender="ENV", cells=(info((0, 0, 0)), info((1, 0, 0), CellKind.EMPTY, "D01"))))
    assert p.listened(False) == [Follow(moves=False, status=False)]
    p.receive(status_of(1, D01=(1, 0, 0), D02=(3, 3, 0)))
    assert p.receive(env_phase(2, move("D01", (1, 0, 0), (2, 0, 0)))) == [], "moved, reported to nobody"
    p.receive(status_of(2, D01=(2, 0, 0), D02=(3, 3, 0)))
    assert replied(p.asked("q", ask(3, (2, 0, 0))), "q").drones == ((0, "D01"),)


def test_an_env_phase_before_the_status_of_the_turn_before_waits_for_it() -> None:
    p = process()
    p.listened(True)
    p.receive(env_phase(1, move("D01", (0, 0, 0), (1, 0, 0))))
    assert p.receive(env_phase(2, move("D01", (1, 0, 0), (2, 0, 0)))) == [], "STATUS(1) has not come yet"
    (report,) = p.receive(status_of(1, D01=(1, 0, 0), D02=(3, 3, 0)))
    assert isinstance(report, Report)
    assert report.msg.turn == 2 and report.msg.cells[-1] == info((2, 0, 0), CellKind.EMPTY, "D01")
    assert p.receive(env_phase(1, move("D01", (0, 0, 0), (1, 0, 0)))) == [], "the turn before: nothing to apply"


def test_an_env_phase_of_another_turn_or_with_bad_moves_is_refused_and_changes_nothing() -> None:
    p = process()
    p.listened(True)
    (refusal,) = p.receive(env_phase(5, move("D01", (0, 0, 0), (1, 0, 0))))
    assert isinstance(refusal, Refusal) and isinstance(refusal.err, StaleTurn)
    (refusal,) = p.receive(env_phase(1, move("D01", (2, 2, 0), (2, 2, 1))))
    assert isinstance(refusal, Refusal) and isinstance(refusal.err, OutOfRange)
    assert replied(p.asked("q", ask(1)), "q").drones == ((0, "D01"),)


def test_status_is_taken_when_handed_and_followed_from_the_first_ask_that_waits_for_it() -> None:
    """Drones that chart the map ask nothing: the environment takes only the STATUS handed to it (the newest, before
    a query), skips the others, and follows every one once an ASK had to wait, whoever listens to the UPD."""
    p = process()
    assert p.receive(status_of(6, D01=(2, 0, 0), D02=(3, 3, 0))) == [], "turns 1 to 6 skipped"
    assert replied(p.asked("q", ask(7, (2, 0, 0))), "q").drones == ((0, "D01"),)
    assert p.asked("q9", ask(9, (2, 0, 0))) == [Follow(moves=False, status=True)]
    assert p.listened(True) == [Follow(moves=True, status=True)]
    assert p.listened(False) == [Follow(moves=False, status=True)], "still followed: an ASK waited"
    assert replied(p.receive(status_of(8, D01=(1, 0, 0), D02=(3, 3, 0))), "q9").drones == ()


def test_with_follow_it_takes_every_status_from_the_start() -> None:
    assert process().start() == [], "by default it follows nothing at first"
    p = process(follow=True)
    assert p.start() == [Follow(moves=False, status=True)]
    assert p.listened(True) == [Follow(moves=True, status=True)]
    assert p.listened(False) == [Follow(moves=False, status=True)]


def test_a_status_not_newer_than_the_last_taken_changes_nothing() -> None:
    """The newest STATUS is handed again when none came since (or after one taken from the subscription): nothing
    changes, not even an ENV phase applied since."""
    p = process()
    p.listened(True)
    p.receive(status_of(1, D01=(0, 0, 0), D02=(3, 3, 0)))
    assert p.receive(env_phase(2, move("D01", (0, 0, 0), (1, 0, 0)))) != []
    for old in (status_of(1, D01=(0, 0, 0), D02=(3, 3, 0)), status_of(0, D01=(2, 2, 0), D02=(3, 3, 0))):
        assert p.receive(old) == []
    assert replied(p.asked("q", ask(2, (1, 0, 0))), "q").drones == ((0, "D01"),), "where the ENV phase moved it"


def test_over_ends_the_game_and_refuses_the_asks_still_waiting() -> None:
    p = process()
    p.asked("q", ask(3))
    over = Over(turn=2, sender="SRV", reason=EndReason.TURN_LIMIT)
    assert p.receive(over) == [Fail("q", "the game is over")]
    assert p.over == over
    assert p.asked("q4", ask(4)) == [Fail("q4", "the game is over")], "after the end, one for a later turn too"
    assert replied(p.asked("q0", ask(0, (1, 1, 0))), "q0").kinds == bytes([CellKind.BUILDING]), "the static world"
