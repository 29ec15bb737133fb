"""Crashed, hung and restarted processes over a real router: nothing hangs, nothing is lost, and a
restarted environment or coordinator gives the journal of an uninterrupted run.

The test plays the ground station itself (`ScriptedGCS`), so it acts at exact points of the game: a
turn only moves on when the test answers its GCS phase. A process is stopped (SIGSTOP) to hold the
game inside a DRONES phase while another is killed, so the fault lands mid-turn, not between turns.
"""

from __future__ import annotations

import signal

import pytest

from tests.harness import Cluster, ScriptedGCS, embedded_router, journal_records, play_to_the_end

pytestmark = pytest.mark.integration

SEED = ("--seed", "7")
TARGETS = {"D01": (9, 9, 0), "D02": (9, 0, 3)}


@pytest.fixture
def router():
    with embedded_router() as locator:
        yield locator


def start(c: Cluster, tmp_path, *extra: str, name: str = "SRV", resume: bool = False):
    journal = tmp_path / f"{c.root}.journal"
    args = ["--journal", str(journal), "--drones", "2", "--admit-deadline", "60", *SEED, *extra]
    if resume:
        args.append("--resume")
    srv = c.start(name, "coordinator", *args)
    srv.expect("coordinator ready")
    return srv, journal


def entities(c: Cluster, *, env_name: str = "ENV"):
    env = c.start(env_name, "env", "--no-draw")
    d1 = c.start("D01", "drone", "--id", "D01", "--autopilot", "dstar")
    d2 = c.start("D02", "drone", "--id", "D02", "--autopilot", "seed")
    return env, d1, d2


def reference_journal(router, tmp_path) -> bytes:
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        entities(c)
        play_to_the_end(c, TARGETS)
    return journal.read_bytes()


def hold_in_drones_phase(gcs: ScriptedGCS, drone, turn: int) -> None:
    """Play to `turn`, then stop `drone` (SIGSTOP) so that turn stays in its DRONES phase."""
    gcs.play_until(turn - 1)
    gcs.wait_phase("GCS", turn)
    drone.p.send_signal(signal.SIGSTOP)
    gcs.answer(turn)
    gcs.wait_phase("DRONES", turn)


def test_environment_killed_mid_turn_and_restarted_gives_the_same_journal(router, tmp_path):
    expected = reference_journal(router, tmp_path)
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            hold_in_drones_phase(gcs, d1, 5)
            env.p.kill()  # the environment dies while D01 has not moved yet
            assert env.wait() == -signal.SIGKILL
            # D01 either senses from what the environment already told it (its chart) and turn 5 ends,
            # the next drones' phase then waiting for an environment; or it must ask, and waits for one
            # itself: which, depends on whether the kinds it asked ahead arrived before the kill
            d1.p.send_signal(signal.SIGCONT)
            env2 = c.start("ENV2", "env", "--no-draw")
            env2.expect("You are connected as ENV")
            gcs.play_until()
        finally:
            gcs.close()
        c.procs.remove(env)
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    assert journal.read_bytes() == expected


def test_coordinator_killed_mid_turn_and_resumed_gives_the_same_journal(router, tmp_path):
    expected = reference_journal(router, tmp_path)
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            hold_in_drones_phase(gcs, d1, 5)
            srv.p.kill()  # the coordinator dies in the middle of turn 5
            assert srv.wait() == -signal.SIGKILL
            d1.p.send_signal(signal.SIGCONT)  # D01 decides turn 5 for nobody; it will say it again
            srv2, _ = start(c, tmp_path, name="SRV2", resume=True)
            gcs.play_until()  # it connects again (the resumed game waits for it), then plays on
            srv2.expect("the game resumes at turn 5")
        finally:
            gcs.close()
        c.procs.remove(srv)
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    records = journal_records(journal)
    assert [r["record"] for r in records].count("header") == 1
    assert journal.read_bytes() == expected


def test_drone_killed_is_lost_and_the_others_play_on(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(3)
            gcs.wait_phase("GCS", 4)
            d2.p.kill()
            d2.wait()
            srv.expect("D02 vanished")
            gcs.answer(4)
            gcs.play_until()
            assert gcs.over.reason.value == "ALL_REACHED"
            last = gcs.statuses[-1]
            states = {s.drone: s.state.value for s in last.drones}
            assert states == {"D01": "ALIVE", "D02": "LOST"}
        finally:
            gcs.close()
        c.procs.remove(d2)
        assert set(c.wait_all().values()) == {0}
    records = journal_records(journal)
    assert any(r.get("lost") == ["D02"] for r in records)


def test_drone_hung_misses_its_deadlines_and_is_lost(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path, "--phase-deadline", "0.5", "--lost-after", "2")
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(2)
            d2.p.send_signal(signal.SIGSTOP)  # hung, not dead: its token stays until its lease runs out
            gcs.play_until()
            states = {s.drone: s.state.value for s in gcs.statuses[-1].drones}
            assert states["D02"] == "LOST" and states["D01"] == "ALIVE"
        finally:
            gcs.close()
            d2.p.send_signal(signal.SIGCONT)
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    records = journal_records(journal)
    hovered = [r["turn"] for r in records if "D02" in r.get("hovered", ())]
    lost = [r["turn"] for r in records if "D02" in r.get("lost", ())]
    assert len(hovered) == 2 and lost == [hovered[-1]], "LOST after exactly lost_after missed deadlines"


def test_ground_station_leaves_and_a_new_one_sees_the_state_at_once(router, tmp_path):
    expected = reference_journal(router, tmp_path)
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        gcs.play_until(3)
        gcs.close()  # the ground station disconnects; the drones keep their targets, as in the seed
        srv.expect("GCS vanished")
        gcs2 = ScriptedGCS(router, c.root, TARGETS)
        try:
            while not gcs2.statuses and gcs2.over is None:
                gcs2.next_event()
            # the GCS left after answering turn 3: the state it is shown at once is at least turn 2's
            assert gcs2.statuses[0].turn >= 2, "the new GCS got the current state on joining"
            gcs2.play_until()
        finally:
            gcs2.close()
        assert set(c.wait_all().values()) == {0}
    assert journal.read_bytes() == expected


def scripted_gcs_game(c: Cluster, tmp_path, *, kill_coordinator: bool) -> bytes:
    """A game with the real scripted ground station (`dronesim gcs --targets`), which answers GCS
    phases ahead; with `kill_coordinator`, the coordinator dies in turn 1 while holding those answers."""
    srv, journal = start(c, tmp_path, "--phase-deadline", "60")
    env, d1, d2 = entities(c)
    targets = [item for d, (x, y, z) in TARGETS.items() for item in ("--targets", f"{d}={x},{y},{z}")]
    if kill_coordinator:
        d1.expect("You are connected as D01")
        d1.p.send_signal(signal.SIGSTOP)  # turn 1 will wait for D01 in its drones' phase
    gcs = c.start("GCS", "gcs", *targets, "--quiet", "--log-level", "DEBUG")
    if kill_coordinator:
        gcs.expect("answered turn 3 ahead")
        srv.p.kill()  # it held the GCS's answers for turns 2 and 3: they die with it
        assert srv.wait() == -signal.SIGKILL
        c.procs.remove(srv)
        d1.p.send_signal(signal.SIGCONT)
        # the resumed game waits for the ground station too (up to the coordinator's GCS grace)
        start(c, tmp_path, "--phase-deadline", "60", name="SRV2", resume=True)
    assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    return journal.read_bytes()


def test_a_ground_station_that_answered_ahead_answers_a_resumed_coordinator_again(router, tmp_path):
    for run in ("clean", "killed"):
        (tmp_path / run).mkdir()
    with Cluster(router, tmp_path / "clean") as c:
        expected = scripted_gcs_game(c, tmp_path / "clean", kill_coordinator=False)
    with Cluster(router, tmp_path / "killed") as c:
        got = scripted_gcs_game(c, tmp_path / "killed", kill_coordinator=True)
    assert got == expected
