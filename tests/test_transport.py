"""Inbox over a real router: the threading model of network/transport.py. Zenoh's callbacks only
enqueue; `run` hands every event to its handler on the calling thread, one at a time, in order of
arrival; a deadline the handler sets is kept; a handler's failure is raised by `run` at once; events
arriving after the end stay queued for `get`. And floods: stale, oversized and over-budget messages are
refused before they are queued, and the origins take turns (FairQueue)."""

from __future__ import annotations

import json
import logging
import threading
import time
from typing import Any

import pytest
import zenoh

from network.transport import FairQueue, Inbox, Outbox, Received, _direct, _stamp, _turn, router_config, router_locators
from schema import Ask, Connect, EndReason, Keys, Over, RemoteInputError, Role, Status, StatusTable, Target, encode
from schema.acl import flood_filters
from schema.keys import size_limit
from schema.messages import Message
from schema.samples import SAMPLES
from schema.tables import MAX_DRONE, drone_name
from schema.tuning import TGT_BUDGETED, TGT_RATE
from tests.harness import client_config, embedded_router, unique_root

pytestmark = pytest.mark.integration
LOG = logging.getLogger("test-transport")


def subscribed(out: Outbox, inbox: Inbox, *keys: str) -> None:
    """Until the subscriptions to every key in `keys` have reached `out`'s session (each publisher's matching
    status), taking `inbox`'s events meanwhile."""
    pubs = [out.session.declare_publisher(key) for key in keys]
    while not all(pub.matching_status.matching for pub in pubs):
        inbox.get(0.01)
    for pub in pubs:
        pub.undeclare()


@pytest.fixture
def pair():
    """(inbox of a listening session, outbox of another session, keys)."""
    keys = Keys(unique_root())
    with embedded_router() as locator, zenoh.open(client_config(locator)) as a, \
            zenoh.open(client_config(locator)) as b:
        inbox = Inbox(a, keys, LOG)
        inbox.subscribe(keys.over, Over)
        out = Outbox(b)
        subscribed(out, inbox, keys.over)
        yield inbox, out, keys


def within(seconds: float):
    """A `timeout` for `Inbox.run`: a fixed deadline `seconds` from now."""
    end = time.monotonic() + seconds
    return lambda: max(0.0, end - time.monotonic())


def over(turn: int) -> Over:
    return Over(turn=turn, sender="SRV", reason=EndReason.TURN_LIMIT, text=f"#{turn}")


def test_run_handles_every_event_on_its_own_thread_one_at_a_time_in_order(pair) -> None:
    inbox, out, keys = pair
    n = 400
    seen: list[int] = []
    threads: set[str] = set()
    active = [0]
    overlap = []

    def handle(event) -> None:
        active[0] += 1
        overlap.append(active[0])
        assert isinstance(event, Received)
        seen.append(event.msg.turn)
        threads.add(threading.current_thread().name)
        if event.msg.turn % 7 == 0:  # slow now and then: later events queue up behind it
            sum(range(20000))
        active[0] -= 1

    def send() -> None:
        for t in range(n):
            out.put(keys.over, over(t))

    sender = threading.Thread(target=send)
    sender.start()
    inbox.run(handle, timeout=within(30), until=lambda: len(seen) == n)
    sender.join()
    assert seen == list(range(n)), "every event, in order of arrival"
    assert max(overlap) == 1, "never two at once"
    assert threads == {threading.current_thread().name}, "every event on the thread that runs the inbox"


def test_a_deadline_the_handler_sets_brings_a_none_when_due(pair) -> None:
    """`run` waits without a deadline; handling an event sets one: the handler gets its None when it is
    due (not never, not before)."""
    inbox, out, keys = pair
    due: list[float] = []
    timed_out: list[float] = []

    def timeout() -> float | None:
        return None if not due else max(0.0, due[0] - time.monotonic())

    def handle(event) -> None:
        if event is None:
            timed_out.append(time.monotonic())
        else:
            due.append(time.monotonic() + 0.05)

    out.put(keys.over, over(1))
    inbox.run(handle, timeout=timeout, until=lambda: bool(timed_out))
    assert len(due) == 1 and timed_out[0] >= due[0]


def test_a_handler_failing_fails_run_and_the_events_behind_it_stay_queued(pair) -> None:
    inbox, out, keys = pair

    class Boom(Exception):
        pass

    def handle(event) -> None:
        raise Boom(event)

    for t in range(2):
        out.put(keys.over, over(t))
    with pytest.raises(Boom):
        inbox.run(handle, timeout=within(30), until=lambda: False)
    assert inbox.get(10).msg.turn == 1


def test_events_after_the_end_stay_queued_for_get(pair) -> None:
    inbox, out, keys = pair
    seen: list[int] = []
    for t in range(3):
        out.put(keys.over, over(t))
    inbox.run(lambda e: seen.append(e.msg.turn), timeout=within(30), until=lambda: len(seen) == 1)
    rest = [inbox.get(10), inbox.get(10)]
    assert seen == [0] and [e.msg.turn for e in rest] == [1, 2]


def test_get_with_a_deadline_already_past_returns_at_once(pair) -> None:
    inbox, _, _ = pair
    assert inbox.get(-1.0) is None


# --------------------------------------------------------------------------- floods (issue 18)


def test_a_wait_with_a_time_limit_ends_whatever_came_before() -> None:
    """`take(timeout)` returns, within its time limit or a watchdog's period after it (`_Overdue`), after any mix of
    events put before, during (from another thread) and after waits, wakes and tiny limits. `SimpleQueue.get(timeout=
    ...)` alone can wait forever in CPython 3.11 (without the watchdog this mix, seed 1, hung within seconds;
    `dronesim bench perf`'s ground station once hung so)."""
    import random

    rng, done = random.Random(1), threading.Event()

    def mix() -> None:
        for _ in range(1500):
            q = FairQueue()
            for _ in range(8):
                step = rng.choice(["put", "take", "wait", "during", "wake"])
                if step == "put":
                    q.put("a", 1)
                elif step == "wake":
                    q.wake()
                elif step == "during":
                    t = threading.Timer(0.0002, q.put, ("b", 1))
                    t.start()
                    q.take(0.01)
                    t.join()
                elif step == "take":
                    q.take(0)
                else:
                    q.take(rng.choice([1e-7, 1e-6, 1e-5, 1e-3]))
        done.set()

    threading.Thread(target=mix, daemon=True).start()
    assert done.wait(120), "a take with a time limit waited forever"
    q = FairQueue()
    started = time.monotonic()
    assert q.take(0.05) == (False, None) and 0.04 < time.monotonic() - started < 5
    q.put("a", "x")
    assert q.take(0.05) == (True, "x") and q.take(0) == (False, None)


def test_a_queues_watcher_ends_with_the_queue_or_its_close() -> None:
    """The watchdog is the queue's own (no process-wide state): it ends when its queue is closed or gone, and a
    closed queue's next wait with a time limit has a new one."""
    import gc

    q = FairQueue()
    q.take(0.001)
    first = q._watcher
    assert first is not None and first.thread.is_alive()
    q.close()
    first.thread.join(5)
    assert not first.thread.is_alive() and q._watcher is None
    q.take(0.001)
    second = q._watcher
    assert second is not None and second is not first
    del q, first
    gc.collect()
    second.thread.join(5)
    assert not second.thread.is_alive()


def test_below_its_share_an_origin_keeps_the_order_of_arrival() -> None:
    q = FairQueue(budget=100, share=3)
    for event in [("GCS", 19), ("D01", 18), ("GCS", 20), ("GCS", 21), ("SRV", 1)]:
        q.put(event[0], event)
    assert q.drain() == [("GCS", 19), ("D01", 18), ("GCS", 20), ("GCS", 21), ("SRV", 1)]


def test_beyond_its_share_a_bursting_origin_waits_its_turn() -> None:
    q = FairQueue(budget=100, share=2)
    for n in range(6):
        q.put("D01", ("D01", n))
    q.put("D02", ("D02", 0))
    q.put("D02", ("D02", 1))
    # D02's events came after six of D01's: they wait behind two of them (the share), not six
    assert q.drain() == [("D01", 0), ("D01", 1), ("D02", 0), ("D02", 1), ("D01", 2), ("D01", 3), ("D01", 4),
                         ("D01", 5)]


def test_the_origins_take_turns_each_in_order_of_arrival() -> None:
    q = FairQueue(budget=100, share=1)
    for n in range(4):
        q.put("D01", ("D01", n))
    q.put("D02", ("D02", 0))
    q.put("SRV", ("SRV", 0))
    q.put("D02", ("D02", 1))
    assert [q.take(0)[1] for _ in range(3)] == [("D01", 0), ("D02", 0), ("SRV", 0)]
    assert q.drain() == [("D01", 1), ("D02", 1), ("D01", 2), ("D01", 3)]
    assert q.take(0) == (False, None)


def test_an_origin_over_its_budget_is_refused_and_the_others_are_not() -> None:
    q = FairQueue(budget=3, share=1)
    for n in range(3):
        q.put("D01", n)
    assert q.full("D01") and not q.full("D02")
    with pytest.raises(RemoteInputError, match="3 events from D01 are already waiting") as err:
        q.put("D01", 3)
    assert err.value.reason == "flood"
    q.put("D02", "d")
    q.put("D01", "mine", budgeted=False)  # this process's own events are never refused
    assert q.drain() == [0, "d", 1, 2, "mine"]


def test_an_origin_over_its_bytes_is_refused_and_its_first_event_never_is() -> None:
    q = FairQueue(budget=100, budget_bytes=1000, share=1)
    q.put("D01", "huge", 5000)  # alone: its key's size limit bounds it
    with pytest.raises(RemoteInputError, match="5000 bytes from D01 are already waiting"):
        q.put("D01", "more", 1)
    q.put("D02", "small", 10)
    assert q.take(0) == (True, "huge")
    q.put("D01", "next", 600)
    q.put("D01", "and next", 400)
    assert q.full("D01", 1) == "1000 bytes from D01 are already waiting"
    assert q.drain() == ["small", "next", "and next"] and q.full("D01", 5000) is None


#: A drone whose TGT key a plain router has no budget on (`schema.tuning.TGT_BUDGETED`): several TGTs on it, sent
#: together, all reach the inbox, whose own checks a test looks at.
UNBUDGETED = drone_name(TGT_BUDGETED + 1)


def target(turn: int, drone: str = "D01") -> Target:
    return Target(turn=turn, sender="GCS", drone=drone, pos=(1, 2, 3))


def test_a_quiet_event_wakes_no_one_and_comes_before_what_wakes_the_consumer() -> None:
    """An event put `quiet` (a ground station's answer ahead) puts nothing in the line a waiting consumer is woken by;
    the consumer takes it first at its next take, before the event that woke it, whichever came first."""
    q, got = FairQueue(), []
    consumer = threading.Thread(target=lambda: got.extend([q.take(30), q.take(30), q.take(0)]), daemon=True)
    consumer.start()
    q.put("GCS", "ahead 9", quiet=True)
    assert q._line.qsize() == 0, "a quiet event must not wake the consumer"
    q.put("H01", "moves 1")  # wakes it
    consumer.join(10)
    assert got == [(True, "ahead 9"), (True, "moves 1"), (False, None)]
    q.put("H01", "moves 2")
    q.put("GCS", "ahead 10", quiet=True)
    assert q.take(0) == (True, "ahead 10") and q.take(0) == (True, "moves 2")


def test_quiet_events_beyond_their_bound_wake_the_consumer_and_keep_their_order() -> None:
    q = FairQueue(budget=100, quiet_most=2)
    for n in range(4):
        q.put("GCS", ("ahead", n), quiet=True)
    assert q._line.qsize() == 2, "the two beyond the bound are in the line"
    q.put("H01", "moves")
    assert q.drain() == [("ahead", 0), ("ahead", 1), ("ahead", 2), ("ahead", 3), "moves"]
    with pytest.raises(RemoteInputError, match="already waiting"):  # a quiet one is refused over its budget too
        FairQueue(budget=0).put("GCS", "x", quiet=True)


def test_a_message_for_a_later_turn_than_since_is_quiet_with_ahead_quiet(pair) -> None:
    """The coordinator's DONE subscription: an answer ahead (a turn after `since()`) is queued quiet, one for the
    turn now wakes the main thread; both are taken, the answer ahead first."""
    inbox, out, keys = pair
    inbox.subscribe(keys.tgt(UNBUDGETED), Target, since=lambda: 4, ahead_quiet=True)
    subscribed(out, inbox, keys.tgt(UNBUDGETED))
    out.put(keys.tgt(UNBUDGETED), target(6, UNBUDGETED))
    out.put(keys.tgt(UNBUDGETED), target(4, UNBUDGETED))
    first = inbox.get(10)
    assert first is not None and first.msg.turn == 6, "the quiet one, though it wakes no one, comes first"
    assert inbox.get(10).msg.turn == 4 and inbox.drain() == []


def test_a_message_for_a_turn_before_since_is_refused_before_it_is_queued(pair) -> None:
    inbox, out, keys = pair
    inbox.subscribe(keys.tgt(UNBUDGETED), Target, since=lambda: 4)
    subscribed(out, inbox, keys.tgt(UNBUDGETED))
    for turn in range(1, 7):
        out.put(keys.tgt(UNBUDGETED), target(turn, UNBUDGETED))
    got = [inbox.get(10).msg.turn for _ in range(3)]
    assert got == [4, 5, 6] and inbox.drain() == []
    assert inbox.rejects.snapshot() == {"stale-turn": 3}
    assert inbox.rejects.report() == "{'stale-turn': 3}, from {'GCS': 3}", "counted against the key's writer"


def test_an_origin_over_its_budget_in_the_inbox_is_refused_unread(pair) -> None:
    _, out, keys = pair
    inbox = Inbox(pair[0].session, keys, LOG, budget=2)
    inbox.subscribe(keys.tgt(UNBUDGETED), Target)
    inbox.subscribe(keys.over, Over)
    subscribed(out, inbox, keys.tgt(UNBUDGETED), keys.over)
    arrived = threading.Event()  # the OVER, seen by a plain subscriber after the inbox's callbacks ran
    barrier = inbox.session.declare_subscriber(keys.over, _direct(lambda sample: arrived.set()))
    for turn in range(1, 6):
        out.put(keys.tgt(UNBUDGETED), target(turn, UNBUDGETED))
    out.put(keys.over, over(9))  # after them on the same session: once it is here, so are they
    assert arrived.wait(10)
    events: list[Any] = inbox.drain()
    events += [] if len(events) == 3 else [inbox.get(10)]  # (the OVER's own callback may come just after)
    turns = [e.msg.turn for e in events]
    assert sorted(turns) == [1, 2, 9] and inbox.rejects.snapshot() == {"flood": 3}
    barrier.undeclare()
    inbox.close()


def test_events_posted_from_a_remote_input_are_budgeted_by_origin_and_size(pair) -> None:
    """`Inbox.post_from` (a ROS 2 goal heard on the station's own subscriber): beyond the origin's budget or above
    the size limit, refused unread and counted; another origin's events are not refused; `post` never is."""
    inbox = Inbox(pair[0].session, pair[2], LOG, budget=2)
    for k in range(4):
        inbox.post_from("goal/D01", "ros2/D01", ("D01", k), 80, 4096)
    inbox.post_from("goal/D02", "ros2/D02", ("D02", 0), 80, 4096)
    inbox.post_from("goal/D02", "ros2/D02", ("D02", 1), 5000, 4096)
    for k in range(3):
        inbox.post(("local", k))
    assert inbox.drain() == [("D01", 0), ("D01", 1), ("D02", 0), ("local", 0), ("local", 1), ("local", 2)]
    assert inbox.rejects.snapshot() == {"flood": 2, "too-large": 1}
    assert inbox.rejects.report() == "{'flood': 2, 'too-large': 1}, from {'ros2/D01': 2, 'ros2/D02': 1}"
    inbox.close()


@pytest.mark.parametrize("flooder", ["D01", "SRV"])
def test_asks_are_counted_against_their_sender_one_flooding_cannot_crowd_out_another(pair, flooder: str) -> None:
    """Also when the flooder names itself SRV: a query's sender is its payload's claim, and only a key proves the
    coordinator, whose published messages alone are never budgeted."""
    inbox, _, keys = pair
    inbox = Inbox(inbox.session, keys, LOG, budget=3, share=1)
    inbox.serve(keys.ask, Ask)
    asker = pair[1].session
    replies = {}

    def ask(sender: str, n: int) -> None:
        data = encode(Ask(turn=1, sender=sender, cells=((n, 0, 0),)))
        replies[(sender, n)] = asker.get(keys.ask, payload=data, timeout=10)

    arrived = threading.Event()  # a put after the queries, from the same session: they came before it
    barrier = inbox.session.declare_subscriber(keys.over, _direct(lambda sample: arrived.set()))
    querier = asker.declare_querier(keys.ask)  # (the fixture's OVER subscriber says nothing of the queryable)
    while not querier.matching_status.matching:  # the queryable has reached the asker's side
        arrived.wait(0.01)
    querier.undeclare()
    for n in range(8):
        ask(flooder, n)
    ask("D02", 0)
    asker.put(keys.over, encode(over(1)))
    assert arrived.wait(10)
    barrier.undeclare()
    asked: list[Any] = [inbox.get(10) for _ in range(4)]
    assert [(e.msg.sender, e.msg.cells[0][0]) for e in asked] == [(flooder, 0), ("D02", 0), (flooder, 1), (flooder, 2)]
    for e in asked:
        e.query.reply(e.query.key_expr, b"ok")
        e.query.drop()
    refused = [r for n in range(3, 8) for r in replies[(flooder, n)] if r.err is not None]
    assert len(refused) == 5 and b"already waiting" in refused[0].err.payload.to_bytes()
    assert inbox.rejects.report() == f"{{'flood': 5}}, from {{'{flooder}': 5}}"
    inbox.close()


def test_queries_beyond_those_that_may_wait_are_refused_unread_whatever_sender_they_name() -> None:
    """Issue 33, 6: CONNECTs with invented sessions, each naming another sender, got past every budget of one
    origin and cost the coordinator's main thread a decode and an error reply each. With `most`, a query that finds
    that many queued or held by the main thread (`waiting`) is refused on Zenoh's thread, unread. (Through a router
    without its budget of CONNECTs a session, which would end 4 of the 5 this one session asks at once:
    test_a_routers_budget_of_connects_or_maps_a_session_ends_the_rest_at_once_without_a_reply; the coordinator's
    bound is for CONNECTs from many sessions.)"""
    keys = Keys(unique_root())
    conf = router_config("tcp/127.0.0.1:0")
    conf.insert_json5("downsampling", json.dumps(flood_filters(["**"])["downsampling"][:1]))
    with zenoh.open(conf) as router, zenoh.open(client_config(router_locators(router)[0])) as a, \
            zenoh.open(client_config(router_locators(router)[0])) as b:
        _refused_unread(Inbox(a, keys, LOG), Outbox(b), keys)


def _refused_unread(inbox: Inbox, out: Outbox, keys: Keys) -> None:
    held = [1]  # (the main thread holds one already: a CONNECT waiting for its token)
    inbox.serve(keys.connect, Connect, most=3, waiting=lambda: held[0])
    asker = out.session
    replies = {}
    arrived = threading.Event()  # a put after the queries, from the same session: they came before it
    barrier = inbox.session.declare_subscriber(keys.over, _direct(lambda sample: arrived.set()))
    querier = asker.declare_querier(keys.connect)
    while not querier.matching_status.matching:
        arrived.wait(0.01)
    querier.undeclare()
    for n in range(1, 6):
        sender = drone_name(n)
        data = encode(Connect(turn=0, sender=sender, role=Role.DRONE, drones=(sender,), session=f"s{n}"))
        replies[sender] = asker.get(keys.connect, payload=data, timeout=10)
    asker.put(keys.over, encode(over(1)))
    assert arrived.wait(10)
    barrier.undeclare()
    refused = {d: [r.err.payload.to_bytes() for r in replies[d] if r.err is not None] for d in ("D03", "D04", "D05")}
    assert all(b"already wait" in errs[0] for errs in refused.values()), refused
    assert inbox.rejects.report() == "{'flood': 3}, from {'D03': 1, 'D04': 1, 'D05': 1}"
    asked: list[Any] = [inbox.get(10) for _ in range(2)]
    assert [e.msg.sender for e in asked] == ["D01", "D02"], "the first two, queued and read"
    for e in asked:
        e.query.reply(e.query.key_expr, b"ok")
        e.query.drop()
    assert [r.ok.payload.to_bytes() for r in replies["D01"]] == [b"ok"]
    inbox.close()


def test_a_plain_routers_budget_of_tgts_is_a_drones_a_session_the_rest_never_reach_the_coordinator() -> None:
    """Issue 33, 6: on a router without access control (any peer may put on a drone's TGT key) each of the first
    `TGT_BUDGETED` drones' TGT key has a budget of `TGT_RATE` puts a second from one session (`flood_filters`): of a
    flood of stale TGTs for D01 from one session, few reach the coordinator, each refused there as stale and counted
    against the GCS; that session's TGTs for 16 other drones sent together all pass (a budget a drone, not one for
    all), and so does another session's TGT for D01 (a budget a session)."""
    keys = Keys(unique_root())
    with embedded_router() as locator, zenoh.open(client_config(locator)) as srv, \
            zenoh.open(client_config(locator)) as station, zenoh.open(client_config(locator)) as other:
        inbox = Inbox(srv, keys, LOG)
        inbox.subscribe(keys.any_tgt, Target, since=lambda: 5)
        arrived = threading.Event()  # a put after the TGTs, from the same session: they came before it
        barrier = srv.declare_subscriber(keys.over, _direct(lambda sample: arrived.set()))
        out = Outbox(station)
        while not out._pub(keys.tgt("D01")).matching_status.matching:
            arrived.wait(0.01)
        sent = 2_000  # as fast as it can: closer together than 1 / TGT_RATE s, but for a pause of the whole machine
        stale = encode(Target(turn=1, sender="GCS", drone="D01", pos=(1, 1, 1)))
        for _ in range(sent):
            out._pub(keys.tgt("D01")).put(stale)
        drones = [drone_name(n) for n in range(2, 18)]
        for drone in drones:
            out.put(keys.tgt(drone), Target(turn=5, sender="GCS", drone=drone, pos=(2, 2, 2)))
        out.put(keys.over, over(1))
        assert arrived.wait(10)
        Outbox(other).put(keys.tgt("D01"), Target(turn=5, sender="GCS", drone="D01", pos=(3, 3, 3)))
        got: list[Any] = [inbox.get(10) for _ in range(len(drones) + 1)]
        assert sorted(e.msg.drone for e in got) == sorted([*drones, "D01"]), "every TGT sent within its budget came"
        passed = inbox.rejects.total
        assert 1 <= passed < sent // 2, passed  # the flood's first, and about one a batch the router read
        assert inbox.rejects.report() == f"{{'stale-turn': {passed}}}, from {{'GCS': {passed}}}"
        barrier.undeclare()
        inbox.close()
    plain = {r["key_expr"]: r["freq"] for item in flood_filters(["**"])["downsampling"] for r in item["rules"]}
    assert plain["**/D01/TGT"] == plain[f"**/{drone_name(TGT_BUDGETED)}/TGT"] == TGT_RATE
    assert f"**/{drone_name(TGT_BUDGETED + 1)}/TGT" not in plain and "**/*/TGT" not in plain


@pytest.mark.parametrize("kind", ["connect", "map"])
def test_a_routers_budget_of_connects_or_maps_a_session_ends_the_rest_at_once_without_a_reply(kind: str) -> None:
    """Issue 33, 6: a router keeps at most CONNECT_RATE CONNECTs (MAP_RATE MAP queries) a second from one session
    (`flood_filters`); the rest never reach the coordinator (the environment), and each ends at once, without a
    reply (Zenoh's router ends a query its interceptor drops), so a process asks again. Another session has a
    budget of its own."""
    keys = Keys(unique_root())
    key = keys.connect if kind == "connect" else keys.map
    got: list[bytes] = []
    with embedded_router() as locator, zenoh.open(client_config(locator)) as srv, \
            zenoh.open(client_config(locator)) as asker, zenoh.open(client_config(locator)) as other:
        queryable = srv.declare_queryable(key, _direct(
            lambda q: (got.append(q.payload.to_bytes() if q.payload else b""), q.reply(q.key_expr, b"ok"), q.drop())))
        querier = asker.declare_querier(key)
        while not querier.matching_status.matching:
            threading.Event().wait(0.01)
        querier.undeclare()
        sent = 200  # at once: closer together than 1 / CONNECT_RATE (MAP_RATE) s, but for a pause of the whole machine
        flood = [asker.get(key, payload=b"flood", timeout=30) for _ in range(sent)]
        answered = sum(1 for replies in flood if any(r.ok is not None for r in replies))
        assert 1 <= answered < sent and got.count(b"flood") == answered, (answered, got.count(b"flood"))
        assert [r.ok.payload.to_bytes() for r in other.get(key, payload=b"other", timeout=30)] == [b"ok"]
        queryable.undeclare()


def test_newest_keeps_the_last_message_queues_no_event_and_checks_it_when_read(pair) -> None:
    """A key read with `Inbox.newest` (the environment's STATUS): nothing is queued for it; each read gives the
    message that came since the last read, checked as a subscription's are."""
    inbox, out, keys = pair
    read = inbox.newest(keys.status, Status)
    subscribed(out, inbox, keys.status)
    assert read() is None, "nothing came yet"
    for turn in range(1, 4):
        out.put(keys.status, Status(turn=turn, sender="OBS", drones=StatusTable.of([])))
    out.put(keys.over, over(9))  # after them on the same session: once it is here, so are they
    assert inbox.get(10).msg == over(9) and inbox.drain() == [], "no event for a STATUS"
    got = read()
    assert isinstance(got, Received) and got.key == keys.status and got.msg.turn == 3, "the last one only"
    assert read() is None, "each one is read once"
    out.session.put(keys.status, b"\x81\xa1v\x05")  # a map, but no message
    out.put(keys.over, over(10))
    assert inbox.get(10).msg == over(10)
    assert read() is None and sum(inbox.rejects.snapshot().values()) == 1, "refused and counted"


@pytest.fixture
def bare():
    """(inbox of a router session without flood filters, outbox of a client of it, keys): what a
    process's own checks do, with nothing dropped on the way."""
    keys = Keys(unique_root())
    conf = zenoh.Config()
    for name, value in (("mode", '"router"'), ("listen/endpoints", '["tcp/127.0.0.1:0"]'),
                        ("scouting/multicast/enabled", "false"),
                        ("adminspace", '{"enabled": true, "permissions": {"read": true, "write": false}}')):
        conf.insert_json5(name, value)
    with zenoh.open(conf) as a, zenoh.open(client_config(router_locators(a)[0])) as b:
        inbox = Inbox(a, keys, LOG)
        inbox.subscribe(keys.tgt("D01"), Target)
        out = Outbox(b)
        subscribed(out, inbox, keys.tgt("D01"))
        yield inbox, out, keys


def test_the_largest_valid_connect_is_within_its_keys_size_limit() -> None:
    """A swarm host flying every drone there can be connects (its CONNECT lists their ids)."""
    host = Connect(turn=0, sender="H9999", role=Role.DRONE, drones=tuple(map(drone_name, range(1, MAX_DRONE + 1))),
                   autopilot="a" * 32, cooperative=True, session="f" * 64)
    assert len(encode(host)) <= size_limit(Connect)


@pytest.mark.parametrize("where", ["bare", "pair"])
def test_a_payload_above_its_keys_size_limit_is_refused_unread(where, request) -> None:
    """The inbox refuses it before reading it; a router this project configures drops it on the way."""
    inbox, out, keys = request.getfixturevalue(where)
    drone = "D01" if where == "bare" else UNBUDGETED  # (a drone whose TGTs a plain router does not budget)
    if where == "pair":
        inbox.subscribe(keys.tgt(drone), Target)
        subscribed(out, inbox, keys.tgt(drone))
    out.session.put(keys.tgt(drone), b"\x81" * (size_limit(Target) + 1))
    out.put(keys.tgt(drone), target(1, drone))  # after it: once this one is here, the big one was dealt with
    assert inbox.get(10).msg == target(1, drone)
    expected = {"too-large": 1} if where == "bare" else {}
    assert inbox.rejects.snapshot() == expected


def test_a_wake_posted_from_another_thread_ends_the_wait_at_once(pair) -> None:
    """`post(None)`: what `network.signals.waking` does when a signal lands (issue 33, 1: a coordinator waiting
    in a long wait, e.g. a resumed game's ground station's grace, noted SIGTERM and waited on to the end). The
    wait returns None for it, not the event that comes next (nor nothing until its timeout)."""
    inbox = pair[0]
    inbox.post(None)
    inbox.post("next")
    assert inbox.get(timeout=3600.0) is None
    assert inbox.get(timeout=3600.0) == "next"


def test_the_fast_read_of_a_payloads_turn_says_what_the_unpacker_says() -> None:
    """Issue 33, 6: a subscription refuses a stale message from its first bytes, read without an Unpacker (`_turn`,
    for each message of a flood the router lets through); it must say what `_stamp` says of any payload: every
    sample message, turns of every width, and those bytes cut, mangled or written another way."""
    import random

    import msgpack

    payloads = [encode(m) for m in SAMPLES.values() if isinstance(m, Message)]
    for turn in (0, 1, 127, 128, 255, 256, 65_535, 65_536, 2**32 - 1, 2**32, 2**40, 2**64 - 1):
        payloads.append(encode(Target(turn=turn, sender="GCS", drone="D01", pos=(1, 1, 1))) if turn < 2**63 else
                        msgpack.packb({"v": 5, "t": "TGT", "turn": turn, "from": "GCS"}))
    for odd in (-1, True, None, 1.5, "7", [7]):
        payloads.append(msgpack.packb({"v": 5, "t": "DONE", "turn": odd, "from": "GCS"}))
    payloads += [msgpack.packb({"v": 5, "t": "DONE", "turn": 1, "turn ": 2}), msgpack.packb({"v": 5, "t": "DONE"}),
                 b"\x84\xa1v\x05\xa1t\xa4DONE\xa4turn\x01\xa4turn\x09", b"\x83\xa1v\x05\xa1t\xa3N\xb4S\xa4turn\x01"]
    rnd = random.Random(33)
    for _ in range(20_000):
        data = bytearray(rnd.choice(payloads)[:rnd.randint(0, 48)])
        for _ in range(rnd.randint(0, 2)):
            if data:
                data[rnd.randrange(len(data))] = rnd.randrange(256)
        payloads.append(bytes(data))
    differ = [p for p in payloads if _turn(p) != _stamp(p)[0] or type(_turn(p)) is not type(_stamp(p)[0])]
    assert not differ, differ[:5]


def test_zenohs_threads_keep_their_python_thread_state_from_one_callback_to_the_next(pair) -> None:
    """A callback given through `_direct` runs on a Zenoh thread whose Python thread state lasts: what it keeps in a
    `threading.local` is there at its next message (without `_keep_thread_state` each message had a new state, made
    and destroyed around it: 20-27 µs a callback)."""
    inbox, out, keys = pair
    mine = threading.local()
    seen: list[tuple[int, int]] = []  # (the thread, messages it had seen before this one)
    arrived = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        mine.count = getattr(mine, "count", 0) + 1
        seen.append((threading.get_ident(), mine.count - 1))
        if len(seen) == 20:
            arrived.set()

    sub = inbox.session.declare_subscriber(keys.status, _direct(on_sample))
    pub = out.session.declare_publisher(keys.status)
    try:
        while not pub.matching_status.matching:
            inbox.get(0.01)
        for i in range(20):
            pub.put(b"%d" % i)
            while len(seen) <= i and not arrived.is_set():  # one at a time: each a callback of its own
                inbox.get(0.001)
        assert arrived.wait(10)
    finally:
        pub.undeclare()
        sub.undeclare()
    by_thread: dict[int, list[int]] = {}
    for thread, before in seen:
        by_thread.setdefault(thread, []).append(before)
    assert all(counts == list(range(len(counts))) for counts in by_thread.values()), by_thread
    assert any(len(counts) > 1 for counts in by_thread.values())  # a thread ran several: its state lasted
