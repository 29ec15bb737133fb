"""Issue: 16 drones, dumb and smart, over a real router; two process layouts give identical journals,
and replay re-simulates them byte for byte."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import pytest

from coordinator.journal import read
from dronesim import replay
from dronesim.scenario import Scenario
from tests.harness import embedded_router, journal_records, play_scenario

pytestmark = pytest.mark.integration

SCENARIO = pathlib.Path(__file__).resolve().parent.parent / "scenarios" / "swarm16.json"


def run_layout(locator: str, tmp: pathlib.Path, layout: str) -> pathlib.Path:
    journal, srv, procs = play_scenario(locator, tmp, SCENARIO, layout,  # the seed's drones flown by SeedSwarm:
                                        "--log-level", "INFO", "--swarm-pilot-min", "1")
    # the coordinator checked every UPD (--verify-env, see the harness) and none disagreed with its world
    assert "UPD" not in "\n".join(line for line in srv.err if "rejected" in line), srv.text[-3000:]
    if layout == "swarm":  # the hosts whose autopilot senses charted the environment's whole map
        for host in (p for p in procs if p.name.startswith("H")):
            charted = "charted the environment's map: 1024 cells" in host.text
            assert charted == ("--autopilot v1" not in " ".join(host.argv)), host.text[-2000:]
            vectorised = "drones with the seed autopilot's swarm form" in host.text
            assert vectorised == ("--autopilot seed" in " ".join(host.argv)), host.text[-2000:]
    return journal


def test_sixteen_drones_two_layouts_identical_journals_and_replay(tmp_path):
    with embedded_router() as locator:
        a = run_layout(locator, tmp_path, "processes")
        b = run_layout(locator, tmp_path, "swarm")
    assert a.read_bytes() == b.read_bytes()
    records = journal_records(a)
    over = records[-1]
    assert over["record"] == "over" and over["reason"] == "ALL_REACHED"
    deaths = {d: c for r in records for d, c in r.get("deaths", {}).items()}
    pilots = Scenario.load(SCENARIO).autopilots
    # the dumb V1 drones fly into buildings; the cooperative D* drones never die
    assert {d for d, p in pilots.items() if p == "v1"} <= {d for d, c in deaths.items() if c == "BUILDING"}
    assert not {d for d in deaths if pilots[d] == "dstar"}
    assert "VERTEX" in deaths.values()
    # the journal is what a fresh in-process re-simulation writes
    config, autopilots = replay.header_config(records[0])
    assert replay.verify(str(a), list(read(a)), config, autopilots) is None
    out = subprocess.run([sys.executable, "-m", "dronesim", "replay", str(a), "--verify"], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "verified" in out.stdout and "D16: ALIVE" in out.stdout
