"""The MAVLink ground station's pure core (entities/mavlink: geo, vehicle, bridge) and the adapter's datagram
reading, without a network: messages are built by pymavlink, framed as a client would send them and read back
as the adapter reads a datagram. The real clients fly it in tests/test_mavlink_clients.py."""

from __future__ import annotations

import logging
import math
import socket
import threading

import pytest

mav = pytest.importorskip("pymavlink.dialects.v20.ardupilotmega", reason="pymavlink (the mavlink extra) is needed")

from entities.gcs import Ground, Plan, SendDone  # noqa: E402
from entities.mavlink.bridge import COMMANDS_PER_TURN, Bridge  # noqa: E402
from entities.mavlink.geo import DEFAULT_ORIGIN, BadPosition, Geo  # noqa: E402
from entities.mavlink.node import Links, Packet, Reader, decode_datagram  # noqa: E402
from entities.mavlink.vehicle import MISSION_LIMIT, UPLOAD_TIMEOUT_S, Goal, Mav, Mode, Origin, Vehicle  # noqa: E402
from schema import (  # noqa: E402
    Cause,
    DroneState,
    DroneStatus,
    EndReason,
    Note,
    Over,
    Phase,
    RejectCounter,
    RemoteInputError,
    Status,
    Turn,
    UsageError,
)
from schema.errors import Refusal  # noqa: E402
from world.grid import Building, World  # noqa: E402

WORLD = World.from_buildings((12, 12, 8), [Building(x=6, y=6, length=2, width=2, height=4)])
STARTS = {"D01": (0, 0, 0), "D02": (0, 2, 0), "D03": (0, 4, 0)}
GEO = Geo()
GCS = Origin(0, ("127.0.0.1", 14550))
CLIENT = mav.MAVLink(None, srcSystem=255, srcComponent=190)


def wire(msg):
    """`msg` as a client sends it and the bridge reads it (framed by pymavlink, decoded on its own)."""
    (decoded,) = decode_datagram(msg.pack(CLIENT))
    return decoded


def bridge() -> Bridge:
    return Bridge(Ground(WORLD, dict(STARTS), Plan(())), GEO, period=0.0, telemetry_period=1.0, now=0.0)


def sent(effects, kind: str) -> list:
    return [e.msg for e in effects if isinstance(e, Mav) and e.msg.get_type() == kind]


def acks(effects) -> list[int]:
    return [m.result for m in sent(effects, "COMMAND_ACK")]


def refusals(effects) -> list[str]:
    return [e.err.reason for e in effects if isinstance(e, Refusal)]


def command(system: int, cmd: int, *params: float, confirmation: int = 0):
    p = [*params, *[0.0] * (7 - len(params))]
    return wire(mav.MAVLink_command_long_message(system, 1, cmd, confirmation, *p))


def arm(system: int, on: bool = True):
    return command(system, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if on else 0.0)


def set_mode(system: int, mode: int):
    return command(system, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)


def local_target(system: int, north: float, east: float, down: float, mask: int = 0b110111111000):
    return wire(mav.MAVLink_set_position_target_local_ned_message(0, system, 1, mav.MAV_FRAME_LOCAL_NED, mask,
                                                                  north, east, down, 0, 0, 0, 0, 0, 0, 0, 0))


def reposition(system: int, cell, frame: int = mav.MAV_FRAME_GLOBAL_INT):
    lat, lon, alt = GEO.wgs84(cell)
    return wire(mav.MAVLink_command_int_message(system, 1, frame, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1,
                                                mav.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0, 0,
                                                round(lat * 1e7), round(lon * 1e7), alt))


def status(turn: int, **rows: DroneStatus) -> Status:
    drones = tuple(rows.get(d, DroneStatus(drone=d, pos=c, state=DroneState.ALIVE)) for d, c in STARTS.items())
    return Status(turn=turn, sender="OBS", drones=drones)


def row(drone: str, pos, target=None, note=Note.NONE, state=DroneState.ALIVE, cause=Cause.NONE) -> DroneStatus:
    return DroneStatus(drone=drone, pos=pos, state=state, target=target, note=note, cause=cause)


def guided(b: Bridge, system: int) -> None:
    """Vehicle `system` armed in GUIDED."""
    effects = b.packet(GCS, [set_mode(system, Mode.GUIDED), arm(system)])
    assert acks(effects) == [mav.MAV_RESULT_ACCEPTED] * 2


def answer(b: Bridge, turn: int, now: float = 100.0, in_force: dict | None = None) -> SendDone:
    """The bridge's DONE for the GCS phase of `turn`, after the STATUS of the turn before (with the targets
    `in_force`)."""
    b.receive(status(turn - 1, **{d: row(d, STARTS[d], target=c) for d, c in (in_force or {}).items()}), now)
    b.receive(Turn(turn=turn, sender="SRV", phase=Phase.GCS), now)
    (done,) = [e for e in b.tick(now) if isinstance(e, SendDone)]
    return done


# ---------------------------------------------------------------------------------------------- coordinates


def test_geo_maps_cells_both_ways_and_rounds_to_the_nearest_cell() -> None:
    geo = Geo(cell_size=2.5, origin=(-33.86, 151.2, 10.0))
    for cell in [(0, 0, 0), (3, 7, 2), (-4, 11, 5), (999, 999, 99)]:
        assert geo.cell_of_wgs84(*geo.wgs84(cell)) == cell
        assert geo.cell_of_ned(*geo.ned(cell)) == cell
    assert geo.ned((1, 2, 3)) == (2.5, 5.0, -7.5)  # north = x, east = y, down = -z
    assert geo.cell_of_ned(3.7, 1.2, -6.3) == (1, 0, 3)  # 1.48, 0.48, 2.52 cells
    assert GEO.wgs84((0, 0, 0)) == DEFAULT_ORIGIN
    lat, lon, _ = GEO.wgs84((1, 1, 0))
    assert lat > DEFAULT_ORIGIN[0] and lon > DEFAULT_ORIGIN[1]  # x north, y east
    for bad in [(math.nan, 8.5, 490.0), (47.3, math.inf, 490.0), (91.0, 8.5, 490.0), (47.3, 8.5, 1e300)]:
        with pytest.raises(BadPosition):
            GEO.cell_of_wgs84(*bad)
    for size in [0.0, -1.0, math.nan]:
        with pytest.raises(UsageError):
            Geo(cell_size=size)
    with pytest.raises(UsageError, match="LAT,LON,ALT"):
        Geo.parse_origin("47.3,8.5")


# ---------------------------------------------------------------------------------------------- commands


def test_telemetry_presents_an_ardupilot_copter_at_its_cell() -> None:
    b = bridge()
    effects = b.tick(0.0)
    kinds = {e.msg.get_type() for e in effects if e.system == 2}
    assert {"HEARTBEAT", "SYS_STATUS", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "HOME_POSITION",
            "EXTENDED_SYS_STATE", "BATTERY_STATUS"} <= kinds
    hb = next(e.msg for e in effects if e.system == 2 and e.msg.get_type() == "HEARTBEAT")
    assert (hb.type, hb.autopilot, hb.custom_mode) == (mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                       Mode.LOITER)
    assert hb.system_status == mav.MAV_STATE_STANDBY and not hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
    local = next(e.msg for e in effects if e.system == 2 and e.msg.get_type() == "LOCAL_POSITION_NED")
    assert (local.x, local.y, local.z) == (0.0, 2.0, 0.0)
    assert b.wake(0.5) == 0.5  # the next set is due after the telemetry period
    # every turn brings each vehicle's position
    effects = b.receive(status(1, D02=row("D02", (1, 2, 0))), 0.1)
    (pos,) = [e.msg for e in effects if e.system == 2 and e.msg.get_type() == "GLOBAL_POSITION_INT"]
    assert GEO.cell_of_wgs84(pos.lat / 1e7, pos.lon / 1e7, pos.alt / 1000) == (1, 2, 0)


def test_arm_guided_and_position_targets_become_the_stations_targets() -> None:
    b = bridge()
    effects = b.packet(GCS, [set_mode(2, Mode.GUIDED)])  # a mode, an arming: a HEARTBEAT says each at once
    assert [h.custom_mode for h in sent(effects, "HEARTBEAT")] == [Mode.GUIDED]
    effects = b.packet(GCS, [arm(2)])
    assert [h.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED for h in sent(effects, "HEARTBEAT")] == \
        [mav.MAV_MODE_FLAG_SAFETY_ARMED]
    assert not sent(b.packet(GCS, [arm(2)]), "HEARTBEAT")  # (nothing changed: none)
    assert not sent(b.receive(status(0, D02=row("D02", (1, 2, 0))), 0.1), "HEARTBEAT")  # (a move says nothing new)
    hb = b.vehicles[2].heartbeat()
    assert hb.custom_mode == Mode.GUIDED and hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == mav.MAV_STATE_ACTIVE
    b.packet(GCS, [local_target(2, 5.2, 3.9, -2.6)])  # rounded to the nearest cell
    b.packet(GCS, [arm(3), set_mode(3, Mode.GUIDED), reposition(3, (4, 4, 1))])
    lat, lon, _ = GEO.wgs84((7, 1, 0))
    b.packet(GCS, [set_mode(1, Mode.GUIDED), arm(1), wire(mav.MAVLink_set_position_target_global_int_message(
        0, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b110111111000, round(lat * 1e7), round(lon * 1e7), 2.2,
        0, 0, 0, 0, 0, 0, 0, 0))])
    done = answer(b, 1)
    assert {a.drone: a.pos for a in done.msg.targets} == {"D01": (7, 1, 2), "D02": (5, 4, 3), "D03": (4, 4, 1)}
    assert answer(b, 2, in_force={a.drone: a.pos for a in done.msg.targets}).msg.targets == ()  # (only changes)
    # a second identical command is accepted and changes nothing (the command protocol's idempotence)
    assert acks(b.packet(GCS, [arm(2)])) == [mav.MAV_RESULT_ACCEPTED]


def test_an_armed_vehicle_entering_guided_holds_its_cell_until_its_takeoff() -> None:
    """MAVSDK's order for ArduPilot (seen on the wire): arm in the first mode (LOITER), then GUIDED, then
    NAV_TAKEOFF. Entering GUIDED armed holds where the vehicle is (as ArduCopter does): the station is asked
    for its own cell, and the takeoff replaces it. When a turn ends between the two commands, the journal
    records the hold first."""
    b = bridge()
    v = b.vehicles[2]
    b.packet(GCS, [arm(2)])
    assert (v.mode, v.goal) == (Mode.LOITER, None)  # (LOITER holds: the arming asks for nothing)
    b.packet(GCS, [set_mode(2, Mode.GUIDED)])
    assert v.goal == (0, 2, 0)
    assert {a.drone: a.pos for a in answer(b, 1).msg.targets} == {"D02": (0, 2, 0)}  # the hold, this turn
    b.packet(GCS, [command(2, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0)])
    assert {a.drone: a.pos for a in answer(b, 2, in_force={"D02": (0, 2, 0)}).msg.targets} == {"D02": (0, 2, 3)}


def test_takeoff_land_rtl_and_disarm_set_the_targets_of_their_modes() -> None:
    b = bridge()
    v = b.vehicles[1]
    assert acks(b.packet(GCS, [command(1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0)])) == \
        [mav.MAV_RESULT_DENIED]  # disarmed
    guided(b, 1)
    assert acks(b.packet(GCS, [command(1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0)])) == \
        [mav.MAV_RESULT_ACCEPTED]
    assert v.goal == (0, 0, 3)
    b.receive(status(5, D01=row("D01", (2, 3, 3), target=(2, 3, 3), note=Note.REACHED)), 1.0)
    b.packet(GCS, [command(1, mav.MAV_CMD_NAV_LAND)])
    assert (v.mode, v.goal) == (Mode.LAND, (2, 3, 0))  # the lowest free cell below
    effects = b.receive(status(8, D01=row("D01", (2, 3, 0), target=(2, 3, 0), note=Note.REACHED)), 2.0)
    assert not v.armed and any("landed" in m.text for m in sent(effects, "STATUSTEXT"))
    guided(b, 1)
    b.packet(GCS, [command(1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)])
    assert (v.mode, v.goal) == (Mode.RTL, (0, 0, 0))
    b.receive(status(9, D01=row("D01", (1, 3, 0), target=(0, 0, 0))), 3.0)
    b.packet(GCS, [arm(1, False)])
    assert v.goal == (1, 3, 0)  # a disarmed drone holds its cell
    assert acks(b.packet(GCS, [reposition(1, (5, 5, 1))])) == [mav.MAV_RESULT_DENIED]
    assert v.goal == (1, 3, 0)
    # above a building, a drone lands on its roof
    w = Vehicle(9, "D09", (6, 6, 6), WORLD, GEO)
    assert w._ground_below((6, 6, 6)) == (6, 6, 4)


def test_a_landing_stops_above_a_drone_below() -> None:
    """The lowest free cell below: a drone there now (on the ground, or hovering) is not free."""
    b = bridge()
    guided(b, 2)
    b.receive(status(3, D01=row("D01", (2, 3, 0)), D02=row("D02", (2, 3, 4)), D03=row("D03", (5, 5, 2))), 1.0)
    b.packet(GCS, [command(2, mav.MAV_CMD_NAV_LAND)])
    assert b.vehicles[2].goal == (2, 3, 1)
    b.receive(status(4, D01=row("D01", (2, 3, 0)), D02=row("D02", (5, 5, 4)), D03=row("D03", (5, 5, 2))), 2.0)
    b.packet(GCS, [set_mode(2, Mode.GUIDED), command(2, mav.MAV_CMD_NAV_LAND)])
    assert b.vehicles[2].goal == (5, 5, 3)  # (above D03, hovering)
    b.receive(status(5, D01=row("D01", (2, 3, 0)), D02=row("D02", (5, 5, 4)),
                     D03=row("D03", (5, 5, 2), state=DroneState.DEAD, cause=Cause.VERTEX)), 3.0)
    b.packet(GCS, [set_mode(2, Mode.GUIDED), command(2, mav.MAV_CMD_NAV_LAND)])
    assert b.vehicles[2].goal == (5, 5, 0)  # (a dead drone holds no cell)


def test_modes_the_vehicle_does_not_fly_and_unknown_commands_are_refused() -> None:
    b = bridge()
    effects = b.packet(GCS, [set_mode(1, 15)])  # Plane's GUIDED
    assert acks(effects) == [mav.MAV_RESULT_DENIED] and refusals(effects) == ["mavlink-denied"]
    assert "mode 15" in sent(effects, "STATUSTEXT")[0].text
    assert acks(b.packet(GCS, [set_mode(1, Mode.AUTO)])) == [mav.MAV_RESULT_DENIED]  # no mission
    assert acks(b.packet(GCS, [command(1, mav.MAV_CMD_DO_SET_MODE, 0, 4)])) == [mav.MAV_RESULT_UNSUPPORTED]
    assert acks(b.packet(GCS, [command(1, mav.MAV_CMD_DO_CHANGE_SPEED, 1, 5)])) == [mav.MAV_RESULT_UNSUPPORTED]
    set_mode_msg = wire(mav.MAVLink_set_mode_message(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, Mode.RTL))
    assert acks(b.packet(GCS, [set_mode_msg])) == [mav.MAV_RESULT_ACCEPTED] and b.vehicles[1].mode is Mode.RTL
    effects = b.packet(GCS, [command(1, mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)])
    assert acks(effects) == [mav.MAV_RESULT_ACCEPTED] and sent(effects, "AUTOPILOT_VERSION")
    assert b.vehicles[1].goal is None and b.vehicles[2].goal is None


def test_the_parameter_list_is_one_read_only_parameter() -> None:
    """Ground stations fetch a vehicle's parameters when they meet it (QGroundControl holds it not ready until the
    list is complete): the list is SYSID_THISMAV, by list, index or name; a set leaves it as it is; other names
    are not answered."""
    b = bridge()

    def values(msg) -> list:
        return [(m.param_id, m.param_value, m.param_count, m.param_index) for m in sent(b.packet(GCS, [wire(msg)]),
                                                                                        "PARAM_VALUE")]

    one = [("SYSID_THISMAV", 2.0, 1, 0)]
    assert values(mav.MAVLink_param_request_list_message(2, 0)) == one
    assert values(mav.MAVLink_param_request_read_message(2, 0, b"", 0)) == one
    assert values(mav.MAVLink_param_request_read_message(2, 0, b"SYSID_THISMAV", -1)) == one
    assert values(mav.MAVLink_param_set_message(2, 0, b"SYSID_THISMAV", 7.0, mav.MAV_PARAM_TYPE_INT16)) == one
    assert values(mav.MAVLink_param_request_read_message(2, 0, b"", 1)) == []
    assert values(mav.MAVLink_param_request_read_message(2, 0, b"WPNAV_SPEED", -1)) == []
    assert values(mav.MAVLink_param_set_message(2, 0, b"WPNAV_SPEED", 5.0, mav.MAV_PARAM_TYPE_REAL32)) == []
    assert b.vehicles[2].system == 2 and b.vehicles[2].goal is None


# ---------------------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("target", [
    pytest.param(lambda: local_target(2, math.nan, 1, -1), id="NaN"),
    pytest.param(lambda: local_target(2, 1, math.inf, -1), id="infinite"),
    pytest.param(lambda: local_target(2, 50, 1, -1), id="outside-the-world"),
    pytest.param(lambda: local_target(2, 1, 1, 2), id="below-the-ground"),
    pytest.param(lambda: local_target(2, 6, 6, -1), id="inside-a-building"),
    pytest.param(lambda: local_target(2, 1e12, 1, -1), id="far-out-of-range"),
    pytest.param(lambda: reposition(2, (30, 0, 1)), id="reposition-outside"),
    pytest.param(lambda: wire(mav.MAVLink_command_int_message(
        2, 1, mav.MAV_FRAME_GLOBAL_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 1, 0, 0, -(1 << 31), -(1 << 31), 490)),
        id="latitude-out-of-range"),
    pytest.param(lambda: wire(mav.MAVLink_command_long_message(2, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 1, 0, 0,
                                                               47.4, 8.5, math.nan)), id="far-away"),
])
def test_bad_targets_are_refused_and_counted_and_change_nothing(target) -> None:
    b = bridge()
    guided(b, 2)
    b.packet(GCS, [local_target(2, 2, 2, -1)])
    effects = b.packet(GCS, [target()])
    assert refusals(effects) == ["mavlink-denied"]
    assert acks(effects) in ([], [mav.MAV_RESULT_DENIED])
    assert sent(effects, "STATUSTEXT")  # why, for the person at the ground station
    assert b.vehicles[2].goal == (2, 2, 1)
    assert {a.drone: a.pos for a in answer(b, 1).msg.targets} == {"D02": (2, 2, 1)}


def test_wrong_target_systems_are_refused_and_counted() -> None:
    b = bridge()
    effects = b.packet(GCS, [arm(7)])  # no system 7 in this game
    assert refusals(effects) == ["mavlink-target"] and not acks(effects)
    effects = b.packet(GCS, [arm(0)])  # a command on the shared link must name its system
    assert refusals(effects) == ["mavlink-target"]
    effects = b.packet(Origin(3, ("127.0.0.1", 5000)), [arm(2)])  # system 2's command on system 3's port
    assert refusals(effects) == ["mavlink-target"]
    assert not any(v.armed for v in b.vehicles.values())
    effects = b.packet(Origin(3, ("127.0.0.1", 5000)), [arm(0)])  # on a vehicle's port, 0 is that vehicle
    assert acks(effects) == [mav.MAV_RESULT_ACCEPTED] and b.vehicles[3].armed
    assert effects[0].to == Origin(3, ("127.0.0.1", 5000))  # answered where it came from
    heartbeat = wire(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))  # a ground station's: nothing to do
    assert b.packet(GCS, [heartbeat]) == [] and b.ignored == {"HEARTBEAT": 1}  # (counted, reported at the end)


def test_a_dead_drone_takes_no_commands_and_says_why_once() -> None:
    b = bridge()
    guided(b, 2)
    effects = b.receive(status(4, D02=row("D02", (1, 2, 0), state=DroneState.DEAD, cause=Cause.VERTEX)), 1.0)
    (text,) = sent(effects, "STATUSTEXT")
    assert "D02 died" in text.text and "vertex" in text.text
    assert b.vehicles[2].heartbeat().system_status == mav.MAV_STATE_EMERGENCY
    assert not sent(b.receive(status(5, D02=row("D02", (1, 2, 0), state=DroneState.DEAD, cause=Cause.VERTEX)),
                              1.1), "STATUSTEXT")
    for msg in [arm(2), reposition(2, (3, 3, 1)), command(2, mav.MAV_CMD_NAV_TAKEOFF)]:
        effects = b.packet(GCS, [msg])
        assert acks(effects) == [mav.MAV_RESULT_DENIED] and refusals(effects) == ["mavlink-denied"]
    assert refusals(b.packet(GCS, [local_target(2, 3, 3, -1)])) == ["mavlink-denied"]
    assert b.vehicles[2].goal is None and answer(b, 6).msg.targets == ()


def test_a_command_flood_is_denied_beyond_its_budget_a_turn() -> None:
    b = bridge()
    guided(b, 1)
    flood = [local_target(1, 1 + i % 3, 1, -1) for i in range(COMMANDS_PER_TURN * 4)]
    effects = b.packet(GCS, flood)
    assert refusals(effects).count("mavlink-flood") == len(flood) - (COMMANDS_PER_TURN - 2)
    assert b.commands[1] == len(flood) + 2
    cmds = b.packet(GCS, [arm(1, False)])  # still over budget this turn: TEMPORARILY_REJECTED, still armed
    assert acks(cmds) == [mav.MAV_RESULT_TEMPORARILY_REJECTED] and b.vehicles[1].armed
    assert acks(b.packet(GCS, [arm(2)])) == [mav.MAV_RESULT_ACCEPTED]  # the other vehicles are not affected
    b.receive(status(1), 1.0)  # a new turn: a new budget
    assert acks(b.packet(GCS, [arm(1, False)])) == [mav.MAV_RESULT_ACCEPTED]


@pytest.mark.parametrize("param1", [math.nan, math.inf, -math.inf, 1e20, -1.0, 0.5, 2.0, 21196.0])
def test_arm_disarm_takes_exactly_0_or_1_and_nothing_else_disarms(param1: float) -> None:
    """COMPONENT_ARM_DISARM's param1 is 1 (arm) or 0 (disarm): anything else is DENIED, counted, and a drone
    in flight stays armed, on its way."""
    b = bridge()
    guided(b, 1)
    b.packet(GCS, [local_target(1, 3, 0, -2)])
    effects = b.packet(GCS, [command(1, mav.MAV_CMD_COMPONENT_ARM_DISARM, param1)])
    assert acks(effects) == [mav.MAV_RESULT_DENIED] and refusals(effects) == ["mavlink-denied"]
    assert "param1" in sent(effects, "STATUSTEXT")[0].text
    assert b.vehicles[1].armed and b.vehicles[1].goal == (3, 0, 2)
    assert acks(b.packet(GCS, [arm(1, False)])) == [mav.MAV_RESULT_ACCEPTED] and not b.vehicles[1].armed


def test_datagrams_that_are_not_mavlink_2_are_refused() -> None:
    heartbeat = mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)
    good = heartbeat.pack(mav.MAVLink(None, srcSystem=255))
    assert [m.get_type() for m in decode_datagram(good + good)] == ["HEARTBEAT", "HEARTBEAT"]
    v1 = mav.MAVLink(None, srcSystem=255)
    v1.WIRE_PROTOCOL_VERSION = "1.0"
    old = heartbeat.pack(v1, force_mavlink1=True)
    assert old[0] == 0xFE
    with pytest.raises(RemoteInputError) as err:
        decode_datagram(old)
    assert err.value.reason == "mavlink1"
    corrupt = bytearray(good)
    corrupt[-1] ^= 0xFF  # a bad checksum
    for garbage in [b"", b"\x00" * 40, b"\xfd\x09garbage", bytes(corrupt), good[:-3], good + b"\x01\x02",
                    bytes(range(256)) * 4]:
        with pytest.raises(RemoteInputError) as err:
            decode_datagram(garbage)
        assert err.value.reason == "mavlink-garbage"


def test_frames_of_message_ids_pymavlink_does_not_know_are_garbage() -> None:
    """pymavlink cannot check the checksum of a message id it does not know (it yields MAVLink_unknown): any
    0xFD and a dozen bytes would pass. Such a frame makes its datagram garbage, refused and counted."""
    import struct

    unknown = struct.pack("<BBBBBBBHB", 0xFD, 1, 0, 0, 0, 255, 190, 0xBCDE, 0x0A) + b"\x01\x00\x00"
    good = mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mav.MAVLink(None, srcSystem=255))
    for datagram in [unknown, good + unknown, unknown * 100]:
        with pytest.raises(RemoteInputError) as err:
            decode_datagram(datagram)
        assert err.value.reason == "mavlink-garbage"


def test_the_reader_refuses_garbage_and_floods_and_keeps_reading(logger) -> None:
    """Through real sockets: garbage and MAVLink 1 are refused and counted, good datagrams after them still
    come through, and no more than `limit` datagrams wait for the main thread."""

    class Counting(RejectCounter):
        seen = threading.Semaphore(0)

        def reject(self, *args, **kwargs) -> None:
            super().reject(*args, **kwargs)
            self.seen.release()

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.bind(("127.0.0.1", 0))
        links = Links(client.getsockname(), 30000, [1, 2])
        got: list[Packet] = []
        arrived = threading.Semaphore(0)
        rejects = Counting(logger)

        def post(packet: Packet) -> None:
            got.append(packet)
            arrived.release()

        reader = Reader(links, post, rejects, limit=3)
        reader.start()
        try:
            vehicle_port = links.sockets[2].getsockname()
            gcs_port = ("127.0.0.1", links.sockets[0].getsockname()[1])
            good = arm(2).pack(CLIENT)
            client.sendto(b"\xfd\x01garbage", vehicle_port)
            v1 = mav.MAVLink(None, srcSystem=255)
            client.sendto(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(v1, force_mavlink1=True),
                          vehicle_port)
            for _ in range(3):
                client.sendto(good, vehicle_port)
            for _ in range(3):
                assert arrived.acquire(timeout=10)
            client.sendto(good, vehicle_port)  # a 4th and a 5th while 3 wait: refused
            client.sendto(good, gcs_port)
            for _ in range(4):
                assert rejects.seen.acquire(timeout=10)
            reader.taken(got[0])
            client.sendto(good * 2, gcs_port)  # one message was taken: no room for a datagram of two
            assert rejects.seen.acquire(timeout=10)
            reader.taken(got[1])  # (after a datagram found no room, none is read until the main thread takes one)
            client.sendto(good, gcs_port)  # room for one
            assert arrived.acquire(timeout=10)
        finally:
            reader.stop()
            links.close()
    assert [p.origin.port for p in got] == [2, 2, 2, 0]
    assert got[0].messages[0].get_type() == "COMMAND_LONG"
    assert rejects.snapshot() == {"mavlink-garbage": 1, "mavlink1": 1, "mavlink-flood": 3}


def test_the_readers_bound_is_in_messages_so_memory_stays_bounded_under_a_flood() -> None:
    """A datagram of 64 KiB holds some 1,500 commands (1.2 MB decoded): the reader's bound counts the messages
    waiting, so that however the datagrams are made, what waits for the main thread stays a few MB."""
    from schema.tuning import MAVLINK_QUEUE

    frame = arm(1).pack(CLIENT)
    fat = frame * (65000 // len(frame))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.bind(("127.0.0.1", 0))
        links = Links(client.getsockname(), 30000, [1])
        got: list[Packet] = []
        rejects = RejectCounter(logging.getLogger("dronesim.tests"))
        reader = Reader(links, got.append, rejects)  # (not started: datagrams handed to it one by one)
        origin = Origin(0, ("127.0.0.1", 9))
        try:
            for _ in range(50):
                reader._datagram(origin, fat)
            waiting, taken = sum(len(p.messages) for p in got), len(got)
            assert 0 < waiting <= MAVLINK_QUEUE < 50 * len(decode_datagram(fat))
            assert rejects.snapshot() == {"mavlink-flood": 50 - taken}
            reader.taken(got[0])  # the main thread took one: room for one more
            reader._datagram(origin, fat)
            assert len(got) == taken + 1
        finally:
            reader._selector.close()
            links.close()


def test_a_reader_without_room_refuses_datagrams_unread_until_the_main_thread_takes_one() -> None:
    """A datagram that finds no room (its messages would pass the bound) was decoded to learn that; the next
    ones are refused unread -- a flood costs a read, not a decode, however the waiting count sits below the
    bound -- until the main thread takes a packet."""
    good = arm(1).pack(CLIENT)
    links = Links(("127.0.0.1", 9), 30000, [1])
    got: list[Packet] = []
    rejects = RejectCounter(logging.getLogger("dronesim.tests"))
    reader = Reader(links, got.append, rejects, limit=3)  # (not started: datagrams handed to it one by one)
    origin = Origin(0, ("127.0.0.1", 9))
    try:
        reader._datagram(origin, good * 2)
        reader._datagram(origin, good * 2)  # 2 waiting of 3: no room for 2 more
        assert len(got) == 1 and rejects.snapshot() == {"mavlink-flood": 1}
        reader._datagram(origin, b"\xfd\x09garbage")  # not decoded: refused as the flood it is part of
        reader._datagram(origin, good)  # (one would fit: refused all the same until a packet is taken)
        assert len(got) == 1 and rejects.snapshot() == {"mavlink-flood": 3}
        reader.taken(got[0])
        reader._datagram(origin, good)
        reader._datagram(origin, b"\xfd\x09garbage")  # read again: garbage is garbage
        assert len(got) == 2 and rejects.snapshot() == {"mavlink-flood": 3, "mavlink-garbage": 1}
    finally:
        reader._selector.close()
        links.close()


def test_the_reader_stops_at_once_under_a_flood_that_never_ends(logger) -> None:
    """A flood that never lets the socket go empty (each datagram read brings another) does not hold `stop`
    up: the ground station exits, and a second Ctrl-C stops it, whatever a client keeps sending."""
    feeding = threading.Event()
    feeding.set()

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as client:
        client.bind(("127.0.0.1", 0))
        links = Links(client.getsockname(), 30000, [1])
        port = links.sockets[1].getsockname()
        read = threading.Semaphore(0)

        class Feeding(RejectCounter):
            def reject(self, *args, **kwargs) -> None:
                super().reject(*args, **kwargs)
                if feeding.is_set():  # one datagram read, one more sent: the socket never empties
                    client.sendto(b"\xfd\x09garbage", port)
                read.release()

        rejects = Feeding(logger)
        reader = Reader(links, lambda packet: None, rejects)
        for _ in range(20):
            client.sendto(b"\xfd\x09garbage", port)
        stopping = threading.Thread(target=reader.stop, daemon=True)
        reader.start()
        try:
            for _ in range(100):  # (well past the first 20: the flood feeds itself)
                assert read.acquire(timeout=10)
            stopping.start()
            stopping.join(timeout=60)  # (a guard against a hang, not a measure: it returns at once)
            stopped = not stopping.is_alive()
        finally:
            feeding.clear()  # (a reader that did not stop finds its socket empty now, and stops)
            if stopping.ident is None:  # (not started: an assertion above failed)
                reader.stop()
            else:
                stopping.join(timeout=60)
            links.close()
    assert stopped, "Reader.stop waited for the flood to end"
    assert rejects.snapshot()["mavlink-garbage"] >= 100


# ---------------------------------------------------------------------------------------------- missions


def item(seq: int, cell, command: int = mav.MAV_CMD_NAV_WAYPOINT, frame: int = mav.MAV_FRAME_GLOBAL_INT):
    lat, lon, alt = GEO.wgs84(cell)
    return wire(mav.MAVLink_mission_item_int_message(2, 1, seq, frame, command, 0, 1, 0, 0, 0, 0,
                                                     round(lat * 1e7), round(lon * 1e7), alt))


def upload(b: Bridge, items: list, system: int = 2) -> list:
    effects = b.packet(GCS, [wire(mav.MAVLink_mission_count_message(system, 1, len(items)))])
    for it in items:
        (request,) = sent(effects, "MISSION_REQUEST_INT")
        assert request.seq == it.seq
        effects = b.packet(GCS, [it])
    return effects


def test_a_mission_is_uploaded_downloaded_and_flown_in_auto() -> None:
    b = bridge()
    v = b.vehicles[2]
    cells = [(0, 2, 0), (0, 2, 2), (3, 2, 2), (3, 5, 2)]
    items = [item(0, cells[0]), item(1, cells[1], mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT),
             item(2, cells[2]), item(3, cells[3]), item(4, (0, 0, 0), mav.MAV_CMD_NAV_LAND)]
    items[1] = wire(mav.MAVLink_mission_item_int_message(2, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                         mav.MAV_CMD_NAV_TAKEOFF, 0, 1, 0, 0, 0, 0, 0, 0, 2.0))
    items[4] = wire(mav.MAVLink_mission_item_int_message(2, 1, 4, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                         mav.MAV_CMD_NAV_LAND, 0, 1, 0, 0, 0, 0, 0, 0, 0))
    effects = upload(b, items)
    assert [a.type for a in sent(effects, "MISSION_ACK")] == [mav.MAV_MISSION_ACCEPTED]
    assert len(v.mission) == 5 and v.goal is None  # (not in AUTO yet)
    # download: the same items back
    effects = b.packet(GCS, [wire(mav.MAVLink_mission_request_list_message(2, 1))])
    assert sent(effects, "MISSION_COUNT")[0].count == 5
    back = sent(b.packet(GCS, [wire(mav.MAVLink_mission_request_int_message(2, 1, 2))]), "MISSION_ITEM_INT")[0]
    assert (back.seq, back.x, back.y, back.z) == (2, items[2].x, items[2].y, items[2].z)
    # AUTO flies the items in order (item 0 is home)
    b.packet(GCS, [arm(2), set_mode(2, Mode.AUTO)])
    assert v.goal == (0, 2, 2)
    flown = []
    pos = (0, 2, 0)
    for turn in range(1, 6):
        if not v.armed:
            break
        flown.append(v.goal)
        pos = v.goal
        effects = b.receive(status(turn, D02=row("D02", pos, target=pos, note=Note.REACHED)), float(turn))
        assert sent(effects, "MISSION_CURRENT")[0].seq == v.current
        assert sent(effects, "MISSION_ITEM_REACHED")[0].seq == turn
    assert flown == [(0, 2, 2), (3, 2, 2), (3, 5, 2), (3, 5, 0)]
    assert v.mission_current().mission_state == mav.MISSION_STATE_COMPLETE
    assert any("landed" in m.text for m in sent(effects, "STATUSTEXT"))
    b.packet(GCS, [arm(2)])
    # set current, then clear
    b.packet(GCS, [wire(mav.MAVLink_mission_set_current_message(2, 1, 2))])
    assert (v.current, v.goal) == (2, (3, 2, 2))
    effects = b.packet(GCS, [wire(mav.MAVLink_mission_clear_all_message(2, 1))])
    assert sent(effects, "MISSION_ACK")[0].type == mav.MAV_MISSION_ACCEPTED and v.mission == []
    assert v.mode is Mode.LOITER


def test_bad_missions_are_refused_whole_and_keep_the_mission_in_force() -> None:
    b = bridge()
    v = b.vehicles[2]
    upload(b, [item(0, (0, 2, 0)), item(1, (2, 2, 1))])
    kept = list(v.mission)
    effects = b.packet(GCS, [wire(mav.MAVLink_mission_count_message(2, 1, 10_000))])  # a 10,000-item mission
    assert [a.type for a in sent(effects, "MISSION_ACK")] == [mav.MAV_MISSION_NO_SPACE]
    assert refusals(effects) == ["mavlink-denied"] and v.upload is None
    for bad in [item(2, (6, 6, 1)), item(2, (40, 2, 1)),
                item(2, (1, 1, 1), command=mav.MAV_CMD_DO_SET_SERVO)]:
        effects = upload(b, [item(0, (0, 2, 0)), item(1, (1, 2, 1)), bad])
        assert sent(effects, "MISSION_ACK")[0].type != mav.MAV_MISSION_ACCEPTED
        assert refusals(effects) == ["mavlink-denied"]
        assert v.mission == kept
    # an item out of order is asked for again; an item outside an upload is refused
    b.packet(GCS, [wire(mav.MAVLink_mission_count_message(2, 1, 2))])
    assert sent(b.packet(GCS, [item(1, (1, 2, 1))]), "MISSION_REQUEST_INT")[0].seq == 0
    assert refusals(upload(b, [item(0, (0, 2, 0)), item(1, (1, 2, 1))]) + b.packet(GCS, [item(5, (1, 1, 1))])) == \
        ["mavlink-denied"]
    # a fence is not kept
    fence = wire(mav.MAVLink_mission_count_message(2, 1, 3, mav.MAV_MISSION_TYPE_FENCE))
    assert sent(b.packet(GCS, [fence]), "MISSION_ACK")[0].type == mav.MAV_MISSION_UNSUPPORTED
    assert MISSION_LIMIT < 10_000


def test_a_landing_item_outside_the_world_or_in_a_frame_not_flown_refuses_the_mission_whole() -> None:
    """A NAV_LAND at a latitude and longitude is checked at the upload as waypoints are (its altitude is the
    drone's when it lands): outside the world or in a frame not supported, the mission is refused whole."""
    b = bridge()
    v = b.vehicles[2]
    upload(b, [item(0, (0, 2, 0)), item(1, (2, 2, 1))])
    kept = list(v.mission)

    def land(frame: int, x: int, y: int):
        return wire(mav.MAVLink_mission_item_int_message(2, 1, 1, frame, mav.MAV_CMD_NAV_LAND, 0, 1, 0, 0, 0, 0,
                                                         x, y, 0.0))

    rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    lat, lon, _ = GEO.wgs84((0, 40, 0))
    for bad, result in [(land(rel, 900_000_000, 10), mav.MAV_MISSION_DENIED),  # (as a waypoint there)
                        (land(rel, round(lat * 1e7), round(lon * 1e7)), mav.MAV_MISSION_DENIED),
                        (land(mav.MAV_FRAME_LOCAL_NED, -20_000, 10_000), mav.MAV_MISSION_DENIED),
                        (land(200, 5, 5), mav.MAV_MISSION_UNSUPPORTED_FRAME)]:
        effects = upload(b, [item(0, (0, 2, 0)), bad])
        assert [a.type for a in sent(effects, "MISSION_ACK")] == [result]
        assert refusals(effects) == ["mavlink-denied"] and "mission item 1" in sent(effects, "STATUSTEXT")[0].text
        assert v.mission == kept
    lat, lon, _ = GEO.wgs84((6, 6, 0))  # on the building's roof, where the drone is, inside the world: taken
    for good in [land(rel, round(lat * 1e7), round(lon * 1e7)), land(200, 0, 0), land(mav.MAV_FRAME_LOCAL_NED,
                                                                                          30_000, 10_000)]:
        assert [a.type for a in sent(upload(b, [item(0, (0, 2, 0)), good]), "MISSION_ACK")] == \
            [mav.MAV_MISSION_ACCEPTED]


def goto(system: int, cell, client=CLIENT):
    """ArduPilot's guided goto: MISSION_ITEM_INT with current 2 (MAVProxy's `guided`)."""
    lat, lon, alt = GEO.wgs84(cell)
    return decode_datagram(mav.MAVLink_mission_item_int_message(
        system, 1, 0, mav.MAV_FRAME_GLOBAL_INT, mav.MAV_CMD_NAV_WAYPOINT, 2, 1, 0, 0, 0, 0, round(lat * 1e7),
        round(lon * 1e7), alt).pack(client))[0]


def test_an_upload_left_unfinished_is_dropped_after_its_timeout_and_never_takes_a_guided_goto() -> None:
    """A client gone mid-upload: the upload is dropped `UPLOAD_TIMEOUT_S` after it last moved (ArduPilot's 8 s),
    its uploader told (MISSION_ACK OPERATION_CANCELLED), counted, the mission in force kept; meanwhile a guided
    goto (current 2) from another client is flown, never taken as an item of it."""
    b = Bridge(Ground(WORLD, dict(STARTS), Plan(())), GEO, period=0.0, telemetry_period=100.0, now=0.0)
    v = b.vehicles[2]
    guided(b, 2)
    upload(b, [item(0, (0, 2, 0)), item(1, (2, 2, 1))])
    kept = list(v.mission)
    other = Origin(2, ("127.0.0.1", 6000))
    b.packet(GCS, [wire(mav.MAVLink_mission_count_message(2, 1, 3))], 10.0)
    assert sent(b.packet(GCS, [item(0, (0, 2, 0))], 12.0), "MISSION_REQUEST_INT")[0].seq == 1  # (it moved at 12)
    effects = b.packet(other, [goto(2, (3, 2, 1))], 13.0)
    assert v.goal == (3, 2, 1) and not refusals(effects) and not sent(effects, "MISSION_REQUEST_INT")
    assert v.upload is not None and len(v.upload.items) == 1  # (the goto is no item of it)
    b.tick(13.0)  # (telemetry: the next in 100 s)
    assert b.wake(13.0) == pytest.approx(12.0 + UPLOAD_TIMEOUT_S - 13.0)  # (woken to drop it in time)
    assert not sent(b.tick(12.0 + UPLOAD_TIMEOUT_S - 0.5), "MISSION_ACK") and v.upload is not None
    effects = b.tick(12.0 + UPLOAD_TIMEOUT_S)
    (cancelled,) = [e for e in effects if isinstance(e, Mav) and e.msg.get_type() == "MISSION_ACK"]
    assert cancelled.msg.type == mav.MAV_MISSION_OPERATION_CANCELLED and cancelled.to == GCS
    assert refusals(effects) == ["mavlink-timeout"] and "upload cancelled" in sent(effects, "STATUSTEXT")[0].text
    assert v.upload is None and v.mission == kept and not b.uploading
    effects = b.packet(GCS, [item(1, (2, 2, 1))], 21.0)  # the uploader back, too late: outside an upload
    assert refusals(effects) == ["mavlink-denied"] and v.mission == kept
    # an upload also lapses at the next message for its vehicle (whatever the ticks): another client's is taken
    b.packet(GCS, [wire(mav.MAVLink_mission_count_message(2, 1, 3))], 30.0)
    effects = b.packet(other, [wire(mav.MAVLink_mission_count_message(2, 1, 2))], 30.0 + UPLOAD_TIMEOUT_S)
    assert [(e.msg.get_type(), e.to) for e in effects if isinstance(e, Mav) and e.msg.get_type().startswith(
        "MISSION_")] == [("MISSION_ACK", GCS), ("MISSION_REQUEST_INT", other)]
    assert v.upload is not None and v.upload.origin == other


def test_only_the_uploader_uploads_while_its_upload_is_under_way() -> None:
    """Another client's items, MISSION_COUNT or clear during an upload are refused (MISSION_ACK DENIED to it,
    as ArduPilot answers), counted, and change nothing: the uploader's mission is the one taken. A client
    that sends from the uploader's address under another system id is another client."""
    b = bridge()
    v = b.vehicles[2]
    upload(b, [item(0, (0, 2, 0)), item(1, (2, 2, 1))])
    kept = list(v.mission)
    other = Origin(2, ("127.0.0.1", 6000))
    spoof = mav.MAVLink(None, srcSystem=254, srcComponent=190)

    def from_other(msg, client=CLIENT):
        return decode_datagram(msg.pack(client))[0]

    assert sent(b.packet(GCS, [wire(mav.MAVLink_mission_count_message(2, 1, 3))]), "MISSION_REQUEST_INT")
    lat, lon, alt = GEO.wgs84((9, 9, 3))
    theirs = mav.MAVLink_mission_item_int_message(2, 1, 0, mav.MAV_FRAME_GLOBAL_INT, mav.MAV_CMD_NAV_WAYPOINT, 0,
                                                  1, 0, 0, 0, 0, round(lat * 1e7), round(lon * 1e7), alt)
    for origin, msg in [(other, from_other(theirs)), (GCS, from_other(theirs, spoof)),
                        (other, from_other(mav.MAVLink_mission_count_message(2, 1, 2))),
                        (other, from_other(mav.MAVLink_mission_clear_all_message(2, 1)))]:
        effects = b.packet(origin, [msg])
        assert refusals(effects) == ["mavlink-sender"]
        assert [(e.msg.type, e.to) for e in effects if isinstance(e, Mav)] == [(mav.MAV_MISSION_DENIED, origin)]
        assert v.upload is not None and v.upload.origin == GCS and v.upload.items == [] and v.mission == kept
    effects = b.packet(GCS, [item(0, (0, 2, 0))])
    effects = b.packet(GCS, [item(1, (3, 2, 1))])
    effects = b.packet(GCS, [item(2, (3, 5, 1))])
    assert [(a.type, e.to) for e in effects if isinstance(e, Mav) and (a := e.msg).get_type() == "MISSION_ACK"] == \
        [(mav.MAV_MISSION_ACCEPTED, GCS)]
    assert [(it.x, it.y) for it in v.mission] == [(item(s, c).x, item(s, c).y)
                                                  for s, c in enumerate([(0, 2, 0), (3, 2, 1), (3, 5, 1)])]
    # the uploader may start again (a new MISSION_COUNT restarts its upload), as in ArduPilot
    b.packet(GCS, [wire(mav.MAVLink_mission_count_message(2, 1, 3))])
    b.packet(GCS, [item(0, (0, 2, 0))])
    assert sent(b.packet(GCS, [wire(mav.MAVLink_mission_count_message(2, 1, 2))]), "MISSION_REQUEST_INT")[0].seq == 0
    assert v.upload is not None and (v.upload.count, v.upload.items) == (2, [])


def test_a_mission_goes_on_from_an_item_the_drone_is_on_already() -> None:
    """Two items on one cell, a takeoff below the drone: reached at once (MISSION_ITEM_REACHED each), the
    mission goes on; it never waits for a target it has reached already."""
    b = bridge()
    v = b.vehicles[2]
    takeoff = wire(mav.MAVLink_mission_item_int_message(2, 1, 3, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                        mav.MAV_CMD_NAV_TAKEOFF, 0, 1, 0, 0, 0, 0, 0, 0, 1.0))
    upload(b, [item(0, (0, 2, 0)), item(1, (2, 2, 1)), item(2, (2, 2, 1)), takeoff, item(4, (3, 2, 1))])
    b.packet(GCS, [arm(2), set_mode(2, Mode.AUTO)])
    assert v.goal == (2, 2, 1)
    effects = b.receive(status(1, D02=row("D02", (2, 2, 1), target=(2, 2, 1), note=Note.REACHED)), 1.0)
    assert [m.seq for m in sent(effects, "MISSION_ITEM_REACHED")] == [1, 2, 3]
    assert (v.current, v.goal) == (4, (3, 2, 1))
    assert [m.seq for m in sent(effects, "MISSION_CURRENT")] == [2, 3, 4]


def test_a_mission_of_a_thousand_items_that_cannot_be_flown_is_skipped_in_one_go() -> None:
    """Takeoffs far above the world pass the upload (their altitude is a number) and are skipped in flight,
    each said: a thousand of them end the mission at once (a loop: no recursion to overflow)."""
    b = bridge()
    v = b.vehicles[2]
    high = [wire(mav.MAVLink_mission_item_int_message(2, 1, i, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                      mav.MAV_CMD_NAV_TAKEOFF, 0, 1, 0, 0, 0, 0, 0, 0, 500.0))
            for i in range(1, MISSION_LIMIT)]
    assert sent(upload(b, [item(0, (0, 2, 0)), *high]), "MISSION_ACK")[0].type == mav.MAV_MISSION_ACCEPTED
    effects = b.packet(GCS, [arm(2), set_mode(2, Mode.AUTO)])
    assert acks(effects) == [mav.MAV_RESULT_ACCEPTED] * 2
    texts = [m.text for m in sent(effects, "STATUSTEXT")]
    assert sum("skipped" in t for t in texts) == MISSION_LIMIT - 1 and "mission complete" in texts[-1]
    assert v.current == MISSION_LIMIT and v.goal == (0, 2, 0)
    assert v.mission_current().mission_state == mav.MISSION_STATE_COMPLETE


def test_mission_items_in_a_local_frame_and_a_landing_at_a_position() -> None:
    """MISSION_ITEM_INT carries local x and y in metres * 1e4; a NAV_LAND with a latitude and longitude
    lands below them (in the relative frame QGroundControl and MAVProxy use)."""
    b = bridge()
    v = b.vehicles[2]
    local = wire(mav.MAVLink_mission_item_int_message(2, 1, 1, mav.MAV_FRAME_LOCAL_NED, mav.MAV_CMD_NAV_WAYPOINT,
                                                      0, 1, 0, 0, 0, 0, 30_000, 50_000, -2.0))
    lat, lon, _ = GEO.wgs84((4, 1, 0))
    land = wire(mav.MAVLink_mission_item_int_message(2, 1, 2, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                     mav.MAV_CMD_NAV_LAND, 0, 1, 0, 0, 0, 0, round(lat * 1e7),
                                                     round(lon * 1e7), 0.0))
    assert sent(upload(b, [item(0, (0, 2, 0)), local, land]), "MISSION_ACK")[0].type == mav.MAV_MISSION_ACCEPTED
    b.packet(GCS, [arm(2), set_mode(2, Mode.AUTO)])
    assert v.goal == (3, 5, 2)
    b.receive(status(1, D02=row("D02", (3, 5, 2), target=(3, 5, 2), note=Note.REACHED)), 1.0)
    assert v.goal == (4, 1, 0)
    effects = b.receive(status(9, D02=row("D02", (4, 1, 0), target=(4, 1, 0), note=Note.REACHED)), 2.0)
    assert [m.seq for m in sent(effects, "MISSION_ITEM_REACHED")] == [2] and not v.armed


def test_a_lost_drone_and_an_unreachable_target_are_said_and_in_the_heartbeat() -> None:
    b = bridge()
    guided(b, 1)
    b.packet(GCS, [local_target(1, 5, 5, -1)])
    effects = b.receive(status(3, D01=row("D01", (1, 0, 0), target=(5, 5, 1), note=Note.UNREACHABLE)), 1.0)
    (text,) = sent(effects, "STATUSTEXT")
    assert "unreachable" in text.text and text.severity == mav.MAV_SEVERITY_CRITICAL
    assert [h.system_status for h in sent(effects, "HEARTBEAT")] == [mav.MAV_STATE_CRITICAL]  # (at once)
    effects = b.receive(status(4, D01=row("D01", (1, 0, 0), state=DroneState.LOST, cause=Cause.LOST)), 2.0)
    (text,) = sent(effects, "STATUSTEXT")
    assert "D01 is LOST" in text.text and text.severity == mav.MAV_SEVERITY_EMERGENCY
    assert [h.system_status for h in sent(effects, "HEARTBEAT")] == [mav.MAV_STATE_EMERGENCY]
    assert not sent(b.receive(status(5, D01=row("D01", (1, 0, 0), state=DroneState.LOST)), 3.0), "HEARTBEAT")
    effects = b.packet(GCS, [arm(1, False)])
    assert acks(effects) == [mav.MAV_RESULT_DENIED] and "lost" in sent(effects, "STATUSTEXT")[0].text


# ---------------------------------------------------------------------------------------------- the game


def test_the_phase_is_answered_at_the_turn_period_and_the_game_over_is_said() -> None:
    b = Bridge(Ground(WORLD, dict(STARTS), Plan(())), GEO, period=0.25, telemetry_period=10.0, now=0.0)
    b.tick(0.0)
    b.receive(status(0), 0.0)
    assert [type(e) for e in b.receive(Turn(turn=1, sender="SRV", phase=Phase.GCS), 0.0)] == []
    assert isinstance(b.tick(0.0)[0], SendDone)  # the first at once
    b.receive(status(1), 0.05)
    b.receive(Turn(turn=2, sender="SRV", phase=Phase.GCS), 0.05)
    assert b.wake(0.05) == pytest.approx(0.20) and b.tick(0.1) == []
    assert isinstance(b.tick(0.25)[0], SendDone)
    effects = b.receive(Over(turn=2, sender="SRV", reason=EndReason.TURN_LIMIT, text="turn limit 2"), 0.3)
    texts = sent(effects, "STATUSTEXT")
    assert len(texts) == 3 and all("game over" in t.text for t in texts)


def test_goal_effects_never_leave_the_core() -> None:
    b = bridge()
    guided(b, 1)
    assert not [e for e in b.packet(GCS, [local_target(1, 3, 0, -1)]) if isinstance(e, Goal)]
    assert b.station.wanted == {"D01": (3, 0, 1)}


def test_any_values_of_the_messages_handled_never_break_the_bridge() -> None:
    """Every message kind a vehicle acts on, with values drawn at random in their wire types (NaN, infinities,
    extremes), for systems in and out of the game: refused or taken, never an exception."""
    import random

    from entities.mavlink.bridge import HANDLED

    rng = random.Random(36)
    limits = {"int8_t": (-128, 127), "uint8_t": (0, 255), "int16_t": (-(1 << 15), (1 << 15) - 1),
              "uint16_t": (0, (1 << 16) - 1), "int32_t": (-(1 << 31), (1 << 31) - 1), "uint32_t": (0, (1 << 32) - 1),
              "int64_t": (-(1 << 63), (1 << 63) - 1), "uint64_t": (0, (1 << 64) - 1)}
    floats = [math.nan, math.inf, -math.inf, 0.0, 1.0, -1.0, 1e38, -1e38, 47.4, 8.5, 3.0]
    interesting = [0, 1, 2, 3, 4, 5, 6, 9, 15, 20, 21, 22, 176, 192, 300, 400, 512]

    def value(kind: str, name: str):
        if kind in ("float", "double"):
            return rng.choice(floats) if rng.random() < 0.7 else rng.uniform(-100, 100)
        if kind == "char":
            return rng.choice([b"x", b"", b"SYSID_THISMAV", b"\xff" * 16])
        lo, hi = limits[kind]
        if name in ("target_system", "target_component"):
            return rng.choice([0, 1, 2, 3, 7, 255])
        pick = rng.choice(interesting) if rng.random() < 0.6 else rng.randint(lo, hi)
        return min(max(pick, lo), hi)

    classes = [c for c in mav.mavlink_map.values() if c.msgname in HANDLED]
    assert len(classes) == len(HANDLED)
    b = bridge()
    for _ in range(1500):
        cls = rng.choice(classes)
        args = []
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))  # (array_lengths are in wire order)
        for name, kind in zip(cls.fieldnames, cls.fieldtypes):
            length = lengths[name]
            args.append([value(kind, name) for _ in range(length)] if length and kind != "char" else value(kind, name))
        msg = cls(*args)
        b.packet(Origin(rng.choice([0, 1, 2, 3]), ("127.0.0.1", 9)), [wire(msg)])
        if rng.random() < 0.05:
            b.receive(status(1), 1.0)


def test_links_send_a_destinations_frames_together_in_order_and_under_the_mtu() -> None:
    from entities.mavlink.node import DATAGRAM_PACK

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gcs, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as api:
        gcs.bind(("127.0.0.1", 0))
        api.bind(("127.0.0.1", 0))
        links = Links(gcs.getsockname(), api.getsockname()[1], [1])
        try:
            texts = [f"message {i}" for i in range(100)]
            for text in texts:
                links.send(Mav(1, mav.MAVLink_statustext_message(6, text.encode())))
            assert links.sent == 0  # (queued until flushed)
            links.flush()
            for sock in (gcs, api):
                got, sock_texts = [], []
                sock.settimeout(10)
                while len(sock_texts) < len(texts):
                    data = sock.recv(65535)
                    got.append(len(data))
                    sock_texts += [m.text for m in decode_datagram(data)]
                assert sock_texts == texts and max(got) <= DATAGRAM_PACK and len(got) < len(texts) / 10
            seqs = [m.get_seq() for m in decode_datagram(b"".join(
                links.encode(1, mav.MAVLink_heartbeat_message(2, 3, 0, 0, 3, 3)) for _ in range(3)))]
            assert seqs == [100, 101, 102]  # one sequence a vehicle
        finally:
            links.close()


def test_drones_past_system_255_fly_on_without_a_vehicle() -> None:
    world = World.from_buildings((30, 30, 2), [])
    starts = {f"D{n:02d}": (n % 30, n // 30, 0) for n in range(1, 301)}
    b = Bridge(Ground(world, starts, Plan(())), GEO, period=0.0, telemetry_period=1.0, now=0.0)
    assert sorted(b.vehicles) == list(range(1, 256)) and b.unseen == 45
    rows = tuple(DroneStatus(drone=d, pos=c, state=DroneState.ALIVE) for d, c in starts.items())
    b.receive(Status(turn=0, sender="OBS", drones=rows), 0.0)  # (rows of drones without a vehicle: skipped)
    assert {e.system for e in b.tick(0.0) if isinstance(e, Mav)} == set(range(1, 256))


def test_the_flags_are_checked_before_anything_starts() -> None:
    from entities.mavlink.options import parse_udpout

    assert parse_udpout("udpout:127.0.0.1:14550") == ("127.0.0.1", 14550)
    assert parse_udpout("udpout:gcs.example:9") == ("gcs.example", 9)
    for bad in ["udpin:0.0.0.0:14550", "udpout:127.0.0.1", "udpout::14550", "udpout:h:0", "udpout:h:70000", "x"]:
        with pytest.raises(UsageError, match="udpout:HOST:PORT"):
            parse_udpout(bad)
    with pytest.raises(UsageError, match="must be UDP ports"):
        Links(("127.0.0.1", 9), 65500, [1, 2, 255])
