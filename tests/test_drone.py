"""The drone process's core (entities/drone.py), driven with messages and no network: its queries are
answered (or not) by an in-test environment, and what it publishes is compared with the autopilots
flown directly over the same world."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from entities.autopilots import make_autopilot
from entities.autopilots.base import drive, fly_pilots
from entities.drone import (
    Answer,
    DroneProcess,
    EnvPresence,
    Expired,
    Query,
    Refusal,
    SendMoves,
    Timer,
)
from entities.environment import Environment, build_world
from schema import (
    Ans,
    Ask,
    CellInfo,
    MalformedMessage,
    MapRequest,
    Moves,
    Nps,
    Order,
    Over,
    Phase,
    RemoteInputError,
    Start,
    Turn,
    Welcome,
    WorldMap,
    WorldSpec,
)
from schema.messages import EndReason

LOG = logging.getLogger("test.drone")
SPEC = WorldSpec(size=(8, 8, 3), seed=5)
STARTS = {"D01": (0, 0, 0), "D02": (0, 2, 0), "D03": (0, 4, 0)}
TARGETS = {"D01": (7, 7, 0), "D02": (6, 1, 2), "D03": (5, 6, 1)}


class Env:
    """The environment, answering the core's queries as its process would."""

    def __init__(self) -> None:
        self.world = build_world(SPEC, STARTS.values())
        self.env = Environment(self.world, dict(STARTS))

    def answer(self, query: Query) -> Answer:
        match query.msg:
            case MapRequest():
                return Answer(query.ref, (WorldMap(turn=0, sender="ENV", size=self.world.size,
                                                   buildings=self.world.packed()),))
            case Ask(turn=turn, cells=cells, around=around):
                kinds, drones = self.env.survey(cells, around, drones=turn > 0)
                return Answer(query.ref, (Ans(turn=turn, sender="ENV", kinds=kinds, drones=drones),))
        raise AssertionError(query)

    def oracle(self, pending):
        return {d: dict(zip(cells, self.env.answer(cells))) for d, cells in pending.items()}


def welcome(drones=STARTS) -> Welcome:
    return Welcome(turn=0, sender="SRV", entity="D01", text="You are connected", world=SPEC,
                   starts=tuple(Start(drone=d, pos=p) for d, p in sorted(drones.items())))


def turn(t: int, pos: dict | None = None) -> Turn:
    pos = pos or STARTS
    return Turn(turn=t, sender="SRV", phase=Phase.DRONES,
                orders=tuple(Order(drone=d, pos=p, target=TARGETS[d]) for d, p in sorted(pos.items())))


def started(core: DroneProcess) -> list:
    """Admitted, with an environment present (its presence, as the adapter feeds it, right after)."""
    return core.start() + core.receive([EnvPresence("e0", True)])


def unprepared(core: DroneProcess) -> None:
    """`started`, but nobody answered the cells asked before the game (the map stays on its way)."""
    core.receive([Answer(q.ref, ()) for q in queries(started(core), Ask)])


def queries(effects, kind=None) -> list[Query]:
    return [e for e in effects if isinstance(e, Query) and (kind is None or isinstance(e.msg, kind))]


def sent(effects) -> list:
    return [e.msg for e in effects if isinstance(e, SendMoves)]


def expected_nps(t: int, drones=("D01",), pos=None) -> list[Nps]:
    """What the drones' autopilots decide, flown directly over the environment."""
    env = Env()
    pilots = {d: make_autopilot("seed", world_size=SPEC.size) for d in drones}
    decisions = drive(fly_pilots(pilots, turn(t, pos).orders.orders(set(drones)), host=None), env.oracle)
    return [Nps(turn=t, sender=d, pos=dec.pos, note=dec.note) for d, dec in decisions.items()]


def test_a_turn_is_answered_from_the_chart_once_the_map_came() -> None:
    env = Env()
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    start = started(core)
    (ask_map,) = queries(start, MapRequest)
    assert queries(start, Ask)  # the static world around the start, asked ahead
    assert core.receive([env.answer(ask_map)]) == [] and core.chart.complete
    effects = core.receive([turn(1)])
    assert queries(effects) == [] and sent(effects) == expected_nps(1)  # no round trip


def test_what_it_asks_before_the_game_waits_for_an_environment() -> None:
    """A host admitted before the environment started: its questions would go unanswered, so the map and the
    cells around the starts are asked when the environment's presence appears, once, and not once the game
    has begun."""
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    assert core.start() == []
    early = core.receive([EnvPresence("e1", True)])
    assert len(queries(early, MapRequest)) == 1 and queries(early, Ask)
    assert core.receive([EnvPresence("e1", False), EnvPresence("e2", True)]) == []  # asked already
    late = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    late.start()
    effects = late.receive([turn(1)])  # the game began first: the turn asks for itself
    assert len(queries(effects, MapRequest)) == 1 and all(q.msg.turn == 1 for q in queries(effects, Ask))
    assert late.receive([EnvPresence("e1", True)]) == []


def test_a_turn_that_needs_an_ask_waits_for_its_answer_then_asks_ahead() -> None:
    env = Env()
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    start = started(core)
    (ask_map,) = queries(start, MapRequest)
    nobody = [Answer(q.ref, ()) for q in start]  # nobody served the map or the cells ahead (yet)
    assert core.receive(nobody) == []
    effects = core.receive([turn(1)])
    assert len(queries(effects, MapRequest)) == 1  # asked again, in a later turn
    (ask,) = queries(effects, Ask)
    assert ask.msg.turn == 1 and sent(effects) == []
    effects = core.receive([env.answer(ask)])
    assert sent(effects) == expected_nps(1)
    ahead = queries(effects)
    assert ahead and all(isinstance(q.msg, Ask) and q.msg.turn == 0 for q in ahead)  # the next sensing, ahead
    assert core.chart.kind(ask.msg.cells[0]) is not None  # what it was told is charted


def test_a_turn_waits_for_the_cells_asked_ahead_instead_of_asking_them_again() -> None:
    env = Env()
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    ahead = queries(started(core), Ask)
    assert ahead and all(q.msg.turn == 0 for q in ahead)
    assert core.receive([turn(1)]) == []  # the cells around the start are on their way: nothing asked twice
    effects = core.receive([env.answer(q) for q in ahead])
    assert queries(effects, Ask) == [] or all(q.msg.turn == 0 for q in queries(effects, Ask))
    assert sent(effects) == expected_nps(1)  # decided from the chart
    # With the environment gone, it waits no more: the turn asks (and waits for an environment as usual).
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    started(core)
    (ask,) = queries(core.receive([EnvPresence("e0", False), turn(1)]))
    assert ask.msg.turn == 1


def test_a_late_map_answers_the_turns_after_it() -> None:
    env = Env()
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    start = started(core)
    (ask_map,) = queries(start, MapRequest)
    core.receive([Answer(q.ref, ()) for q in queries(start, Ask)])  # nobody answered the cells ahead
    (ask,) = queries(core.receive([turn(1)]))  # the map is on its way (not waited for): the turn asks
    assert core.receive([env.answer(ask_map)]) == [] and core.chart.complete  # it comes meanwhile
    assert sent(core.receive([env.answer(ask)])) == expected_nps(1)
    effects = core.receive([turn(2, {"D01": expected_nps(1)[0].pos})])
    assert queries(effects) == [] and len(sent(effects)) == 1


def test_the_map_is_asked_again_in_a_later_turn_while_nobody_answers_it() -> None:
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    (ask_map,) = queries(started(core), MapRequest)
    core.receive([Answer(ask_map.ref, ())])
    again = queries(core.receive([turn(1)]), MapRequest)
    assert len(again) == 1 and queries(core.receive([turn(1)]), MapRequest) == []  # once per turn at most
    refused = core.receive([Answer(again[0].ref, (RemoteInputError("no map here", reason="error-reply"),))])
    assert [type(e) for e in refused] == [Refusal] and refused[0].what == "MAP"
    assert queries(core.receive([turn(2)]), MapRequest) == []  # refused: not asked again


def test_over_ends_the_turn_being_decided_and_a_late_answer_changes_nothing() -> None:
    env = Env()
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    unprepared(core)
    (ask,) = queries(core.receive([turn(1)]))
    over = Over(turn=1, sender="SRV", reason=EndReason.ABORTED, text="stopped")
    assert core.receive([over]) == [] and core.over == over
    assert sent(core.receive([env.answer(ask)])) == []


def test_refused_and_malformed_answers_are_counted_and_the_drone_decides_without_them() -> None:
    for reply in (RemoteInputError("ENV/ASK answered an error: busy", reason="error-reply"),
                  Ans(turn=1, sender="ENV", kinds=b"\x00\x00")):  # two kinds for the one cell asked
        core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
        unprepared(core)
        effects, refusals = core.receive([turn(1)]), []
        while not sent(effects):  # the seed's drone asks cell after cell: every answer is refused
            (ask,) = queries(effects, Ask)
            assert len(ask.msg.cells) == 1
            effects = core.receive([Answer(ask.ref, (reply,))])
            refusals += [e for e in effects if isinstance(e, Refusal)]
        assert len(refusals) == 4 and {r.what for r in refusals} == {"ANS for D01"}
        assert all(isinstance(r.err, MalformedMessage if isinstance(reply, Ans) else RemoteInputError)
                   for r in refusals)
        (nps,) = sent(effects)  # told nothing: it hovers
        assert nps.pos == STARTS["D01"]


def test_an_ask_nobody_answered_is_asked_again_once_the_environment_is_back() -> None:
    env = Env()
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG, patience=12.5)
    unprepared(core)
    (ask,) = queries(core.receive([turn(1)]))
    effects = core.receive([Answer(ask.ref, ()), EnvPresence("e0", False)])
    (timer,) = [e for e in effects if isinstance(e, Timer)]
    assert timer.seconds == 12.5 and queries(effects) == []  # no environment: it waits for one
    (again,) = queries(core.receive([EnvPresence("e2", True)]))
    assert again.msg == ask.msg
    assert sent(core.receive([env.answer(again)])) == expected_nps(1)
    # An environment that stays away: once patience is over, the drone decides without its answers.
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    unprepared(core)
    (ask,) = queries(core.receive([turn(1), EnvPresence("e0", False)]))
    (timer,) = [e for e in core.receive([Answer(ask.ref, ())]) if isinstance(e, Timer)]
    assert core.receive([Expired(timer.ref - 1)]) == []  # another timer's: nothing
    (nps,) = sent(core.receive([Expired(timer.ref)]))
    assert nps.pos == STARTS["D01"]


def test_a_later_turn_supersedes_the_one_being_decided_and_a_repeat_gets_the_same_moves() -> None:
    env = Env()
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    unprepared(core)
    (ask,) = queries(core.receive([turn(1)]))
    effects = core.receive([turn(2)])  # turn 1 was not decided in time: the game moved on
    (ask2,) = queries(effects)
    assert ask2.msg.turn == 2 and sent(effects) == []
    assert sent(core.receive([env.answer(ask)])) == []  # turn 1's answer: charted, nothing sent
    moves = sent(core.receive([env.answer(ask2)]))
    assert [m.turn for m in moves] == [2]
    assert sent(core.receive([turn(2)])) == moves  # a repeat (e.g. after the coordinator restarted)
    # A batch of everything queued acts only on its latest TURN.
    core = DroneProcess(welcome(), drones=("D01",), autopilot="seed", logger=LOG)
    (ask_map,) = queries(started(core), MapRequest)
    core.receive([env.answer(ask_map)])
    assert [m.turn for m in sent(core.receive([turn(3), turn(4)]))] == [4]


@pytest.mark.parametrize("swarm_min", [1, 1000])
def test_a_swarm_host_sends_one_moves_equal_to_its_drones_decisions(monkeypatch, swarm_min) -> None:
    """The swarm form (swarm_min 1) and one pilot per drone give the same MOVES; without the map, cells
    go in ASKs of at most Ask.MAX_CELLS cells, and are charted."""
    monkeypatch.setattr(Ask, "MAX_CELLS", 4)
    env = Env()
    drones = tuple(sorted(STARTS))
    core = DroneProcess(welcome(), drones=drones, autopilot="seed", logger=LOG, host="H01", swarm_min=swarm_min)
    assert (core.swarm is not None) == (swarm_min == 1)
    unprepared(core)  # (the map is never answered here)
    effects = core.receive([turn(1)])
    asks = queries(effects, Ask)
    assert asks and all(len(q.msg.cells) <= 4 for q in asks) and sent(effects) == []
    for q in asks[:-1]:
        assert sent(core.receive([env.answer(q)])) == []
    (moves,) = sent(core.receive([env.answer(asks[-1])]))
    assert isinstance(moves, Moves) and moves.sender == "H01" and moves.turn == 1
    expected = {n.sender: (n.pos, n.note) for n in expected_nps(1, drones)}
    assert {m.drone: (m.pos, m.note) for m in moves.moves.records()} == expected


@pytest.mark.parametrize("host", [None, "H01"])
def test_without_its_chart_every_turn_asks_the_environment_and_decides_the_same(host) -> None:
    """The benchmark's switch (`chart=False`): nothing asked ahead or charted, each turn's cells asked."""
    env = Env()
    drones = ("D01",) if host is None else tuple(sorted(STARTS))
    core = DroneProcess(welcome(), drones=drones, autopilot="seed", logger=LOG, host=host, chart=False)
    assert started(core) == []
    pos = None
    for t in (1, 2):
        effects = core.receive([turn(t, pos)])
        asks = queries(effects)
        assert asks and all(isinstance(q.msg, Ask) and q.msg.turn == t for q in asks) and sent(effects) == []
        for q in asks:
            effects = core.receive([env.answer(q)])
        expected = expected_nps(t, drones, pos)
        inside = [c for q in asks for c in q.msg.cells if all(0 <= v < n for v, n in zip(c, SPEC.size))]
        assert inside and all(core.chart.kind(c) is None for c in inside)  # nothing charted
        assert queries(effects) == []  # nothing asked ahead
        if host is None:
            assert sent(effects) == expected
        else:
            (moves,) = sent(effects)
            assert {m.drone: (m.pos, m.note) for m in moves.moves.records()} == {
                n.sender: (n.pos, n.note) for n in expected}
        pos = {**(pos or STARTS), **{n.sender: n.pos for n in expected}}


def test_a_blind_autopilot_asks_nothing() -> None:
    core = DroneProcess(welcome(), drones=("D01",), autopilot="v1", logger=LOG)
    assert started(core) == []
    effects = core.receive([turn(1)])
    assert queries(effects) == [] and len(sent(effects)) == 1


# --------------------------------------------------------------------------- the chart


def test_chart_remembers_what_it_was_told_and_lists_the_unknown_neighbours() -> None:
    from entities.drone import Chart
    from schema import CellKind

    chart = Chart((4, 4, 2))
    assert chart.kind((1, 1, 1)) is None and chart.kind((-1, 0, 0)) is CellKind.OUTSIDE
    assert chart.unknown([(0, 0, 0)]) == ((1, 0, 0), (0, 1, 0), (0, 0, 1))  # in AROUND order, in the world
    chart.learn([(1, 0, 0), (0, 1, 0), (9, 9, 9)], bytes([CellKind.BUILDING, CellKind.EMPTY, CellKind.OUTSIDE]))
    assert chart.kind((1, 0, 0)) is CellKind.BUILDING and chart.kind((0, 1, 0)) is CellKind.EMPTY
    assert chart.unknown([(0, 0, 0), (0, 0, 1)]) == ((0, 0, 1), (1, 0, 1), (0, 1, 1), (0, 0, 0))


def test_answers_from_the_chart_are_what_the_environment_says() -> None:
    """Kinds the environment told once, and the drones in each cell from the turn's orders, give the
    same CellInfo as an ASK for that turn."""

    from entities.drone import Chart, occupancy_of
    from entities.environment import Environment
    from schema import Ans, Order, OrderTable
    from world.grid import World

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
    from entities.drone import Chart
    from schema import CellKind
    from schema.tuning import CHART_FEW_CELLS

    around = [(x, y, z) for x in range(0, 8, 2) for y in range(0, 8, 2) for z in (0, 2)]
    assert len(around) * 6 > CHART_FEW_CELLS
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
    from entities.drone import Chart

    chart = Chart((9, 9, 9))
    far = chart.unknown([(4, 4, 4)], reach=3)
    assert len(far) == 62 and set(far[:6]) == set(chart.unknown([(4, 4, 4)]))  # 6 + 18 + 38 cells, nearest first
    assert all(0 < sum(abs(a - 4) for a in c) <= 3 for c in far)
    assert len(Chart((2, 2, 1)).unknown([(0, 0, 0)], reach=3)) == 3  # only cells in the world


def test_chart_from_the_environments_map_answers_every_cell_as_the_environment_does() -> None:
    """The static map (ENV/MAP, as the environment serves it) charts every cell: the answers are the
    environment's, and nothing is left to ask."""
    import pytest

    from entities.drone import Chart
    from entities.environment import Environment
    from schema import CellKind, OutOfRange, WorldMap
    from world.grid import World

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
