"""`dronesim up --mavlink` flown by the real clients, several vehicles at once: MAVProxy headless (on the ground
station's shared link and on a vehicle's API port), pymavlink (raw commands, position targets, the mission
protocol, and bad input over the wire), MAVSDK-Python (telemetry, arm, takeoff, goto_location, land, and a
mission uploaded and flown). Each game's journal shows the targets the clients set, and `dronesim replay
--verify` re-simulates it byte for byte.

Each game runs on ports of its own (--mavlink-gcs, --mavlink-api-base), so tests may run side by side."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import queue
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

mavutil = pytest.importorskip("pymavlink.mavutil", reason="pymavlink (the mavlink extra) is needed")

from dronesim import child_env  # noqa: E402
from entities.mavlink.geo import Geo  # noqa: E402
from tests.harness import Proc, journal_records  # noqa: E402

pytestmark = [pytest.mark.integration]

WORLD = {"format": "dronesim-world", "version": 1, "size": [12, 12, 8], "buildings": [[6, 6, 2, 2, 4]]}
STARTS = [(0, 0, 0), (0, 2, 0), (0, 4, 0), (0, 6, 0)]
GEO = Geo()
COPTER_GUIDED, COPTER_AUTO = 4, 3


def free_ports(n: int) -> int:
    """The first of `n` consecutive UDP ports free on loopback now."""
    for _ in range(200):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.1", 0))
            base = probe.getsockname()[1]
        if base + n > 65535:
            continue
        socks = []
        try:
            for port in range(base, base + n):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", port))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise AssertionError("no free UDP ports")


def children(pid: int) -> list[int]:
    """The processes whose parent is `pid` (from /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, IndexError, ValueError):
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(stat.parent.name))
    return out


def cmdline(pid: int) -> str:
    try:
        return " " + Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode() + " "
    except OSError:
        return ""


@dataclass
class Game:
    proc: Proc
    gcs: int  # the ground station's port (the fleet sends there)
    api: int  # vehicle n's API client port is api + n - 1
    journal: Path
    tmp: Path

    def targets(self) -> dict[str, list[tuple[int, int, int]]]:
        """Each drone's targets, in the order the journal records them."""
        out: dict[str, list[tuple[int, int, int]]] = {}
        for record in journal_records(self.journal):
            for drone, cell in record.get("targets", {}).items():
                out.setdefault(drone, []).append(tuple(cell))
        return out

    def finish(self) -> str:
        """End the game as the station's person does (Ctrl-C on the ground station: it quits the game at its
        next phase), check every process exited 0 and the journal re-simulates; return the output."""
        gcs = [pid for pid in children(self.proc.p.pid) if " gcs " in cmdline(pid)]
        assert len(gcs) == 1, f"the ground station's process among {children(self.proc.p.pid)}"
        os.kill(gcs[0], signal.SIGINT)
        assert self.proc.wait(120) == 0, self.proc.text[-3000:]
        assert "GCS_QUIT" in self.proc.text
        verify = subprocess.run([sys.executable, "-m", "dronesim", "replay", "--verify", str(self.journal)],
                                capture_output=True, text=True, env=child_env(), timeout=300)
        assert verify.returncode == 0 and "verified" in verify.stdout, verify.stdout + verify.stderr
        return self.proc.text


@contextlib.contextmanager
def game(tmp_path: Path, drones: int = 3, period: float = 0.05) -> Iterator[Game]:
    world = tmp_path / "world.json"
    world.write_text(json.dumps(WORLD))
    gcs, api = free_ports(1), free_ports(drones)
    journal = tmp_path / "journal.jsonl"
    argv = [sys.executable, "-m", "dronesim", "up", "--mavlink", "--world", str(world), "--drones", str(drones),
            "--starts", ";".join(",".join(map(str, c)) for c in STARTS[:drones]), "--max-turns", "3000",
            "--turn-period", str(period), "--mavlink-gcs", f"udpout:127.0.0.1:{gcs}", "--mavlink-api-base", str(api),
            "--journal", str(journal), "--quiet", "--log-level", "INFO",
            "--autopilot", "dstar"]  # (the seed's pilot explores before it goes where it has been: slow the 2nd time)
    proc = Proc("up", argv, tmp_path)
    try:
        expect(proc, r"MAVLink ground station: systems 1\.\.")
        yield Game(proc, gcs, api, journal, tmp_path)
    finally:
        proc.kill()


def expect(proc: Proc, pattern: str, timeout: float = 120.0) -> str:
    """The first line of `proc` matching `pattern` within `timeout` s in all (`Proc.expect` waits that long
    for each line: a client that talks all the time would never time out)."""
    rx, end, closed = re.compile(pattern), time.monotonic() + timeout, 0
    for line in proc.out + proc.err:
        if rx.search(line):
            return line
    while closed < 2 and (left := end - time.monotonic()) > 0:
        try:
            item = proc.lines.get(timeout=left)
        except queue.Empty:
            break
        if item is None:
            closed += 1
        elif rx.search(item[1]):
            return item[1]
    raise AssertionError(f"{proc.name}: no line matching {pattern!r} within {timeout} s:\n{proc.text[-4000:]}")


def relative(cell: tuple[int, int, int]) -> tuple[float, float, float]:
    """A cell as latitude, longitude and altitude above home (home on the ground: z = 0)."""
    lat, lon, _ = GEO.wgs84(cell)
    return lat, lon, float(cell[2])


# ---------------------------------------------------------------------------------------------- MAVProxy


def mavproxy(master: str, target: int, cmds: list[str], cwd: Path, name: str) -> Proc:
    """MAVProxy headless. Its --cmd runs before the first vehicle message, when nothing can be sent yet (the
    link learns the vehicle's address from what it receives): each command is repeated every second, as the
    command protocol allows (a repeat is accepted and changes nothing)."""
    beside = Path(sys.executable).parent / "mavproxy.py"  # (pip puts it beside the interpreter)
    exe = shutil.which("mavproxy.py") or (str(beside) if beside.exists() else None)
    if exe is None:
        pytest.skip("MAVProxy (the mavlink extra) is not installed: mavproxy.py not found")
    repeats = "; ".join(f"repeat add 1 {c}" for c in cmds)
    argv = [sys.executable, exe, f"--master={master}", "--non-interactive", "--no-state",
            f"--target-system={target}", "--cmd", repeats]
    proc = Proc(name, argv, cwd)
    return proc


def test_mavproxy_flies_two_vehicles_at_once(tmp_path: Path) -> None:
    """One MAVProxy on the ground station's link (the whole fleet) flies D02, another on D03's API port
    flies D03: mode GUIDED, arm throttle, guided LAT LON ALT (DO_REPOSITION). A third, on D01's API port, is
    refused: `guided` into the building (DENIED, and a STATUSTEXT saying why), a mode Copter has and the
    vehicle does not fly (CIRCLE: DENIED, the modes it flies said), DO_CHANGE_SPEED (UNSUPPORTED); D01 never
    gets a target."""
    goal2, goal3 = (8, 3, 3), (4, 9, 2)
    with game(tmp_path) as g:
        lat, lon, alt = relative(goal2)
        fleet = mavproxy(f"udpin:0.0.0.0:{g.gcs}", 2, ["mode GUIDED", "arm throttle", f"guided {lat} {lon} {alt}"],
                         tmp_path, "mavproxy-fleet")
        lat, lon, alt = relative(goal3)
        one = mavproxy(f"udpin:127.0.0.1:{g.api + 2}", 3, ["mode GUIDED", "arm throttle",
                                                            f"guided {lat} {lon} {alt}"], tmp_path, "mavproxy-d03")
        lat, lon, alt = relative((6, 7, 1))  # (the building: x 6..7, y 6..7, up to z 3)
        refused = mavproxy(f"udpin:127.0.0.1:{g.api}", 1, ["mode GUIDED", "arm throttle", f"guided {lat} {lon} {alt}",
                                                           "mode CIRCLE", "long DO_CHANGE_SPEED 1 5 -1"],
                           tmp_path, "mavproxy-d01")
        try:
            expect(fleet, r"Detected vehicle 3:1")  # the shared link shows the whole fleet
            expect(fleet, r"AP: D02 reached \(8, 3, 3\)")
            expect(one, r"AP: D03 reached \(4, 9, 2\)")
            expect(one, r"Received 1 parameters")  # (its parameter list: SYSID_THISMAV, after trying MAVFTP)
            expect(refused, r"Got COMMAND_ACK: DO_REPOSITION: DENIED")
            expect(refused, r"AP: D01: target refused: .*building")
            expect(refused, r"AP: D01: mode 7 is not flown here: AUTO 3, GUIDED 4, LOITER 5, RTL 6, LAND 9")
            expect(refused, r"Got COMMAND_ACK: DO_CHANGE_SPEED: UNSUPPORTED")
        finally:
            fleet.kill()
            one.kill()
            refused.kill()
        out = g.finish()
    targets = g.targets()
    assert targets["D02"] == [goal2] and targets["D03"] == [goal3] and "D01" not in targets
    assert "D02: " in out


# ---------------------------------------------------------------------------------------------- pymavlink


def wait_for(conn, kind: str, system: int, pred=lambda m: True, timeout: float = 30.0):
    end = time.monotonic() + timeout
    while (left := end - time.monotonic()) > 0:
        msg = conn.recv_match(type=kind, blocking=True, timeout=left)
        if msg is not None and msg.get_srcSystem() == system and pred(msg):
            return msg
    raise AssertionError(f"no {kind} from system {system} within {timeout} s")


def command(conn, system: int, cmd: int, *params: float) -> int:
    p = [*params, *[0.0] * (7 - len(params))]
    conn.mav.command_long_send(system, 1, cmd, 0, *p)
    return wait_for(conn, "COMMAND_ACK", system, lambda m: m.command == cmd).result


def test_pymavlink_commands_position_targets_missions_and_bad_input(tmp_path: Path) -> None:
    """pymavlink on the shared link: raw COMMAND_LONGs, SET_POSITION_TARGET_LOCAL_NED for D01,
    SET_POSITION_TARGET_GLOBAL_INT for D02, a mission uploaded to D03, read back, flown in AUTO, flown again from
    item 1 (MISSION_SET_CURRENT) and cleared; meanwhile garbage,
    MAVLink 1 frames, commands for systems the game does not fly, NaN targets, a 10,000-item mission, a
    position inside the building (DENIED, said why), a mode not flown (DENIED), DO_CHANGE_SPEED (UNSUPPORTED)
    and a flood of 500 commands (TEMPORARILY_REJECTED past the budget) are refused and counted, and change
    nothing."""
    mav = mavutil.mavlink
    with game(tmp_path) as g:
        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{g.gcs}", source_system=255, dialect="ardupilotmega")
        try:
            for system in (1, 2, 3):
                wait_for(conn, "HEARTBEAT", system)
                assert command(conn, system, mav.MAV_CMD_DO_SET_MODE, 1, COPTER_GUIDED) == mav.MAV_RESULT_ACCEPTED
                assert command(conn, system, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
            # bad input first: none of it may move anything
            (bridge,) = conn.clients  # (the fleet writes from one socket: bad input goes there)
            conn.port.sendto(b"\xfd\x05garbage that is not a frame", bridge)
            conn.port.sendto(bytes(range(256)), bridge)
            conn.port.sendto(b"\xfd\x01\x00\x00\x00\xff\xbe\xde\xbc\x0a\x01\x00\x00", bridge)  # (an unknown id)
            v1 = mav.MAVLink(None, srcSystem=255)
            conn.port.sendto(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0,
                                                              0, 0, 0).pack(v1, force_mavlink1=True), bridge)
            conn.mav.command_long_send(9, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0)  # no system 9
            assert command(conn, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, math.nan) == mav.MAV_RESULT_DENIED  # (armed)
            conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)  # (ignored: counted)
            assert command(conn, 1, mav.MAV_CMD_DO_REPOSITION, -1, 1, 0, 0, math.nan, math.nan, 1e9) == \
                mav.MAV_RESULT_DENIED
            conn.mav.set_position_target_local_ned_send(0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b110111111000,
                                                        math.nan, 1.0, -1.0, 0, 0, 0, 0, 0, 0, 0, 0)
            wait_for(conn, "STATUSTEXT", 1, lambda m: "not a finite position" in m.text)
            conn.mav.mission_count_send(2, 1, 10_000)
            assert wait_for(conn, "MISSION_ACK", 2).type == mav.MAV_MISSION_NO_SPACE
            lat, lon, alt = relative((7, 6, 2))  # (inside the building)
            conn.mav.command_int_send(2, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0,
                                      -1, 0, 0, 0, round(lat * 1e7), round(lon * 1e7), alt)
            assert wait_for(conn, "COMMAND_ACK", 2, lambda m: m.command == mav.MAV_CMD_DO_REPOSITION).result == \
                mav.MAV_RESULT_DENIED
            wait_for(conn, "STATUSTEXT", 2, lambda m: "target refused: (7, 6, 2) is inside" in m.text)  # (a chunk)
            assert command(conn, 2, mav.MAV_CMD_DO_CHANGE_SPEED, 1, 5, -1) == mav.MAV_RESULT_UNSUPPORTED
            assert command(conn, 2, mav.MAV_CMD_DO_SET_MODE, 1, 7) == mav.MAV_RESULT_DENIED  # (Copter's CIRCLE)
            # D01: a local position target (north 5, east 1, up 2), D02: a global one (above home)
            conn.mav.set_position_target_local_ned_send(0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b110111111000,
                                                        5.0, 1.0, -2.0, 0, 0, 0, 0, 0, 0, 0, 0)
            lat, lon, alt = relative((9, 2, 2))
            conn.mav.set_position_target_global_int_send(0, 2, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                                         0b110111111000, round(lat * 1e7), round(lon * 1e7), alt,
                                                         0, 0, 0, 0, 0, 0, 0, 0)
            # D03: a mission (item 0 is home, as in ArduPilot's), uploaded, read back, flown in AUTO
            cells = [STARTS[2], (2, 4, 2), (2, 8, 2), (4, 8, 2)]
            conn.mav.mission_count_send(3, 1, len(cells))
            for _ in cells:
                req = wait_for(conn, "MISSION_REQUEST_INT", 3)
                lat, lon, alt = relative(cells[req.seq])
                conn.mav.mission_item_int_send(3, 1, req.seq, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                               mav.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0, round(lat * 1e7),
                                               round(lon * 1e7), alt)
            assert wait_for(conn, "MISSION_ACK", 3).type == mav.MAV_MISSION_ACCEPTED
            conn.mav.mission_request_list_send(3, 1)
            assert wait_for(conn, "MISSION_COUNT", 3).count == len(cells)
            conn.mav.mission_request_int_send(3, 1, 2)
            back = wait_for(conn, "MISSION_ITEM_INT", 3)
            assert (back.seq, GEO.cell_of_wgs84(back.x / 1e7, back.y / 1e7, GEO.amsl(0) + back.z)) == (2, cells[2])
            conn.mav.mission_ack_send(3, 1, mav.MAV_MISSION_ACCEPTED)
            assert command(conn, 3, mav.MAV_CMD_DO_SET_MODE, 1, COPTER_AUTO) == mav.MAV_RESULT_ACCEPTED
            wait_for(conn, "MISSION_ITEM_REACHED", 3, lambda m: m.seq == 3, timeout=60)
            # set current: item 1 again (MISSION_CURRENT says so), the rest flown again; then the mission cleared
            conn.mav.mission_set_current_send(3, 1, 1)
            wait_for(conn, "MISSION_CURRENT", 3, lambda m: m.seq == 1)
            wait_for(conn, "MISSION_ITEM_REACHED", 3, lambda m: m.seq == 3, timeout=60)
            conn.mav.mission_clear_all_send(3, 1)
            assert wait_for(conn, "MISSION_ACK", 3).type == mav.MAV_MISSION_ACCEPTED
            conn.mav.mission_request_list_send(3, 1)
            assert wait_for(conn, "MISSION_COUNT", 3).count == 0
            # (a STATUSTEXT comes once: it may have gone by while waiting for the mission; positions come every turn)
            wait_for(conn, "LOCAL_POSITION_NED", 1, lambda m: (m.x, m.y, m.z) == (5.0, 1.0, -2.0), timeout=60)
            wait_for(conn, "GLOBAL_POSITION_INT", 2, lambda m: GEO.cell_of_wgs84(m.lat / 1e7, m.lon / 1e7,
                                                                                  m.alt / 1000) == (9, 2, 2))
            # a command flood at D01, there now: 500 mode changes (to its mode) in two datagrams, each answered
            # (encoded by the connection: MAVLink 2 since it heard the vehicles; `mav` is the dialect before that)
            frame = conn.mav.command_long_encode(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, COPTER_GUIDED, 0, 0, 0, 0, 0)
            for _ in range(2):
                conn.port.sendto(frame.pack(conn.mav) * 250, bridge)
            wait_for(conn, "COMMAND_ACK", 1, lambda m: m.result == mav.MAV_RESULT_TEMPORARILY_REJECTED)
            out = g.finish()  # (the station quits: every vehicle says the game is over)
            for system in (1, 2, 3):
                wait_for(conn, "STATUSTEXT", system, lambda m: m.text.startswith("game over: GCS_QUIT"))
        finally:
            conn.close()
    assert g.targets() == {"D01": [(5, 1, 2)], "D02": [(9, 2, 2)], "D03": [(2, 4, 2), (2, 8, 2), (4, 8, 2)] * 2}
    (rejected,) = [line for line in out.splitlines() if "rejected inputs" in line and "GCS" in line]
    for reason in ("mavlink-garbage", "mavlink1", "mavlink-target", "mavlink-denied", "mavlink-flood"):
        assert reason in rejected
    (ignored,) = [line for line in out.splitlines() if "MAVLink messages ignored" in line and "GCS" in line]
    assert "HEARTBEAT" in ignored


# ---------------------------------------------------------------------------------------------- MAVSDK


def test_mavsdk_flies_one_vehicle_and_a_mission_on_another(tmp_path: Path) -> None:
    """MAVSDK-Python (the native 4.x binding), one instance a vehicle as PX4's layout has it (udpin on
    14540 + n - 1): D02 takes off, is refused a position in the building (COMMAND_DENIED, the STATUSTEXT
    saying why) and a speed (UNSUPPORTED), goes to a position (goto_location) and lands; D03 flies a mission
    uploaded by MissionRaw (item 0 home, as ArduPilot's missions are)."""
    mavsdk = pytest.importorskip("mavsdk.asyncio", reason="MAVSDK-Python (the mavlink extra) is needed")
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
    from mavsdk.plugins.action import ActionError, ActionResult
    from mavsdk.plugins.mission_raw import MissionItem

    async def connect(sdk, port: int):
        await sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await sdk.first_autopilot(timeout_s=30.0)
        assert system is not None, f"no autopilot on port {port}"
        return system

    async def position(tel, pred=lambda p: True):
        async for p in tel.subscribe_position():
            if not math.isnan(p.latitude_deg) and pred(p):
                return p

    async def status_text(tel, part: str) -> str:
        async for text in tel.subscribe_status_text():
            if part in text.text:
                return text.text
        raise AssertionError("no more status texts")

    async def fly_d02(sdk, port: int) -> None:
        system = await connect(sdk, port)
        assert await system.get_system_id() == 2
        tel, act = TelemetryAsync(system), ActionAsync(system)
        home = await position(tel)
        assert GEO.cell_of_wgs84(home.latitude_deg, home.longitude_deg, home.absolute_altitude_m) == STARTS[1]
        await act.arm()
        await act.set_takeoff_altitude(3.0)
        await act.takeoff()
        up = await position(tel, lambda p: p.relative_altitude_m > 2.5)
        # refused: a position inside the building (DENIED, a STATUSTEXT saying why), a speed (UNSUPPORTED)
        texts = asyncio.ensure_future(status_text(tel, "target refused"))
        await asyncio.sleep(0)  # (the task subscribes at its first step, before the command goes)
        with pytest.raises(ActionError) as denied:
            await act.goto_location(*GEO.wgs84((6, 7, 1)), 0.0)
        assert denied.value.result is ActionResult.COMMAND_DENIED
        assert "inside a building" in await asyncio.wait_for(texts, 30)
        with pytest.raises(ActionError) as unsupported:
            await act.set_current_speed(5.0)
        assert unsupported.value.result is ActionResult.UNSUPPORTED
        lat, lon, amsl = GEO.wgs84((5, 3, 3))
        await act.goto_location(lat, lon, amsl, 0.0)
        await position(tel, lambda p: GEO.cell_of_wgs84(p.latitude_deg, p.longitude_deg,
                                                        p.absolute_altitude_m) == (5, 3, 3))
        await act.land()
        async for in_air in tel.subscribe_in_air():
            if not in_air:
                break
        assert up.relative_altitude_m == pytest.approx(3.0)

    async def fly_d03(sdk, port: int) -> None:
        system = await connect(sdk, port)
        mission = MissionRawAsync(system)
        frame, wp = mavutil.mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavutil.mavlink.MAV_CMD_NAV_WAYPOINT
        cells = [STARTS[2], (1, 4, 1), (1, 7, 1)]
        items = [MissionItem(seq=i, frame=frame, command=wp, current=int(i == 0), autocontinue=1, param1=0,
                             param2=0, param3=0, param4=0, x=round(relative(c)[0] * 1e7),
                             y=round(relative(c)[1] * 1e7), z=relative(c)[2], mission_type=0)
                 for i, c in enumerate(cells)]
        await mission.upload_mission(items)
        await ActionAsync(system).arm()
        await mission.start_mission()
        async for progress in mission.subscribe_mission_progress():
            if progress.current >= len(cells) - 1:  # flying the last item
                break
        await position(TelemetryAsync(system), lambda p: GEO.cell_of_wgs84(
            p.latitude_deg, p.longitude_deg, p.absolute_altitude_m) == cells[-1])

    async def main(api: int) -> None:
        configs = [mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION)
                   for _ in range(2)]
        async with mavsdk.Mavsdk(configs[0]) as one, mavsdk.Mavsdk(configs[1]) as other:
            await asyncio.wait_for(asyncio.gather(fly_d02(one, api + 1), fly_d03(other, api + 2)), 90)

    with game(tmp_path) as g:
        asyncio.run(main(g.api))
        g.finish()
    targets = g.targets()
    # MAVSDK arms in LOITER, then asks for GUIDED, then takes off: entering GUIDED armed holds the start cell
    # (tests/test_mavlink.py), in the journal too when a turn ends before the takeoff comes
    d02 = targets["D02"][1:] if targets["D02"][0] == STARTS[1] else targets["D02"]
    assert d02[:2] == [(0, 2, 3), (5, 3, 3)] and d02[-1] == (5, 3, 0)
    assert targets["D03"] == [(1, 4, 1), (1, 7, 1)]


# ---------------------------------------------------------------------------------------------- a swarm


def test_a_hundred_vehicles_stream_while_the_game_plays_at_full_speed(tmp_path: Path) -> None:
    """100 drones from one swarm host, --turn-period 0: every one of them a vehicle whose telemetry reaches a
    pymavlink ground station on the shared link while the game plays to its turn limit (its speed is
    `dronesim bench perf`'s MAVLink row, not a test's)."""
    gcs, turns = free_ports(1), 150
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs}", source_system=255, dialect="ardupilotmega")
    journal = tmp_path / "journal.jsonl"
    argv = [sys.executable, "-m", "dronesim", "up", "--mavlink", "--swarm", "--drones", "100", "--size", "64,64,4",
            "--max-turns", str(turns), "--turn-period", "0", "--quiet", "--journal", str(journal),
            "--mavlink-gcs", f"udpout:127.0.0.1:{gcs}", "--mavlink-api-base", str(free_ports(100))]
    proc = Proc("up", argv, tmp_path)
    heartbeats: set[int] = set()
    positions = 0
    try:
        end = time.monotonic() + 300
        while proc.p.poll() is None and time.monotonic() < end:
            msg = conn.recv_msg()
            if msg is None:
                conn.select(0.5)
            elif msg.get_type() == "HEARTBEAT":
                heartbeats.add(msg.get_srcSystem())
            elif msg.get_type() == "LOCAL_POSITION_NED":
                positions += 1
        assert proc.wait(60) == 0, proc.text[-3000:]
    finally:
        conn.close()
        proc.kill()
    assert heartbeats == set(range(1, 101))
    assert positions >= 100  # (at least each vehicle's telemetry set once)
    assert sum(1 for r in journal_records(journal) if r["record"] == "turn") == turns


def test_the_speed_benchmarks_game_flies_every_vehicle_every_turn() -> None:
    """`python -m benchmarks.mavlink`'s whole game (BENCHMARKS.md, "MAVLink ground station"), with 10 vehicles:
    its pymavlink ground station flies every vehicle 150 cells north, so D01 moves every turn for 150 turns and
    the rate is timed over them (the rate itself is the benchmark's, not a test's)."""
    from benchmarks.mavlink import game_rate

    r = game_rate(vehicles=10, turns=250)
    assert r["turns"] == 250 and 145 <= r["moving"] <= 150 and r["tps"] > 0 and r["messages"] >= 10
