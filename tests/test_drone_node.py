"""The drone process's Zenoh adapter: how the outcome of its queries comes back to the core, over a router."""

from __future__ import annotations

import functools
import logging
import threading
import types

import numpy as np
import pytest
import zenoh

from entities.drone import Answer
from entities.drone_node import Deciding, Effects, thread_cpu
from entities.environment import Environment
from network.transport import Inbox, client_config
from schema import Ans, Ask, Keys, Moves, RemoteInputError, Step, decode, encode
from schema.tuning import DECIDING_SILENCE_S, MOVES_REPEAT_S, PUT_GAP
from world.grid import World

from .harness import embedded_router, unique_root


def test_a_query_comes_back_as_one_answer_event_whatever_its_outcome() -> None:
    """Answered, refused, malformed, or nobody there: each query is one `Answer` event in the inbox, with
    the decoded reply, the refusal as a RemoteInputError, or nothing (zenoh's own timeout is no reply)."""
    keys = Keys(unique_root())
    env = Environment(World.generate((5, 5, 3), np.random.default_rng(4)), {})
    mode = {"how": "answer"}

    def serve(query: zenoh.Query) -> None:
        ask = decode(query.payload.to_bytes(), Ask)
        match mode["how"]:
            case "answer":
                kinds, drones = env.survey(ask.cells, ask.around)
                query.reply(query.key_expr, encode(Ans(turn=ask.turn, sender="ENV", kinds=kinds, drones=drones)))
            case "refuse":
                query.reply_err(b"not now")
            case "garble":
                query.reply(query.key_expr, b"\x00garbage")
            case "hang":
                return  # no reply: the asker's timeout ends the query
        query.drop()

    ask = Ask(turn=1, sender="D01", cells=((0, 0, 0), (9, 9, 9)))
    with embedded_router() as locator, zenoh.open(client_config(locator)) as served, \
            zenoh.open(client_config(locator)) as session:
        inbox = Inbox(session, keys, logging.getLogger("test"))

        def outcome(ref: int, timeout: float = 5.0) -> Answer:
            inbox.query(keys.ask, ask, Ans, timeout=timeout, then=functools.partial(Answer, ref))
            event = inbox.get(timeout + 5.0)
            assert isinstance(event, Answer) and event.ref == ref
            return event

        assert outcome(1).replies == ()  # nobody serves ENV/ASK yet
        querier = session.declare_querier(keys.ask)  # (only to see the queryable reach this session)
        matched = querier.declare_matching_listener()
        queryable = served.declare_queryable(keys.ask, serve, complete=True)
        try:
            while not matched.recv().matching:
                pass
            (ans,) = outcome(2).replies
            assert isinstance(ans, Ans) and len(ans.kinds) == 2
            mode["how"] = "refuse"
            (err,) = outcome(3).replies
            assert isinstance(err, RemoteInputError) and "not now" in str(err)
            mode["how"] = "garble"
            (err,) = outcome(4).replies
            assert isinstance(err, RemoteInputError)
            mode["how"] = "hang"
            assert outcome(5, timeout=0.3).replies == ()
        finally:
            queryable.undeclare()
            querier.undeclare()


@pytest.mark.parametrize("ids", ["foo", "D01-Dx", "0", "99999", "3-1", "D01,D01"])
def test_a_bad_drone_list_is_refused_with_exit_2_and_why(ids: str, capsys) -> None:
    from entities.drone_node import cli

    assert cli(["--id", ids, "--host", "H01"]) == 2
    assert "bad drone list" in capsys.readouterr().err


@pytest.mark.parametrize(("flags", "why"), [
    (["--id", "D01", "--host", "X1"], "is not a host id"), (["--id", "D01", "--connect", "foo"], "bad zenoh setting"),
    (["--id", "D01", "--listen", "nonsense"], "bad zenoh setting"),
])
def test_a_bad_host_or_endpoint_is_refused_with_exit_2_and_why(flags: list[str], why: str, capsys) -> None:
    """(Both crashed with a traceback: a MalformedMessage for the host, a zenoh.ZError for the endpoint.)"""
    from entities.drone_node import cli

    assert cli(flags) == 2
    assert why in capsys.readouterr().err


def test_the_router_refuses_an_endpoint_that_is_not_one_with_exit_2(capsys) -> None:
    from dronesim.router import cli

    assert cli(["--listen", "foo"]) == 2
    assert "bad zenoh setting listen/endpoints" in capsys.readouterr().err


class _Core:
    """What `Deciding` reads of the core: the turn being decided (None: none)."""

    sender = "H01"

    def __init__(self) -> None:
        self.turn: int | None = None

    def deciding(self) -> int | None:
        return self.turn


def test_a_host_says_it_is_still_deciding_only_while_its_main_thread_computes_the_same_turn() -> None:
    """Issue 33, 8: a host whose planning outlasts the phase deadline says so (an empty MOVES) at each look while its
    main thread computes (its CPU time goes on); a hung one (no CPU), or one that is not deciding, says nothing."""
    core, cpu = _Core(), [0.0]
    pulse = Deciding(core, lambda *a, **k: None, lambda: cpu[0], every=0.05)  # type: ignore[arg-type]
    assert pulse.look() is None, "not deciding"
    core.turn = 3
    cpu[0] += 0.05
    assert pulse.look() is None, "a turn first seen: its planning may end at once (most turns take a millisecond)"
    cpu[0] += 0.04
    word = pulse.look()
    assert word is not None and (word.turn, word.sender, len(word.moves)) == (3, "H01", 0)
    assert pulse.look() is None, "no CPU since the last look: hung (or waiting), it says nothing"
    cpu[0] += 0.05
    core.turn = 4
    assert pulse.look() is None, "another turn: first seen"
    cpu[0] += 0.05
    assert pulse.look() is not None
    core.turn = None
    cpu[0] += 0.05
    assert pulse.look() is None, "decided"


def test_a_hosts_word_that_it_is_deciding_does_not_follow_the_moves_of_its_turn() -> None:
    """The word is sent from its own thread: once the turn's moves went out (the core no longer decides it), a word
    for it is not sent (it would reach the coordinator after them)."""
    keys = Keys("sim")
    out = types.SimpleNamespace(sent=[])
    out.put = lambda key, msg: out.sent.append((key, msg))
    effects = Effects(types.SimpleNamespace(keys=keys), out, ask_timeout=1.0, map_timeout=1.0)  # type: ignore[arg-type]
    core = _Core()
    pulse = Deciding(core, effects.send, lambda: 0.0)
    word = Moves(turn=5, sender="H01", moves=())
    core.turn = 5
    pulse.send(word, unless=functools.partial(pulse._decided, 5))
    core.turn = None  # its moves went out
    pulse.send(word, unless=functools.partial(pulse._decided, 5))
    assert out.sent == [(keys.moves("H01"), word)]


def test_a_hosts_moves_go_out_a_put_gap_after_its_word_so_that_the_routers_budget_keeps_them() -> None:
    """The router keeps at most PUT_RATE puts a second from one session on a MOVES key (issue 18's budget): a host's
    MOVES sent right after its word that it is still deciding would be dropped, and its drones would hover."""
    keys, now, slept = Keys("sim"), [10.0], []
    out = types.SimpleNamespace(sent=[])
    out.put = lambda key, msg: out.sent.append((now[0], msg.turn))
    effects = Effects(types.SimpleNamespace(keys=keys), out, ask_timeout=1.0, map_timeout=1.0,  # type: ignore[arg-type]
                      clock=lambda: now[0], sleep=lambda s: (slept.append(s), now.__setitem__(0, now[0] + s)))
    effects.send(Moves(turn=3, sender="H01", moves=()))
    now[0] += PUT_GAP / 5
    effects.send(Moves(turn=3, sender="H01", moves=()))
    assert slept == [pytest.approx(PUT_GAP * 4 / 5)] and out.sent[1][0] - out.sent[0][0] == pytest.approx(PUT_GAP)
    now[0] += 1.0
    effects.send(Moves(turn=4, sender="H01", moves=()))
    assert len(slept) == 1, "a put long after the last waits for nothing"


def test_a_hosts_moves_after_its_word_go_out_again_while_the_coordinator_may_wait_for_them() -> None:
    """On a loaded machine a host's word that it is still deciding and its MOVES reached the router in one batch,
    and its budget dropped the MOVES: a MOVES that followed a word of its turn goes out again MOVES_REPEAT_S later,
    then twice as long each time, up to DECIDING_SILENCE_S after it; one without a word before it, never."""
    keys, now = Keys("sim"), [10.0]
    out = types.SimpleNamespace(sent=[])
    out.put = lambda key, msg: out.sent.append((round(now[0] - 10.0, 6), msg.turn, len(msg.moves)))
    effects = Effects(types.SimpleNamespace(keys=keys), out, ask_timeout=1.0, map_timeout=1.0,  # type: ignore[arg-type]
                      clock=lambda: now[0], sleep=lambda s: now.__setitem__(0, now[0] + s))
    moves = Moves(turn=3, sender="H01", moves=(Step(drone="D01", pos=(1, 0, 0)),))
    effects.send(Moves(turn=3, sender="H01", moves=()))
    now[0] += 0.01
    effects.send(moves)
    while now[0] < 12.0:
        effects.repeat()
        now[0] += 0.001
    at = [t for t, *_ in out.sent[2:]]
    assert out.sent[1:] == [(0.01, 3, 1)] + [(t, 3, 1) for t in at], "its MOVES, again"
    assert at == pytest.approx([0.01 + MOVES_REPEAT_S * k for k in (2 ** i for i in range(10))
                                if MOVES_REPEAT_S * k <= DECIDING_SILENCE_S], abs=0.0011)
    del out.sent[:]
    effects.send(Moves(turn=4, sender="H01", moves=(Step(drone="D01", pos=(2, 0, 0)),)))  # (no word for turn 4)
    effects.send(Moves(turn=5, sender="H01", moves=()))
    effects.send(Moves(turn=4, sender="H01", moves=(Step(drone="D01", pos=(2, 0, 0)),)))  # (a word, of turn 5)
    now[0] += 2.0
    effects.repeat()
    assert [turn for _, turn, _ in out.sent] == [4, 5, 4], "none again"
    del out.sent[:]
    effects.send(Moves(turn=6, sender="H01", moves=()))
    effects.send(Moves(turn=6, sender="H01", moves=(Step(drone="D01", pos=(3, 0, 0)),)))
    now[0] += 1.0
    effects.repeat(7)  # (the host decides turn 7: turn 6 is over for the coordinator)
    now[0] += 1.0
    effects.repeat(None)
    assert [turn for _, turn, _ in out.sent] == [6, 6], "not once a later turn is decided"


def test_the_main_threads_cpu_clock_is_read_from_another_thread() -> None:
    clock, seen = thread_cpu(), []
    reader = threading.Thread(target=lambda: seen.append(clock()))
    start = clock()
    while clock() - start < 0.02:  # this thread computes
        pass
    reader.start()
    reader.join()
    assert seen[0] >= start + 0.02
