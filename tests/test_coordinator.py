"""The coordinator's loop (`coordinator.node.Coordinator`) driven with events and a clock of the test's,
no network: pacing, a lost link (a router restart), signals, a second coordinator, presence."""

from __future__ import annotations

import logging
import signal

import numpy as np
import pytest

from coordinator.config import DroneSpec, GameConfig
from coordinator.engine import Engine
from coordinator.node import LINGER_S, SETTLE_S, Coordinator, Executor, parse_starts
from network.signals import Interrupted
from network.transport import Asked, Presence, Received, Sessions, sessions_listed
from schema import (
    Connect,
    Done,
    EndReason,
    Keys,
    Message,
    Moves,
    Nps,
    Over,
    Phase,
    RejectCounter,
    Role,
    Status,
    Turn,
    UsageError,
    WorldSpec,
    decode,
)
from schema.tuning import DECIDING_SILENCE_S

LOG = logging.getLogger("dronesim.tests.coordinator")
ME = "5e55"  # the coordinator's session id
SESSIONS = {"ENV": "e0", "GCS": "g0", "D01": "d1", "D02": "d2"}


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Wire:
    """The Outbox: what was published, in order."""

    def __init__(self) -> None:
        self.sent: list[Message] = []

    def put(self, key: str, msg: Message, data: bytes | None = None) -> None:
        self.sent.append(msg)

    def matching(self, key: str) -> bool:
        return True

    def of(self, kind: type) -> list:
        return [m for m in self.sent if isinstance(m, kind)]


class Journal:
    def __init__(self) -> None:
        self.records: list[dict] = []

    def append(self, record: dict) -> None:
        self.records.append(record)


class Query:
    """A CONNECT query: keeps the reply."""

    key_expr = "sim/SRV/CONNECT"

    def __init__(self) -> None:
        self.replies: list[Message] = []

    def reply(self, key: str, data: bytes) -> None:
        self.replies.append(decode(data))

    def drop(self) -> None:
        pass


class Run:
    def __init__(self, drones: int = 1, pace: float = 0.0, **config) -> None:
        empty = np.packbits(np.zeros(6 * 6 * 2, bool)).tobytes()  # no building
        game = GameConfig(world=WorldSpec(size=(6, 6, 2), cells=empty),
                          drones=tuple(DroneSpec(drone=f"D{i:02d}", start=(0, 2 * (i - 1), 0))
                                       for i in range(1, drones + 1)), **config)
        self.clock, self.wire, self.journal = Clock(), Wire(), Journal()
        self.engine = Engine(game, LOG)
        rejects = RejectCounter(LOG)
        executor = Executor(Keys("sim"), self.wire, self.journal, rejects, pace, clock=self.clock)
        self.audits: list[float] = []  # when the coordinator asked which sessions are connected
        self.srv = Coordinator(self.engine, executor, rejects, LOG, ME, clock=self.clock,
                               audit=lambda: self.audits.append(self.clock.now))
        self.srv.handle(Presence("SRV", ME, True))
        for entity, role in [("ENV", Role.ENV), ("GCS", Role.GCS)] + [(d.drone, Role.DRONE) for d in game.drones]:
            self.join(entity, role)

    def join(self, entity: str, role: Role, session: str | None = None) -> Message:
        query = Query()
        session = session or SESSIONS[entity]
        self.srv.handle(Presence(entity, session, True))
        drones = (entity,) if role is Role.DRONE else ()
        self.srv.handle(Asked(query, Connect(turn=0, sender=entity, role=role, drones=drones, autopilot="seed",
                                             session=session)))
        return query.replies[0]

    def wait(self, seconds: float) -> None:
        """`seconds` pass: what is due happens (the inbox hands None to the loop when its timeout passes)."""
        end = self.clock.now + seconds
        while (left := self.srv.timeout()) is not None and self.clock.now + left <= end and not self.srv.finished():
            self.clock.now += left
            self.srv.handle(None)
        self.clock.now = end

    def send(self, msg: Message) -> None:
        self.srv.handle(Received("key", msg))

    def turn_sent(self, turn: int, phase: Phase) -> int:
        return sum(1 for t in self.wire.of(Turn) if (t.turn, t.phase) == (turn, phase))

    def play(self, turn: int, moves: dict, *, ahead: bool = False) -> None:
        """The GCS answers turn `turn` (and with `ahead` the next one too), the drones move."""
        self.send(Done(turn=turn, sender="GCS", phase=Phase.GCS))
        if ahead:
            self.send(Done(turn=turn + 1, sender="GCS", phase=Phase.GCS))
        for d, p in moves.items():
            self.send(Nps(turn=turn, sender=d, pos=p))

    def leave(self, *entities: str) -> None:
        for e in entities:
            self.srv.handle(Presence(e, SESSIONS[e], False))


def test_a_paced_game_that_ends_while_a_turn_is_held_publishes_its_over_at_once() -> None:
    """dronesim up --pace: the drone's process is killed while the next turn waits for its pace."""
    run = Run(pace=10.0)
    run.play(1, {"D01": (1, 0, 0)}, ahead=True)  # turn 2's GCS phase answered ahead: its drones' phase opens
    assert run.engine.turn == 2 and run.turn_sent(2, Phase.DRONES) == 0, "held by the pace"
    run.leave("D01")
    run.wait(SETTLE_S)
    assert run.engine.end is not None and run.engine.end.reason is EndReason.NO_DRONE_ALIVE
    assert run.wire.of(Over) == [run.engine.end], "OVER went out without waiting for the pace"
    assert run.journal.records[-1]["record"] == "over"
    run.leave("ENV", "GCS")
    assert run.srv.finished()


def test_a_router_restart_holds_the_game_and_it_goes_on_as_if_nothing_happened() -> None:
    run = Run(drones=2, phase_deadline=1.0)
    run.play(1, {"D01": (1, 0, 0)})  # D02's move of turn 1 is lost with the link
    run.leave("D01", "D02")  # the others' presences may vanish just before the coordinator's own
    run.srv.handle(Presence("SRV", ME, False))
    run.leave("ENV", "GCS")
    run.wait(20.0)  # far past the phase deadline: the game holds
    assert run.engine.turn == 1 and not run.journal.records[1:], "nobody hovered, nobody was lost"
    sent = len(run.wire.sent)
    for e in ("SRV", "ENV", "GCS", "D01", "D02"):
        run.srv.handle(Presence(e, ME if e == "SRV" else SESSIONS[e], True))
    again = run.wire.sent[sent:]
    assert [type(m) for m in again] == [Status, Turn] and again[1].phase is Phase.DRONES, \
        "the turn in progress goes out again"
    run.send(Nps(turn=1, sender="D01", pos=(1, 0, 0)))  # a repeat of what came through: refused, harmless
    run.send(Nps(turn=1, sender="D02", pos=(1, 2, 0)))
    assert run.engine.turn == 2 and "hovered" not in run.journal.records[-1]


def test_entities_that_do_not_come_back_within_the_link_grace_have_vanished() -> None:
    run = Run(drones=2, link_grace=5.0)
    run.play(1, {"D01": (1, 0, 0), "D02": (0, 3, 0)})
    run.srv.handle(Presence("SRV", ME, False))
    run.leave("ENV", "GCS", "D01", "D02")
    for e in ("SRV", "ENV", "GCS", "D01"):
        run.srv.handle(Presence(e, ME if e == "SRV" else SESSIONS[e], True))
    run.wait(4.9)
    assert run.engine.drones["D02"].state.value == "ALIVE"
    run.wait(0.2)
    assert run.engine.drones["D02"].state.value == "LOST" and run.engine.drones["D01"].state.value == "ALIVE"


def test_a_departure_counts_once_settled_unless_the_link_went_with_it() -> None:
    run = Run(drones=2)
    run.play(1, {})
    run.leave("D02")
    assert run.engine.drones["D02"].state.value == "ALIVE", "not yet: the link may be going"
    run.wait(SETTLE_S)
    assert run.engine.drones["D02"].state.value == "LOST"


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_ends_the_game_interrupted_and_the_coordinator_leaves_once_the_others_have(signum) -> None:
    run = Run()
    run.play(1, {"D01": (1, 0, 0)})
    run.srv.handle(Interrupted(signum))
    over = run.wire.of(Over)
    assert len(over) == 1 and over[0].reason is EndReason.INTERRUPTED and over[0].turn == 1, \
        "the last turn played (its STATUS went out)"
    assert run.journal.records[-1] == {"record": "over", "turn": 1, "reason": "INTERRUPTED",
                                       "text": over[0].text}
    assert run.srv.signal == signum and not run.srv.finished(), "it lets OVER reach the others first"
    run.leave("ENV", "GCS")
    assert not run.srv.finished()
    run.wait(LINGER_S)
    assert run.srv.finished(), "not forever: D01 did not leave"


def test_a_second_signal_stops_waiting_for_the_others() -> None:
    run = Run()
    run.srv.handle(Interrupted(signal.SIGINT))
    run.srv.handle(Interrupted(signal.SIGINT))
    assert run.srv.finished()


def test_of_two_coordinators_started_at_once_the_one_with_the_larger_session_yields() -> None:
    run = Run()
    run.srv.handle(Presence("SRV", "ffff", True))
    assert not run.srv.finished(), "the other one yields"
    run.srv.handle(Presence("SRV", "0000", True))
    assert run.srv.finished() and run.srv.rival == "0000"


def test_a_connect_waits_for_its_presence_token_then_is_refused() -> None:
    run = Run(drones=2)
    query = Query()
    run.srv.handle(Asked(query, Connect(turn=0, sender="H01", role=Role.DRONE, drones=("D01",), session="x")))
    assert not query.replies
    run.wait(10.0)
    assert "no presence token of H01" in query.replies[0].text


def test_a_process_that_replaces_a_vanished_one_is_admitted_at_once() -> None:
    run = Run()
    run.play(1, {"D01": (1, 0, 0)})
    run.leave("ENV")
    welcome = run.join("ENV", Role.ENV, session="e1")  # a new environment process
    assert welcome.TAG == "WELCOME", welcome


def test_what_arrives_after_over_is_dropped_unjudged() -> None:
    run = Run()
    run.srv.handle(Interrupted(signal.SIGTERM))
    run.send(Done(turn=5, sender="GCS", phase=Phase.GCS))  # answered ahead before the sender saw OVER
    assert not run.srv.rejects.total


def test_a_signal_noted_by_its_handler_is_acted_on_at_the_next_wake() -> None:
    run = Run()
    run.srv.stop(Interrupted(signal.SIGTERM))  # the handler only notes it
    assert run.srv.timeout() == 0 and not run.wire.of(Over)
    run.srv.handle(None)  # the loop, woken
    assert run.wire.of(Over)[0].reason is EndReason.INTERRUPTED and run.srv.signal == signal.SIGTERM


def test_a_departure_restarts_the_deadline_it_changes() -> None:
    """The environment leaves during a long GCS phase (a person thinking): the game then waits its grace."""
    run = Run(env_grace=5.0)
    run.wait(100.0)  # the GCS phase has no deadline
    run.leave("ENV")
    run.wait(SETTLE_S)
    assert run.engine.end is None, "the environment's grace starts when it is gone, not with the phase"
    run.wait(5.0)
    assert run.engine.end is not None and run.engine.end.reason is EndReason.ABORTED


def test_by_default_the_game_waits_for_its_entities_ten_minutes_then_ends_naming_who_never_came() -> None:
    from coordinator.node import build_parser, game_config
    from coordinator.stages import Stage

    config = game_config(build_parser().parse_args(["--seed", "7"]))
    assert config.admit_deadline == 600.0, "no wait without a deadline, unless asked (--admit-deadline 0)"
    assert game_config(build_parser().parse_args(["--admit-deadline", "0"])).admit_deadline is None
    engine = Engine(config, LOG)
    assert engine.stage is Stage.ADMITTING and engine.deadline() == 600.0
    effects = engine.expire(Stage.ADMITTING, engine.turn)
    (over,) = [e.msg for e in effects if isinstance(getattr(e, "msg", None), Over)]
    assert over.reason is EndReason.ABORTED and "never connected: D01, ENV, GCS" in over.text


def test_a_missed_deadline_asks_who_is_connected_and_a_drone_whose_token_is_a_copy_is_lost_at_once() -> None:
    """On a plain router anyone may declare a copy of D02's exact presence key: when D02 dies, its token
    stays. Its missed deadline makes the coordinator ask the routers which sessions they connect."""
    run = Run(drones=2, phase_deadline=1.0, lost_after=3)
    run.play(1, {"D01": (1, 0, 0)})  # D02 says nothing: dead, its token held by a copy
    run.wait(1.0)
    assert len(run.audits) == 1 and run.engine.drones["D02"].state.value == "ALIVE", "hovering: missed once"
    listed = frozenset({ME, "e0", "g0", "d1", "r0"})  # the router lists every session but D02's
    run.srv.handle(Sessions(listed))
    assert run.engine.drones["D02"].state.value == "LOST" and run.engine.drones["D01"].state.value == "ALIVE"
    run.play(2, {"D01": (2, 0, 0)})
    assert run.engine.turn == 3, "the game goes on without waiting for D02"


@pytest.mark.parametrize("listed", [None, frozenset({"e0", "g0", "d1"})], ids=["incomplete", "without-me"])
def test_a_listing_that_may_be_incomplete_changes_nothing(listed) -> None:
    run = Run(drones=2, phase_deadline=1.0)
    run.play(1, {"D01": (1, 0, 0)})
    run.wait(1.0)
    run.srv.handle(Sessions(listed))
    assert run.engine.drones["D02"].state.value == "ALIVE", "only its deadlines (--lost-after) can tell"


def test_the_listing_of_the_routers_is_complete_only_without_peers_and_unanswered_routers() -> None:
    def router(zid: str, *sessions: tuple[str, str]) -> dict:
        return {"zid": zid, "sessions": [{"peer": p, "whatami": w} for p, w in sessions]}

    assert sessions_listed([router("r0", ("a", "client"), ("b", "client"))]) == {"r0", "a", "b"}
    assert sessions_listed([router("r0", ("a", "client"), ("r1", "router")),
                            router("r1", ("b", "client"), ("r0", "router"))]) == {"r0", "r1", "a", "b"}
    assert sessions_listed([router("r0", ("a", "client"), ("r1", "router"))]) is None, "r1 did not answer"
    assert sessions_listed([router("r0", ("p", "peer"))]) is None, "a peer may carry others"
    assert sessions_listed([]) is None, "nobody answered (no admin space, a link down)"


def test_a_vanished_presence_asks_who_is_connected_and_counts_at_once_when_its_session_is_gone() -> None:
    """A killed drone: its token vanishes with its session. The routers, asked at once, no longer list
    the session, so it is lost before SETTLE_S (which waits in case the coordinator's own link is down)."""
    run = Run(drones=2, phase_deadline=1.0)
    run.leave("D02")
    assert run.audits == [run.clock.now] and run.engine.drones["D02"].state.value == "ALIVE"
    run.leave("D01")  # asked while the first audit is under way: asked again after its answer
    assert len(run.audits) == 1
    run.srv.handle(Sessions(frozenset({ME, "e0", "g0", "d1", "r0"})))  # listed before D01 went
    assert run.engine.drones["D02"].state.value == "LOST" and run.engine.drones["D01"].state.value == "ALIVE"
    assert len(run.audits) == 2
    run.srv.handle(Sessions(frozenset({ME, "e0", "g0", "r0"})))
    assert run.engine.drones["D01"].state.value == "LOST"


def test_a_vanished_presence_whose_session_is_still_listed_waits_its_settle_time() -> None:
    """The listing may lag the token (or the routers cannot be asked): then SETTLE_S decides, as before."""
    for listed in (frozenset({ME, "e0", "g0", "d1", "d2", "r0"}), None):
        run = Run(drones=2, phase_deadline=1.0)
        run.leave("D02")
        run.srv.handle(Sessions(listed))
        assert run.engine.drones["D02"].state.value == "ALIVE"
        run.wait(SETTLE_S)
        assert run.engine.drones["D02"].state.value == "LOST"


def test_a_presence_that_was_never_admitted_asks_nothing() -> None:
    run = Run(drones=2, phase_deadline=1.0)
    run.srv.handle(Presence("D02", "other", False))  # not D02's admitted session
    run.srv.handle(Presence("D07", "d7", False))
    assert not run.audits


def test_default_starts_fill_the_world_row_after_row_and_refuse_what_does_not_fit(capsys) -> None:
    """Every other cell along y from (0,0,0) (the seed's row, unchanged while it fits), then the next row
    (x + 2), then the next layer (z + 2), skipping blocked cells; more drones than fit are refused, and
    `dronesim up` refuses them before it starts any process."""
    from dronesim.up import cli as up

    def cells(count, size, blocked=None):
        return [d.start for d in parse_starts("", count, size, blocked)]

    assert cells(3, (10, 10, 10)) == [(0, 0, 0), (0, 2, 0), (0, 4, 0)]
    assert cells(3, (10, 10, 10)) == [d.start for d in parse_starts("", 3)]  # no size: one row
    assert cells(4, (3, 5, 1)) == [(0, 0, 0), (0, 2, 0), (0, 4, 0), (2, 0, 0)]
    assert cells(5, (3, 3, 3)) == [(0, 0, 0), (0, 2, 0), (2, 0, 0), (2, 2, 0), (0, 0, 2)]
    assert cells(2, (1, 5, 1), blocked=lambda c: c == (0, 2, 0)) == [(0, 0, 0), (0, 4, 0)]
    with pytest.raises(UsageError, match="30 drones do not fit in a 4x4x1 world"):
        parse_starts("", 30, (4, 4, 1))
    assert [d.start for d in parse_starts("1,1,1;2,2,2", 2, (4, 4, 1))] == [(1, 1, 1), (2, 2, 2)]
    assert up(["--size", "4,4,1", "--drones", "30", "--quiet"]) == 2
    assert "30 drones do not fit" in capsys.readouterr().err


@pytest.mark.parametrize(("flags", "why"), [
    (["--starts", "x,y,z"], "--starts needs 1 cells"), (["--starts", "1,2,3;4,5", "--drones", "2"], "--starts needs 2"),
    (["--drones", "-3"], "at least one drone"), (["--drones", "0"], "at least one drone"),
])
def test_a_bad_game_flag_is_a_usage_error_before_anything_starts(flags, why) -> None:
    """(`--starts x,y,z` and `--drones -3` crashed with a ValueError; a negative deadline started a game.)"""
    from coordinator.node import build_parser, game_config

    with pytest.raises(UsageError, match=why):
        game_config(build_parser().parse_args(flags))


@pytest.mark.parametrize("flags", [["--phase-deadline", "-1"], ["--phase-deadline", "nan"], ["--gcs-deadline", "-2"],
                                   ["--admit-deadline", "-5"], ["--link-grace", "-1"], ["--gcs-grace", "-1"],
                                   ["--admit-deadline", "inf"], ["--pace", "1e300"]])
def test_a_bad_wait_flag_is_refused_by_its_parser(flags, capsys) -> None:
    """A wait is seconds in 0..a day (`schema.errors.seconds`); beyond, the coordinator crashed mid-game."""
    from coordinator.node import build_parser

    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(flags)
    assert exit_.value.code == 2 and f"argument {flags[0]}: " in capsys.readouterr().err


def test_a_zero_deadline_is_a_usage_error() -> None:
    from coordinator.node import build_parser, game_config

    with pytest.raises(UsageError, match="deadlines must be positive"):
        game_config(build_parser().parse_args(["--phase-deadline", "0"]))


def routed(run: Run) -> Run:
    """The coordinator's first question (`probe`, at start) answered: a router answers audits."""
    run.srv.probe()
    run.srv.handle(Sessions(frozenset({ME, *SESSIONS.values(), "r0"})))
    return run


def test_a_deadline_that_passes_while_no_router_answers_does_not_count_and_the_game_goes_on() -> None:
    """A frozen router (SIGSTOP, a stalled VM or link) shorter than the leases: no token vanishes, nothing
    arrives, the deadline passes. The coordinator asks the routers first: none answers, so nobody can be reached
    and nobody is to blame; the game holds, asking again, until one answers, then goes on as if nothing
    happened: the phase again, its deadline anew, nobody hovered (issue 33, 5)."""
    run = routed(Run(drones=2, phase_deadline=1.0))
    run.play(1, {"D01": (1, 0, 0)})  # D02's move is held up by the frozen router
    asked = len(run.audits)
    run.wait(1.0)
    assert len(run.audits) == asked + 1 and run.engine.turn == 1, "asked the routers before counting it"
    assert run.engine.drones["D02"].misses == 0
    run.srv.handle(Sessions(None, answered=False))  # no router answered in time
    assert run.engine.holding and len(run.audits) == asked + 2, "the game holds, asking again"
    run.wait(10.0)
    run.srv.handle(Sessions(None, answered=False))
    run.wait(10.0)
    assert run.engine.turn == 1 and run.engine.drones["D02"].misses == 0 and len(run.journal.records) == 1
    sent = len(run.wire.sent)
    run.srv.handle(Sessions(frozenset({ME, *SESSIONS.values(), "r0"})))  # thawed: the router answers again
    again = run.wire.sent[sent:]
    assert not run.engine.holding
    assert [type(m) for m in again] == [Status, Turn] and again[1].phase is Phase.DRONES, "the phase again"
    run.wait(0.9)  # its deadline anew
    run.send(Nps(turn=1, sender="D02", pos=(1, 2, 0)))  # what the router held comes through
    assert run.engine.turn == 2 and "hovered" not in run.journal.records[-1]
    assert run.srv.timeout() is None, "nothing left waiting"


def test_a_deadline_counts_once_a_router_answers() -> None:
    run = routed(Run(drones=2, phase_deadline=1.0))
    run.play(1, {"D01": (1, 0, 0)})  # D02 is hung: the router answers, D02 does not
    run.wait(1.0)
    assert run.engine.turn == 1 and run.srv.timeout() is None, "waiting for the routers' answer"
    run.srv.handle(Sessions(frozenset({ME, *SESSIONS.values(), "r0"})))
    assert run.engine.turn == 2 and run.journal.records[-1]["hovered"] == ["D02"]


def test_an_answer_to_a_question_asked_before_the_deadline_passed_decides_nothing() -> None:
    run = routed(Run(drones=2, phase_deadline=1.0))
    run.play(1, {"D01": (1, 0, 0)})
    run.srv.handle(Presence("D01", "other", False))  # (no audit: not D01's session)
    run.leave("D02")  # an audit under way...
    run.srv.handle(Presence("D02", SESSIONS["D02"], True))  # (D02 was back at once)
    run.wait(1.0)  # ... when the deadline passes: asked again after its answer
    run.srv.handle(Sessions(frozenset({ME, *SESSIONS.values(), "r0"})))  # the earlier question's answer
    assert run.engine.turn == 1 and run.engine.drones["D02"].misses == 0
    run.srv.handle(Sessions(None, answered=False))  # the awaited answer: none (the router froze meanwhile)
    assert run.engine.holding and run.engine.drones["D02"].misses == 0


def test_a_router_frozen_past_the_leases_becomes_a_lost_link_whose_grace_counts_from_then() -> None:
    run = routed(Run(drones=2, phase_deadline=1.0, link_grace=5.0))
    run.play(1, {"D01": (1, 0, 0)})
    run.wait(1.0)
    run.srv.handle(Sessions(None, answered=False))
    run.wait(4.0)
    run.srv.handle(Presence("SRV", ME, False))  # the leases ran out: every link goes, every token vanishes
    run.leave("ENV", "GCS", "D01", "D02")
    run.wait(4.0)  # 8 s since the hold began, 4 since the link went: within the grace
    for e in ("SRV", "ENV", "GCS", "D01", "D02"):
        run.srv.handle(Presence(e, ME if e == "SRV" else SESSIONS[e], True))
    assert not run.engine.holding and all(d.state.value == "ALIVE" for d in run.engine.drones.values())
    run.send(Nps(turn=1, sender="D02", pos=(1, 2, 0)))
    assert run.engine.turn == 2 and "hovered" not in run.journal.records[-1]


def test_an_entity_whose_token_flickers_while_the_game_holds_is_away_again_not_lost() -> None:
    """A router continued after a freeze past the leases: a drone's token comes back from its old link, then
    vanishes as the router drops that link (its session connected to no router), then comes back on the new one
    (seen in a full run: the drone was LOST, its reconnection refused). While the game holds, it is away again."""
    run = routed(Run(drones=2, phase_deadline=1.0, link_grace=5.0))
    run.play(1, {"D01": (1, 0, 0)})
    run.srv.handle(Presence("SRV", ME, False))  # every link goes, every token vanishes
    run.leave("ENV", "GCS", "D01", "D02")
    run.srv.handle(Presence("SRV", ME, True))
    run.srv.handle(Presence("D01", SESSIONS["D01"], True))  # back from its old link...
    run.srv.handle(Presence("D01", SESSIONS["D01"], False))  # ... which the router then drops
    run.srv.handle(Sessions(frozenset({ME, "r0"})))  # (the audit: D01's session connected to no router)
    assert run.engine.holding and run.engine.drones["D01"].state.value == "ALIVE"
    for e in ("ENV", "GCS", "D01", "D02"):
        run.srv.handle(Presence(e, SESSIONS[e], True))
    assert not run.engine.holding and all(d.state.value == "ALIVE" for d in run.engine.drones.values())
    run.send(Nps(turn=1, sender="D02", pos=(1, 2, 0)))
    assert run.engine.turn == 2 and "hovered" not in run.journal.records[-1]

def test_without_a_router_that_answers_a_deadline_counts_as_it_passes() -> None:
    """No router (peers), or one whose admin space is closed: nothing tells a frozen router, as before."""
    run = Run(drones=2, phase_deadline=1.0)
    run.srv.probe()
    run.srv.handle(Sessions(None, answered=False))
    run.play(1, {"D01": (1, 0, 0)})
    run.wait(1.0)
    assert run.engine.turn == 2 and run.journal.records[-1]["hovered"] == ["D02"]


def _deciding(run: Run, drone: str = "D01") -> None:
    """`drone`'s process says it is still deciding the current turn (an empty MOVES)."""
    run.send(Moves(turn=run.engine.turn, sender=drone, moves=()))


def test_a_host_that_says_it_is_still_deciding_keeps_its_phase_open_up_to_the_cap() -> None:
    """Issue 33, 8: a swarm host whose planning outlasted the phase deadline had its drones hover, then LOST, alive
    and working as it was. Its words keep the phase open, each for the deadline (at least DECIDING_SILENCE_S)."""
    run = Run(drones=1, phase_deadline=1.0, phase_cap=10.0)
    run.send(Done(turn=1, sender="GCS", phase=Phase.GCS))
    for _ in range(19):
        run.wait(0.5)
        _deciding(run)
    assert (run.engine.turn, run.engine.drones["D01"].misses) == (1, 0), "9.5 s: deciding, and waited for"
    run.wait(0.5)
    _deciding(run)
    assert run.engine.turn == 2 and run.engine.drones["D01"].misses == 1, "the cap: the phase ends all the same"


def test_a_host_that_falls_silent_after_saying_it_is_deciding_misses_the_phase_once_its_silence_has_lasted() -> None:
    run = Run(drones=2, phase_deadline=0.2)
    run.send(Done(turn=1, sender="GCS", phase=Phase.GCS))
    run.send(Nps(turn=1, sender="D02", pos=(1, 2, 0)))
    run.wait(0.1)
    _deciding(run)
    run.wait(DECIDING_SILENCE_S - 0.01)
    assert run.engine.turn == 1, "one word late or lost does not end the phase"
    run.wait(0.01)
    assert run.engine.turn == 2 and run.engine.drones["D01"].misses == 1 and not run.engine.drones["D02"].misses


def test_a_hung_host_says_nothing_and_misses_the_phase_at_its_deadline() -> None:
    run = Run(drones=1, phase_deadline=0.2)
    run.send(Done(turn=1, sender="GCS", phase=Phase.GCS))
    run.wait(0.19)
    assert run.engine.turn == 1
    run.wait(0.01)
    assert run.engine.turn == 2 and run.engine.drones["D01"].misses == 1


def test_a_word_that_comes_while_the_routers_are_asked_about_a_passed_deadline_keeps_the_phase_open() -> None:
    run = Run(drones=1, phase_deadline=0.5)
    run.srv.handle(Sessions(frozenset({ME, "e0", "g0", "d1"})))  # the routers answer: a deadline waits for them
    run.send(Done(turn=1, sender="GCS", phase=Phase.GCS))
    run.wait(0.5)
    asked = len(run.audits)
    assert asked and run.engine.turn == 1, "the deadline passed: the routers are asked first"
    _deciding(run)
    run.srv.handle(Sessions(frozenset({ME, "e0", "g0", "d1"})))
    assert run.engine.turn == 1 and run.engine.drones["D01"].misses == 0, "it spoke meanwhile: not passed"
    run.wait(DECIDING_SILENCE_S)
    run.srv.handle(Sessions(frozenset({ME, "e0", "g0", "d1"})))
    assert run.engine.turn == 2 and run.engine.drones["D01"].misses == 1
