"""Move arbitration (coordinator/arbiter.py).

The second half tests `cooperate`, the arbitration in force (PIBT over each cooperative drone's ranked
candidates): a cooperative drone only ever ends in a cell it offered or its own, never shares a cell or swaps
with another cooperative drone, never with a non-cooperative one unless that one flew into it; pushes,
backtracking, giving way. The first half tests `arbitrate`, the former fixed-priority rule, which the
benchmark still compares (`dronesim bench swarm`): cooperative drones give way by a fixed priority.

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

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from coordinator.arbiter import OpenCells, arbitrate, cooperate
from coordinator.observer import deaths
from schema import Cause
from schema.messages import AROUND
from schema.tables import rank_steps

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


# =========================================================================== PIBT (arbiter.cooperate)

SIZE = (8, 8, 3)
STAY = (0, 0, 0)


def coop_arb(drones: dict[str, tuple], priority: dict[str, int] | None = None,
             targets: dict[str, tuple] | None = None, blocked: np.ndarray | None = None, size: tuple = SIZE,
             salt: int | None = None):
    """`drones`: id -> (cell, [offered steps, best first]) for a cooperative drone, or (cell, proposed cell,
    None) for one that is not; `targets` (id -> cell) and the world's buildings (`blocked`, a grid of `size`)
    for the swap, which needs both; `salt` for the tie-breaks. Returns (final cells by id, yielded ids,
    gave-way ids)."""
    ids = sorted(drones)
    before = np.array([drones[d][0] for d in ids], np.int32).reshape(len(ids), 3)
    coop = np.array([len(drones[d]) == 2 for d in ids])
    proposed = before.copy()
    ranked = np.zeros(len(ids), np.uint32)
    for k, d in enumerate(ids):
        if coop[k]:
            steps = drones[d][1]
            ranked[k] = rank_steps(steps)
            if steps:
                proposed[k] = np.add(drones[d][0], steps[0])
        else:
            proposed[k] = drones[d][1]
    prio = np.array([(priority or {}).get(d, 0) for d in ids], np.int64)
    aims = None if targets is None else \
        np.array([targets.get(d, (-1, -1, -1)) for d in ids], np.int32).reshape(len(ids), 3)
    world = None if blocked is None else OpenCells(blocked)
    final, yielded, gave = cooperate(size, before, proposed, ranked, coop, prio, aims, world, salt)
    cells = {d: tuple(final[k].tolist()) for k, d in enumerate(ids)}
    return cells, {d for k, d in enumerate(ids) if yielded[k]}, {d for k, d in enumerate(ids) if gave[k]}


X, NX, Y, NY, Z, NZ = AROUND


def test_pibt_free_moves_are_taken() -> None:
    cells, yielded, _ = coop_arb({"D01": ((1, 1, 0), [X, STAY]), "D02": ((4, 4, 0), [Y, STAY])})
    assert cells == {"D01": (2, 1, 0), "D02": (4, 5, 0)} and not yielded


def test_pibt_higher_priority_wins_a_cell_then_the_id() -> None:
    drones = {"D01": ((1, 1, 0), [X, STAY]), "D02": ((3, 1, 0), [NX, STAY])}
    assert coop_arb(drones)[0] == {"D01": (2, 1, 0), "D02": (3, 1, 0)}
    assert coop_arb(drones, {"D02": 5})[0] == {"D01": (1, 1, 0), "D02": (2, 1, 0)}


def test_pibt_pushes_a_drone_that_offers_another_cell() -> None:
    # D01 wants D02's cell; D02 (parked) offers to stay, then to step sideways: it is pushed aside.
    cells, yielded, gave = coop_arb({"D01": ((1, 1, 0), [X, STAY]), "D02": ((2, 1, 0), [STAY, Y, NY])}, {"D01": 3})
    assert cells == {"D01": (2, 1, 0), "D02": (2, 2, 0)} and yielded == {"D02"} and not gave


def test_pibt_pushed_drone_steps_out_of_line_before_straight_on() -> None:
    # D02 ranks straight on (+x) before the side step (+y), both below staying: pushed, it sidesteps.
    cells, _, _ = coop_arb({"D01": ((1, 1, 0), [X]), "D02": ((2, 1, 0), [STAY, X, Y])}, {"D01": 3})
    assert cells == {"D01": (2, 1, 0), "D02": (2, 2, 0)}
    # ... unless straight on is what it prefers anyway (ranked above staying)
    cells, _, _ = coop_arb({"D01": ((1, 1, 0), [X]), "D02": ((2, 1, 0), [X, STAY, Y])}, {"D01": 3})
    assert cells == {"D01": (2, 1, 0), "D02": (3, 1, 0)}


def test_pibt_pushed_drone_steps_off_the_way_its_pusher_goes_on() -> None:
    """Pushed, a drone retreats first to a cell its pusher will not want next: not one closer to the pusher's
    target than the cell the pusher enters (here +y, towards D01's target), though it ranks it first."""
    drones = {"D01": ((1, 1, 0), [X, STAY]), "D02": ((2, 1, 0), [STAY, Y, NY])}
    assert coop_arb(drones, {"D01": 3})[0]["D02"] == (2, 2, 0)  # no target known: its own order
    cells, _, _ = coop_arb(drones, {"D01": 3}, {"D01": (4, 3, 0), "D02": (2, 1, 0)})
    assert cells == {"D01": (2, 1, 0), "D02": (2, 0, 0)}
    cells, _, _ = coop_arb(drones, {"D01": 3}, {"D01": (4, 0, 0), "D02": (2, 1, 0)})  # the pusher turns the other way
    assert cells == {"D01": (2, 1, 0), "D02": (2, 2, 0)}


def test_pibt_a_pushed_drone_chooses_its_side_by_the_turn() -> None:
    """Among the cells a drone ranks after staying (where it goes when pushed), the order is drawn from the salt
    (the turn) and the cells: the same for the same salt, not the same at every turn (a loop of drones pushing
    each other round does not repeat for ever); without a salt, the drone's order."""
    drones = {"D01": ((1, 1, 1), [X]), "D02": ((2, 1, 1), [STAY, Y, NY, Z, NZ])}
    assert coop_arb(drones, {"D01": 3})[0]["D02"] == (2, 2, 1)
    sides = [coop_arb(drones, {"D01": 3}, salt=t)[0]["D02"] for t in range(40)]
    assert sides == [coop_arb(drones, {"D01": 3}, salt=t)[0]["D02"] for t in range(40)]
    assert set(sides) == {(2, 2, 1), (2, 0, 1), (2, 1, 2), (2, 1, 0)}
    # the cells it ranks before staying keep its order whatever the salt
    ahead = {"D01": ((1, 1, 1), [X]), "D02": ((2, 1, 1), [Y, NY, STAY, Z])}
    assert {coop_arb(ahead, {"D01": 3}, salt=t)[0]["D02"] for t in range(40)} == {(2, 2, 1)}


def test_pibt_never_moves_a_drone_to_a_cell_it_did_not_offer() -> None:
    # D02 offers nothing but its cell: D01 cannot push it, takes its next candidate, and gave way.
    cells, yielded, gave = coop_arb({"D01": ((1, 1, 0), [X, STAY, Y]), "D02": ((2, 1, 0), [STAY])}, {"D01": 3})
    assert cells == {"D01": (1, 1, 0), "D02": (2, 1, 0)} and yielded == {"D01"} and gave == {"D01"}


def test_pibt_goes_round_a_drone_rather_than_pushing_it_when_as_short() -> None:
    # +x and +y both get D01 closer (ranked before staying): it takes the free one, whatever its order
    cells, yielded, gave = coop_arb({"D01": ((1, 1, 0), [X, Y, STAY]), "D02": ((2, 1, 0), [STAY, NY])}, {"D01": 3})
    assert cells == {"D01": (1, 2, 0), "D02": (2, 1, 0)} and yielded == {"D01"} and not gave
    # without its cell in the ranking, nothing says which cells are as good: its order holds
    cells, _, _ = coop_arb({"D01": ((1, 1, 0), [X, Y]), "D02": ((2, 1, 0), [STAY, NY])}, {"D01": 3})
    assert cells == {"D01": (2, 1, 0), "D02": (2, 0, 0)}


def test_pibt_push_chain_backtracks() -> None:
    # D01 pushes D02, which can only go on into D03, which can go nowhere: both fail; D01 takes +y.
    drones = {"D01": ((1, 1, 0), [X, Y]), "D02": ((2, 1, 0), [STAY, X]), "D03": ((3, 1, 0), [STAY])}
    cells, _, gave = coop_arb(drones, {"D01": 9})
    assert cells == {"D01": (1, 2, 0), "D02": (2, 1, 0), "D03": (3, 1, 0)} and gave == {"D01"}


def test_pibt_gives_way_when_its_own_push_tree_holds_the_cells() -> None:
    """A drone whose pushes failed stays, and its cell is then taken: by the same push tree, not by a drone of
    higher priority. D01 pushes D02, which tries D03 (stuck: it stays), then D04, which would have to push D05
    into D03's cell: every request fails because of drones D01 itself drove to try, so D01 gives way (its
    priority resets and they push it back next turn), as when the drones it pushed had nowhere to go at all."""
    drones = {"D01": ((0, 1, 0), [X, STAY]), "D02": ((1, 1, 0), [STAY, X, Y]), "D03": ((2, 1, 0), [STAY]),
              "D04": ((1, 2, 0), [STAY, X]), "D05": ((2, 2, 0), [STAY, NY])}
    cells, yielded, gave = coop_arb(drones, {"D01": 9})
    assert cells == {d: c for d, (c, _) in drones.items()} and yielded == {"D01"} and gave == {"D01"}
    # ... but not when a drone of higher priority took the cell it needed first
    drones |= {"D03": ((2, 1, 0), [STAY, X]), "D06": ((2, 0, 0), [Y])}
    cells, _, gave = coop_arb(drones, {"D01": 9, "D06": 10})
    assert cells["D06"] == (2, 1, 0) and cells["D01"] == (0, 1, 0) and not gave


def test_pibt_a_long_push_chain_moves_as_one() -> None:
    n = 7  # a queue along x, each wanting the cell ahead; the head is free to go on
    drones = {f"D0{k + 1}": ((k, 0, 0), [X, STAY]) for k in range(n)}
    cells, yielded, _ = coop_arb(drones, {"D01": 9})
    assert cells == {f"D0{k + 1}": (k + 1, 0, 0) for k in range(n)} and not yielded


def test_pibt_no_swap_between_cooperative_drones() -> None:
    cells, _, _ = coop_arb({"D01": ((1, 1, 0), [X, STAY]), "D02": ((2, 1, 0), [NX, STAY])})
    assert cells == {"D01": (1, 1, 0), "D02": (2, 1, 0)}  # D02 would have to enter D01's cell: refused


def test_pibt_rotation_is_allowed() -> None:
    ring = [(1, 1, 0), (2, 1, 0), (2, 2, 0), (1, 2, 0)]
    steps = [X, Y, NX, NY]
    drones = {f"D0{k + 1}": (ring[k], [steps[k]]) for k in range(4)}
    assert coop_arb(drones)[0] == {f"D0{k + 1}": ring[(k + 1) % 4] for k in range(4)}


def test_pibt_non_cooperative_moves_are_kept_and_avoided() -> None:
    # D09 (not cooperative) flies into (2, 1, 0): D01 may not enter it, nor swap with D08.
    drones = {"D01": ((1, 1, 0), [X, Y, STAY]), "D09": ((3, 1, 0), (2, 1, 0), None),
              "D02": ((5, 5, 0), [X, STAY]), "D08": ((6, 5, 0), (5, 5, 0), None)}
    cells, _, _ = coop_arb(drones, {"D01": 9, "D02": 9})
    assert cells == {"D01": (1, 2, 0), "D09": (2, 1, 0), "D02": (5, 5, 0), "D08": (5, 5, 0)}


def test_pibt_a_cooperative_drone_flees_a_non_cooperative_one() -> None:
    cells, _, _ = coop_arb({"D01": ((1, 1, 0), [STAY, Y]), "D09": ((2, 1, 0), (1, 1, 0), None)})
    assert cells == {"D01": (1, 2, 0), "D09": (1, 1, 0)}


def test_pibt_without_a_ranking_a_cooperative_drone_takes_its_move_or_stays() -> None:
    cells, _, _ = coop_arb({"D01": ((1, 1, 0), []), "D02": ((2, 2, 0), [NY, STAY])})
    assert cells == {"D01": (1, 1, 0), "D02": (2, 1, 0)}


def grid_of(rows: list[str]) -> np.ndarray:
    """A one-floor grid [x, y, z] from rows of text (row k is y = k; '#' a building)."""
    return np.array([[c == "#" for c in r] for r in rows]).T[:, :, None]


#: A dead-end corridor (y = 1, x = 2..5) off a 2 x 3 room (x = 0..1): its junction is (1, 1).
DEAD_END = grid_of(["..####", "......", "..####"])


@pytest.mark.parametrize("swap", [True, False])
def test_pibt_swap_leads_a_drone_out_of_a_dead_end(swap: bool) -> None:
    """PIBT's swap (Okumura, IJCAI 2023): D01 (at the mouth, going to the end) meets D02 (coming out). Pushing
    D02 on would drive it to the end and back; with the swap D01 steps back, towards the junction, and pulls
    D02 into the cell it leaves (which D02 offered first). Without the world (no swap), it pushes."""
    drones = {"D01": ((2, 1, 0), [X, STAY, NX]), "D02": ((3, 1, 0), [NX, STAY, X])}
    cells, _, gave = coop_arb(drones, {"D01": 5, "D02": 1}, {"D01": (5, 1, 0), "D02": (0, 1, 0)},
                              DEAD_END if swap else None, DEAD_END.shape)
    if swap:
        assert cells == {"D01": (1, 1, 0), "D02": (2, 1, 0)} and not gave  # it leads: it does not give way
    else:
        assert cells == {"D01": (3, 1, 0), "D02": (4, 1, 0)}


def test_pibt_no_swap_where_the_other_drone_can_be_pushed_aside() -> None:
    """Beyond D02 the corridor meets a junction (x = 4 opens up and down): pushing it on lets D01 pass there."""
    grid = grid_of(["..##.#", "......", "..##.#"])
    drones = {"D01": ((2, 1, 0), [X, STAY, NX]), "D02": ((3, 1, 0), [NX, STAY, X])}
    cells, _, _ = coop_arb(drones, {"D01": 5, "D02": 1}, {"D01": (5, 1, 0), "D02": (0, 1, 0)}, grid, grid.shape)
    assert cells == {"D01": (3, 1, 0), "D02": (4, 1, 0)}


def test_pibt_no_swap_with_a_drone_whose_target_is_in_the_corridor() -> None:
    """D02 is going to the end itself (it wants D01's cell only to let it by): pulling it out gains nothing."""
    drones = {"D01": ((2, 1, 0), [X, STAY, NX]), "D02": ((3, 1, 0), [NX, STAY, X])}
    cells, _, _ = coop_arb(drones, {"D01": 5, "D02": 1}, {"D01": (5, 1, 0), "D02": (4, 1, 0)}, DEAD_END,
                           DEAD_END.shape)
    assert cells == {"D01": (3, 1, 0), "D02": (4, 1, 0)}


def test_pibt_swap_pulls_a_drone_off_its_target_that_blocks_a_deeper_one() -> None:
    """Two targets in a dead end, the shallower one taken first: D02 is parked on (3, 1), D01 wants the end
    beyond it. Pushing D02 on drives it to the end and back for ever; D01 steps back instead, pulling D02 off
    its target (it offered that cell) towards the junction, where D02 will let D01 in first."""
    drones = {"D01": ((2, 1, 0), [X, STAY, NX]), "D02": ((3, 1, 0), [STAY, NX, X])}
    cells, _, gave = coop_arb(drones, {"D01": 5}, {"D01": (4, 1, 0), "D02": (3, 1, 0)}, DEAD_END, DEAD_END.shape)
    assert cells == {"D01": (1, 1, 0), "D02": (2, 1, 0)} and not gave
    # not when the end is D02's own target (then D01 stops short of it: pushing is right)
    cells, _, _ = coop_arb(drones, {"D01": 5}, {"D01": (4, 1, 0), "D02": (5, 1, 0)}, DEAD_END, DEAD_END.shape)
    assert cells == {"D01": (3, 1, 0), "D02": (4, 1, 0)}


def test_pibt_clear_a_drone_lets_the_one_going_deeper_in_first() -> None:
    """The clear operation (lacam3): D02, out of the dead end next to its target (3, 1), would enter first; D01,
    beside it at the junction and wanting its cell, goes to the end (5, 1). Entering first, D02 would park in
    D01's way: it steps back instead (its cells in reverse) and pulls D01 into its cell."""
    drones = {"D02": ((2, 1, 0), [X, STAY, NY, Y]), "D01": ((1, 1, 0), [X, STAY, NX])}
    targets = {"D01": (5, 1, 0), "D02": (3, 1, 0)}
    cells, _, _ = coop_arb(drones, {"D02": 5}, targets, DEAD_END, DEAD_END.shape)
    assert cells["D01"] == (2, 1, 0) and cells["D02"] in {(2, 0, 0), (2, 2, 0)}
    # the other way round (D01's target the shallower one) D02 goes in first: no clear
    cells, _, _ = coop_arb(drones, {"D02": 5}, {"D01": (3, 1, 0), "D02": (5, 1, 0)}, DEAD_END, DEAD_END.shape)
    assert cells == {"D02": (3, 1, 0), "D01": (2, 1, 0)}


def test_pibt_a_pushed_drone_retreats_out_of_its_neighbours_way() -> None:
    """Among its retreats, a pushed drone takes first one where it hinders none of the drones next to it that
    want its cell (Okumura & Nagai's hindrance): D03, beside D02, wants D02's cell on its way to (1, 5), and
    from there (2, 3) is closer to it than (2, 1): D02, pushed by D01, steps -y rather than +y, though it ranks
    +y first. A neighbour that does not want D02's cell does not count."""
    drones = {"D01": ((1, 2, 0), [X, STAY]), "D02": ((2, 2, 0), [STAY, Y, NY]), "D03": ((3, 2, 0), [NX, STAY])}
    targets = {"D01": (6, 2, 0), "D02": (2, 2, 0), "D03": (1, 5, 0)}
    assert coop_arb(drones, {"D01": 3}, {"D01": (6, 2, 0), "D02": (2, 2, 0)})[0]["D02"] == (2, 3, 0)
    cells, _, _ = coop_arb(drones, {"D01": 3}, targets)
    assert cells == {"D01": (2, 2, 0), "D02": (2, 1, 0), "D03": (3, 2, 0)}
    assert coop_arb(drones | {"D03": ((3, 2, 0), [STAY, NX])}, {"D01": 3}, targets)[0]["D02"] == (2, 3, 0)


@st.composite
def ranked_scenes(draw):
    n = draw(st.integers(1, 10))
    cells = draw(st.lists(st.tuples(st.integers(1, 3), st.integers(1, 3), st.integers(0, 1)),
                          min_size=n, max_size=n, unique=True))
    ids = [f"D{i:02d}" for i in draw(st.lists(st.integers(1, 40), min_size=n, max_size=n, unique=True))]
    drones, priority = {}, {}
    for d, c in zip(ids, cells):
        if draw(st.booleans()) or draw(st.booleans()):
            steps = draw(st.lists(st.sampled_from(AROUND + (STAY,)), unique=True, max_size=7))
            drones[d] = (c, steps)
        else:
            s = draw(st.sampled_from(AROUND + (STAY,)))
            drones[d] = (c, (c[0] + s[0], c[1] + s[1], c[2] + s[2]), None)
        priority[d] = draw(st.integers(0, 3))
    # targets and buildings (for the swap, in half the scenes): corridors appear among random buildings
    if draw(st.booleans()):
        return drones, priority, None, None
    spots = st.tuples(st.integers(0, 4), st.integers(0, 4), st.integers(0, 1))
    targets = {d: draw(spots) for d in ids if draw(st.booleans()) or draw(st.booleans())}
    blocked = np.zeros(SIZE, bool)
    for c in draw(st.lists(spots, max_size=20)):
        blocked[c] = c not in cells
    return drones, priority, targets, blocked


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ranked_scenes(), st.one_of(st.none(), st.integers(0, 1 << 40)))
def test_property_pibt_guarantees(scene, salt: int | None) -> None:
    drones, priority, targets, blocked = scene
    cells, yielded, gave = coop_arb(drones, priority, targets, blocked, salt=salt)
    coop = {d for d in drones if len(drones[d]) == 2}
    before = {d: drones[d][0] for d in drones}
    for d in drones:
        if d not in coop:
            assert cells[d] == drones[d][1], "a non-cooperative move was changed"
            continue
        offered = {(before[d][0] + s[0], before[d][1] + s[1], before[d][2] + s[2]) for s in drones[d][1]}
        assert cells[d] in offered | {before[d]}, f"{d} moved to a cell it did not offer"
        first = drones[d][1][0] if drones[d][1] else STAY
        assert (d in yielded) == (cells[d] != tuple(np.add(before[d], first).tolist()))
        for e in drones:
            if e == d:
                continue
            if cells[e] == cells[d]:  # sharing a cell: only ever with a non-cooperative drone that forced it
                assert e not in coop and cells[d] == before[d], f"{d} and {e} share {cells[d]}"
            swapped = cells[d] == before[e] and cells[e] == before[d] and cells[d] != before[d]
            assert not swapped, f"{d} swapped with {e}"
    assert gave <= yielded
    dead = deaths(WORLD, before, cells, set())  # (a drone offering a cell off the world may die there)
    for d, cause in dead.items():  # a cooperative drone collides only where a non-cooperative one flew into it
        if d in coop and cause in (Cause.VERTEX, Cause.SWAP):
            assert any(e not in coop and cells[e] == cells[d] for e in drones if e != d)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ranked_scenes(), st.one_of(st.none(), st.integers(0, 1 << 40)), st.integers(0, 1 << 30))
def test_property_drones_alone_settled_first_change_nothing(scene, salt: int | None, seed: int) -> None:
    """`cooperate` settling the drones `alone` first (in numpy) gives what PIBT's loop over every drone gives,
    on the random scenes above and on sparse ones (drones far apart in a bigger world, most of them alone)."""
    drones, priority, targets, blocked = scene
    ids = sorted(drones)
    before = np.array([drones[d][0] for d in ids], np.int32).reshape(-1, 3)
    coop = np.array([len(drones[d]) == 2 for d in ids])
    ranked = np.array([rank_steps(drones[d][1]) if coop[k] else 0 for k, d in enumerate(ids)], np.uint32)
    proposed = np.array([np.add(drones[d][0], drones[d][1][0]) if coop[k] and drones[d][1] else
                         (drones[d][0] if coop[k] else drones[d][1]) for k, d in enumerate(ids)], np.int32)
    prio = np.array([priority.get(d, 0) for d in ids], np.int64)
    aims = None if targets is None else np.array([targets.get(d, (-1, -1, -1)) for d in ids], np.int32)
    world = None if blocked is None else OpenCells(blocked)
    args = (SIZE, before, proposed.reshape(-1, 3), ranked, coop, prio, aims, world, salt)
    for a, b in zip(cooperate(*args), cooperate(*args, shortcut=False)):
        assert a.tolist() == b.tolist()
    rng = np.random.default_rng(seed)  # sparse: 40 drones in 12 x 12 x 3
    n, size = 40, (12, 12, 3)
    flat = rng.choice(size[0] * size[1] * size[2], n, replace=False)
    before = np.stack(np.unravel_index(flat, size), axis=1).astype(np.int32)
    ranked = np.array([rank_steps([(AROUND + (STAY,))[k] for k in rng.permutation(7)[:rng.integers(1, 8)]])
                       for _ in range(n)], np.uint32)
    coop = rng.random(n) < 0.9
    proposed = before + np.array(AROUND, np.int32)[rng.integers(0, 6, n)]
    aims = np.where(rng.random((n, 1)) < 0.8, rng.integers(0, 12, (n, 3)) % np.array(size), -1).astype(np.int32)
    args = (size, before, proposed, ranked, coop, rng.integers(0, 4, n), aims, OpenCells(np.zeros(size, bool)), salt)
    for a, b in zip(cooperate(*args), cooperate(*args, shortcut=False)):
        assert a.tolist() == b.tolist()


@pytest.mark.parametrize("shape", [(1, 1, 1), (3, 5, 2), (17, 9, 4), (40, 33, 7)])
def test_the_open_cells_read_as_the_world_padded_with_blocked_cells(shape) -> None:
    """One bit a cell, made a slab at a time: the same as a padded copy of the world would say."""
    grid = np.random.default_rng(sum(shape)).random(shape) < 0.3
    padded = np.zeros(tuple(n + 2 for n in shape), bool)
    padded[1:-1, 1:-1, 1:-1] = ~grid
    is_open = OpenCells(grid)
    assert [is_open[u] for u in range(padded.size)] == padded.reshape(-1).astype(int).tolist()
