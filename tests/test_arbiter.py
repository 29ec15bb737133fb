"""Move arbitration (coordinator/arbiter.py): cooperative drones give way by a fixed priority.

What `arbitrate(before, proposed, cooperative)` guarantees, and what these tests check:

* only cooperative drones' moves change, and a changed move is always a hover (``final == before``);
* a cooperative drone that moves is the only drone in its final cell (it never enters a cell held by
  a hovering drone or claimed by any drone that does not give way);
* no two cooperative drones end in one cell and no two cooperative drones swap cells;
* a cooperative drone that moves does not swap with the drone entering its cell;
* the result does not depend on the order of the input mappings.

What it does *not* (and cannot) guarantee: a non-cooperative drone may still move into the cell of a
cooperative drone that hovers (or has to hover); the observer then kills both. So, with the observer's
rules, a cooperative drone may die of VERTEX or SWAP, but only with a non-cooperative drone.
"""

from __future__ import annotations

import random
from collections import Counter

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dronesim.coordinator.arbiter import arbitrate
from dronesim.coordinator.observer import deaths
from dronesim.schema import Cause

A, B, C, D, E, F = (0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0), (5, 0, 0)


def arb(moves: dict[str, tuple], coop) -> dict:
    """`moves`: drone -> (before, proposed)."""
    before = {d: m[0] for d, m in moves.items()}
    proposed = {d: m[1] for d, m in moves.items()}
    return arbitrate(before, proposed, set(coop))


def hovers(final: dict, moves: dict) -> set[str]:
    return {d for d in final if final[d] == moves[d][0] and moves[d][1] != moves[d][0]}


# --------------------------------------------------------------------------- basic rules


def test_no_drones() -> None:
    assert arbitrate({}, {}, set()) == {}


def test_free_moves_are_kept() -> None:
    moves = {"D01": (A, B), "D02": ((0, 5, 0), (0, 6, 0)), "D03": ((9, 9, 9), (9, 9, 9))}
    assert arb(moves, {"D01", "D02", "D03"}) == {d: m[1] for d, m in moves.items()}


def test_inputs_are_not_mutated() -> None:
    before = {"D01": A, "D02": C}
    proposed = {"D01": B, "D02": B}
    coop = {"D01", "D02"}
    arbitrate(before, proposed, coop)
    assert before == {"D01": A, "D02": C} and proposed == {"D01": B, "D02": B} and coop == {"D01", "D02"}


def test_cooperative_ids_not_in_the_game_are_ignored() -> None:
    assert arb({"D01": (A, B)}, {"D01", "D77"}) == {"D01": B}


@pytest.mark.parametrize("first,second", [("D01", "D02"), ("D02", "D01")])
def test_two_cooperative_claim_one_cell_smaller_id_moves(first: str, second: str) -> None:
    moves = {first: (A, B), second: (C, B)}
    final = arb(moves, {first, second})
    assert final == {"D01": B, "D02": moves["D02"][0]}


def test_three_cooperative_claim_one_cell() -> None:
    moves = {"D03": (A, B), "D02": (C, B), "D01": ((1, 1, 0), B)}
    final = arb(moves, {"D01", "D02", "D03"})
    assert final == {"D01": B, "D02": C, "D03": A}


@pytest.mark.parametrize("hoverer_cooperative", [True, False])
@pytest.mark.parametrize("hoverer", ["D01", "D09"])
def test_cooperative_never_enters_a_hovering_drones_cell(hoverer: str, hoverer_cooperative: bool) -> None:
    coop = {"D05"} | ({hoverer} if hoverer_cooperative else set())
    final = arb({"D05": (A, B), hoverer: (B, B)}, coop)
    assert final == {"D05": A, hoverer: B}


@pytest.mark.parametrize("other", ["D01", "D09"])  # whatever the ids, a non-cooperative drone wins
def test_cooperative_never_enters_a_cell_claimed_by_a_non_cooperative(other: str) -> None:
    final = arb({"D05": (A, B), other: (C, B)}, {"D05"})
    assert final == {"D05": A, other: B}


def test_swap_between_cooperative_never_happens() -> None:
    moves = {"D01": (A, B), "D02": (B, A)}
    final = arb(moves, {"D01", "D02"})
    assert final == {"D01": A, "D02": B}  # both hover: the loser hovers, so the winner is then blocked


@pytest.mark.parametrize("coop_id,other_id", [("D01", "D02"), ("D02", "D01")])
def test_swap_with_a_non_cooperative_the_cooperative_hovers(coop_id: str, other_id: str) -> None:
    final = arb({coop_id: (A, B), other_id: (B, A)}, {coop_id})
    assert final == {coop_id: A, other_id: A}  # the non-cooperative flies on (and the observer judges it)


@pytest.mark.parametrize("follower,leader", [("D01", "D02"), ("D02", "D01")])
def test_following_chain_is_allowed(follower: str, leader: str) -> None:
    final = arb({follower: (A, B), leader: (B, C)}, {follower, leader})
    assert final == {follower: B, leader: C}


def test_long_following_chain_moves_as_one() -> None:
    ids = ["D04", "D02", "D05", "D01", "D03"]  # tail to head, ids mixed
    cells = [A, B, C, D, E, F]
    moves = {d: (cells[i], cells[i + 1]) for i, d in enumerate(ids)}
    assert arb(moves, set(ids)) == {d: m[1] for d, m in moves.items()}


@pytest.mark.parametrize("ids", [
    ["D01", "D02", "D03", "D04", "D05"],  # tail has the smallest id: one more pass per link
    ["D05", "D04", "D03", "D02", "D01"],
    ["D03", "D01", "D05", "D02", "D04"],
])
@pytest.mark.parametrize("blocker_cooperative", [True, False])
def test_blocked_head_makes_the_whole_chain_hover(ids: list[str], blocker_cooperative: bool) -> None:
    cells = [A, B, C, D, E, F]
    moves = {d: (cells[i], cells[i + 1]) for i, d in enumerate(ids)}
    moves["D09"] = (F, F)  # hovering in the head's destination
    coop = set(ids) | ({"D09"} if blocker_cooperative else set())
    final = arb(moves, coop)
    assert final == {d: m[0] for d, m in moves.items()}


def test_chain_behind_a_head_that_loses_a_claim_hovers() -> None:
    # D03 follows D02; D02 and D01 claim the same cell, D01 wins: D02 hovers, so D03 must hover too.
    moves = {"D03": (A, B), "D02": (B, C), "D01": ((2, 1, 0), C)}
    final = arb(moves, {"D01", "D02", "D03"})
    assert final == {"D01": C, "D02": B, "D03": A}


def test_rotation_without_swap_is_allowed() -> None:
    ring = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    moves = {f"D0{i + 1}": (ring[i], ring[(i + 1) % 4]) for i in range(4)}
    assert arb(moves, set(moves)) == {d: m[1] for d, m in moves.items()}


def test_non_cooperative_drones_are_never_changed() -> None:
    moves = {"D01": (A, B), "D02": (C, B), "D03": (B, A), "D04": (D, D), "D05": (E, D)}
    final = arb(moves, set())
    assert final == {d: m[1] for d, m in moves.items()}  # collisions included: the observer judges them


def test_mixed_non_cooperative_kept_cooperative_yield() -> None:
    moves = {"D01": (A, B), "D02": (C, B), "D03": (D, C), "D04": (E, D)}
    final = arb(moves, {"D02", "D03", "D04"})
    # D01 (non-coop) takes B; D02 hovers in C; D03 may not enter C; D04 may not enter D.
    assert final == {"D01": B, "D02": C, "D03": D, "D04": E}


SCENES = [
    ({"D01": (A, B), "D02": (C, B)}, {"D01", "D02"}),
    ({"D01": (A, B), "D02": (B, A)}, {"D01", "D02"}),
    ({"D01": (A, B), "D02": (B, A)}, {"D02"}),
    ({"D04": (A, B), "D02": (B, C), "D05": (C, D), "D01": (D, E), "D03": (E, F), "D09": (F, F)},
     {"D01", "D02", "D03", "D04", "D05"}),
    ({"D01": (A, B), "D02": (C, B), "D03": (D, C), "D04": (E, D)}, {"D02", "D03", "D04"}),
    ({"D03": (A, B), "D02": (B, C), "D01": ((2, 1, 0), C)}, {"D01", "D02", "D03"}),
]


@pytest.mark.parametrize("moves,coop", SCENES)
def test_result_does_not_depend_on_insertion_order(moves: dict, coop: set) -> None:
    ref = arb(moves, coop)
    rng = random.Random(1)
    for _ in range(20):
        keys = list(moves)
        rng.shuffle(keys)
        before = {d: moves[d][0] for d in keys}
        rng.shuffle(keys)
        proposed = {d: moves[d][1] for d in keys}
        assert arbitrate(before, proposed, set(coop)) == ref


# --------------------------------------------------------------------------- a real bug


# D02 (cooperative) at A wants B, where D01 (not cooperative) comes from, moving into A: a swap, so D02
# must hover. D03 (not cooperative) enters A too. `arriving` maps a cell to ONE drone entering it (the last
# in dict order), so when that is D03, D02's swap with D01 goes unseen and D02 flies into it.
_BUG_BEFORE = {"D01": B, "D02": A, "D03": (0, 1, 0)}
_BUG_PROPOSED = {"D01": A, "D02": B, "D03": A}


def test_swap_with_non_cooperative_is_seen_when_two_drones_enter_the_cell() -> None:
    final = arbitrate(_BUG_BEFORE, _BUG_PROPOSED, {"D02"})
    assert final["D02"] == A  # the documented rule: it would swap with a drone that does not give way


def test_insertion_order_with_two_drones_entering_a_cell() -> None:
    forward = arbitrate(_BUG_BEFORE, _BUG_PROPOSED, {"D02"})
    backward = arbitrate(dict(reversed(_BUG_BEFORE.items())), dict(reversed(_BUG_PROPOSED.items())), {"D02"})
    assert forward == backward


# --------------------------------------------------------------------------- properties

STEPS = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (0, 0, 0))
WORLD = (6, 6, 5)  # starts in 1..3 x 1..3 x 1..2: every 6-neighbour stays inside


@st.composite
def scenes(draw):
    n = draw(st.integers(1, 9))
    cells = draw(st.lists(st.tuples(st.integers(1, 3), st.integers(1, 3), st.integers(1, 2)),
                          min_size=n, max_size=n, unique=True))
    ids = draw(st.lists(st.integers(1, 30), min_size=n, max_size=n, unique=True))
    names = [f"D{i:02d}" for i in ids]
    before = dict(zip(names, cells))
    proposed = {}
    for d, c in before.items():
        s = draw(st.sampled_from(STEPS))
        proposed[d] = (c[0] + s[0], c[1] + s[1], c[2] + s[2])
    coop = set(draw(st.lists(st.sampled_from(names), unique=True)))
    return before, proposed, coop


def _swaps(before: dict, final: dict, d: str, e: str) -> bool:
    return final[d] != before[d] and final[e] != before[e] and final[d] == before[e] and final[e] == before[d]


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes())
def test_property_arbitration_guarantees(scene) -> None:
    before, proposed, coop = scene
    final = arbitrate(before, proposed, coop)
    assert set(final) == set(proposed)
    for d in final:
        if d not in coop:
            assert final[d] == proposed[d], f"non-cooperative {d} was changed"
        else:
            assert final[d] in (proposed[d], before[d]), f"{d} was given a move it did not propose"
    entering = Counter(final[d] for d in final if final[d] != before[d])
    for d in coop:
        if final[d] != before[d]:
            others = [e for e in final if e != d and final[e] == final[d]]
            assert not others, f"cooperative {d} moved into {final[d]} with {others}"
            for e in final:
                if e != d and _swaps(before, final, d, e) and entering[before[d]] == 1:
                    pytest.fail(f"cooperative {d} swaps with {e}")
        for e in coop:
            if e != d:
                assert final[d] != final[e], f"cooperative {d} and {e} share {final[d]}"
                assert not _swaps(before, final, d, e), f"cooperative {d} and {e} swap"


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes(), st.randoms(use_true_random=False))
def test_property_insertion_order_does_not_matter(scene, rnd) -> None:
    before, proposed, coop = scene
    ref = arbitrate(before, proposed, coop)
    keys = list(before)
    rnd.shuffle(keys)
    assert arbitrate({k: before[k] for k in keys}, {k: proposed[k] for k in reversed(keys)}, coop) == ref


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes())
def test_property_cooperative_drones_never_kill_each_other(scene) -> None:
    before, proposed, coop = scene
    final = arbitrate(before, proposed, coop)
    dead = deaths(WORLD, before, final, set())
    assert all(c in (Cause.VERTEX, Cause.SWAP) for c in dead.values())  # nothing else in this world
    for d, cause in dead.items():
        if d not in coop:
            continue
        if cause is Cause.VERTEX:
            assert final[d] == before[d], f"cooperative {d} died moving"
            mates = [e for e in final if e != d and final[e] == final[d]]
            assert mates and all(e not in coop for e in mates), f"{d} collided with cooperative {mates}"
        else:
            partners = [e for e in final if e != d and _swaps(before, final, d, e)]
            assert partners and all(e not in coop for e in partners), f"{d} swapped with {partners}"
    # and among cooperative drones alone, nobody ever dies
    only = sorted(coop)
    assert deaths(WORLD, {d: before[d] for d in only}, {d: final[d] for d in only}, set()) == {}
