"""Inbox.run over a real router: events handled one at a time, in order of arrival, on the main thread or
on Zenoh's; deadlines that an event handled on Zenoh's thread moves are kept; a failure there is raised
by `run`; an event arriving after the end is kept for `get`."""

from __future__ import annotations

import logging
import threading
import time

import pytest
import zenoh

from dronesim.schema import Keys, Over, EndReason
from dronesim.transport import Inbox, Outbox, Received
from tests.harness import client_config, embedded_router, unique_root

pytestmark = pytest.mark.integration
LOG = logging.getLogger("test-transport")


@pytest.fixture
def pair():
    """(inbox of a listening session, outbox of another session, keys)."""
    keys = Keys(unique_root())
    with embedded_router() as locator, zenoh.open(client_config(locator)) as a, \
            zenoh.open(client_config(locator)) as b:
        inbox = Inbox(a, keys, LOG)
        inbox.subscribe(keys.over, Over)
        out = Outbox(b)
        while not out.matching(keys.over):  # the subscription has reached the publisher's side
            inbox.get(0.01)
        yield inbox, out, keys


def within(seconds: float):
    """A `timeout` for `Inbox.run`: a fixed deadline `seconds` from now."""
    end = time.monotonic() + seconds
    return lambda: max(0.0, end - time.monotonic())


def over(turn: int) -> Over:
    return Over(turn=turn, sender="SRV", reason=EndReason.TURN_LIMIT, text=f"#{turn}")


def test_run_handles_events_one_at_a_time_in_order_some_on_zenohs_thread(pair) -> None:
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
    assert threads - {threading.main_thread().name}, "some were handled on Zenoh's thread, without a handoff"


def test_a_deadline_set_on_zenohs_thread_wakes_the_waiting_thread(pair) -> None:
    """`run` waits without a deadline; an event handled on Zenoh's thread sets one: the handler gets its
    None when it is due (not never)."""
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

    result: list[BaseException | None] = []

    def go() -> None:
        try:
            inbox.run(handle, timeout=timeout, until=lambda: bool(timed_out))
            result.append(None)
        except BaseException as exc:  # pragma: no cover - reported below
            result.append(exc)

    runner = threading.Thread(target=go)
    runner.start()
    out.put(keys.over, over(1))
    runner.join(20)
    assert not runner.is_alive(), "run never woke up for the deadline set on Zenoh's thread"
    assert result == [None] and timed_out[0] >= due[0]


def test_a_handler_failing_on_zenohs_thread_fails_run(pair) -> None:
    inbox, out, keys = pair

    class Boom(Exception):
        pass

    def handle(event) -> None:
        raise Boom(event)

    def send() -> None:
        out.put(keys.over, over(1))

    threading.Thread(target=send).start()
    with pytest.raises(Boom):
        inbox.run(handle, timeout=within(30), until=lambda: False)


def test_an_event_after_the_end_is_kept_for_get(pair) -> None:
    inbox, out, keys = pair
    seen: list[int] = []
    for t in range(3):
        out.put(keys.over, over(t))
    inbox.run(lambda e: seen.append(e.msg.turn), timeout=within(30), until=lambda: len(seen) == 1)
    rest = [inbox.get(10), inbox.get(10)]
    assert seen == [0] and [e.msg.turn for e in rest] == [1, 2]
