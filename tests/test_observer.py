"""The observer's rules: which drones die in a turn, and why."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dronesim.coordinator.observer import deaths, inside
from dronesim.schema import Cause

SIZE = (5, 5, 5)


def die(before: dict, after: dict, buildings=frozenset(), size=SIZE) -> dict:
    return deaths(size, before, after, set(buildings))


def test_inside() -> None:
    assert inside((0, 0, 0), SIZE)
    assert inside((4, 4, 4), SIZE)
    for c in [(-1, 0, 0), (0, -1, 0), (0, 0, -1), (5, 0, 0), (0, 5, 0), (0, 0, 5)]:
        assert not inside(c, SIZE)


def test_nobody_dies_on_free_moves() -> None:
    before = {"D01": (0, 0, 0), "D02": (2, 2, 2)}
    after = {"D01": (1, 0, 0), "D02": (2, 2, 3)}
    assert die(before, after) == {}


def test_building() -> None:
    assert die({"D01": (0, 0, 0)}, {"D01": (1, 0, 0)}, {(1, 0, 0)}) == {"D01": Cause.BUILDING}


def test_building_cells_elsewhere_are_harmless() -> None:
    assert die({"D01": (0, 0, 0)}, {"D01": (1, 0, 0)}, {(2, 0, 0), (0, 1, 0)}) == {}


@pytest.mark.parametrize("before,after", [
    ((0, 2, 2), (-1, 2, 2)),
    ((4, 2, 2), (5, 2, 2)),
    ((2, 0, 2), (2, -1, 2)),
    ((2, 4, 2), (2, 5, 2)),
    ((2, 2, 0), (2, 2, -1)),
    ((2, 2, 4), (2, 2, 5)),
], ids=["-x", "+x", "-y", "+y", "-z", "+z"])
def test_outside_each_face(before, after) -> None:
    assert die({"D01": before}, {"D01": after}) == {"D01": Cause.OUTSIDE}


def test_outside_in_a_non_cubic_world() -> None:
    size = (3, 1, 2)
    assert die({"D01": (2, 0, 1)}, {"D01": (2, 0, 2)}, size=size) == {"D01": Cause.OUTSIDE}
    assert die({"D01": (2, 0, 1)}, {"D01": (2, 1, 1)}, size=size) == {"D01": Cause.OUTSIDE}
    assert die({"D01": (1, 0, 1)}, {"D01": (2, 0, 1)}, size=size) == {}


def test_vertex_conflict_two_movers() -> None:
    before = {"D01": (0, 0, 0), "D02": (2, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (1, 0, 0)}
    assert die(before, after) == {"D01": Cause.VERTEX, "D02": Cause.VERTEX}


def test_vertex_conflict_three_movers() -> None:
    before = {"D01": (0, 1, 0), "D02": (2, 1, 0), "D03": (1, 0, 0), "D04": (3, 3, 3)}
    after = {"D01": (1, 1, 0), "D02": (1, 1, 0), "D03": (1, 1, 0), "D04": (3, 3, 4)}
    assert die(before, after) == {"D01": Cause.VERTEX, "D02": Cause.VERTEX, "D03": Cause.VERTEX}


def test_vertex_conflict_mover_enters_hovering_drone() -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (1, 0, 0)}
    assert die(before, after) == {"D01": Cause.VERTEX, "D02": Cause.VERTEX}


def test_swap_conflict() -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (0, 0, 0)}
    assert die(before, after) == {"D01": Cause.SWAP, "D02": Cause.SWAP}


def test_swap_conflict_vertical_among_others() -> None:
    before = {"D01": (2, 2, 2), "D02": (2, 2, 3), "D03": (0, 0, 0)}
    after = {"D01": (2, 2, 3), "D02": (2, 2, 2), "D03": (0, 0, 1)}
    assert die(before, after) == {"D01": Cause.SWAP, "D02": Cause.SWAP}


def test_chain_is_not_a_swap() -> None:
    """A moves into B's cell while B moves on elsewhere: a train, not a swap."""
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (2, 0, 0)}
    assert die(before, after) == {}
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (2, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (2, 0, 0), "D03": (2, 1, 0)}
    assert die(before, after) == {}


def test_chain_with_turn_is_not_a_swap() -> None:
    before = {"D01": (1, 0, 0), "D02": (0, 0, 0)}
    after = {"D01": (1, 1, 0), "D02": (1, 0, 0)}
    assert die(before, after) == {}


def test_rotation_of_three_is_not_a_swap() -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (1, 1, 0), "D04": (0, 1, 0)}
    after = {"D01": (1, 0, 0), "D02": (1, 1, 0), "D03": (0, 1, 0), "D04": (0, 0, 0)}
    assert die(before, after) == {}


def test_hovering_drones_never_conflict() -> None:
    cells = [(x, y, z) for x, y, z in itertools.product(range(2), repeat=3)]
    before = {f"D{i + 1:02d}": c for i, c in enumerate(cells)}
    assert die(before, dict(before)) == {}


def test_hovering_next_to_a_mover_is_not_a_swap() -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0)}
    after = {"D01": (0, 0, 0), "D02": (1, 1, 0)}
    assert die(before, after) == {}


def test_precedence_outside_over_everything() -> None:
    before = {"D01": (0, 0, 0), "D02": (0, 1, 0)}
    after = {"D01": (-1, 0, 0), "D02": (-1, 0, 0)}  # both leave the world into the same cell
    assert die(before, after) == {"D01": Cause.OUTSIDE, "D02": Cause.OUTSIDE}


def test_precedence_building_over_vertex() -> None:
    before = {"D01": (0, 0, 0), "D02": (2, 0, 0)}
    after = {"D01": (1, 0, 0), "D02": (1, 0, 0)}
    assert die(before, after, {(1, 0, 0)}) == {"D01": Cause.BUILDING, "D02": Cause.BUILDING}


def test_precedence_vertex_over_swap() -> None:
    """D01 and D02 swap, and D03 also enters D01's old cell: D02 and D03 collide there (VERTEX),
    D01 dies of the swap."""
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (0, 1, 0)}
    after = {"D01": (1, 0, 0), "D02": (0, 0, 0), "D03": (0, 0, 0)}
    assert die(before, after) == {"D01": Cause.SWAP, "D02": Cause.VERTEX, "D03": Cause.VERTEX}


def test_precedence_does_not_depend_on_names() -> None:
    before = {"D03": (0, 0, 0), "D02": (1, 0, 0), "D01": (0, 1, 0)}
    after = {"D03": (1, 0, 0), "D02": (0, 0, 0), "D01": (0, 0, 0)}
    assert die(before, after) == {"D03": Cause.SWAP, "D02": Cause.VERTEX, "D01": Cause.VERTEX}


def test_vertex_ignores_the_dead() -> None:
    """A drone that died entering a building does not also count in a vertex conflict elsewhere."""
    before = {"D01": (0, 0, 0), "D02": (2, 0, 0)}
    after = {"D01": (0, 0, 1), "D02": (1, 0, 0)}
    assert die(before, after, {(0, 0, 1)}) == {"D01": Cause.BUILDING}


def test_result_is_independent_of_mapping_order() -> None:
    before = {"D01": (0, 0, 0), "D02": (1, 0, 0), "D03": (3, 3, 3), "D04": (3, 2, 3)}
    after = {"D01": (1, 0, 0), "D02": (0, 0, 0), "D03": (3, 2, 3), "D04": (3, 1, 3)}
    expected = die(before, after)
    assert expected == {"D01": Cause.SWAP, "D02": Cause.SWAP}
    for perm in itertools.permutations(before):
        assert die({d: before[d] for d in perm}, {d: after[d] for d in reversed(perm)}) == expected


def _reference(size, before: dict, after: dict, buildings: set) -> dict:
    """The rules written drone by drone (the first implementation): the oracle for the columnar one."""
    from collections import defaultdict
    dead: dict = {}
    order = sorted(after)
    by_cell = defaultdict(list)
    for d in order:
        cell = after[d]
        if not inside(cell, size):
            dead[d] = Cause.OUTSIDE
        elif cell in buildings:
            dead[d] = Cause.BUILDING
        else:
            by_cell[cell].append(d)
    for ds in by_cell.values():
        if len(ds) > 1:
            for d in ds:
                dead[d] = Cause.VERTEX
    arriving = {after[d]: d for d in order if after[d] != before[d]}
    for d in order:
        src, dst = before[d], after[d]
        other = arriving.get(src)
        if src != dst and other is not None and other != d and before[other] == dst:
            for x in (d, other):
                dead.setdefault(x, Cause.SWAP)
    return dead


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
    assert deaths(size, before, after, buildings) == _reference(size, before, after, buildings)
