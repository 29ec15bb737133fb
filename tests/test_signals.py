"""network/signals.py: a signal that another thread takes still ends the main thread's wait at once."""

from __future__ import annotations

import queue
import signal
import threading

from network.signals import Interrupted, on_stop, waking


def test_a_signal_taken_by_another_thread_ends_the_main_threads_wait() -> None:
    """The C handler runs on the thread the signal reached (any of Zenoh's may); the Python handler waits for
    the main thread to run Python code, which, blocked in a queue, it would not do: `waking` wakes it."""
    woken: queue.SimpleQueue[str] = queue.SimpleQueue()
    seen: list[Interrupted] = []

    def other() -> None:
        signal.pthread_kill(threading.get_ident(), signal.SIGTERM)

    with on_stop(seen.append), waking(lambda: woken.put("woken")):
        threading.Thread(target=other).start()
        assert woken.get(timeout=60) == "woken"  # without waking: queue.Empty after 60 s
    assert seen == [Interrupted(signal.SIGTERM)]


def test_waking_off_the_main_thread_does_nothing() -> None:
    done: list[bool] = []

    def off_main() -> None:
        with waking(lambda: None):
            done.append(True)

    t = threading.Thread(target=off_main)
    t.start()
    t.join()
    assert done == [True]


def test_a_signal_that_lands_while_a_message_is_decoded_is_not_taken_for_a_bad_payload(monkeypatch) -> None:
    """The handlers that count a bad payload as a rejection catch Exception: Stop is not one."""
    import msgpack
    import pytest

    from network.signals import Stop
    from schema import decode

    def interrupted(*args, **kwargs):
        raise Stop(2)

    monkeypatch.setattr(msgpack, "unpackb", interrupted)
    with pytest.raises(Stop):
        decode(b"\x80")


ENDED = """
import logging, os, signal, sys, threading
from network.signals import closing, until_stopped
from schema import EndReason, Over

def run():
    if sys.argv[1] == "over":  # the game is over (its journal could not be written: status 75), the process closes
        closing(Over(turn=3, sender="SRV", reason=EndReason.JOURNAL_FAILED, text="disk full"))
    os.kill(os.getpid(), signal.SIGTERM)
    threading.Event().wait(60)

sys.exit(until_stopped(run, logging.getLogger("test")))
"""


def test_a_signal_once_the_game_is_over_ends_the_process_with_the_games_status(tmp_path) -> None:
    """Issue 33, 1: `docker compose down` signals the entities as soon as the coordinator has seen their presence
    go, which can be while they close: they leave with their game's status (here 75), not 143, which says
    "stopped". Before the end, a signal stops them (143)."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    for when, status in (("over", 75), ("playing", 143)):
        p = subprocess.run([sys.executable, "-c", ENDED, when], cwd=root, capture_output=True, text=True, timeout=60)
        assert p.returncode == status, (when, p.stderr)


FINALIZING = """
import logging, os, signal, sys
from network.signals import closing, until_stopped
from schema import EndReason, Over

class Late:  # freed as the interpreter finalizes its modules, after it has put back the signals' default actions
    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)

late = Late()

def run():
    over = Over(turn=3, sender="SRV", reason=EndReason.JOURNAL_FAILED, text="disk full")
    closing(over)
    return over

sys.exit(until_stopped(run, logging.getLogger("test")))
"""


def test_a_signal_while_the_interpreter_finalizes_after_the_game_leaves_the_games_status(tmp_path) -> None:
    """The CI run of 2026-12-01: `docker compose stop` signalled a drone and the environment while their
    interpreters freed their objects, once Python had put the default action back on SIGTERM: killed (-15, 143),
    though their game was over. `closing` has the signals ignored from there on: the status stays the game's."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    p = subprocess.run([sys.executable, "-c", FINALIZING], cwd=root, capture_output=True, text=True, timeout=60)
    assert p.returncode == 75, p.stderr


def test_closing_leaves_the_handlers_of_a_process_that_is_not_an_entitys_command() -> None:
    """A game played in a test's process (no `until_stopped`): `closing` changes none of its handlers."""
    from network.signals import closing

    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    closing(None)
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before
