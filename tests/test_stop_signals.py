"""SIGTERM and SIGINT on the coordinator in every wait it can be in (issue 33, 1): admitting the entities, a
phase, waiting for a vanished environment, a resumed game waiting for its entities or for its ground station,
a game held for a router that does not answer. Each time the game ends INTERRUPTED at once, its over record
closes the journal (a game that never started leaves it empty), and the coordinator exits 143 (SIGTERM) or 130
(SIGINT) soon after: it waits at most STOP_LINGER_S for the entities to leave, not LINGER_S, and says so. Each
wait is reached by its log line, never by sleeping."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from schema.tuning import STOP_LINGER_S
from tests.harness import Cluster, Proc, ScriptedGCS, embedded_router, journal_records
from tests.test_frozen_router import router_process
from tests.test_reliability import TARGETS, entities, hold_in_drones_phase, start

pytestmark = pytest.mark.integration

#: Long enough that nothing the test waits in ends by itself meanwhile.
LONG = ("--phase-deadline", "60", "--gcs-grace", "60", "--link-grace", "60")


def stopped(srv: Proc, signum: int, journal: Path, *, staying: bool = True) -> dict | None:
    """Signal the coordinator: it exits 128 + signum without a traceback, after OVER INTERRUPTED; with entities
    `staying` (the test's ground station, a held process), it does not wait LINGER_S for them to leave, only
    STOP_LINGER_S, as it says. The journal's last record (None: the journal is empty)."""
    srv.p.send_signal(signum)
    assert srv.wait() == 128 + signum, srv.text
    assert "Traceback" not in srv.text
    srv.expect(rf"OVER at turn \d+: INTERRUPTED: the coordinator was stopped \({signal.Signals(signum).name}\)")
    if staying:
        srv.expect(rf"stopped: not waiting for .* to leave \(OVER went out {STOP_LINGER_S:g} s ago\)")
    records = journal_records(journal)
    return records[-1] if records else None


@pytest.fixture
def router():
    with embedded_router() as locator:
        yield locator


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_admitting(router, tmp_path, signum):
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path, *LONG)
        c.start("ENV", "env", "--no-draw").expect("You are connected as ENV")  # the others never come
        assert stopped(srv, signum, journal, staying=False) is None, "no game began: the journal stays empty"


def test_a_phase(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path, *LONG)
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            hold_in_drones_phase(gcs, d1, 3)  # turn 3's drones' phase waits for D01 (stopped)
            last = stopped(srv, signal.SIGTERM, journal)
        finally:
            d1.p.send_signal(signal.SIGCONT)
            gcs.close()
        assert last == {"record": "over", "turn": 2, "reason": "INTERRUPTED",
                        "text": "the coordinator was stopped (SIGTERM)"}
        assert (env.wait(), d2.wait()) == (0, 0), "they saw OVER and left"


def test_waiting_for_the_environment(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path, *LONG)
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(2)
            env.kill()
            srv.expect("ENV vanished")
            gcs.play_until(3)
            srv.expect("turn 3 waits for the environment")
            last = stopped(srv, signal.SIGTERM, journal)
        finally:
            gcs.close()
        assert last is not None and (last["record"], last["turn"], last["reason"]) == ("over", 2, "INTERRUPTED")


def crashed_mid_game(c: Cluster, router: str, tmp_path: Path) -> tuple[Path, list[Proc]]:
    """A game whose coordinator was killed (SIGKILL) in turn 3: its journal, and its entities (waiting)."""
    srv, journal = start(c, tmp_path, *LONG)
    ents = list(entities(c))
    gcs = ScriptedGCS(router, c.root, TARGETS)
    try:
        gcs.play_until(3)
    finally:
        gcs.close()
    srv.kill()
    c.procs.remove(srv)
    for e in ents:
        e.expect("the coordinator vanished")
    return journal, ents


def test_resuming(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        journal, ents = crashed_mid_game(c, router, tmp_path)
        for e in ents:  # the entities are gone too: the resumed game waits for all of them
            e.kill()
        srv, _ = start(c, tmp_path, *LONG, name="SRV2", resume=True)
        srv.expect("restored turn 2")
        last = stopped(srv, signal.SIGTERM, journal, staying=False)
        assert last is not None and (last["record"], last["turn"], last["reason"]) == ("over", 2, "INTERRUPTED")


def test_a_resumed_game_waiting_for_its_ground_station(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        journal, ents = crashed_mid_game(c, router, tmp_path)
        srv, _ = start(c, tmp_path, *LONG, name="SRV2", resume=True)
        for e in ("ENV", "D01", "D02"):  # they come back; the ground station (the test's) does not
            srv.expect(f"admitted {e}")
        last = stopped(srv, signal.SIGTERM, journal, staying=False)
        assert last is not None and (last["record"], last["turn"], last["reason"]) == ("over", 2, "INTERRUPTED")
        c.procs.remove(srv)
        assert set(c.wait_all().values()) == {0}, "they saw OVER and left"


def test_held_for_a_router_that_does_not_answer(tmp_path):
    with router_process(tmp_path) as (locator, router), Cluster(locator, tmp_path) as c:
        srv, journal = start(c, tmp_path, "--phase-deadline", "1")
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(locator, c.root, TARGETS)
        try:
            hold_in_drones_phase(gcs, d1, 3)
            router.p.send_signal(signal.SIGSTOP)
            srv.expect("turn 3: no router answers")
            last = stopped(srv, signal.SIGTERM, journal)
        finally:
            router.p.send_signal(signal.SIGCONT)
            d1.p.send_signal(signal.SIGCONT)
            gcs.close()
        assert last is not None and (last["record"], last["turn"], last["reason"]) == ("over", 2, "INTERRUPTED")
