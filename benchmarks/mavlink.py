"""The MAVLink ground station's CPU per turn (a row of `dronesim bench perf`; docs/mavlink.md, Speed).

In this process, the bridge as `dronesim gcs --mavlink` runs it, without Zenoh: `vehicles` drones armed in
GUIDED, each flying to a target, every turn a STATUS in which each of them moves a cell and the GCS phase
answered, the game clock at 20 turns a second (the whole telemetry set every `MAVLINK_TELEMETRY_S`), every
message encoded by pymavlink and sent over UDP to the ground station's port and each vehicle's API port, as
the adapter sends them. CPU: this process's user + system time over the measured turns."""

from __future__ import annotations

import socket
import time

from schema import DroneState, DroneStatus, Phase, Status, StatusTable, Turn, drone_id
from schema.tuning import MAVLINK_TELEMETRY_S

#: The turn rate the bridge must sustain with 100 vehicles (issue 36).
TARGET_TPS = 20.0


def bridge_cpu(vehicles: int = 100, turns: int = 200, warmup: int = 20) -> dict[str, float]:
    """{"cpu": CPU seconds per turn, "messages": messages sent per turn, "datagrams": datagrams sent per turn,
    "turns": turns measured}."""
    from pymavlink.dialects.v20 import ardupilotmega as mav

    from entities.gcs import Ground, Plan
    from entities.mavlink.bridge import Bridge
    from entities.mavlink.geo import Geo
    from entities.mavlink.node import Links, decode_datagram
    from entities.mavlink.vehicle import Mav, Origin
    from world.grid import World

    side = 64
    world = World.from_buildings((side, side, 8), [])
    starts = {drone_id(n): ((n - 1) % side, 2 * ((n - 1) // side), 1) for n in range(1, vehicles + 1)}
    bridge = Bridge(Ground(world, starts, Plan(())), Geo(), period=0.0, telemetry_period=MAVLINK_TELEMETRY_S,
                    now=0.0)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
        sink.bind(("127.0.0.1", 0))
        sink.setblocking(False)
        links = Links(sink.getsockname(), 40000, sorted(bridge.vehicles))
        client = mav.MAVLink(None, srcSystem=255, srcComponent=190)
        gcs = Origin(0, sink.getsockname())

        def perform(effects) -> int:
            sent = 0
            for e in effects:
                if isinstance(e, Mav):
                    links.send(e)
                    sent += 1
            links.flush()
            while True:  # (the sink drops what it got: its buffer never fills)
                try:
                    sink.recv(65535)
                except BlockingIOError:
                    break
            return sent

        for n in bridge.vehicles:  # every vehicle armed in GUIDED, flying to the far side
            for msg in (mav.MAVLink_command_long_message(n, 1, 176, 0, 1, 4, 0, 0, 0, 0, 0),
                        mav.MAVLink_command_long_message(n, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
                        mav.MAVLink_set_position_target_local_ned_message(0, n, 1, 1, 0b110111111000,
                                                                          side - 1, starts[drone_id(n)][1], -1,
                                                                          0, 0, 0, 0, 0, 0, 0, 0)):
                perform(bridge.packet(gcs, decode_datagram(msg.pack(client))))
        statuses = []  # every turn's STATUS, made before the clock starts (the coordinator's work, not ours)
        pos = dict(starts)
        for turn in range(1, warmup + turns + 1):
            pos = {d: ((x + 1) % side, y, z) for d, (x, y, z) in pos.items()}
            rows = StatusTable.of(DroneStatus(drone=d, pos=c, state=DroneState.ALIVE, target=(side - 1, c[1], 1))
                                  for d, c in sorted(pos.items()))
            statuses.append(Status(turn=turn - 1, sender="OBS", drones=rows))
        cpu0, sent, datagrams = 0.0, 0, 0
        try:
            for turn, status in enumerate(statuses, 1):
                if turn == warmup + 1:
                    cpu0, sent, datagrams = time.process_time(), 0, links.sent
                now = turn / TARGET_TPS
                sent += perform(bridge.receive(status, now))
                sent += perform(bridge.receive(Turn(turn=turn, sender="SRV", phase=Phase.GCS), now))
                sent += perform(bridge.tick(now))
            cpu, datagrams = time.process_time() - cpu0, links.sent - datagrams
        finally:
            links.close()
    return {"cpu": cpu / turns, "messages": sent / turns, "datagrams": datagrams / turns, "turns": float(turns)}


def game_rate(vehicles: int = 100, turns: int = 400, timeout: float = 300.0) -> dict[str, float]:
    """`dronesim up --mavlink --swarm` with `vehicles` drones at full speed (--turn-period 0) on an empty world of
    200 x 64 cells, flown by a pymavlink ground station in this process on the shared link, as a person's would:
    once the fleet is heard, each vehicle armed in GUIDED and sent 150 cells north (SET_POSITION_TARGET_LOCAL_NED
    in LOCAL_OFFSET_NED), so that every one moves a cell a turn and streams its position each turn, beside every
    vehicle's telemetry set.
    The rate is timed by the vehicles' own clock (time_boot_ms): the turns' position batches (stamps that are no
    telemetry set's) while D01 moves, their count less one over their span. {"tps": that rate, "moving": those
    turns, "turns": turns played, "messages": MAVLink messages received a turn while they moved}."""
    import json
    import subprocess
    import sys
    import tempfile

    from pymavlink import mavutil

    from coordinator.journal import is_turn, read
    from dronesim import child_env

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, dialect="ardupilotmega")
    mav = mavutil.mavlink
    folder = tempfile.TemporaryDirectory(prefix="dronesim-mavlink-")
    world, journal = f"{folder.name}/world.json", f"{folder.name}/journal.jsonl"
    with open(world, "w", encoding="utf-8") as f:
        json.dump({"format": "dronesim-world", "version": 1, "size": [200, 64, 2], "buildings": []}, f)
    argv = [sys.executable, "-m", "dronesim", "up", "--mavlink", "--swarm", "--drones", str(vehicles),
            "--world", world, "--max-turns", str(turns), "--turn-period", "0", "--quiet", "--journal", journal,
            "--mavlink-gcs", f"udpout:127.0.0.1:{port}", "--mavlink-api-base", "41000"]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=child_env())
    flying = False
    stamps: set[int] = set()  # time_boot_ms of the turns' positions (D01's, while it moves)
    sets: set[int] = set()  # ... of the telemetry sets (ATTITUDE comes only in them)
    last: tuple[float, float] | None = None
    received = 0
    window: list[int] = []  # messages received while D01 moves: [first index, last index]
    end = time.monotonic() + timeout
    try:
        while proc.poll() is None and time.monotonic() < end:
            msg = conn.recv_msg()
            if msg is None:
                conn.select(0.5)
                continue
            received += 1
            kind, system = msg.get_type(), msg.get_srcSystem()
            if kind == "ATTITUDE":
                sets.add(msg.time_boot_ms)
            if not flying:  # the fleet is there: fly it (GUIDED, armed, 150 cells north of where each one is)
                for n in range(1, vehicles + 1):
                    conn.mav.command_long_send(n, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 4, 0, 0, 0, 0, 0)
                    conn.mav.command_long_send(n, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
                    conn.mav.set_position_target_local_ned_send(0, n, 1, mav.MAV_FRAME_LOCAL_OFFSET_NED,
                                                                0b110111111000, 150, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
                flying = True
            if kind == "LOCAL_POSITION_NED" and system == 1 and (msg.x, msg.y) != last:
                moved, last = last is not None, (msg.x, msg.y)
                if not moved:
                    continue
                stamps.add(msg.time_boot_ms)
                window[:] = [window[0] if window else received, received]
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        conn.close()
        played = sum(1 for r in read(journal) if is_turn(r))
        folder.cleanup()
    moving = sorted(stamps - sets)
    span = (moving[-1] - moving[0]) / 1000 if len(moving) > 1 else 0.0
    return {"tps": (len(moving) - 1) / span if span > 0 else float("nan"), "moving": float(len(moving)),
            "turns": float(played), "messages": (window[1] - window[0]) / max(len(moving) - 1, 1) if window else 0.0}


def main() -> None:  # pragma: no cover (a quick look: python -m benchmarks.mavlink)
    g = game_rate()
    print(f"a game of 100 vehicles flown by a pymavlink ground station, each moving a cell a turn: {g['tps']:.1f} "
          f"turns/s over the {g['moving']:.0f} turns D01 moved ({g['turns']:.0f} played), {g['messages']:.0f} "
          f"messages a turn at the ground station")
    r = bridge_cpu()
    print(f"{r['cpu'] * 1e3:.2f} ms CPU a turn, {r['messages']:.0f} messages in {r['datagrams']:.0f} datagrams a turn: "
          f"at most {1 / r['cpu']:.0f} turns/s (target >= {TARGET_TPS:g})")


if __name__ == "__main__":  # pragma: no cover
    main()
