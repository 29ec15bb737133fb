"""Several hosts (network namespaces joined by veth links): a router host, a simulation host and a
remote ground station host. The GCS link is cut and restored mid-game: the game goes on without the
ground station (the drones keep their targets, as in the seed) and the GCS catches up when it is back."""

from __future__ import annotations

import os
import shutil
import signal
import sys

import pytest

from tests.harness import Cluster, Hosts, Proc, journal_records

pytestmark = [pytest.mark.integration, pytest.mark.privileged]


def _can_netns() -> str:
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    if not shutil.which("ip"):
        return "needs iproute2 (tests/setup.d/netns.sh installs it)"
    return ""


@pytest.fixture
def hosts():
    why = _can_netns()
    if why:
        if os.environ.get("CI"):
            pytest.fail(f"multi-host test cannot run in CI: {why}")
        pytest.skip(why)
    with Hosts("SIM", "GCS") as h:
        yield h


def test_remote_gcs_link_cut_and_restored(hosts, tmp_path):
    router = Proc("ROUTER", ["ip", "netns", "exec", hosts.router, sys.executable, "-m", "dronesim", "router",
                             "--listen", "tcp/0.0.0.0:7447", "--log-level", "WARNING"], tmp_path)
    try:
        router.expect("listening on")
        sim = f"tcp/{hosts.addr['SIM']}:7447"
        gcs_at = f"tcp/{hosts.addr['GCS']}:7447"
        journal = tmp_path / "game.journal"
        with Cluster(sim, tmp_path) as c:
            srv = c.start("SRV", "coordinator", "--seed", "7", "--size", "16,16,8", "--journal", str(journal),
                          "--pace", "0.05", "--admit-deadline", "60", "--max-turns", "2000", "--log-level", "DEBUG",
                          netns=hosts.ns("SIM"))
            srv.expect("coordinator ready")
            c.start("ENV", "env", "--no-draw", netns=hosts.ns("SIM"))
            c.start("D01", "drone", "--id", "D01", "--autopilot", "dstar", netns=hosts.ns("SIM"))
            # the remote GCS: a short lease so a cut link is noticed within about a second
            gcs = c.start("GCS", "gcs", "--targets", "15,15,7", "--targets", "0,0,0@400", "--lease", "1",
                          "--grace", "60", netns=hosts.ns("GCS"), connect=gcs_at)
            gcs.expect(r"^turn 5:")
            hosts.cut("GCS")
            srv.expect("GCS vanished")
            cut_at = int(srv.expect(r"turn \d+ observed").split("turn ")[1].split()[0])
            srv.expect(rf"turn {cut_at + 5} observed")  # the game goes on without its ground station
            hosts.restore("GCS")
            srv.expect("admitted GCS")  # the GCS connected again ...
            line = gcs.expect(r"^turn \d+:", fresh=True)  # the first state it shows once back
            assert int(line.split()[1].rstrip(":")) > cut_at + 4, "... and caught up with the current turn"
            codes = c.wait_all(timeout=120)
            assert set(codes.values()) == {0}, [p.text for p in c.procs]
        records = journal_records(journal)
        assert records[-1]["reason"] == "ALL_REACHED"
        assert any("GAME OVER" in line for line in gcs.out)
    finally:
        router.p.send_signal(signal.SIGTERM)
        router.wait(timeout=30)
