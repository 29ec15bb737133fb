"""Soak: 10,000 turns with 64 drones over a real router. No message may be lost (no drone ever misses
a phase, none is LOST), and no process may grow in memory beyond noise between turn 1,000 and the end.

Turn latency over the run is reported (printed) for the record, not asserted: tests check behaviour,
benchmarks measure time (see `dronesim bench`)."""

from __future__ import annotations

import json
import re
import time

import pytest

from tests.harness import Cluster, embedded_router, journal_records

pytestmark = [pytest.mark.integration, pytest.mark.slow]

TURNS = 10_000
DRONES = 64


def rss_kib(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        return int(re.search(r"VmRSS:\s+(\d+)", f.read())[1])


def scenario(path) -> None:
    from entities.environment import build_world
    from schema import WorldSpec

    starts = [(8 * (i % 8), 8 * (i // 8), 0) for i in range(DRONES)]
    world = build_world(WorldSpec(size=(64, 64, 16), seed=1), starts)
    drones, targets = [], []
    for i, (x, y, _) in enumerate(starts):
        d = f"D{i + 1:02d}"
        drones.append({"id": d, "start": [x, y, 0], "autopilot": "dstar"})
        # a patrol: back and forth between two cells every 1,000 turns (the GCS keeps the game going); the
        # column above a start is free (buildings rise from the ground), the cell beside it may be a building's
        far = [x + 1, y + 1, 4] if not world.is_building((x + 1, y + 1, 4)) else [x, y, 4]
        for k, t in enumerate(range(1, TURNS, 1000)):
            cell = far if k % 2 == 0 else [x, y, 2]
            targets.append(f"{d}={cell[0]},{cell[1]},{cell[2]}@{t}")
        targets.append(f"{d}={x},{y},3@{TURNS}")  # a last order at the last turn: CONTINUE until then
    path.write_text(json.dumps({"format": "dronesim-scenario", "version": 1,
                                "world": {"size": [64, 64, 16], "seed": 1}, "drones": drones,
                                "targets": targets, "max_turns": TURNS}))


def test_ten_thousand_turns_sixty_four_drones(tmp_path):
    spec = tmp_path / "soak.json"
    scenario(spec)
    journal = tmp_path / "soak.journal"
    with embedded_router() as router, Cluster(router, tmp_path, log_level="WARNING") as c:
        srv = c.start("SRV", "coordinator", "--scenario", str(spec), "--journal", str(journal),
                      "--admit-deadline", "120", "--log-level", "DEBUG")
        srv.expect("coordinator ready")
        c.start("ENV", "env", "--no-draw")
        c.start("H01", "drone", "--id", f"D01-D{DRONES}", "--host", "H01", "--autopilot", "dstar")
        c.start("GCS", "gcs", "--scenario", str(spec), "--quiet", "--no-draw")
        srv.expect(r"turn 1000 observed", timeout=600)
        t1000 = time.monotonic()
        early = {p.name: rss_kib(p.p.pid) for p in c.procs}
        srv.expect(rf"turn {TURNS - 1000} observed", timeout=1800)
        t_late = time.monotonic()
        srv.expect(rf"turn {TURNS - 10} observed", timeout=600)
        late = {p.name: rss_kib(p.p.pid) for p in c.procs}
        codes = c.wait_all(timeout=600)
    assert set(codes.values()) == {0}
    records = journal_records(journal)
    # the last order comes at the last turn: the game ends there (turn limit, or all there at once)
    assert records[-1]["reason"] in ("TURN_LIMIT", "ALL_REACHED") and records[-1]["turn"] == TURNS
    turns = [r for r in records if r["record"] == "turn"]
    assert len(turns) == TURNS
    assert not [r["turn"] for r in turns if r.get("hovered") or r.get("lost")], "a message was lost"
    assert not [r["turn"] for r in turns if r.get("deaths")], "cooperative D* drones never collide"
    rate = (TURNS - 2000) / (t_late - t1000)
    print(f"\nsoak: {rate:.0f} turns/s between turn 1000 and {TURNS - 1000}; RSS KiB at turn 1000 {early}, "
          f"at the end {late}")
    for name in early:
        grown = late[name] - early[name]
        assert grown < max(8 * 1024, early[name] // 10), f"{name} grew by {grown} KiB ({early[name]} -> {late[name]})"
