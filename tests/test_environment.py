"""The environment's state: ASK answers, moves (UPD), sync from STATUS, and building the world."""

from __future__ import annotations

import numpy as np
import pytest

from dronesim.entities.environment import Environment, build_world
from dronesim.entities.world import Building, World
from dronesim.schema import (
    CellInfo, CellKind, DroneState, DroneStatus, Move, OutOfRange, Status, UnknownEntity, WorldSpec,
)

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
    changed = e.apply([move("D02", (3, 3, 0), (3, 2, 0)), move("D01", (0, 0, 0), (1, 0, 0))])
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
    e.apply([move("D01", (0, 0, 0), (0, 1, 0))])
    changed = e.apply([move("D01", (0, 1, 0), (1, 1, 0))])
    assert changed == (info((0, 1, 0)), info((1, 1, 0), CellKind.BUILDING, "D01"))


def test_apply_swap_and_shared_cell() -> None:
    e = Environment(world(), {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (0, 2, 0)})
    changed = e.apply([move("D01", (0, 0, 0), (1, 0, 0)), move("D02", (1, 0, 0), (0, 0, 0)),
                       move("D03", (0, 2, 0), (0, 2, 1))])
    assert changed == (info((0, 0, 0), CellKind.EMPTY, "D02"), info((0, 2, 0)),
                       info((0, 2, 1), CellKind.EMPTY, "D03"), info((1, 0, 0), CellKind.EMPTY, "D01"))
    changed = e.apply([move("D02", (0, 0, 0), (0, 1, 0)), move("D01", (1, 0, 0), (0, 0, 0))])
    assert changed == (info((0, 0, 0), CellKind.EMPTY, "D01"), info((0, 1, 0), CellKind.EMPTY, "D02"),
                       info((1, 0, 0)))
    e.apply([move("D02", (0, 1, 0), (0, 0, 0))])
    assert e.what_inside((0, 0, 0)).drones == ("D01", "D02")


@pytest.mark.parametrize("dst", [(-1, 0, 0), (0, -1, 0), (0, 0, -1)])
def test_drones_leaving_the_world_are_removed(dst) -> None:
    e = env()
    changed = e.apply([move("D01", (0, 0, 0), dst)])
    assert changed == (info((0, 0, 0)),), "only in-world cells are reported"
    assert "D01" not in e.drones
    assert e.drones == {"D02": (3, 3, 0)}
    assert e.what_inside(dst).kind is CellKind.OUTSIDE
    with pytest.raises(UnknownEntity):
        e.apply([move("D01", (0, 0, 0), (1, 0, 0))])


def test_leaving_through_the_far_faces() -> None:
    e = env()
    assert e.apply([move("D02", (3, 3, 0), (4, 3, 0))]) == (info((3, 3, 0)),)
    assert e.drones == {"D01": (0, 0, 0)}


def test_no_moves_change_nothing() -> None:
    e = env()
    assert e.apply([]) == ()
    assert e.drones == {"D01": (0, 0, 0), "D02": (3, 3, 0)}


@pytest.mark.parametrize("bad,error", [
    (move("D02", (3, 2, 0), (3, 1, 0)), OutOfRange),  # wrong source
    (move("D09", (2, 2, 2), (2, 2, 1)), UnknownEntity),  # not in the world
])
def test_a_bad_move_is_refused_whole(bad: Move, error: type) -> None:
    e = env()
    before = (dict(e.drones), e.answer([(0, 0, 0), (1, 0, 0), (3, 3, 0), (3, 2, 0)]))
    with pytest.raises(error, match=bad.drone):
        e.apply([move("D01", (0, 0, 0), (1, 0, 0)), bad])  # the good move comes first
    assert (dict(e.drones), e.answer([(0, 0, 0), (1, 0, 0), (3, 3, 0), (3, 2, 0)])) == before


def status(*items) -> Status:
    return Status(turn=4, sender="OBS", drones=tuple(
        DroneStatus(drone=d, pos=p, state=s) for d, p, s in items))


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
    e.apply([move("D01", (0, 0, 0), (1, 0, 0))])
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
    from dronesim.schema import Ans, Ask

    e = Environment(World.generate((6, 6, 4), np.random.default_rng(5)), {"D01": (0, 0, 0), "D02": (2, 3, 1)})
    cells = tuple((x, y, z) for x in range(-1, 7) for y in (0, 3, 6) for z in (-1, 0, 1, 4))
    kinds, drones = e.survey(cells)
    assert Ans(turn=1, sender="ENV", kinds=kinds, drones=drones).infos(cells) == e.answer(cells)
    assert drones == ((cells.index((0, 0, 0)), "D01"), (cells.index((2, 3, 1)), "D02"))
    assert e.survey(()) == (b"", ())
    ask = Ask(turn=1, sender="H01", cells=cells[:5], around=((1, 0, 0), (2, 3, 0), (5, 5, 3)))
    kinds, drones = e.survey(ask.cells, ask.around)
    assert Ans(turn=1, sender="ENV", kinds=kinds, drones=drones).infos(ask.asked()) == e.answer(ask.asked())


def test_following_status_only_while_someone_needs_the_drones() -> None:
    from dronesim.entities.environment import Following

    f = Following(turns=2)
    assert not f.wanted(waiting=False), "nobody asked: the environment does not follow STATUS"
    assert f.wanted(waiting=True), "an ASK waits for its turn's STATUS"
    f.asked()
    assert f.wanted(waiting=False)
    f.status(), f.status()
    assert f.wanted(waiting=False), "for `turns` STATUS after the last question"
    f.status()
    assert not f.wanted(waiting=False)
    f.listened = True
    assert f.wanted(waiting=False), "someone listens to the UPD reports, made from every turn"
    f.listened = False
    f.asked()
    assert f.wanted(waiting=False)
