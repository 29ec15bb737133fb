"""The Zenoh backend of an RL episode (`dronesim.rl.Turns`): each step is one lockstep turn of the real
coordinator and environment processes, on a router this process starts (or joins: `connect`).

This process plays the ground station and the swarm host H01 (every drone) from one Zenoh session: per turn
it sends the DONE and the host's MOVES at once (the coordinator holds MOVES that come before their drones'
phase opens; `moves_ahead=False`: once it opens, a second round trip) and waits for the observer's STATUS.
Every wait has a deadline and watches the processes: one that dies raises `BackendError` at once, a game
that stops answering when the deadline passes.
"""

from __future__ import annotations

import contextlib
import logging
import subprocess
import sys
import tempfile
import time
import uuid
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import cast

import numpy as np
import zenoh

from coordinator.config import GameConfig
from dronesim import child_env
from dronesim.rl import HOST, BackendError, Board, hellos, turn_messages
from network.membership import Membership, NotAdmitted
from network.transport import (
    Inbox,
    Outbox,
    Presence,
    Received,
    client_config,
    router_config,
    router_locators,
    session_id,
    zenoh_error,
)
from schema import Done, Intent, Keys, Message, Moves, Over, Phase, Status, Turn, UsageError
from schema.tuning import LEFT_GRACE_S, PROCESS_CHECK_S, RL_WAIT_S
from world.grid import World

#: The processes of a game, by the name their presence token has.
ROLES = {"SRV": "coordinator", "ENV": "environment"}


class ZenohTurns:
    """Games on real processes over Zenoh, one per episode (see the module's docstring)."""

    def __init__(self, *, connect: str | None = None, deadline: float = RL_WAIT_S, moves_ahead: bool = True) -> None:
        self.deadline = deadline
        self.moves_ahead = moves_ahead  # False: each MOVES waits for its drones' phase (a second round trip)
        self._log = logging.getLogger("dronesim.rl")
        self._logs = tempfile.TemporaryDirectory(prefix="dronesim-rl-")
        self._tag = uuid.uuid4().hex[:8]
        self._games = 0
        self._router: zenoh.Session | None = None
        self._session: zenoh.Session | None = None
        self._game: _Game | None = None
        #: Every process started, for the finalizer: an environment dropped without close() (or an interpreter
        #: that exits) must not leave a coordinator behind that waits for a router gone with this process.
        self._children: list[subprocess.Popen] = []
        self._files: list = []  # the current game's log files
        #: The sessions open, for the finalizer too: one left for the interpreter's teardown to drop hangs it
        #: (a script that ends or raises mid-episode without close() would never exit).
        self._sessions: list[zenoh.Session] = []
        self._finalizer = weakref.finalize(self, _abandon, self._children, self._files, self._logs, self._sessions)
        try:
            if connect is None:
                self._router = zenoh.open(router_config("tcp/127.0.0.1:0"))
                self._sessions.append(self._router)
                connect = router_locators(self._router)[0]
            self.locator = connect
            self._session = zenoh.open(client_config(connect))
            self._sessions.append(self._session)
        except Exception as err:
            self.close()
            where = f"the Zenoh router at {connect}" if connect else "a Zenoh router in this process"
            raise BackendError(f"cannot open a session with {where}: {zenoh_error(err)}") from None

    def start(self, game: GameConfig, world: World) -> Board:
        self.stop()
        self._games += 1
        self._children[:] = [p for p in self._children if p.poll() is None]
        self._game = _Game(self, f"rl{self._tag}g{self._games}", game)
        return Board.of_status(self._game.begin(world), len(game.drones))

    def play(self, turn: int, aim_rows: np.ndarray, aims: np.ndarray, move_rows: np.ndarray, moves: np.ndarray,
             notes: np.ndarray) -> tuple[Board, Over | None]:
        if self._game is None:
            raise BackendError("no game is running")
        status, over = self._game.play(*turn_messages(turn, aim_rows, aims, move_rows, moves, notes))
        return Board.of_status(status, len(self._game.game.drones)), over

    def stop(self) -> None:
        game, self._game = self._game, None
        if game is not None:
            game.end()

    def close(self) -> None:
        try:
            self.stop()
        finally:
            self._session = self._router = None
            self._finalizer()  # (closes the sessions)


class _Game:
    """One game: its processes, this process's presence and subscriptions, and the turn being played."""

    def __init__(self, turns: ZenohTurns, root: str, game: GameConfig) -> None:
        assert turns._session is not None
        self.session, self.keys, self.deadline, self.log = turns._session, Keys(root), turns.deadline, turns._log
        self.moves_ahead, self.game, self.root, self.locator = turns.moves_ahead, game, root, turns.locator
        self.turn = 0  # the last turn whose STATUS arrived
        self.over: Over | None = None
        self.procs: dict[str, subprocess.Popen] = {}
        self.children, self._files, self.logs = turns._children, turns._files, Path(turns._logs.name)
        self.inbox = Inbox(self.session, self.keys, self.log)
        self.out = Outbox(self.session)
        self.members: list[Membership] = []  # the ground station's and the swarm host's admissions
        self.vanished: tuple[str, float] | None = None  # a role whose presence token vanished before OVER, and until
        # when its OVER may still come (`_event`)

    def _start(self, name: str, argv: list[str]) -> None:
        log = open(self.logs / f"{self.root}.{name}.log", "w", encoding="utf-8")  # noqa: SIM115 - closed in end()
        self._files.append(log)
        self.procs[name] = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                            env=child_env(PYTHONUNBUFFERED="1"))
        self.children.append(self.procs[name])

    # ------------------------------------------------------------------ failures

    def _tail(self, name: str) -> str:
        with contextlib.suppress(OSError):
            lines = (self.logs / f"{self.root}.{name}.log").read_text(errors="replace").splitlines()
            return " | ".join(lines[-6:])
        return ""

    def _check(self) -> None:
        """BackendError if a process of the game has exited before the game's end."""
        for name, proc in self.procs.items():
            if (code := proc.poll()) is not None and self.over is None:
                raise BackendError(f"the {ROLES[name]} process exited with {code} during the game: "
                                   f"{self._tail(name)}")

    def _event(self, end: float, waiting_for: str):
        """The next event, checking the processes while none comes; BackendError past `end`."""
        while True:
            now = time.monotonic()
            if self.vanished is not None and now >= self.vanished[1] and self.over is None:
                raise BackendError(f"the {ROLES[self.vanished[0]]} left the game (its presence token vanished)")
            left = end - now
            if left <= 0:
                raise BackendError(f"no {waiting_for} within {self.deadline:g} s: the game's processes stopped "
                                   "answering")
            grace = [] if self.vanished is None else [max(0.0, self.vanished[1] - now)]
            event = self.inbox.get(min(left, PROCESS_CHECK_S, *grace))
            if event is None:
                self._check()
                continue
            if isinstance(event, Presence) and not event.alive and event.entity in ROLES and self.over is None:
                self._check()  # (a process ending at the game's end: its OVER may still be on its way)
                self.vanished = self.vanished or (event.entity, time.monotonic() + LEFT_GRACE_S)
                continue
            return event

    # ------------------------------------------------------------------ the game

    def begin(self, world: World) -> Status:
        """Start the game's processes, connect as the ground station and the swarm host, then wait for the
        STATUS of turn 0."""
        game, root = self.game, self.root
        try:
            for key, typ in ((self.keys.status, Status), (self.keys.over, Over)):
                self.inbox.subscribe(key, typ)
            if not self.moves_ahead:
                self.inbox.subscribe(self.keys.turn_of(Phase.DRONES), Turn)
            self.inbox.watch_presence()
            world_file = self.logs / f"{root}.world.json"
            world.save(world_file)
            base, deadline = [sys.executable, "-m", "dronesim"], str(self.deadline)
            common = ["--mode", "client", "--connect", self.locator, "--root", root, "--log-level", "WARNING"]
            starts = ";".join(f"{x},{y},{z}" for x, y, z in (d.start for d in game.drones))
            self._start("SRV", [*base, "coordinator", *common, "--world", str(world_file),
                                "--drones", str(len(game.drones)), "--starts", starts,
                                "--max-turns", str(game.max_turns), "--phase-deadline", deadline,
                                "--admit-deadline", deadline])
            self._start("ENV", [*base, "env", *common, "--no-draw", "--connect-timeout", deadline])
            end = time.monotonic() + self.deadline
            for hello in hellos(self.game, session_id(self.session)):  # (admission as the inbox's events; a process
                try:  # that dies meanwhile raises at once)
                    self.members.append(Membership(self.session, self.inbox, hello, self.log, grace=0.0,
                                                   connect_timeout=max(0.1, end - time.monotonic()), check=self._check))
                except NotAdmitted as err:
                    raise BackendError(f"the coordinator refused {hello.sender}: {err}") from None
                except UsageError:
                    raise BackendError(f"no coordinator admitted {hello.sender} within {self.deadline:g} s: "
                                       f"{self._tail('SRV')}") from None
            return self._status(0, end)
        except BaseException:
            self.end()
            raise

    def _status(self, turn: int, end: float) -> Status:
        status = self._awaited(end, f"turn {turn}'s STATUS", lambda m: isinstance(m, Status) and m.turn == turn)
        self.turn = turn
        return cast(Status, status)

    def _awaited(self, end: float, what: str, wanted: Callable[[Message], bool]) -> Message:
        """The next message that is `wanted`; BackendError if the game ends first (or past `end`)."""
        while True:
            match self._event(end, what):
                case Received(_, msg) if wanted(msg):
                    return msg
                case Received(_, Over() as over):
                    self.over = over
                    raise BackendError(f"the game ended before {what}: {over.reason.value}: {over.text}")

    def play(self, done: Done, moves: Moves | None) -> tuple[Status, Over | None]:
        t = done.turn
        if self.over is not None or t != self.turn + 1:
            where = "over" if self.over else f"at turn {self.turn}"
            raise BackendError(f"turn {t} cannot be played: the game is {where}")
        end = time.monotonic() + self.deadline
        self.out.put(self.keys.gcs_done, done)
        if moves is not None:  # at once: the coordinator holds them until the drones' phase opens
            if not self.moves_ahead:  # (the benchmark's "off": the MOVES once its drones' phase is announced)
                self._awaited(end, f"the drones' phase of turn {t}",
                              lambda m: isinstance(m, Turn) and m.phase is Phase.DRONES and m.turn == t)
            self.out.put(self.keys.moves(HOST), moves)
        status = self._status(t, end)
        last = t >= self.game.max_turns or not status.drones.alive_mask().any()
        return status, (self._over(end) if last else None)

    def _over(self, end: float) -> Over:
        while self.over is None:
            match self._event(end, "OVER"):
                case Received(_, Over() as over):
                    self.over = over
        return self.over

    def end(self) -> None:
        """End the game if it runs (the ground station quits), then its processes, subscriptions and presence."""
        try:
            if self.over is None and self.members and all(p.poll() is None for p in self.procs.values()):
                self.out.put(self.keys.gcs_done, Done(turn=self.turn + 1, sender="GCS", phase=Phase.GCS,
                                                      intent=Intent.QUIT))
                self._over(time.monotonic() + min(self.deadline, 10.0))
        except BackendError as err:
            self.log.warning("the game did not end cleanly: %s", err)
        finally:
            for member in self.members:  # gone: the coordinator, which waits for its entities to leave, ends
                with contextlib.suppress(Exception):
                    member.close()
            self.members.clear()
            end = time.monotonic() + min(self.deadline, 10.0)
            for proc in self.procs.values():
                try:
                    proc.wait(max(0.1, end - time.monotonic()))
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            self.inbox.close()
            self.out.close()
            for f in self._files:
                f.close()
            self._files.clear()


def _abandon(children: list[subprocess.Popen], files: list, logs: tempfile.TemporaryDirectory,
             sessions: list[zenoh.Session]) -> None:
    """Close the sessions still open (the client's first), kill the processes still running and remove their logs
    (after close(), or as the finalizer of an environment dropped without it, at the latest when the interpreter
    exits: before its teardown, which would hang on an open session)."""
    while sessions:
        with contextlib.suppress(Exception):
            sessions.pop().close()
    for proc in children:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    for f in files:
        f.close()
    logs.cleanup()
