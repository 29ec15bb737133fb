"""What the browser ground station knows and shows, and what it decides. Pure: no network, no clock.

`GroundState`, owned by one thread (the Zenoh main loop), is fed the coordinator's TURN, STATUS and OVER
and the human's commands (set a target, pause, resume, step, pace, quit), and says when the ground station
answers its GCS phase; what it answers is the protocol's (`entities.gcs.Station`). `snapshot()` is the JSON
the page renders.

Pacing: a human cannot click between turns that take milliseconds, so the GCS phase is answered at most
every `pace` seconds, and is *held* (not answered) while there is nothing to do -- no alive drone has a
target it has not reached or found unreachable -- or while the human pauses. Holding is the seed's rule
(the ground station forces a first target) extended to every turn: the game never burns its turns while
the human thinks. `step` answers one phase now, `quit` ends the game.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

from schema import (
    Cause,
    Cell,
    DroneState,
    DroneStatus,
    Intent,
    Message,
    Note,
    Over,
    Status,
    Turn,
    UsageError,
    Welcome,
    is_drone_id,
)
from schema.errors import excerpt
from schema.tuning import STATUS_GRACE, WEB_PACE_S
from world.grid import World

from ..gcs import Effect, Ground, Station, check_cell

#: How the page names a drone's state.
ALIVE, REACHED, UNREACHABLE, DEAD, LOST = "alive", "reached", "unreachable", "dead", "lost"

CAUSE_TEXT = {
    Cause.BUILDING: "crashed into a building",
    Cause.OUTSIDE: "left the world",
    Cause.VERTEX: "collided with another drone (same cell)",
    Cause.SWAP: "collided with another drone (swapped cells)",
    Cause.LOST: "missed its deadlines or its process vanished",
}

#: Bounds on what a snapshot carries (a long game must not make every update huge).
LOG_LIMIT = 300
TRAIL_LIMIT = 2000
PACE_RANGE = (0.0, 10.0)


class Rejected(Exception):
    """The human's command cannot be carried out; `status` is the HTTP status that says why."""

    def __init__(self, text: str, status: int = 422) -> None:
        super().__init__(text)
        self.text, self.status = text, status


def view_of(s: DroneStatus) -> str:
    if s.state is not DroneState.ALIVE:
        return s.state.value.lower()  # DEAD, LOST
    return {Note.REACHED: REACHED, Note.UNREACHABLE: UNREACHABLE}.get(s.note, ALIVE)


def fmt(cell: Iterable[int] | None) -> str:
    return "none" if cell is None else "(" + ", ".join(str(c) for c in cell) + ")"


#: The most digits of a coordinate: no world is a billion cells wide. It bounds `int()` (which refuses more than
#: 4300 digits with a ValueError) and the messages that quote a cell.
MAX_DIGITS = 9
_NUMBER = rf"(-?[0-9]{{1,{MAX_DIGITS}}})"  # (ASCII digits only: \d would take any script's, like "１")
_CELL_TEXT = re.compile(rf"\s*\(?\s*{_NUMBER}\s*[, ]\s*{_NUMBER}\s*[, ]\s*{_NUMBER}\s*\)?\s*\Z", re.ASCII)


def parse_cell(value: object) -> Cell:
    """A cell given as ``[x, y, z]`` (three integers) or ``"x,y,z"`` / ``"x y z"``, of at most `MAX_DIGITS`
    digits each; `Rejected` (400) if it is neither. Bounds are checked against the world by
    `GroundState.set_target`."""
    if isinstance(value, str):
        m = _CELL_TEXT.match(value)
        if not m:
            raise Rejected(f"{excerpt(repr(value))} is not x,y,z (three integers of at most {MAX_DIGITS} digits)",
                           400)
        return (int(m[1]), int(m[2]), int(m[3]))
    if isinstance(value, (list, tuple)) and len(value) == 3 and \
            all(type(v) is int and abs(v) < 10 ** MAX_DIGITS for v in value):
        return (value[0], value[1], value[2])
    raise Rejected(f"a cell must be [x, y, z] (three integers of at most {MAX_DIGITS} digits) or \"x,y,z\", "
                   f"got {excerpt(repr(value))}", 400)


def world_json(world: World, *, mode: str, title: str = "") -> dict:
    """The static world for the page: size and, per floor z, one string per row x ('#' building, '.' empty)."""
    floors = [["".join("#" if b else "." for b in row) for row in world.grid[:, :, z].tolist()]
              for z in range(world.size[2])]
    return {"mode": mode, "title": title, "size": list(world.size), "floors": floors,
            "building_cells": int(world.grid.sum())}


def drone_json(drone: str, pos: Cell, status: str, cause: Cause, target: Cell | None) -> dict:
    """A drone as the page shows it, live or replayed."""
    return {"id": drone, "pos": list(pos), "status": status,
            "cause": None if cause is Cause.NONE else cause.value.lower(), "cause_text": CAUSE_TEXT.get(cause, ""),
            "target": None if target is None else list(target)}


def entry(turn: int, kind: str, text: str) -> dict:  # a line of the page's log
    return {"turn": turn, "kind": kind, "text": text}


def change_entry(turn: int, drone: str, status: str, cause: Cause, pos: Cell, target: Cell | None) -> dict:
    """The log's line for a drone that became `status` at `pos`."""
    where = fmt(pos)
    if status == DEAD:
        return entry(turn, "death", f"{drone} died at {where}: {CAUSE_TEXT.get(cause, cause.value)}")
    if status == LOST:
        return entry(turn, "lost", f"{drone} is LOST at {where}: {CAUSE_TEXT[Cause.LOST]}")
    if status == REACHED:
        return entry(turn, "reached", f"{drone} reached its target {where}")
    if status == UNREACHABLE:
        return entry(turn, "unreachable", f"{drone} reports its target {fmt(target)} unreachable; hovering at {where}")
    return entry(turn, "info", f"{drone} is on its way again from {where}")


def over_entry(turn: int, reason: str, text: str) -> dict:
    return entry(turn, "over", f"GAME OVER at turn {turn}: {reason}" + (f" - {text}" if text else ""))


@dataclass(frozen=True, slots=True)
class Refresh:
    """The state the page shows has changed: send it the new snapshot."""


class GroundState:
    """The live ground station's state around the protocol's `Station` (held: the page's pacing says when it
    answers). `intro` (the coordinator's welcome) starts the page's log. Times are seconds of any monotonic clock."""

    def __init__(self, ground: Ground, *, pace: float = WEB_PACE_S, title: str = "", intro: str = "") -> None:
        self.station = Station(ground, hold=True)
        self.world = ground.world
        self.title = title
        self.drones = {d: DroneStatus(drone=d, pos=c, state=DroneState.ALIVE) for d, c in sorted(ground.starts.items())}
        self.trails = {d: [c] for d, c in sorted(ground.starts.items())}  # each drone's cells, the last where it is
        self.turn = 0  # the turn in progress (the latest TURN seen)
        self.phase: str | None = None
        self.pending_since = 0.0
        self.last_answer: float | None = None
        self.pace = self._check_pace(pace)
        self.paused = self.step_requested = self.quit_requested = self.quit_sent = False
        self.log: deque[dict] = deque(maxlen=LOG_LIMIT)
        self.seq = 0  # bumped on every change the page should see
        self._shown = 0  # the `seq` the page was last sent
        if intro:
            self.note("info", f"{intro}; {self.describe()}")

    def describe(self) -> str:
        return (f"world {'x'.join(map(str, self.world.size))} with {int(self.world.grid.sum())} building cells; "
                f"drones {', '.join(self.drones)}")

    @property
    def wanted(self) -> dict[str, Cell]:
        return self.station.wanted

    @property
    def pending(self) -> int | None:
        return self.station.pending

    @property
    def status_turn(self) -> int:
        return self.station.status_turn

    @staticmethod
    def _check_pace(value: object) -> float:
        lo, hi = PACE_RANGE
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                if lo <= float(value) <= hi:
                    return float(value)
            except OverflowError:  # (an integer of hundreds of digits is no float)
                pass
        raise Rejected(f"pace must be a number of seconds in {lo:g}..{hi:g}, got {excerpt(repr(value))}", 400)

    def note(self, kind: str, text: str) -> None:
        """An event from outside the game's messages (connection, the human's commands...)."""
        self.log.append(entry(self.turn, kind, text))
        self.seq += 1

    def receive(self, msg: Message, now: float) -> list[Effect]:
        """A message from the coordinator (TURN of any phase, STATUS, OVER)."""
        effects: list[Effect] = []
        match msg:
            case Turn() if msg.turn >= self.turn:  # (an older phase is overtaken by a newer one)
                self.turn, self.phase = msg.turn, msg.phase.value
                was, before = self.pending, dict(self.wanted)
                effects = self.station.receive(msg, now)
                if self.pending is not None and self.pending != was:
                    self.pending_since = now
                self.log.extend(entry(self.turn, "target", f"scripted target of {d}: {fmt(c)}")
                                for d, c in self.wanted.items() if before.get(d) != c)
            case Status() if msg.turn >= self.status_turn:
                self._show_status(msg)
                effects = self.station.receive(msg, now)
            case Over() if self.station.over is None:
                effects = self.station.receive(msg, now)
                self.log.append(over_entry(msg.turn, msg.reason.value, msg.text))
            case _:
                return []
        self.seq += 1
        return effects

    def admitted(self, welcome: Welcome) -> list[Effect]:
        self.note("info", "the coordinator came back: connected again")
        return self.station.admitted(welcome)

    def _show_status(self, msg: Status) -> None:
        for s in msg.drones:  # (one not in our Welcome, which a correct coordinator never sends, is shown too)
            was = self.drones.get(s.drone)
            self.drones[s.drone] = s
            trail = self.trails.setdefault(s.drone, [s.pos])
            if trail[-1] != s.pos:
                trail.append(s.pos)
                del trail[:-TRAIL_LIMIT]
            if (status := view_of(s)) not in (ALIVE if was is None else view_of(was), ALIVE):
                self.log.append(change_entry(msg.turn, s.drone, status, s.cause, s.pos, s.target))

    def set_target(self, drone: object, cell: Cell) -> dict:
        """Checked: a known, alive drone, a cell inside the world and not a building's (the seed's correctForm)."""
        if self.station.over is not None:
            raise Rejected("the game is over: no more targets", 409)
        if not isinstance(drone, str) or not is_drone_id(drone):
            raise Rejected(f"{excerpt(repr(drone))} is not a drone id (like D01)", 400)
        view = self.drones.get(drone)
        if view is None:
            raise Rejected(f"unknown drone {drone}: this game flies {', '.join(self.drones)}")
        if not view.alive:
            raise Rejected(f"{drone} is {view_of(view)}: it takes no more targets")
        try:
            check_cell(cell, self.world.size, self.world)
        except UsageError as err:
            raise Rejected(str(err)) from None
        self.station.want({drone: cell})
        self.step_requested = False
        self.note("target", f"target of {drone} set to {fmt(cell)}")
        return {"ok": True, "text": f"target of {drone} set to {fmt(cell)}; sent at the next GCS phase"}

    def control(self, action: object, value: object = None) -> dict:
        """pause, resume, step, quit, or pace (with `value` seconds)."""
        if self.station.over is not None:
            raise Rejected("the game is over", 409)
        match action:
            case "pause" | "resume":
                self.paused = action == "pause"
                text = "paused: the ground station holds its phase" if self.paused else "resumed"
            case "step":
                self.step_requested = True
                text = "one turn"
            case "pace":
                self.pace = self._check_pace(value)
                text = f"one turn every {self.pace:g} s at most"
            case "quit":
                self.quit_requested = True
                text = "ending the game"
            case _:
                raise Rejected(f"unknown action {action!r}: use pause, resume, step, pace or quit", 400)
        self.note("control", text)
        return {"ok": True, "text": text}

    def busy(self) -> bool:
        """Whether turns must go on by themselves: a drone has a target it has not reached (or found
        unreachable), or a scripted target is still to come."""
        if self.pending is not None and self.station.plan.last_turn >= self.pending:
            return True
        views = ((self.drones.get(d), cell) for d, cell in self.wanted.items())
        return any(v is not None and v.alive and (v.target != cell or view_of(v) == ALIVE) for v, cell in views)

    def waiting(self) -> tuple[str, str]:
        """(code, text) of what the game is waiting for, for the page."""
        if self.station.over is not None:
            return "over", f"game over: {self.station.over.reason.value}"
        if self.quit_requested:
            return "quitting", "ending the game at the next GCS phase"
        if self.turn == 0:
            return "starting", "waiting for every entity to connect"
        if self.paused:
            return "paused", "paused: press Resume or Step"
        if not any(v.alive for v in self.drones.values()):
            return "idle", "no drone alive"
        if self.pending is not None and not self.busy():
            if not any(d in self.wanted for d, v in self.drones.items() if v.alive):
                return "target", "waiting for a first target: pick a drone, then click a cell"
            return "idle", "every drone is at its target (or reports it unreachable): set a new target or quit"
        return "running", f"running, one turn every {self.pace:g} s at most"

    def due(self, now: float) -> float | None:
        """Seconds until the pending GCS phase should be answered (0: now), or None: held, no timer."""
        if self.pending is None or self.station.over is not None or self.quit_sent:
            return None
        if self.quit_requested or self.step_requested:
            return 0.0
        if self.paused or not self.busy():
            return None
        wait = 0.0 if self.last_answer is None else self.last_answer + self.pace - now
        if self.status_turn < self.pending - 1:  # its STATUS is on the way (another key): decide on it
            wait = max(wait, self.pending_since + STATUS_GRACE - now)
        return max(0.0, wait)

    def wake(self, now: float) -> float | None:  # (as Station.wake)
        return min((w for w in (self.due(now), self.station.wake(now)) if w is not None), default=None)

    def tick(self, now: float) -> list[Effect | Refresh]:
        """What is due at `now`: the pending phase's answer, the end, the page's new state."""
        effects: list[Effect | Refresh] = [*self.answer(now)] if self.due(now) == 0.0 else []
        effects += self.station.tick(now)
        if self.seq != self._shown:
            self._shown = self.seq
            effects.append(Refresh())
        return effects

    def answer(self, now: float) -> list[Effect]:
        """Answer the pending phase (call when `due` says 0): the DONE to send."""
        assert self.pending is not None
        self.last_answer, self.step_requested, self.quit_sent = now, False, self.quit_requested
        self.seq += 1
        return self.station.answer(self.pending, Intent.QUIT if self.quit_requested else Intent.CONTINUE)

    def snapshot(self) -> dict:
        code, text = self.waiting()
        drones = [{**drone_json(d, s.pos, view_of(s), s.cause, s.target),
                   "wanted": None if (wanted := self.wanted.get(d)) is None else list(wanted),
                   "trail": [list(c) for c in self.trails[d]]} for d, s in self.drones.items()]
        end = self.station.over
        over = None if end is None else {"turn": end.turn, "reason": end.reason.value, "text": end.text}
        return {"mode": "live", "seq": self.seq, "turn": self.turn, "phase": self.phase,
                "status_turn": max(self.status_turn, 0), "drones": drones, "log": list(self.log), "over": over,
                "control": {"paused": self.paused, "pace": self.pace, "waiting": code, "text": text,
                            "pending": self.pending}}


def check_pace_arg(value: float) -> float:
    """The --pace flag (a UsageError, not an HTTP refusal)."""
    try:
        return GroundState._check_pace(value)
    except Rejected as err:
        raise UsageError(err.text) from None
