"""A frozen router (issue 33, 5): `dronesim router` as a process of its own, stopped (SIGSTOP) mid-turn for
longer than the phase deadline, then continued. The deadline that passed while no router answered does not
count: the journal equals a clean run's, byte for byte (the freeze shorter than the leases, and longer: then
every link goes and comes back, as for a router restart)."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.harness import Cluster, Proc, ScriptedGCS
from tests.test_reliability import TARGETS, entities, hold_in_drones_phase, start

pytestmark = pytest.mark.integration

DEADLINE = ("--phase-deadline", "2")


@contextmanager
def router_process(tmp: Path) -> Iterator[tuple[str, Proc]]:
    """`dronesim router` on a free loopback port, in a process of its own: its locator and process."""
    proc = Proc("router", [sys.executable, "-m", "dronesim", "router", "--listen", "tcp/127.0.0.1:0"], tmp)
    try:
        line = proc.expect(r"listening on tcp/127\.0\.0\.1:\d+")
        yield re.search(r"tcp/127\.0\.0\.1:\d+", line)[0], proc  # type: ignore[index]
    finally:
        proc.p.send_signal(signal.SIGCONT)
        proc.p.terminate()
        try:
            proc.p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def game(tmp: Path, freeze: str | None) -> bytes:
    """A game of two drones on its own router; with `freeze`, the router is stopped in turn 4's drones' phase
    (D01 held meanwhile, so the phase cannot end before the freeze) until the coordinator has seen its deadline
    pass with no router answering ("short"), or until every link has gone with the leases ("past-leases")."""
    tmp.mkdir()
    with router_process(tmp) as (locator, router), Cluster(locator, tmp) as c:
        srv, journal = start(c, tmp, *DEADLINE)
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(locator, c.root, TARGETS)
        try:
            if freeze:
                hold_in_drones_phase(gcs, d1, 4)
                router.p.send_signal(signal.SIGSTOP)
                d1.p.send_signal(signal.SIGCONT)  # its move of turn 4 waits in the frozen router's socket
                srv.expect("turn 4: no router answers")  # its deadline passed while nobody could be reached
                if freeze == "past-leases":  # until the entities' leases have run out: every link goes
                    for e in (env, d1, d2):
                        e.expect("the coordinator vanished")
                router.p.send_signal(signal.SIGCONT)
                srv.expect("the routers answer again" if freeze == "short" else "every entity is back")
            gcs.play_until()
        finally:
            gcs.close()
        codes = c.wait_all()
        assert set(codes.values()) == {0}, [p.text for p in c.procs]
        assert "hovering" not in srv.text and "LOST" not in srv.text, srv.text
    return journal.read_bytes()


@pytest.mark.parametrize("freeze", ["short", "past-leases"])
def test_a_frozen_router_holds_the_game_and_the_journal_equals_a_clean_runs(tmp_path: Path, freeze: str) -> None:
    expected = game(tmp_path / "clean", None)
    assert game(tmp_path / "frozen", freeze) == expected
