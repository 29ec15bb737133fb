"""Stopping on a signal: SIGINT (Ctrl-C) and SIGTERM (a process manager, `docker stop`, a closed terminal)
become an event of the process's loop instead of a traceback or a sudden death, so that it can end its
game cleanly; the process then exits with the status shells expect (128 + the signal: 130, 143)."""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import signal
import socket
import sys
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from schema import EndReason, Over


@dataclass(frozen=True, slots=True)
class Interrupted:
    """A signal asked this process to stop."""

    signum: int

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


class Stop(BaseException):
    """Raised by a signal handler to unwind the main thread (see `on_stop`). A BaseException, as
    KeyboardInterrupt is: the handlers that turn a bad payload into a counted rejection (`except Exception`)
    must not swallow a signal that lands while a message is decoded."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: The exit status of every process of a game that ended because its journal could not be written (OVER
#: JOURNAL_FAILED: a full disk, a file size limit): EX_TEMPFAIL (sysexits.h), "try again later": once there is
#: room, the coordinator resumes the game from its journal (`--resume`).
JOURNAL_FAILED_STATUS = 75


def over_status(over: object) -> int:
    """The exit status of an entity whose game ended with `over` (an OVER, or anything else: 0)."""
    return JOURNAL_FAILED_STATUS if isinstance(over, Over) and over.reason is EndReason.JOURNAL_FAILED else 0


def stop(event: Interrupted) -> None:
    """`on_stop`'s handler for a main thread that waits in a blocking call: raise `Stop`."""
    raise Stop(event.signum)


def exit_status(signum: int) -> int:
    """The exit status of a process stopped by `signum`, as shells report it (SIGINT: 130, SIGTERM: 143)."""
    return 128 + signum


#: The signals that stop a process of a game.
STOPPING = (signal.SIGINT, signal.SIGTERM)


@dataclass(frozen=True, slots=True)
class _Posting:
    """`on_stop`'s handler."""

    post: Callable[[Interrupted], None]

    def __call__(self, signum: int, _frame: object) -> None:
        self.post(Interrupted(signum))


@contextlib.contextmanager
def on_stop(post: Callable[[Interrupted], None]) -> Iterator[None]:
    """While inside (on the main thread): SIGINT and SIGTERM call `post(Interrupted(signum))` instead of
    raising KeyboardInterrupt or ending the process; the previous handlers come back on leaving. `post`
    runs on the main thread between two bytecodes: it hands the event over (e.g. `Inbox.post`), or raises
    `Stop` to unwind what the main thread is waiting in."""
    handler = _Posting(post)
    previous = {s: signal.signal(s, handler) for s in STOPPING}
    try:
        yield
    finally:
        for s, before in previous.items():
            if signal.getsignal(s) is handler:  # (not if `closing` has taken over since)
                signal.signal(s, before)


def closing(over: object) -> None:
    """Called by an entity once its game is over (`over`: the OVER that ended it), before it closes (its presence, its
    session, the interpreter): from then until it exits, SIGINT and SIGTERM end it at once with its game's status
    (`over_status`), not with 130/143.
    It was not stopped, it was leaving: a cluster's `docker compose stop` or `down` signals the entities as soon as
    the coordinator has seen their presence go, which can be while they close. Only in a process whose signals
    `on_stop` handles (an entity's command, `until_stopped`): a game played in a test's process leaves them be."""
    if threading.current_thread() is not threading.main_thread() or not isinstance(
            signal.getsignal(signal.SIGTERM), _Posting):
        return
    status = over_status(over)

    def leave(_signum: int, _frame: object) -> None:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):  # (a closed stream, a write that the signal interrupted)
                stream.flush()
        os._exit(status)

    for s in STOPPING:
        signal.signal(s, leave)
    atexit.unregister(_ignore_stopping)  # (once, however often the game ends)
    atexit.register(_ignore_stopping)


def _ignore_stopping() -> None:
    """The last of `closing`: as the interpreter finalizes, it puts the default action back on the signals that had
    a Python handler (`leave` included), and a SIGTERM then would end the process as killed (-15: 143) while it frees
    its objects (Zenoh's among them). Ignored instead (that it keeps): the process is exiting with its status anyway.
    (One that hung from there on would end only by SIGKILL: Docker's after its stop timeout, `dronesim up`'s after
    `KILL_S`.)"""
    for s in STOPPING:
        signal.signal(s, signal.SIG_IGN)


def until_stopped(run: Callable[[], object], logger: logging.Logger) -> int:
    """Run an entity's `run` on the main thread; Ctrl-C or SIGTERM unwinds it wherever it waits (its sessions,
    presence and servers close on the way out): one warning line, no traceback, and the status shells expect.
    Otherwise the exit status `run` returns, or for the OVER that ended its game (an entity's `main`) 0, or
    JOURNAL_FAILED_STATUS if the game ended because its journal could not be written."""
    try:
        with on_stop(stop):
            status = run()
        return status if isinstance(status, int) else over_status(status)
    except Stop as sig:
        logger.warning("stopped by %s", sig)
        return exit_status(sig.signum)


@contextlib.contextmanager
def waking(*wake: Callable[[], None]) -> Iterator[None]:
    """While inside (on the main thread): every signal that has a Python handler also calls each `wake`, on
    a helper thread. A Python handler runs only when the main thread runs Python code: a signal landing just
    before that thread blocks in a wait would wait for the next event, maybe forever (a prompt, a phase held
    for a person). A `wake` puts something in the queue the main thread waits on, so that the handler runs at
    once. (Off the main thread, nothing is done: signals are for the main thread.)"""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    reader, writer = socket.socketpair()
    writer.setblocking(False)
    previous = signal.set_wakeup_fd(writer.fileno(), warn_on_full_buffer=False)

    def pump() -> None:
        while reader.recv(64):  # one byte per signal; empty once `writer` is closed
            for fn in wake:
                fn()

    thread = threading.Thread(target=pump, name="signal-wake", daemon=True)
    thread.start()
    try:
        yield
    finally:
        signal.set_wakeup_fd(previous)
        writer.close()
        thread.join()
        reader.close()
