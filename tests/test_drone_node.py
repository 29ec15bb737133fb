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
    from dronesim.schema import Ans, Order

    starts = {"D01": (1, 1, 1), "D02": (2, 1, 1), "D03": (2, 1, 1)}
    e = Environment(World.generate((6, 6, 4), np.random.default_rng(2)), starts)
    cells = tuple((x, y, z) for x in range(-1, 7) for y in range(-1, 7) for z in (0, 1, 3))
    kinds, none = e.survey(cells, drones=False)
    assert none == ()
    chart = Chart((6, 6, 4))
    chart.learn(cells, kinds)
    occupied = occupancy_of([Order(drone=d, pos=p) for d, p in sorted(starts.items(), reverse=True)])
    kinds, drones = e.survey(cells)
    expected = Ans(turn=1, sender="ENV", kinds=kinds, drones=drones).infos(cells)
    assert tuple(CellInfo(pos=c, kind=chart.kind(c), drones=occupied.get(c, ())) for c in cells) == expected
    assert occupied[(2, 1, 1)] == ("D02", "D03")
