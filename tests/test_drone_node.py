"""The drone process's pure parts: how it reads the environment's answers."""

from __future__ import annotations


from dronesim.schema import CellInfo



def test_chart_remembers_what_it_was_told_and_lists_the_unknown_neighbours() -> None:
    from dronesim.entities.drone_node import Chart
    from dronesim.schema import CellKind

    chart = Chart((4, 4, 2))
    assert chart.kind((1, 1, 1)) is None and chart.kind((-1, 0, 0)) is CellKind.OUTSIDE
    assert chart.unknown([(0, 0, 0)]) == ((1, 0, 0), (0, 1, 0), (0, 0, 1))  # in AROUND order, in the world
    chart.learn([(1, 0, 0), (0, 1, 0), (9, 9, 9)], bytes([CellKind.BUILDING, CellKind.EMPTY, CellKind.OUTSIDE]))
    assert chart.kind((1, 0, 0)) is CellKind.BUILDING and chart.kind((0, 1, 0)) is CellKind.EMPTY
    assert chart.unknown([(0, 0, 0), (0, 0, 1)]) == ((0, 0, 1), (1, 0, 1), (0, 1, 1), (0, 0, 0))


def test_answers_from_the_chart_are_what_the_environment_says() -> None:
    """Kinds the environment told once, and the drones in each cell from the turn's orders, give the
    same CellInfo as an ASK for that turn."""
    import numpy as np

    from dronesim.entities.drone_node import Chart, occupancy_of
    from dronesim.entities.environment import Environment
    from dronesim.entities.world import World
    from dronesim.schema import Ans, Order, OrderTable

    starts = {"D01": (1, 1, 1), "D02": (2, 1, 1), "D03": (2, 1, 1)}
    e = Environment(World.generate((6, 6, 4), np.random.default_rng(2)), starts)
    cells = tuple((x, y, z) for x in range(-1, 7) for y in range(-1, 7) for z in (0, 1, 3))
    kinds, none = e.survey(cells, drones=False)
    assert none == ()
    chart = Chart((6, 6, 4))
    chart.learn(cells, kinds)
    occupied = occupancy_of(OrderTable.of(Order(drone=d, pos=p) for d, p in sorted(starts.items(), reverse=True)))
    kinds, drones = e.survey(cells)
    expected = Ans(turn=1, sender="ENV", kinds=kinds, drones=drones).infos(cells)
    assert tuple(CellInfo(pos=c, kind=chart.kind(c), drones=occupied.get(c, ())) for c in cells) == expected
    assert occupied[(2, 1, 1)] == ("D02", "D03")


def test_chart_gives_the_same_in_numpy_for_many_cells() -> None:
    """Past a few cells the chart works in numpy: same answers as cell by cell."""
    from dronesim.entities.drone_node import SMALL, Chart
    from dronesim.schema import CellKind

    around = [(x, y, 1) for x in range(0, 8, 2) for y in range(0, 8, 3)]
    assert len(around) * 6 > SMALL
    one_by_one = Chart((8, 8, 3))
    expected = tuple(dict.fromkeys(c for p in around for c in one_by_one.unknown([p])))
    assert Chart((8, 8, 3)).unknown(around) == expected
    kinds = bytes([CellKind.BUILDING if sum(c) % 3 == 0 else CellKind.EMPTY for c in expected])
    bulk = Chart((8, 8, 3))
    bulk.learn(expected, kinds)
    for c, k in zip(expected, kinds):
        one_by_one.learn([c], bytes([k]))
    assert bulk._kinds == one_by_one._kinds and bulk.unknown(around) == ()


def test_chart_reaches_farther_when_asked() -> None:
    from dronesim.entities.drone_node import Chart

    chart = Chart((9, 9, 9))
    far = chart.unknown([(4, 4, 4)], reach=3)
    assert len(far) == 62 and set(far[:6]) == set(chart.unknown([(4, 4, 4)]))  # 6 + 18 + 38 cells, nearest first
    assert all(0 < sum(abs(a - 4) for a in c) <= 3 for c in far)
    assert len(Chart((2, 2, 1)).unknown([(0, 0, 0)], reach=3)) == 3  # only cells in the world


def test_chart_from_the_environments_map_answers_every_cell_as_the_environment_does() -> None:
    """The static map (ENV/MAP, as the environment serves it) charts every cell: the answers are the
    environment's, and nothing is left to ask."""
    import numpy as np
    import pytest

    from dronesim.entities.drone_node import Chart
    from dronesim.entities.environment import Environment
    from dronesim.entities.world import World
    from dronesim.schema import CellKind, OutOfRange, WorldMap

    world = World.generate((7, 5, 3), np.random.default_rng(4))
    env = Environment(world, {})
    chart = Chart(world.size)
    assert not chart.complete
    chart.learn_map(WorldMap(turn=0, sender="ENV", size=world.size, buildings=world.packed()))
    assert chart.complete
    cells = tuple((x, y, z) for x in range(-1, 8) for y in range(-1, 6) for z in range(-1, 4))
    kinds, _ = env.survey(cells, drones=False)
    assert tuple(chart.kind(c) for c in cells) == tuple(CellKind(k) for k in kinds)
    assert chart.unknown([(x, y, z) for x in range(7) for y in range(5) for z in range(3)], reach=2) == ()
    other = World.generate((5, 7, 3), np.random.default_rng(4))
    with pytest.raises(OutOfRange):  # another world's map changes nothing
        Chart(world.size).learn_map(WorldMap(turn=0, sender="ENV", size=other.size, buildings=other.packed()))


def test_a_swarm_host_without_the_map_asks_the_cells_it_was_never_told(monkeypatch) -> None:
    """`Asker.kinds` over the network, with an environment that serves ASK but no map: cells outside the
    world need no question, the others go in ASKs of at most Ask.MAX_CELLS cells, and are charted."""
    import logging

    import numpy as np
    import zenoh

    from dronesim.entities.drone_node import Asker, Chart
    from dronesim.entities.environment import Environment
    from dronesim.entities.world import World
    from dronesim.schema import Ans, Ask, CellKind, Keys, decode, encode
    from dronesim.transport import Inbox, client_config

    from .harness import embedded_router, unique_root

    monkeypatch.setattr(Ask, "MAX_CELLS", 7)
    keys = Keys(unique_root())
    world = World.generate((5, 5, 3), np.random.default_rng(4))
    env = Environment(world, {})
    asks: list[int] = []

    def answer(query: zenoh.Query) -> None:
        ask = decode(query.payload.to_bytes(), Ask)
        asks.append(len(ask.asked()))
        kinds, drones = env.survey(ask.cells, ask.around)
        query.reply(query.key_expr, encode(Ans(turn=ask.turn, sender="ENV", kinds=kinds, drones=drones)))

    cells = np.array([(x, y, z) for x in (-1, 0, 2, 4, 5) for y in (0, 3) for z in (0, 2, 3)])
    cells = np.concatenate([cells, cells[10:14]])  # a cell wanted twice is asked once
    expected = np.array([CellKind.OUTSIDE if not (0 <= x < 5 and z < 3) else
                         CellKind.BUILDING if world.grid[x, y, z] else CellKind.EMPTY for x, y, z in cells.tolist()])
    with embedded_router() as locator, zenoh.open(client_config(locator)) as served, \
            zenoh.open(client_config(locator)) as session:
        queryable = served.declare_queryable(keys.ask, answer, complete=True)
        log = logging.getLogger("test")
        asker = Asker(session, keys, Inbox(session, keys, log), log, sender="H01", timeout=5.0, patience=5.0,
                      size=world.size)
        try:
            assert asker.kinds(1, cells).tolist() == expected.tolist()
            inside = len({c for c, k in zip(map(tuple, cells.tolist()), expected) if k != CellKind.OUTSIDE})
            assert sorted(asks) == sorted([7] * (inside // 7) + ([inside % 7] if inside % 7 else []))
            assert not asker.chart.complete and (asker.chart.kinds(cells) != Chart.UNKNOWN).all()
            asks.clear()
            assert asker.kinds(2, cells[::-1]).tolist() == expected[::-1].tolist() and asks == []  # all charted
        finally:
            asker.close()
            queryable.undeclare()
