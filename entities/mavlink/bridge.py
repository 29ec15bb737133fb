"""The MAVLink ground station's core, pure: the fleet of `Vehicle`s around the ground station's protocol
(`entities.gcs.Station`, held as the web page holds it). It plays `station_link.play`'s `Core` (the game's
TURN, STATUS and OVER) and takes the clients' decoded messages (`packet`), and returns effects: MAVLink messages
to send (`Mav`), the station's DONE (`SendDone`), refusals. Times are seconds of any monotonic clock.

- Dispatch: a message for system n goes to vehicle n; on vehicle n's API port, system 0 means n and any other
  system is refused; on the ground station's shared link, a command must name its system.
- Pacing: the GCS phase is answered `period` seconds after the last one (the game's pace for people), with the
  targets the vehicles asked for since; the game never waits for a client.
- Telemetry: every STATUS brings the position of each vehicle whose row changed (moved, reached, died); the
  whole set, every vehicle's, goes every `telemetry_period`.
- A flood: each vehicle takes at most `COMMANDS_PER_TURN` commands a turn; the rest are DENIED, counted.
- Uploads: a mission upload left waiting `UPLOAD_TIMEOUT_S` for its next item is dropped (its uploader gone),
  at the next `tick` or message for that vehicle."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from schema import Cell, Intent, Message, Over, Status, Turn, Welcome
from schema.errors import Refusal, RemoteInputError, UnknownEntity
from schema.tables import drone_number
from schema.tuning import STATUS_GRACE

from ..gcs import Ground, Station
from .geo import Geo
from .vehicle import UPLOAD_TIMEOUT_S, Goal, Mav, Origin, Vehicle, ack

#: MAVLink's largest system id: drones past D255 fly on, not MAVLink vehicles (their targets from elsewhere).
MAX_SYSTEM = 255
#: Commands (COMMAND_*, SET_MODE, SET_POSITION_TARGET_*) a vehicle takes a turn; more are DENIED.
COMMANDS_PER_TURN = 32
COMMANDS = frozenset({"COMMAND_LONG", "COMMAND_INT", "SET_MODE", "SET_POSITION_TARGET_LOCAL_NED",
                      "SET_POSITION_TARGET_GLOBAL_INT"})
#: Messages a vehicle answers or acts on (others -- heartbeats, stream requests... -- are ignored).
HANDLED = COMMANDS | {"MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_LIST",
                      "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
                      "MISSION_ACK", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"}


class Bridge:
    """The fleet of a game (`ground`: its world and starts) as MAVLink systems 1..n (drone Dnn is system n)."""

    def __init__(self, ground: Ground, geo: Geo, *, period: float, telemetry_period: float, now: float) -> None:
        self.station = Station(ground, hold=True)
        self.vehicles = {drone_number(d): Vehicle(drone_number(d), d, c, ground.world, geo, self.held)
                         for d, c in sorted(ground.starts.items()) if drone_number(d) <= MAX_SYSTEM}
        self.unseen = len(ground.starts) - len(self.vehicles)  # drones beyond D255: no system id for them
        self.period, self.telemetry_period, self.boot = period, telemetry_period, now
        self.last_answer: float | None = None
        self.pending_since = 0.0
        self.next_telemetry = now
        self.commands = dict.fromkeys(self.vehicles, 0)  # commands taken this turn, by vehicle
        self._rows: np.ndarray | None = None  # the last STATUS's rows
        self.ignored: Counter[str] = Counter()  # messages of kinds no vehicle acts on (heartbeats...), by kind
        self.uploading: set[int] = set()  # the systems with a mission upload under way
        self.now = now  # the latest time given (`packet`'s, when none is)
        self.quit = False

    def held(self, cell: Cell) -> bool:
        """Is an alive drone in `cell` now (the last STATUS's positions; asked by a landing, not every turn)."""
        return any(v.pos == cell and v.alive for v in self.vehicles.values())

    def ms(self, now: float) -> int:
        return int((now - self.boot) * 1000) & 0xFFFFFFFF

    # ------------------------------------------------------------------ the game (station_link.Core)

    def admitted(self, welcome: Welcome) -> Sequence[object]:
        return self.station.admitted(welcome)

    def receive(self, msg: Message, now: float) -> Sequence[object]:
        self.now = max(self.now, now)
        effects: list[Any] = []
        match msg:
            case Turn():
                was = self.station.pending
                effects = self.station.receive(msg, now)
                if self.station.pending is not None and self.station.pending != was:
                    self.pending_since = now
            case Status() if msg.turn >= self.station.status_turn:
                effects = self._status(msg, now) + self.station.receive(msg, now)
            case Over() if self.station.over is None:
                effects = [e for v in self.vehicles.values() for e in v.over(f"{msg.reason.value} {msg.text}")]
                effects += self.station.receive(msg, now)
        return effects

    def _status(self, status: Status, now: float) -> list[Any]:
        """Each vehicle whose row changed (it moved, reached, died...) takes its row and sends its position;
        the others' rows are as before (a swarm's hovering drones cost nothing a turn)."""
        effects: list[Any] = []
        ms = self.ms(now)
        table, last = status.drones, self._rows
        rows = table.rows
        if last is not None and last.dtype == rows.dtype and len(last) == len(rows) \
                and np.array_equal(last["drone"], rows["drone"]):
            changed: list[int] = np.flatnonzero(rows != last).tolist()
        else:
            changed = list(range(len(rows)))
        self._rows = rows
        records = table.records() if len(changed) > 1 else ()  # (built together: far cheaper than one by one)
        for i in changed:
            row = records[i] if records else table[i]
            v = self.vehicles.get(drone_number(row.drone))
            if v is None:
                continue
            events = v.observe(row)  # (first: it takes the row's position)
            effects += [Mav(v.system, m) for m in v.positions(ms)]
            effects += events
        self.commands = dict.fromkeys(self.vehicles, 0)
        return self._goals(effects)

    def _goals(self, effects: list[Any]) -> list[Any]:
        """The vehicles' `Goal`s become the station's targets (sent at its next phase); the rest stays."""
        goals = {e.drone: e.cell for e in effects if isinstance(e, Goal)}
        if goals:
            self.station.want(goals)
        return [e for e in effects if not isinstance(e, Goal)]

    def due(self, now: float) -> float | None:
        """Seconds until the pending GCS phase is answered (None: none pending)."""
        station = self.station
        if station.pending is None or station.over is not None:
            return None
        wait = 0.0 if self.last_answer is None or self.quit else self.last_answer + self.period - now
        if station.status_turn < station.pending - 1:  # its STATUS is on the way: decide on it
            wait = max(wait, self.pending_since + STATUS_GRACE - now)
        return max(0.0, wait)

    def wake(self, now: float) -> float | None:
        waits = [w for w in (self.due(now), self.station.wake(now)) if w is not None]
        if self.station.over is None:
            waits.append(max(0.0, self.next_telemetry - now))
        uploads = (self.vehicles[n].upload for n in self.uploading)
        waits += [max(0.0, up.last + UPLOAD_TIMEOUT_S - now) for up in uploads if up is not None]
        return min(waits, default=None)

    def tick(self, now: float) -> Sequence[object]:
        self.now = max(self.now, now)
        effects: list[Any] = []
        if self.uploading:  # (uploads left waiting too long: dropped)
            effects += [e for n in sorted(self.uploading) for e in self.vehicles[n].expire(now)]
            self.uploading = {n for n in self.uploading if self.vehicles[n].upload is not None}
        if self.station.over is None and now >= self.next_telemetry:
            self.next_telemetry = now + self.telemetry_period
            ms = self.ms(now)
            effects += [Mav(v.system, m) for v in self.vehicles.values() for m in v.telemetry(ms)]
        if self.due(now) == 0.0:
            assert self.station.pending is not None
            self.last_answer = now
            effects += self.station.answer(self.station.pending, Intent.QUIT if self.quit else Intent.CONTINUE)
        return effects + self.station.tick(now)

    # ------------------------------------------------------------------ the clients

    def packet(self, origin: Origin, messages: Sequence[Any], now: float | None = None) -> list[Any]:
        """The messages of one datagram, decoded (MAVLink 2), that came from `origin` at `now` (None: the
        latest time the bridge was given)."""
        if now is not None:
            self.now = max(self.now, now)
        effects: list[Any] = []
        for msg in messages:
            effects += self._message(origin, msg, self.now)
        return self._goals(effects)

    def _message(self, origin: Origin, msg: Any, now: float) -> list[Any]:
        kind = msg.get_type()
        if kind not in HANDLED:
            self.ignored[kind] += 1  # (the kinds pymavlink knows: a bounded set; unknown ids are refused before)
            return []
        system = msg.target_system
        if origin.port:  # a vehicle's own API port
            if system not in (0, origin.port):
                return [_refuse(f"{kind} on system {origin.port}'s port", UnknownEntity(
                    f"a message for system {system} on the port of system {origin.port}", reason="mavlink-target"))]
            system = origin.port
        if system not in self.vehicles:
            why = "names no system (0): commands on the shared link name one" if system == 0 else \
                f"is for system {system}, which this game does not fly (1..{max(self.vehicles)})"
            return [_refuse(f"{kind} from {origin.addr}", UnknownEntity(f"a {kind} that {why}",
                                                                        reason="mavlink-target"))]
        vehicle = self.vehicles[system]
        if self.station.over is not None:
            return [*_denied(vehicle, msg, origin, mav.MAV_RESULT_DENIED),
                    _refuse(f"{kind} for {vehicle.drone}", RemoteInputError("the game is over", reason="mavlink-over"))]
        if kind in COMMANDS:
            self.commands[system] += 1
            if self.commands[system] > COMMANDS_PER_TURN:
                return [*_denied(vehicle, msg, origin, mav.MAV_RESULT_TEMPORARILY_REJECTED),
                        _refuse(f"{kind} for {vehicle.drone}", RemoteInputError(
                            f"more than {COMMANDS_PER_TURN} commands in one turn", reason="mavlink-flood"))]
        effects = vehicle.handle(msg, origin, now)
        if vehicle.upload is not None:
            self.uploading.add(system)
        return effects


def _refuse(what: str, err: RemoteInputError) -> Refusal:
    return Refusal(what, err)


def _denied(vehicle: Vehicle, msg: Any, origin: Origin, result: int) -> list[Mav]:
    """A command's COMMAND_ACK with `result` (other messages get none: their refusal is counted)."""
    if msg.get_type() not in ("COMMAND_LONG", "COMMAND_INT"):
        return []
    return [Mav(vehicle.system, ack(msg.command, result, msg), origin)]
