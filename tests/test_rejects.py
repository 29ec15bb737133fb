"""Rejected input is counted whole and logged in bounds (schema.errors.RejectCounter): per origin and
reason, a few lines in full (each an excerpt) per window, the rest summarised in one line when the window
is over; the counts say every rejection, by reason and by origin."""

from __future__ import annotations

import logging

from schema.errors import MalformedMessage, RejectCounter, StaleTurn
from schema.tuning import REJECT_EXCERPT, REJECT_LOG_FIRST, REJECT_LOG_WINDOW


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records]


def test_a_flood_is_logged_a_few_lines_a_window_and_counted_whole(caplog) -> None:
    clock = Clock()
    counter = RejectCounter(logging.getLogger("test-rejects"), clock)
    with caplog.at_level(logging.WARNING):
        for n in range(100_000):
            counter.reject("sim/D01/NPS", StaleTurn(f"NPS for turn {n}"), "D01")
        counter.reject("sim/D02/NPS", StaleTurn("NPS for turn 7"), "D02")  # another origin: its own lines
        assert len(lines(caplog)) == REJECT_LOG_FIRST + 1
        assert counter.due_in() == REJECT_LOG_WINDOW
        counter.flush()
        assert len(lines(caplog)) == REJECT_LOG_FIRST + 1, "the window is not over"
        clock.now += REJECT_LOG_WINDOW
        assert counter.due_in() == 0.0
        counter.flush()
    logged = lines(caplog)
    assert len(logged) == REJECT_LOG_FIRST + 2
    assert logged[-1] == (f"rejected {100_000 - REJECT_LOG_FIRST} more from D01 (stale-turn) in 1.0 s; the last: "
                          "sim/D01/NPS: NPS for turn 99999")
    assert counter.due_in() is None
    assert counter.total == 100_001 and counter.snapshot() == {"stale-turn": 100_001}
    assert counter.report() == "{'stale-turn': 100001}, from {'D01': 100000, 'D02': 1}"


def test_a_new_window_logs_in_full_again_and_flush_everything_ends_them_all(caplog) -> None:
    clock = Clock()
    counter = RejectCounter(logging.getLogger("test-rejects"), clock)
    with caplog.at_level(logging.WARNING):
        for _ in range(REJECT_LOG_FIRST + 2):
            counter.reject("k", MalformedMessage("bad"))
        clock.now += REJECT_LOG_WINDOW
        counter.flush()
        counter.reject("k", MalformedMessage("bad again"))
        counter.flush(everything=True)
    logged = lines(caplog)
    assert logged[REJECT_LOG_FIRST] == "rejected 2 more from k (malformed) in 1.0 s; the last: k: bad"
    assert logged[-1] == "rejected k: bad again (malformed)" and len(logged) == REJECT_LOG_FIRST + 2


def test_a_long_rejection_is_logged_as_an_excerpt(caplog) -> None:
    counter = RejectCounter(logging.getLogger("test-rejects"), Clock())
    with caplog.at_level(logging.WARNING):
        counter.reject("k", MalformedMessage("x" * 4_000_000))
    (line,) = lines(caplog)
    assert len(line) < REJECT_EXCERPT + 100 and line.endswith("... (4000000 characters) (malformed)")


def test_the_thread_that_logs_summaries_is_woken_when_one_starts_being_held() -> None:
    woken = []
    counter = RejectCounter(logging.getLogger("test-rejects"), Clock(), wake=lambda: woken.append(1))
    for _ in range(REJECT_LOG_FIRST):
        counter.reject("k", MalformedMessage("bad"))
    assert woken == [], "nothing held: nothing to log later"
    for _ in range(5):
        counter.reject("k", MalformedMessage("bad"))
    assert woken == [1], "once, when the window starts holding (Inbox.get then waits until it is due)"
