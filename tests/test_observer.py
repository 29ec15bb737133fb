"""The observer's rules: which drones die in a turn, and why.

Every example holds for both forms of the rules: `judge` over columns (what the engine runs) and `deaths`
drone by drone (the reference); a property test holds the first to the second on random turns."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.fleet import CAUSES
from coordinator.observer import deaths, deaths_of_moves, judge
from schema import Cause
from world.grid import in_bounds

SIZE = (5, 5, 5)


def judged(size, before: dict, after: dict, buildings: set) -> dict:
    """`judge` (columns, rows in id order) over the mappings `deaths` takes."""
    order = sorted(after)
    if not order:
        return {}
    b = np.array([before[d] for d in order], np.int64)
    a = np.array([after[d] for d in order], np.int64)
    cause = judge(size, b, a, np.array([after[d] in buildings for d in order], bool))
    return {order[i]: CAUSES[c] for i, c in enumerate(cause.tolist()) if c}


def of_moves(size, before: dict, after: dict, buildings: set) -> dict:
    """`deaths_of_moves` (a few drones' turn in the engine) over the mappings `deaths` takes; the buildings a grid
    (only a drone that moves can enter one: the engine's, where a drone in a building has died)."""
    grid = np.zeros(size, bool)
    for c in buildings:
        if all(0 <= v < s for v, s in zip(c, size)):
            grid[c] = True
    return deaths_of_moves(size, grid.ravel(), before, after, [d for d in sorted(after) if after[d] != before[d]])


@pytest.fixture(params=[judged, deaths], ids=["columns", "drone-by-drone"])
def die(request):
    """Who dies, by one form of the rules: every example runs against both."""
    rules = request.param

    def die(before: dict, after: dict, buildings=frozenset(), size=SIZE) -> dict:
        return rules(size, before, after, set(buildings))

    return die


def test_inside() -> None:
    assert in_bounds((0, 0, 0), SIZE)
    assert in_bounds((4, 4, 4), SIZE)
    for c in [(-1, 0, 0), (0, -1, 0), (0, 0, -1), (5, 0, 0), (0, 5, 0), (0, 0, 5)]:
        assert not in_bounds(c, SIZE)


def test_nobody_dies_on_free_moves(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (2, 2, 2)}
    after = {"D01": (1, 0, 0), "D02": (2, 2, 3)}
    assert die(before, after) == {}


def test_building(die) -> None:
    assert die({"D01": (0, 0, 0)}, {"D01": (1, 0, 0)}, {(1, 0, 0)}) == {"D01": Cause.BUILDING}


def test_building_cells_elsewhere_are_harmless(die) -> None:
    assert die({"D01": (0, 0, 0)}, {"D01": (1, 0, 0)}, {(2, 0, 0), (0, 1, 0)}) == {}


@pytest.mark.parametrize("before,after", [
    ((0, 2, 2), (-1, 2, 2)),
    ((4, 2, 2), (5, 2, 2)),
    ((2, 0, 2), (2, -1, 2)),
    ((2, 4, 2), (2, 5, 2)),
    ((2, 2, 0), (2, 2, -1)),
    ((2, 2, 4), (2, 2, 5)),
], ids=["-x", "+x", "-y", "+y", "-z", "+z"])
def test_outside_each_face(before, after, die) -> None:
    assert die({"D01": before}, {"D01": after}) == {"D01": Cause.OUTSIDE}


def test_outside_in_a_non_cubic_world(die) -> None:
    size = (3, 1, 2)
    assert die({"D01": (2, 0, 1)}, {"D01": (2, 0, 2)}, size=size) == {"D01": Cause.OUTSIDE}
    assert die({"D01": (2, 0, 1)}, {"D01": (2, 1, 1)}, size=size) == {"D01": Cause.OUTSIDE}
    assert die({"D01": (1, 0, 1)}, {"D01": (2, 0, 1)}, size=size) == {}


def test_vertex_conflict_two_movers(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (2, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (1, 0, 0)}
    assert die(before, after) == {"D01": Cause.VERTEX, "D02": Cause.VERTEX}


def test_vertex_conflict_three_movers(die) -> None:
    before = {"D01": (0, 1, 0), "D02": (2, 1, 0), "D03": (1, 0, 0), "D04": (3, 3, 3)}
    after = {"D01": (1, 1, 0), "D02": (1, 1, 0), "D03": (1, 1, 0), "D04": (3, 3, 4)}
    assert die(before, after) == {"D01": Cause.VERTEX, "D02": Cause.VERTEX, "D03": Cause.VERTEX}


def test_vertex_conflict_mover_enters_hovering_drone(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (1, 0, 0)}
    assert die(before, after) == {"D01": Cause.VERTEX, "D02": Cause.VERTEX}


def test_swap_conflict(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (0, 0, 0)}
    assert die(before, after) == {"D01": Cause.SWAP, "D02": Cause.SWAP}


def test_swap_conflict_vertical_among_others(die) -> None:
    before = {"D01": (2, 2, 2), "D02": (2, 2, 3), "D03": (0, 0, 0)}
    after = {"D01": (2, 2, 3), "D02": (2, 2, 2), "D03": (0, 0, 1)}
    assert die(before, after) == {"D01": Cause.SWAP, "D02": Cause.SWAP}


def test_chain_is_not_a_swap(die) -> None:
    """A moves into B's cell while B moves on elsewhere: a train, not a swap."""
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (2, 0, 0)}
    assert die(before, after) == {}
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (2, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (2, 0, 0), "D03": (2, 1, 0)}
    assert die(before, after) == {}


def test_chain_with_turn_is_not_a_swap(die) -> None:
    before = {"D01": (1, 0, 0), "D02": (0, 0, 0)}
    after = {"D01": (1, 1, 0), "D02": (1, 0, 0)}
    assert die(before, after) == {}


def test_rotation_of_three_is_not_a_swap(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (1, 1, 0), "D04": (0, 1, 0)}
    after = {"D01": (1, 0, 0), "D02": (1, 1, 0), "D03": (0, 1, 0), "D04": (0, 0, 0)}
    assert die(before, after) == {}


def test_hovering_drones_never_conflict(die) -> None:
    cells = [(x, y, z) for x, y, z in itertools.product(range(2), repeat=3)]
    before = {f"D{i + 1:02d}": c for i, c in enumerate(cells)}
    assert die(before, dict(before)) == {}


def test_hovering_next_to_a_mover_is_not_a_swap(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0)}
    after = {"D01": (0, 0, 0), "D02": (1, 1, 0)}
    assert die(before, after) == {}


def test_precedence_outside_over_everything(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (0, 1, 0)}
    after = {"D01": (-1, 0, 0), "D02": (-1, 0, 0)}  # both leave the world into the same cell
    assert die(before, after) == {"D01": Cause.OUTSIDE, "D02": Cause.OUTSIDE}


def test_precedence_building_over_vertex(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (2, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (1, 0, 0)}
    assert die(before, after, {(1, 0, 0)}) == {"D01": Cause.BUILDING, "D02": Cause.BUILDING}


def test_precedence_vertex_over_swap(die) -> None:
    """D01 and D02 swap, and D03 also enters D01's old cell: D02 and D03 collide there (VERTEX),
    D01 dies of the swap."""
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (0, 1, 0)}
    after = {"D01": (1, 0, 0), "D02": (0, 0, 0), "D03": (0, 0, 0)}
    assert die(before, after) == {"D01": Cause.SWAP, "D02": Cause.VERTEX, "D03": Cause.VERTEX}


def test_precedence_does_not_depend_on_names(die) -> None:
    before = {"D03": (0, 0, 0), "D02": (1, 0, 0), "D01": (0, 1, 0)}
    after = {"D03": (1, 0, 0), "D02": (0, 0, 0), "D01": (0, 0, 0)}
    assert die(before, after) == {"D03": Cause.SWAP, "D02": Cause.VERTEX, "D01": Cause.VERTEX}


def test_vertex_ignores_the_dead(die) -> None:
    """A drone that died entering a building does not also count in a vertex conflict elsewhere."""
    before = {"D01": (0, 0, 0), "D02": (2, 0, 0)}
    after = {"D01": (0, 0, 1), "D02": (1, 0, 0)}
    assert die(before, after, {(0, 0, 1)}) == {"D01": Cause.BUILDING}


def test_result_is_independent_of_mapping_order(die) -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (3, 3, 3), "D04": (3, 2, 3)}
    after = {"D01": (1, 0, 0), "D02": (0, 0, 0), "D03": (3, 2, 3), "D04": (3, 1, 3)}
    expected = die(before, after)
    assert expected == {"D01": Cause.SWAP, "D02": Cause.SWAP}
    for perm in itertools.permutations(before):
        assert die({d: before[d] for d in perm}, {d: after[d] for d in reversed(perm)}) == expected


STEPS = [(0, 0, 0), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]


@settings(max_examples=600, deadline=None)
@given(st.data())
def test_the_columnar_rules_agree_with_the_rules_drone_by_drone(data) -> None:
    size = (3, 3, 2)
    cells = list(itertools.product(range(3), range(3), range(2)))
    n = data.draw(st.integers(1, 8))
    starts = data.draw(st.lists(st.sampled_from(cells), min_size=n, max_size=n, unique=True))
    ids = data.draw(st.lists(st.integers(1, 1200), min_size=n, max_size=n, unique=True))
    before = {f"D{i:02d}": c for i, c in zip(ids, starts)}
    after = {d: tuple(a + b for a, b in zip(c, data.draw(st.sampled_from(STEPS)))) for d, c in before.items()}
    buildings = {c for c in after.values() if data.draw(st.booleans())}
    expected = deaths(size, before, after, buildings)
    assert judged(size, before, after, buildings) == expected
    entered = {after[d] for d in after if after[d] != before[d]} & buildings  # (the buildings a mover entered)
    assert of_moves(size, before, after, entered) == deaths(size, before, after, entered)
    # rows of drones not alive, among the others in id order, anywhere (in the world, a building, on an alive
    # drone's cell, outside, even "moving"): they take no part
    spots = cells + [(3, 0, 0), (0, -1, 1)]
    spot = st.sampled_from(spots)
    dead = {f"D{i:02d}": (data.draw(spot), data.draw(spot), data.draw(st.booleans()))
            for i in data.draw(st.lists(st.integers(1, 1200), max_size=6, unique=True)) if f"D{i:02d}" not in before}
    order = sorted([*before, *dead])
    b = np.array([before[d] if d in before else dead[d][0] for d in order], np.int64)
    a = np.array([after[d] if d in after else dead[d][1] for d in order], np.int64)
    building = np.array([after[d] in buildings if d in after else dead[d][2] for d in order], bool)
    alive = np.array([d in before for d in order], bool)
    cause = judge(size, b, a, building, alive)
    assert {order[i]: CAUSES[c] for i, c in enumerate(cause.tolist()) if c} == expected
