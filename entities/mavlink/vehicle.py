"""One drone as a MAVLink vehicle, pure: an ArduPilot copter's arming, modes, commands (each answered by
COMMAND_ACK) and mission protocol, driven by decoded pymavlink messages and by the game's STATUS rows. It
returns effects: MAVLink messages to send (`Mav`), the target it wants the ground station to set (`Goal`),
and the input it refused (`schema.errors.Refusal`, counted by the adapter). docs/mavlink.md says what each
command does in the game.

What the vehicle flies to (its *goal*, a cell) follows from its mode, decided when something happens:
a disarmed drone holds its cell; GUIDED holds until given a position (DO_REPOSITION, SET_POSITION_TARGET_*,
takeoff); LOITER holds; RTL goes to its start cell; LAND to the lowest free cell below it (then disarms);
AUTO flies the mission's items in order, item 0 being home as ArduPilot's missions have it."""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from schema import Cause, Cell, DroneState, DroneStatus, Note, UsageError
from schema.errors import OutOfRange, Refusal, RemoteInputError, WrongSender
from world.grid import World

from ..gcs import check_cell
from .geo import BadPosition, Geo

Msg = Any  # a pymavlink message (pymavlink's classes are untyped for mypy's purposes)


class Mode(enum.IntEnum):
    """ArduCopter's mode numbers (HEARTBEAT.custom_mode) of the modes a vehicle flies."""

    AUTO = 3
    GUIDED = 4
    LOITER = 5
    RTL = 6
    LAND = 9


#: The most items a mission holds (a longer upload is answered MAV_MISSION_NO_SPACE, the mission kept).
MISSION_LIMIT = 1000
#: A takeoff without an altitude climbs this many metres.
TAKEOFF_DEFAULT_M = 2.5
#: STATUSTEXT carries 50 characters; a longer text goes in chunks (MAVLink 2's id and chunk_seq).
TEXT_CHUNK = 50
#: The first mission item flown (item 0 is home, as in ArduPilot's missions).
FIRST_ITEM = 1
#: Seconds an upload waits for its next item before it is dropped (MISSION_ACK OPERATION_CANCELLED to the
#: uploader), as ArduPilot's (upload_timeout_ms): a client gone mid-upload does not hold the vehicle's uploads.
UPLOAD_TIMEOUT_S = 8.0
#: MISSION_ITEM(_INT)'s `current` of ArduPilot's guided goto (never an item of an upload).
GUIDED_GOTO = 2

NAV_ITEMS = frozenset({mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LAND,
                       mav.MAV_CMD_NAV_RETURN_TO_LAUNCH})
#: Frames of a position: above mean sea level, above home, local NED from cell (0,0,0), offsets from the drone.
AMSL_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT})
RELATIVE_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                             mav.MAV_FRAME_GLOBAL_TERRAIN_ALT, mav.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT})
OFFSET_FRAMES = frozenset({mav.MAV_FRAME_LOCAL_OFFSET_NED, mav.MAV_FRAME_BODY_NED, mav.MAV_FRAME_BODY_OFFSET_NED,
                           mav.MAV_FRAME_BODY_FRD})
#: The vehicle's one parameter (ArduPilot's name of the system id), read-only.
PARAMETER = "SYSID_THISMAV"
POSITION_IGNORED = 0b111  # SET_POSITION_TARGET_*'s type_mask: x, y, z ignored
INT32_MAX = (1 << 31) - 1


@dataclass(frozen=True, slots=True)
class Origin:
    """Where a message came from and its answer goes: `port` 0 is the ground station's link, n vehicle n's API
    port; `addr` the peer's (host, port)."""

    port: int
    addr: tuple[str, int]


@dataclass(frozen=True, slots=True)
class Mav:
    """Send `msg` as vehicle `system` to `to` (None: to every destination of its telemetry)."""

    system: int
    msg: Msg
    to: Origin | None = None


@dataclass(frozen=True, slots=True)
class Goal:
    """The target this vehicle wants for its drone (the ground station sets it at its next phase)."""

    drone: str
    cell: Cell


Effect = Mav | Goal | Refusal


class Denied(Exception):
    """A command or target refused: `result` is the COMMAND_ACK's (DENIED, UNSUPPORTED...), the text says why."""

    def __init__(self, text: str, result: int = mav.MAV_RESULT_DENIED, mission: int = mav.MAV_MISSION_DENIED) -> None:
        super().__init__(text)
        self.text, self.result, self.mission = text, result, mission


@dataclass(frozen=True, slots=True)
class Item:
    """A mission item as uploaded (given back as it came on download)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    params: tuple[float, float, float, float]
    x: int  # latitude (degrees * 1e7), or local x (metres * 1e4) in a local frame (as MISSION_ITEM_INT's)
    y: int
    z: float


@dataclass(slots=True)
class Upload:
    """A mission upload under way: `count` items expected, `items` so far, from `origin` and the MAVLink
    `sender` (system, component) that sent the MISSION_COUNT (its items alone are taken), which last moved it
    (the count, an item taken) at `last` (seconds of the caller's clock)."""

    count: int
    items: list[Item]
    origin: Origin
    sender: tuple[int, int]
    last: float

    def by(self, msg: Msg, origin: Origin) -> bool:
        """Does `msg` (from `origin`) come from the uploader?"""
        return origin == self.origin and sender_of(msg) == self.sender


def item_of(msg: Msg) -> Item:
    """A MISSION_ITEM_INT or MISSION_ITEM (floats: scaled as MISSION_ITEM_INT's integers) as an `Item`."""
    x, y = msg.x, msg.y
    if msg.get_type() == "MISSION_ITEM":
        if not (math.isfinite(x) and math.isfinite(y)):
            raise Denied(f"mission item {msg.seq}: position not a number", mission=mav.MAV_MISSION_INVALID_PARAM5_X)
        scale = 1e7 if msg.frame in AMSL_FRAMES | RELATIVE_FRAMES else 1e4
        if max(abs(x), abs(y)) * scale > INT32_MAX:
            raise Denied(f"mission item {msg.seq}: position out of range", mission=mav.MAV_MISSION_INVALID_PARAM5_X)
        x, y = round(x * scale), round(y * scale)
    return Item(msg.seq, msg.frame, msg.command, msg.current, msg.autocontinue,
                (msg.param1, msg.param2, msg.param3, msg.param4), x, y, msg.z)


def text_messages(severity: int, text: str, chunk_id: int) -> list[Msg]:
    """STATUSTEXT(s) of `text`: one if it fits, else chunks sharing `chunk_id` (MAVLink 2)."""
    data = text.encode("ascii", "replace")
    if len(data) <= TEXT_CHUNK:
        return [mav.MAVLink_statustext_message(severity, data)]
    chunks = [data[i:i + TEXT_CHUNK] for i in range(0, len(data), TEXT_CHUNK)]
    return [mav.MAVLink_statustext_message(severity, c, chunk_id, i) for i, c in enumerate(chunks)]


class Vehicle:
    """Drone `drone` as MAVLink system `system` (component 1). `pos`, `state` and the rest follow the STATUS
    rows it is given (`observe`); `goal` is what it asked the ground station for last. `held(cell)`: is that
    cell another drone's now (a landing stops above it)."""

    def __init__(self, system: int, drone: str, home: Cell, world: World, geo: Geo,
                 held: Callable[[Cell], bool] = lambda cell: False) -> None:
        self.system, self.drone, self.home, self.world, self.geo, self.held = system, drone, home, world, geo, held
        self.pos: Cell = home
        self.state, self.cause, self.note = DroneState.ALIVE, Cause.NONE, Note.NONE
        self.target: Cell | None = None  # the target in force (the last STATUS's)
        self.armed = False
        self.mode = Mode.LOITER
        self.goal: Cell | None = None  # what this vehicle wants flown to (None: nothing asked yet)
        self.mission: list[Item] = []
        self.current = FIRST_ITEM  # the mission item flown (or to fly) in AUTO
        self.upload: Upload | None = None  # a mission upload under way
        self._reported: tuple[Cell | None, Note] = (None, Note.NONE)  # the (target, note) last said in a STATUSTEXT
        self._chunk = 0

    # ------------------------------------------------------------------ what the game says

    @property
    def alive(self) -> bool:
        return self.state is DroneState.ALIVE

    def observe(self, row: DroneStatus) -> list[Effect]:
        """The drone's row of a STATUS: its events as STATUSTEXT, a mission's progress; a HEARTBEAT at once if
        what it says changed (armed, mode, state)."""
        said = self._said()
        return self._beat(said, self._observe(row))

    def _said(self) -> tuple[Mode, bool, int]:
        return self.mode, self.armed, self.system_status()

    def _beat(self, said: tuple[Mode, bool, int], effects: list[Effect]) -> list[Effect]:
        """`effects`, and a HEARTBEAT if what one says changed since `said`: ground stations see an arming, a
        mode, a death at once, not at the next telemetry set."""
        return [*effects, Mav(self.system, self.heartbeat())] if self._said() != said else effects

    def _observe(self, row: DroneStatus) -> list[Effect]:
        was_alive = self.alive
        self.pos, self.state, self.cause, self.note, self.target = row.pos, row.state, row.cause, row.note, row.target
        if not self.alive:
            if not was_alive:
                return []
            self.upload = None
            what = "is LOST (missed its deadlines)" if self.state is DroneState.LOST else \
                f"died at {self.pos}: {self.cause.value.lower()}"
            return self.say(mav.MAV_SEVERITY_EMERGENCY, f"{self.drone} {what}")
        if self.goal is None or self.target != self.goal or (self.target, self.note) == self._reported:
            return []
        self._reported = (self.target, self.note)
        if self.note is Note.REACHED:
            return self._reached()
        if self.note is Note.UNREACHABLE:
            effects = self.say(mav.MAV_SEVERITY_CRITICAL, f"{self.drone}: target {self.goal} unreachable, holding")
            if self.mode is Mode.AUTO and self.armed:  # the mission goes on with its next item
                effects += self._next_item(self.current + 1)
            return effects
        return []

    def _reached(self) -> list[Effect]:
        effects = self.say(mav.MAV_SEVERITY_INFO, f"{self.drone} reached {self.goal}")
        if not self.armed:
            return effects
        if self.mode is Mode.AUTO and self.current < len(self.mission):
            return effects + self._fly(self.current, reached=True)
        return effects + (self._landed() if self.mode is Mode.LAND else [])

    def _landed(self) -> list[Effect]:
        """On the ground at the end of a landing: disarmed."""
        if not self._on_ground():
            return []
        self.armed = False
        return self.say(mav.MAV_SEVERITY_INFO, f"{self.drone} landed: disarmed")

    def over(self, text: str) -> list[Effect]:
        return self.say(mav.MAV_SEVERITY_NOTICE, f"game over: {text}")

    def say(self, severity: int, text: str) -> list[Effect]:
        self._chunk = self._chunk % 65535 + 1
        return [Mav(self.system, m) for m in text_messages(severity, text, self._chunk)]

    # ------------------------------------------------------------------ what a client says

    def handle(self, msg: Msg, origin: Origin, now: float) -> list[Effect]:
        """A message addressed to this vehicle (its target system checked by the caller), at `now` (seconds of
        the caller's monotonic clock: an upload left waiting `UPLOAD_TIMEOUT_S` is dropped first)."""
        said = self._said()
        effects = self.expire(now)
        return self._beat(said, effects + self._handle(msg, origin, now))

    def expire(self, now: float) -> list[Effect]:
        """Drop an upload that has waited `UPLOAD_TIMEOUT_S` for its next item, as ArduPilot does: MISSION_ACK
        OPERATION_CANCELLED to its uploader, said and counted; the mission in force is kept."""
        up = self.upload
        if up is None or now < up.last + UPLOAD_TIMEOUT_S:
            return []
        self.upload = None
        text = f"{self.drone}: mission upload cancelled: no item {len(up.items)} in {UPLOAD_TIMEOUT_S:g} s"
        err = RemoteInputError(text, reason="mavlink-timeout")
        return [Refusal(f"{self.drone} mission upload from {up.origin.addr}", err),
                *self.say(mav.MAV_SEVERITY_WARNING, text),
                *self._mission_ack(up.origin, mav.MAV_MISSION_OPERATION_CANCELLED)]

    def _handle(self, msg: Msg, origin: Origin, now: float) -> list[Effect]:
        kind = msg.get_type()
        try:
            match kind:
                case "COMMAND_LONG" | "COMMAND_INT":
                    return self._command(msg, origin)
                case "SET_MODE":
                    return self._ack(11, msg, origin, self._set_mode(msg.base_mode, msg.custom_mode))  # (its id)
                case "SET_POSITION_TARGET_LOCAL_NED" | "SET_POSITION_TARGET_GLOBAL_INT":
                    return self._position_target(msg)
                case "MISSION_COUNT" | "MISSION_ITEM_INT" | "MISSION_ITEM" | "MISSION_REQUEST_LIST" | \
                        "MISSION_REQUEST_INT" | "MISSION_REQUEST" | "MISSION_CLEAR_ALL" | "MISSION_SET_CURRENT" | \
                        "MISSION_ACK":
                    return self._mission(kind, msg, origin, now)
                case "PARAM_REQUEST_LIST" | "PARAM_REQUEST_READ" | "PARAM_SET":
                    return self._parameter(kind, msg, origin)
        except Denied as err:  # (a message without an answer of its own: said in a STATUSTEXT)
            return [*self._refused(kind, err), *self.say(mav.MAV_SEVERITY_WARNING, f"{self.drone}: {err.text}")]
        return []

    def _refused(self, what: str, err: Denied) -> list[Effect]:
        return [Refusal(f"{self.drone} {what}", OutOfRange(err.text, reason="mavlink-denied"))]

    def _ack(self, command: int, msg: Msg, origin: Origin, effects: list[Effect],
             result: int = mav.MAV_RESULT_ACCEPTED) -> list[Effect]:
        return [Mav(self.system, ack(command, result, msg), origin), *effects]

    def _command(self, msg: Msg, origin: Origin) -> list[Effect]:
        cmd = msg.command
        try:
            if not self.alive and cmd not in (mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
                raise Denied(f"{self.drone} is {self.state.value.lower()}: it takes no more commands")
            effects = self._run(cmd, msg)
        except Denied as err:
            said = self.say(mav.MAV_SEVERITY_WARNING, f"{self.drone}: {err.text}")
            return self._ack(cmd, msg, origin, [*self._refused(f"command {cmd}", err), *said], err.result)
        return self._ack(cmd, msg, origin, effects)

    def _run(self, cmd: int, msg: Msg) -> list[Effect]:
        p = (msg.param1, msg.param2, msg.param3, msg.param4)
        match cmd:
            case mav.MAV_CMD_COMPONENT_ARM_DISARM:
                if p[0] not in (0.0, 1.0):  # (NaN, 1e20, -1...: no meaning, not a disarm)
                    raise Denied(f"COMPONENT_ARM_DISARM param1 {p[0]:g}: 1 arms, 0 disarms")
                return self._arm(p[0] == 1)
            case mav.MAV_CMD_DO_SET_MODE:
                return self._set_mode(p[0], p[1])
            case mav.MAV_CMD_NAV_TAKEOFF:
                return self._takeoff(self._param7(msg))
            case mav.MAV_CMD_NAV_LAND:
                return self._enter(Mode.LAND)
            case mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                return self._enter(Mode.RTL)
            case mav.MAV_CMD_NAV_LOITER_UNLIM:
                return self._enter(Mode.LOITER)
            case mav.MAV_CMD_DO_REPOSITION:
                if self.mode is not Mode.GUIDED and not whole(p[1]) & mav.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE:
                    raise Denied("DO_REPOSITION outside GUIDED without its change-mode flag")
                cell = self._command_position(msg)
                self._require_armed()
                return self._enter(Mode.GUIDED, cell)
            case mav.MAV_CMD_MISSION_START:
                self._require_armed()
                if len(self.mission) <= FIRST_ITEM:
                    raise Denied("no mission to start")
                first = int(p[0]) if FIRST_ITEM <= p[0] < len(self.mission) else self.current
                self.current = min(max(first, FIRST_ITEM), len(self.mission) - 1)
                return self._enter(Mode.AUTO)
            case mav.MAV_CMD_DO_SET_MISSION_CURRENT:
                return self._set_current(whole(p[0]))
            case mav.MAV_CMD_REQUEST_MESSAGE:
                return self._requested(whole(p[0]))
            case mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
                return [Mav(self.system, self.autopilot_version())]
        raise Denied(f"command {cmd} is not supported", mav.MAV_RESULT_UNSUPPORTED)

    @staticmethod
    def _param7(msg: Msg) -> float:
        return msg.z if msg.get_type() == "COMMAND_INT" else msg.param7

    def _requested(self, msgid: int) -> list[Effect]:
        if msgid == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return [Mav(self.system, self.autopilot_version())]
        if msgid == mav.MAVLINK_MSG_ID_HOME_POSITION:
            return [Mav(self.system, self.home_position())]
        raise Denied(f"message {msgid} is not given on request", mav.MAV_RESULT_UNSUPPORTED)

    def _require_armed(self) -> None:
        if not self.armed:
            raise Denied("disarmed: arm first (a disarmed drone holds its cell)")

    def _arm(self, arm: bool) -> list[Effect]:
        if arm == self.armed:
            return []  # (idempotent, as the command protocol asks)
        self.armed = arm
        if not arm:
            return self._aim(self.pos)
        return self._enter(self.mode) if self.mode in (Mode.AUTO, Mode.RTL, Mode.LAND) else []

    def _set_mode(self, base: float, custom: float) -> list[Effect]:
        if not whole(base, 0) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            raise Denied("only custom (ArduCopter) mode numbers are taken", mav.MAV_RESULT_UNSUPPORTED)
        try:
            mode = Mode(whole(custom))
        except ValueError:
            names = ", ".join(f"{m.name} {m.value}" for m in Mode)
            raise Denied(f"mode {custom:g} is not flown here: {names}") from None
        if mode is Mode.AUTO and len(self.mission) <= FIRST_ITEM:
            raise Denied("AUTO needs a mission")
        return self._enter(mode) if mode is not self.mode else []

    def _enter(self, mode: Mode, cell: Cell | None = None) -> list[Effect]:
        """Fly `mode` (in GUIDED, to `cell` if given): its goal, if armed (the new mode's HEARTBEAT: `handle`'s)."""
        self.mode = mode
        effects: list[Effect] = []
        if not self.armed:
            return effects
        match mode:
            case Mode.GUIDED | Mode.LOITER:
                effects += self._aim(cell or self.pos)
            case Mode.RTL:
                effects += self._aim(self.home)
            case Mode.LAND:
                effects += self._aim(self._ground_below(self.pos))
            case Mode.AUTO:
                effects += self._next_item(self.current)
        return effects

    def _takeoff(self, metres: float) -> list[Effect]:
        self._require_armed()
        metres = TAKEOFF_DEFAULT_M if math.isnan(metres) else metres
        try:
            z = self.geo.floor_of(self.geo.amsl(self.home[2]) + metres)
        except BadPosition as err:
            raise Denied(f"takeoff altitude {metres}: {err}") from None
        return self._enter(Mode.GUIDED, self._checked((self.pos[0], self.pos[1], max(z, self.pos[2]))))

    def _aim(self, cell: Cell) -> list[Effect]:
        if cell == self.goal:
            return []
        self.goal, self._reported = cell, (None, Note.NONE)
        return [Goal(self.drone, cell)]

    def _checked(self, cell: Cell) -> Cell:
        try:
            return check_cell(cell, self.world.size, self.world)
        except UsageError as err:
            raise Denied(f"target refused: {err}") from None

    def _on_ground(self, cell: Cell | None = None) -> bool:
        x, y, z = cell or self.pos
        return z == 0 or self.world.is_building((x, y, z - 1))

    def _ground_below(self, cell: Cell) -> Cell:
        """The lowest free cell below `cell`: above the ground, a roof, or a drone there now."""
        x, y, z = cell
        while z > 0 and not self.world.is_building((x, y, z - 1)) and not self.held((x, y, z - 1)):
            z -= 1
        return (x, y, z)

    # ------------------------------------------------------------------ positions

    def position(self, frame: int, x: float, y: float, z: float, *, scaled: bool) -> Cell:
        """The cell of a position in `frame` (if `scaled`, as MISSION_ITEM_INT and COMMAND_INT carry it: latitude
        and longitude in degrees * 1e7, local x and y in metres * 1e4), checked against the world (`Denied` if
        outside, in a building, or not a number)."""
        return self._checked(self._cell(frame, x, y, z, scaled=scaled))

    def _column(self, frame: int, x: float, y: float) -> tuple[int, int]:
        """The (x, y) of a position in `frame` (as MISSION_ITEM_INT carries it) whatever its altitude (a landing
        there: the altitude is the drone's when it flies it), checked to be inside the world (`Denied` if not)."""
        cx, cy, _ = self._cell(frame, x, y, self._altitude_here(frame), scaled=True)
        try:
            check_cell((cx, cy, 0), self.world.size)  # (on the ground: a roof's column is a landing's too)
        except UsageError as err:
            raise Denied(f"target refused: {err}") from None
        return cx, cy

    def _cell(self, frame: int, x: float, y: float, z: float, *, scaled: bool) -> Cell:
        """The cell of a position in `frame`, not checked against the world (`Denied` if not a number, of a
        frame not supported, or beyond any world)."""
        try:
            if frame in AMSL_FRAMES | RELATIVE_FRAMES:
                lat, lon = (x / 1e7, y / 1e7) if scaled else (x, y)
                alt = z + (self.geo.amsl(self.home[2]) if frame in RELATIVE_FRAMES else 0.0)
                cell = self.geo.cell_of_wgs84(lat, lon, alt)
            elif scaled:
                return self._cell(frame, x / 1e4, y / 1e4, z, scaled=False)
            elif frame == mav.MAV_FRAME_LOCAL_NED:
                cell = self.geo.cell_of_ned(x, y, z)
            elif frame in OFFSET_FRAMES:  # (the drone's yaw is 0: its body frame is NED)
                north, east, down = self.geo.ned(self.pos)
                cell = self.geo.cell_of_ned(north + x, east + y, down + z)
            else:
                raise Denied(f"frame {frame} is not supported", mav.MAV_RESULT_UNSUPPORTED,
                             mav.MAV_MISSION_UNSUPPORTED_FRAME)
        except BadPosition as err:
            raise Denied(f"target refused: {err}", mission=mav.MAV_MISSION_INVALID_PARAM5_X) from None
        return cell

    def _command_position(self, msg: Msg) -> Cell:
        """DO_REPOSITION's position: COMMAND_INT's in its frame, COMMAND_LONG's above home (as ArduPilot takes
        it); a latitude/longitude left out (NaN, or INT32_MAX in COMMAND_INT) keeps the drone's, so does an
        altitude left out."""
        here = self.geo.wgs84(self.pos)
        if msg.get_type() == "COMMAND_INT":
            frame, x, y, z, scaled = msg.frame, msg.x, msg.y, msg.z, True
            if x == INT32_MAX or y == INT32_MAX:
                x, y = round(here[0] * 1e7), round(here[1] * 1e7)
        else:
            frame, x, y, z, scaled = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT, msg.param5, msg.param6, msg.param7, False
            if math.isnan(x) or math.isnan(y):
                x, y = here[0], here[1]
        if isinstance(z, float) and math.isnan(z):
            frame = frame if frame in AMSL_FRAMES | RELATIVE_FRAMES else mav.MAV_FRAME_GLOBAL
            z = here[2] - (self.geo.amsl(self.home[2]) if frame in RELATIVE_FRAMES else 0.0)
        return self.position(frame, x, y, z, scaled=scaled)

    def _position_target(self, msg: Msg) -> list[Effect]:
        mask = msg.type_mask & POSITION_IGNORED
        if mask == POSITION_IGNORED:
            raise Denied("velocity, acceleration and attitude targets are not flown: give a position",
                         mav.MAV_RESULT_UNSUPPORTED)
        if not self.alive:
            raise Denied(f"{self.drone} is {self.state.value.lower()}: it takes no more targets")
        if self.mode is not Mode.GUIDED:
            raise Denied("position targets are flown in GUIDED only")
        self._require_armed()
        local = msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
        frame = msg.coordinate_frame
        if not local and frame not in AMSL_FRAMES | RELATIVE_FRAMES:
            raise Denied(f"SET_POSITION_TARGET_GLOBAL_INT in frame {frame}: a global frame only",
                         mav.MAV_RESULT_UNSUPPORTED)
        x, y, z = (msg.x, msg.y, msg.z) if local else (msg.lat_int, msg.lon_int, msg.alt)
        if mask:  # the axes left out keep the drone's
            if local and frame == mav.MAV_FRAME_LOCAL_NED:
                here: tuple[float, ...] = self.geo.ned(self.pos)
            elif local:
                here = (0.0, 0.0, 0.0)
            else:
                lat, lon, alt = self.geo.wgs84(self.pos)
                here = (lat * 1e7, lon * 1e7, alt - (self.geo.amsl(self.home[2]) if frame in RELATIVE_FRAMES else 0))
            x, y, z = (h if mask & bit else v for v, h, bit in zip((x, y, z), here, (1, 2, 4)))
        return self._aim(self.position(frame, x, y, z, scaled=not local))

    # ------------------------------------------------------------------ the parameter protocol

    def _parameter(self, kind: str, msg: Msg, origin: Origin) -> list[Effect]:
        """The one parameter a vehicle has, SYSID_THISMAV (its system id, read-only): ground stations fetch the
        parameters when they meet a vehicle (QGroundControl holds its vehicle not ready until the list is
        complete), and a list of one is complete. Another name or index is not answered (as ArduPilot does);
        a set is answered with the value in force."""
        by_index = kind == "PARAM_REQUEST_READ" and msg.param_index != -1  # (-1: by its name)
        if kind == "PARAM_REQUEST_LIST" or (msg.param_index == 0 if by_index else msg.param_id == PARAMETER):
            return [Mav(self.system, mav.MAVLink_param_value_message(
                PARAMETER.encode(), float(self.system), mav.MAV_PARAM_TYPE_INT16, 1, 0), origin)]
        return []

    # ------------------------------------------------------------------ the mission protocol

    def _mission(self, kind: str, msg: Msg, origin: Origin, now: float) -> list[Effect]:
        if getattr(msg, "mission_type", 0) != mav.MAV_MISSION_TYPE_MISSION and kind != "MISSION_ACK":
            return self._mission_ack(origin, mav.MAV_MISSION_UNSUPPORTED, msg.mission_type)
        changes_upload = kind in ("MISSION_COUNT", "MISSION_CLEAR_ALL") or (
            kind in ("MISSION_ITEM_INT", "MISSION_ITEM") and msg.current != GUIDED_GOTO)
        if changes_upload and self.upload is not None and not self.upload.by(msg, origin):
            return self._not_uploader(kind, msg, origin)  # (as ArduPilot: MISSION_ACK DENIED, to the sender)
        match kind:
            case "MISSION_COUNT":
                return self._upload_start(msg, origin, now)
            case "MISSION_ITEM_INT" | "MISSION_ITEM":
                if msg.current == GUIDED_GOTO:  # ArduPilot's guided goto (MAVProxy's old `guided`), upload or not
                    if self.mode is not Mode.GUIDED:
                        raise Denied("a guided goto outside GUIDED")
                    self._require_armed()
                    item = item_of(msg)
                    return self._aim(self.position(item.frame, item.x, item.y, item.z, scaled=True))
                return self._upload_item(msg, now)
            case "MISSION_REQUEST_LIST":
                return [Mav(self.system, mav.MAVLink_mission_count_message(origin_system(msg), 0, len(self.mission)),
                            origin)]
            case "MISSION_REQUEST_INT" | "MISSION_REQUEST":
                if not 0 <= msg.seq < len(self.mission):
                    return self._mission_ack(origin, mav.MAV_MISSION_INVALID_SEQUENCE)
                it = self.mission[msg.seq]
                if kind == "MISSION_REQUEST":
                    scale = 1e7 if it.frame in AMSL_FRAMES | RELATIVE_FRAMES else 1e4
                    x, y = it.x / scale, it.y / scale
                    return [Mav(self.system, mav.MAVLink_mission_item_message(
                        0, 0, it.seq, it.frame, it.command, int(it.seq == self.current), it.autocontinue, *it.params,
                        x, y, it.z), origin)]
                return [Mav(self.system, mav.MAVLink_mission_item_int_message(
                    0, 0, it.seq, it.frame, it.command, int(it.seq == self.current), it.autocontinue, *it.params,
                    it.x, it.y, it.z), origin)]
            case "MISSION_CLEAR_ALL":
                self.mission, self.current, self.upload = [], FIRST_ITEM, None
                effects = self._mission_ack(origin, mav.MAV_MISSION_ACCEPTED)
                return effects + (self._enter(Mode.LOITER) if self.mode is Mode.AUTO else [])
            case "MISSION_SET_CURRENT":
                try:
                    return self._set_current(msg.seq)
                except Denied as err:
                    return self._refused(kind, err)
        return []  # MISSION_ACK: the end of a download (nothing to do)

    def _mission_ack(self, origin: Origin, result: int, mission_type: int = 0) -> list[Effect]:
        return [Mav(self.system, mav.MAVLink_mission_ack_message(0, 0, result, mission_type), origin)]

    def _not_uploader(self, kind: str, msg: Msg, origin: Origin) -> list[Effect]:
        """A mission message that would change an upload under way, from another client than its uploader:
        refused (MISSION_ACK DENIED to the sender, as ArduPilot answers it), counted; the upload goes on."""
        assert self.upload is not None
        up = self.upload
        err = WrongSender(f"a {kind} from {origin.addr} (system {sender_of(msg)[0]}) while {up.origin.addr} "
                          f"(system {up.sender[0]}) uploads a mission", reason="mavlink-sender")
        return [Refusal(f"{self.drone} {kind}", err), *self._mission_ack(origin, mav.MAV_MISSION_DENIED)]

    def _upload_start(self, msg: Msg, origin: Origin, now: float) -> list[Effect]:
        """A MISSION_COUNT (from the uploader if an upload is under way: it starts again, as in ArduPilot)."""
        count = msg.count
        if count > MISSION_LIMIT:
            self.upload = None
            err = Denied(f"a mission of {count} items: at most {MISSION_LIMIT}")
            return [*self._refused("MISSION_COUNT", err), *self.say(mav.MAV_SEVERITY_WARNING, err.text),
                    *self._mission_ack(origin, mav.MAV_MISSION_NO_SPACE)]
        if count == 0:
            self.upload = None
            return self._mission(  # (as a clear)
                "MISSION_CLEAR_ALL", mav.MAVLink_mission_clear_all_message(self.system, 1), origin, now)
        self.upload = Upload(count, [], origin, sender_of(msg), now)
        return self._request(0, origin)

    def _request(self, seq: int, origin: Origin) -> list[Effect]:
        return [Mav(self.system, mav.MAVLink_mission_request_int_message(0, 0, seq), origin)]

    def _upload_item(self, msg: Msg, now: float) -> list[Effect]:
        """An item of the upload under way, from its uploader (checked by the caller)."""
        if self.upload is None:
            raise Denied(f"mission item {msg.seq} outside an upload")
        count, items, uploader = self.upload.count, self.upload.items, self.upload.origin
        if msg.seq != len(items):  # (a repeat, or one ahead: ask again for the one expected)
            return self._request(len(items), uploader)
        try:
            items.append(item_of(msg))
            if len(items) < count:
                self.upload.last = now
                return self._request(len(items), uploader)
            self.upload = None
            for it in items[FIRST_ITEM:]:
                self._check_item(it)
        except Denied as err:
            self.upload = None
            return [*self._refused("mission upload", err), *self.say(mav.MAV_SEVERITY_WARNING, err.text),
                    *self._mission_ack(uploader, err.mission)]
        self.mission, self.current = items, FIRST_ITEM
        effects = self._mission_ack(uploader, mav.MAV_MISSION_ACCEPTED)
        effects += self.say(mav.MAV_SEVERITY_INFO, f"{self.drone}: mission of {count} items received")
        return effects + (self._next_item(self.current) if self.mode is Mode.AUTO and self.armed else [])

    def _check_item(self, it: Item) -> None:
        if it.command not in NAV_ITEMS:
            raise Denied(f"mission item {it.seq}: command {it.command} is not flown (NAV_WAYPOINT, NAV_TAKEOFF, "
                         "NAV_LAND, NAV_RETURN_TO_LAUNCH)", mission=mav.MAV_MISSION_UNSUPPORTED)
        if not math.isfinite(it.z) and it.command == mav.MAV_CMD_NAV_TAKEOFF:
            raise Denied(f"mission item {it.seq}: altitude not a number", mission=mav.MAV_MISSION_INVALID_PARAM7)
        try:
            if it.command == mav.MAV_CMD_NAV_WAYPOINT:
                self.position(it.frame, it.x, it.y, it.z, scaled=True)
            elif it.command == mav.MAV_CMD_NAV_LAND and (it.x, it.y) != (0, 0):  # (0, 0: where the drone is)
                self._column(it.frame, it.x, it.y)  # (its altitude, the drone's when it lands, is not checked)
        except Denied as err:
            raise Denied(f"mission item {it.seq}: {err.text}", mission=err.mission) from None

    def _set_current(self, seq: int) -> list[Effect]:
        if not FIRST_ITEM <= seq < len(self.mission):
            raise Denied(f"no mission item {seq} (the mission has {len(self.mission)})")
        self.current = seq
        return [Mav(self.system, self.mission_current()),
                *(self._next_item(seq) if self.mode is Mode.AUTO and self.armed else [])]

    def _next_item(self, seq: int) -> list[Effect]:
        """Fly item `seq` (AUTO): its goal, MISSION_CURRENT; past the last item, hold."""
        return self._fly(seq)

    def _fly(self, seq: int, *, reached: bool = False) -> list[Effect]:
        """AUTO from item `seq` on (`reached`: item `seq` has just been reached): MISSION_ITEM_REACHED for what
        is reached, MISSION_CURRENT for the item flown next and its goal. An item that cannot be flown is skipped
        (said in a STATUSTEXT); one whose cell the drone has reached already (the same cell as the item before,
        a takeoff below the drone) is reached at once; a NAV_LAND reached ends the mission. A loop, not a
        recursion: a mission of `MISSION_LIMIT` such items is one call."""
        effects: list[Effect] = []
        while True:
            if reached:
                effects.append(Mav(self.system, mav.MAVLink_mission_item_reached_message(seq)))
                if self.mission[seq].command == mav.MAV_CMD_NAV_LAND:  # (the mission ends on the ground)
                    self.current = len(self.mission)
                    return [*effects, Mav(self.system, self.mission_current()), *self._landed()]
                seq, reached = seq + 1, False
            self.current = seq
            effects.append(Mav(self.system, self.mission_current()))
            if seq >= len(self.mission):
                return effects + self.say(mav.MAV_SEVERITY_INFO, f"{self.drone}: mission complete") + \
                    self._aim(self.pos)
            try:
                cell = self._item_cell(self.mission[seq])
            except (Denied, BadPosition) as err:
                effects += self.say(mav.MAV_SEVERITY_WARNING, f"{self.drone}: item {seq} skipped: {err}")
                seq += 1
                continue
            if cell == self.goal and self._reported == (cell, Note.REACHED):  # there already
                effects += self.say(mav.MAV_SEVERITY_INFO, f"{self.drone} reached {cell}")
                reached = True
                continue
            return effects + self._aim(cell)

    def _item_cell(self, it: Item) -> Cell:
        """Where a mission item flies the drone from its cell."""
        x, y, z = self.pos
        match it.command:
            case mav.MAV_CMD_NAV_WAYPOINT:
                return self.position(it.frame, it.x, it.y, it.z, scaled=True)
            case mav.MAV_CMD_NAV_TAKEOFF:
                floor = self.geo.floor_of(self.geo.amsl(self.home[2]) + it.z)
                return self._checked((x, y, max(z, floor)))
            case mav.MAV_CMD_NAV_LAND:  # (below its latitude and longitude if given, else below the drone)
                there = self.pos if it.x == 0 and it.y == 0 else \
                    self.position(it.frame, it.x, it.y, self._altitude_here(it.frame), scaled=True)
                return self._ground_below(there)
        return self.home

    def _altitude_here(self, frame: int) -> float:
        """The drone's altitude as a position in `frame` gives it (metres)."""
        z = self.pos[2]
        if frame in AMSL_FRAMES:
            return self.geo.amsl(z)
        if frame in RELATIVE_FRAMES:
            return (z - self.home[2]) * self.geo.cell_size
        return -z * self.geo.cell_size if frame == mav.MAV_FRAME_LOCAL_NED else 0.0

    # ------------------------------------------------------------------ telemetry

    def heartbeat(self) -> Msg:
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.mode in (Mode.GUIDED, Mode.AUTO):
            base |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
        if self.armed:
            base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
                                             int(self.mode), self.system_status(), 3)

    def system_status(self) -> int:
        """HEARTBEAT's state: EMERGENCY dead or lost, CRITICAL with its target unreachable, else ACTIVE armed and
        STANDBY disarmed."""
        if not self.alive:
            return int(mav.MAV_STATE_EMERGENCY)
        if self.note is Note.UNREACHABLE and self.target is not None and self.target == self.goal:
            return int(mav.MAV_STATE_CRITICAL)
        return int(mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY)

    def positions(self, ms: int) -> list[Msg]:
        """What every turn brings: the drone's position, global and local."""
        lat, lon, alt = self.geo.wgs84(self.pos)
        north, east, down = self.geo.ned(self.pos)
        relative = (self.pos[2] - self.home[2]) * self.geo.cell_size
        return [mav.MAVLink_global_position_int_message(ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
                                                        round(relative * 1000), 0, 0, 0, 65535),
                mav.MAVLink_local_position_ned_message(ms, north, east, down, 0.0, 0.0, 0.0)]

    def telemetry(self, ms: int) -> list[Msg]:
        """The whole set, sent at the telemetry rate."""
        sensors = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                   | mav.MAV_SYS_STATUS_SENSOR_3D_MAG | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
                   | mav.MAV_SYS_STATUS_SENSOR_GPS)
        if self.armed:
            landed = mav.MAV_LANDED_STATE_LANDING if self.mode is Mode.LAND and not self._on_ground() else \
                mav.MAV_LANDED_STATE_IN_AIR
        else:
            landed = mav.MAV_LANDED_STATE_ON_GROUND if self._on_ground() else mav.MAV_LANDED_STATE_IN_AIR
        health = sensors if self.alive else 0
        return [self.heartbeat(),
                mav.MAVLink_sys_status_message(sensors, sensors, health, 0, 12600, -1, 100, 0, 0, 0, 0, 0, 0),
                *self.positions(ms),
                mav.MAVLink_attitude_message(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                self.home_position(),
                mav.MAVLink_extended_sys_state_message(mav.MAV_VTOL_STATE_UNDEFINED, landed),
                mav.MAVLink_battery_status_message(0, mav.MAV_BATTERY_FUNCTION_ALL, mav.MAV_BATTERY_TYPE_LIPO, 32767,
                                                   [12600] + [65535] * 9, -1, -1, -1, 100),
                self.mission_current()]

    def home_position(self) -> Msg:
        lat, lon, alt = self.geo.wgs84(self.home)
        x, y, z = self.geo.ned(self.home)
        return mav.MAVLink_home_position_message(round(lat * 1e7), round(lon * 1e7), round(alt * 1000), x, y, z,
                                                 [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)

    def mission_current(self) -> Msg:
        total = max(len(self.mission) - FIRST_ITEM, 0)
        state = (mav.MISSION_STATE_NO_MISSION if not total else mav.MISSION_STATE_COMPLETE
                 if self.current >= len(self.mission) else mav.MISSION_STATE_ACTIVE if self.mode is Mode.AUTO
                 else mav.MISSION_STATE_NOT_STARTED)
        return mav.MAVLink_mission_current_message(min(self.current, 65535), total, state)

    def autopilot_version(self) -> Msg:
        caps = (mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT)
        return mav.MAVLink_autopilot_version_message(caps, 0, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.system)


def whole(value: float, default: int = -1) -> int:
    """A command's parameter as an integer (`default` if it is not a finite number)."""
    return int(value) if math.isfinite(value) else default


def ack(command: int, result: int, msg: Msg) -> Msg:
    """The COMMAND_ACK of `command` (of `msg`), to its sender."""
    return mav.MAVLink_command_ack_message(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())


def sender_of(msg: Msg) -> tuple[int, int]:
    """The (system, component) ids a message's sender gave itself."""
    return int(msg.get_srcSystem()), int(msg.get_srcComponent())


def origin_system(msg: Msg) -> int:
    """The system id of a message's sender."""
    return int(msg.get_srcSystem())
