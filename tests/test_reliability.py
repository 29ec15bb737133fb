"""Crashed, hung and restarted processes over a real router: nothing hangs, nothing is lost, and a
restarted environment or coordinator gives the journal of an uninterrupted run.

The test plays the ground station itself (`ScriptedGCS`), so it acts at exact points of the game: a
turn only moves on when the test answers its GCS phase. A process is stopped (SIGSTOP) to hold the
game inside a DRONES phase while another is killed, so the fault lands mid-turn, not between turns.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from benchmarks.measure import await_presence
from network.transport import client_config, router_config
from schema import Keys
from tests.harness import (
    TIMEOUT,
    Cluster,
    Proc,
    ScriptedGCS,
    embedded_router,
    journal_records,
    play_to_the_end,
    unique_root,
)

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


# --------------------------------------------------------------------------- ends, signals, outages


def children(pid: int) -> dict[int, str]:
    """The processes whose parent is `pid`: their command lines."""
    found = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) == pid:
                found[int(stat.parent.name)] = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, IndexError, ValueError):
            continue  # gone meanwhile
    return found


@contextlib.contextmanager
def dronesim_up(tmp_path, *args: str) -> Iterator[tuple[Proc, Path]]:
    """`dronesim up` as a process, with its journal; whatever it leaves behind is killed on leaving."""
    journal = tmp_path / "up.journal"
    up = Proc("up", [sys.executable, "-m", "dronesim", "up", "--journal", str(journal), "--root", unique_root(),
                     "--log-level", "INFO", *args], tmp_path)
    try:
        yield up, journal
    finally:
        left = children(up.p.pid)
        up.kill()
        for pid in left:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def test_a_paced_game_whose_last_drone_is_killed_ends_with_over_and_its_record(tmp_path):
    """dronesim up --pace: OVER must not wait behind a turn held for its pace."""
    with dronesim_up(tmp_path, "--seed", "7", "--drones", "1", "--pace", "0.2", "--targets", "9,9,0") as (up, journal):
        up.expect(r"^turn 2:")
        drone = next(pid for pid, cmd in children(up.p.pid).items() if " drone " in cmd)
        os.kill(drone, signal.SIGKILL)
        up.expect("GAME OVER at turn .*: NO_DRONE_ALIVE")
        assert up.wait() == 1, up.text  # D01 was killed: up says so
        assert "processes failed: {'D01': -9}" in up.text, "the coordinator, environment and GCS exited 0"
    assert journal_records(journal)[-1]["reason"] == "NO_DRONE_ALIVE"


def test_dronesim_up_refuses_a_target_its_ground_station_would_refuse_before_any_process_starts(tmp_path):
    """A target inside a building: `up` refuses it as its ground station would (exit 2, one line), before any
    process starts: no game, no journal. (A ground station that refuses its input once started, a port taken since
    `up` looked, stops the game and makes `up` exit 2: tests/test_cli_inputs.py.)"""
    world = tmp_path / "block.json"
    world.write_text('{"format": "dronesim-world", "version": 1, "size": [10, 10, 10], '
                     '"buildings": [[4, 4, 3, 3, 5]]}')
    with dronesim_up(tmp_path, "--world", str(world), "--starts", "0,0,0", "--pace", "0.2",
                     "--max-turns", "100000", "--targets", "5,5,0") as (up, journal):
        assert up.wait() == 2, up.text
        assert "inside a building" in up.text, up.text
        assert "Traceback" not in up.text and "GAME" not in up.text
    assert not journal.exists() or not journal.read_text()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_to_dronesim_up_ends_the_game_interrupted_and_stops_every_process(tmp_path, signum):
    with dronesim_up(tmp_path, "--seed", "7", "--drones", "2", "--pace", "0.2", "--targets", "9,9,0") as (up, journal):
        up.expect(r"^turn 2:")
        procs = children(up.p.pid)
        assert len(procs) == 5, procs
        up.p.send_signal(signum)
        assert up.wait() == 128 + signum, up.text
        assert "Traceback" not in up.text
        assert "GAME OVER at turn" in up.text and "INTERRUPTED" in up.text
        assert not set(children(up.p.pid)) and not any(Path(f"/proc/{pid}").exists() for pid in procs), \
            "every child stopped"
    over = journal_records(journal)[-1]
    assert over["record"] == "over" and over["reason"] == "INTERRUPTED"
    from dronesim import replay

    assert replay.main([str(journal), "--verify"]) == 0  # (every turn before the stop, byte for byte)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_to_the_coordinator_ends_the_game_and_the_entities_exit_0(router, tmp_path, signum):
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path, "--pace", "0.2")
        entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(2)
            srv.p.send_signal(signum)
            gcs.play_until()
            assert gcs.over.reason.value == "INTERRUPTED"
        finally:
            gcs.close()
        assert srv.wait() == 128 + signum and "Traceback" not in srv.text
        c.procs.remove(srv)
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    assert journal_records(journal)[-1]["reason"] == "INTERRUPTED"


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_to_a_drone_process_stops_it_cleanly_and_the_game_goes_on(router, tmp_path, signum):
    """Ctrl-C or SIGTERM (`docker stop`) on a drone process, waiting to be admitted or playing: it stops at
    once, without a traceback, exits 130 / 143; in a game, the coordinator sees it gone (LOST)."""
    with Cluster(router, tmp_path) as c:
        nobody = Keys(unique_root())  # no coordinator there: the drone waits to be admitted
        early = c.start("D01@", "drone", "--id", "D01", "--root", nobody.root)
        with zenoh.open(client_config(router)) as session:
            assert await_presence(session, nobody.alive_of("D01"), TIMEOUT)  # it is connecting
        srv, journal = start(c, tmp_path)
        c.start("ENV", "env", "--no-draw")
        c.start("D01", "drone", "--id", "D01", "--autopilot", "dstar")
        d2 = c.start("D02", "drone", "--id", "D02", "--autopilot", "seed")
        gcs = ScriptedGCS(router, c.root, TARGETS)
        early.p.send_signal(signum)
        assert early.wait() == 128 + signum and "Traceback" not in early.text, early.text
        try:
            gcs.play_until(2)
            d2.p.send_signal(signum)
            assert d2.wait() == 128 + signum and "Traceback" not in d2.text, d2.text
            gcs.play_until()
            assert {s.drone: s.state.value for s in gcs.statuses[-1].drones}["D02"] == "LOST"
        finally:
            gcs.close()
        for p in (early, d2):
            c.procs.remove(p)
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    assert any("D02" in r.get("lost", ()) for r in journal_records(journal))


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_to_the_environment_stops_it_cleanly_and_a_new_one_takes_over(router, tmp_path, signum):
    """Ctrl-C or SIGTERM (`docker stop`) on the environment mid-game: it stops at once, without a traceback,
    exits 130 / 143; a restarted environment is admitted and the game plays to the end it has without the fault."""
    expected = reference_journal(router, tmp_path)
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        env, _, _ = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(2)
            env.p.send_signal(signum)
            assert env.wait() == 128 + signum and "Traceback" not in env.text, env.text
            env.expect(f"stopped by {signal.Signals(signum).name}")
            c.procs.remove(env)
            c.start("ENV2", "env", "--no-draw")
            gcs.play_until()
        finally:
            gcs.close()
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    assert journal.read_bytes() == expected


def test_a_second_coordinator_on_the_same_root_is_refused_and_exits(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        second = c.start("SRV2", "coordinator", "--drones", "2")
        assert second.wait() == 2
        assert "another coordinator" in second.text
        c.procs.remove(second)
        entities(c)
        play_to_the_end(c, TARGETS)


@contextlib.contextmanager
def restartable_router() -> Iterator[tuple[str, Callable[[], None], Callable[[], None]]]:
    """A router in this process on a fixed free port: (locator, stop, start again)."""
    with embedded_router() as locator:
        pass  # a free port, now free again
    state: dict = {}

    def up() -> None:
        state["cm"] = zenoh.open(router_config(locator))
        state["cm"].__enter__()

    def down() -> None:
        state.pop("cm").__exit__(None, None, None)

    up()
    try:
        yield locator, down, up
    finally:
        if "cm" in state:
            down()


def scripted_game(c: Cluster, tmp_path, *, restart: Callable[[Cluster, Proc, list[Proc]], None] | None) -> bytes:
    """A paced game with the real scripted ground station; `restart` breaks it somewhere."""
    srv, journal = start(c, tmp_path, "--pace", "0.05", "--max-turns", "60")
    ents = [*entities(c)]
    targets = [item for d, (x, y, z) in TARGETS.items() for item in ("--targets", f"{d}={x},{y},{z}")]
    ents.append(c.start("GCS", "gcs", *targets, "--quiet"))
    if restart is not None:
        restart(c, srv, ents)
    assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    return journal.read_bytes()


def test_a_router_restart_is_survived_and_the_journal_equals_an_uninterrupted_runs(tmp_path):
    for run in ("clean", "restarted"):
        (tmp_path / run).mkdir()
    with restartable_router() as (locator, down, up):
        with Cluster(locator, tmp_path / "clean") as c:
            expected = scripted_game(c, tmp_path / "clean", restart=None)

        def restart(c: Cluster, srv: Proc, ents: list[Proc]) -> None:
            srv.expect("the game starts")
            for e in ents:  # every Welcome has arrived (the last one goes out as the game starts: it may
                e.expect("You are connected as")  # still be on its way, and would be lost with the link)
            ents[1].expect("charted|connected")
            down()  # every link goes: each side sees every presence vanish
            srv.expect("the link is down")
            for e in ents:
                e.expect("the coordinator vanished")
            up()
            srv.expect("every entity is back")

        with Cluster(locator, tmp_path / "restarted") as c:
            got = scripted_game(c, tmp_path / "restarted", restart=restart)
    assert got == expected


def test_a_lost_drone_that_comes_back_stays_out_and_exits_0_at_the_end(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path, "--phase-deadline", "60")
        c.start("ENV", "env", "--no-draw")
        c.start("D01", "drone", "--id", "D01", "--autopilot", "dstar")
        d2 = c.start("D02", "drone", "--id", "D02", "--autopilot", "seed", "--lease", "1")
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(2)
            d2.p.send_signal(signal.SIGSTOP)  # frozen past its lease: the router drops it, it is LOST
            srv.expect("D02 vanished")
            d2.p.send_signal(signal.SIGCONT)
            d2.expect("D02 is LOST: drones cannot join a running game.*takes no further part")
            gcs.play_until()
            assert {s.drone: s.state.value for s in gcs.statuses[-1].drones} == {"D01": "ALIVE", "D02": "LOST"}
        finally:
            gcs.close()
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]


def test_a_replayed_or_foreign_over_turn_or_status_is_refused_by_every_entity(router, tmp_path):
    from schema import DroneState, DroneStatus, EndReason, Keys, Over, Phase, Status, StatusTable, Turn

    expected = reference_journal(router, tmp_path)
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(2)
            gcs.wait_phase("GCS", 3)
            keys, out = Keys(c.root), gcs.out
            for game in ("", "0badc0de"):  # a replay of a game without identity, another game's
                out.put(keys.over, Over(turn=0, sender="SRV", reason=EndReason.ABORTED, game=game))
                out.put(keys.over, Over(turn=3, sender="SRV", reason=EndReason.ABORTED, game=game))
                out.put(keys.status, Status(turn=2, sender="OBS", game=game, drones=StatusTable.of([
                    DroneStatus(drone="D01", pos=(0, 0, 0), state=DroneState.DEAD),
                    DroneStatus(drone="D02", pos=(0, 2, 0), state=DroneState.DEAD)])))
                out.put(keys.turn_of(Phase.DRONES), Turn(turn=3, sender="SRV", phase=Phase.DRONES, game=game))
            for p in (env, d1, d2):
                p.expect(r"rejected .*OVER of game 0badc0de.*\(foreign-game\)")
            gcs.answer(3)
            gcs.play_until()
        finally:
            gcs.close()
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    assert journal.read_bytes() == expected


def test_a_foreign_coordinator_token_does_not_hold_the_entities(router, tmp_path):
    """A token under the coordinator's name that is not the one that admitted them (a second coordinator,
    any client on a plain router) must not keep the entities waiting once their coordinator has died."""
    from schema import Keys

    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path)
        env = c.start("ENV", "env", "--no-draw", "--grace", "2")
        d1 = c.start("D01", "drone", "--id", "D01", "--autopilot", "dstar", "--grace", "2")
        d2 = c.start("D02", "drone", "--id", "D02", "--autopilot", "seed", "--grace", "2")
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(2)
            fake = gcs.session.liveliness().declare_token(Keys(c.root).alive("SRV", "0fa4e1d2"))
            srv.p.kill()
            assert srv.wait() == -signal.SIGKILL
            for p in (env, d1, d2):
                assert p.wait(30) == 2, p.text
                assert "did not come back within 2 s" in p.text
            fake.undeclare()
        finally:
            gcs.close()
        c.procs.remove(srv)


def test_a_copy_of_a_drones_exact_presence_key_does_not_hide_its_death(router, tmp_path):
    """On a plain router any client may declare a token on a drone's own presence key: when the drone dies
    its token stays. Its first missed deadline makes the coordinator ask the router which sessions are
    connected: the drone is LOST then, not after --lost-after missed deadlines."""
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path, "--phase-deadline", "1", "--lost-after", "5")
        env, d1, d2 = entities(c)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(2)
            (reply,) = [r for r in gcs.session.liveliness().get(Keys(c.root).alive_of("D02"), timeout=10)
                        if r.ok is not None]
            copy = gcs.session.liveliness().declare_token(str(reply.ok.key_expr))  # the same key, another session
            gcs.wait_phase("GCS", 3)
            d2.p.kill()
            d2.wait()
            gcs.answer(3)
            gcs.play_until()
            copy.undeclare()
            assert {s.drone: s.state.value for s in gcs.statuses[-1].drones}["D02"] == "LOST"
        finally:
            gcs.close()
        c.procs.remove(d2)
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    assert "is not connected to any router" in srv.text and "D02 vanished" in srv.text
    records = journal_records(journal)
    hovered = [r["turn"] for r in records if "D02" in r.get("hovered", ())]
    lost = [r["turn"] for r in records if "D02" in r.get("lost", ())]
    # (lost as its first deadline passes: the deadline counts once the routers have answered, and they no longer
    # list its session; or, under load, a turn later)
    assert len(lost) == 1 and len(hovered) <= 2 and (not hovered or lost[0] <= hovered[0] + 1), (hovered, lost)


def _dstar_swarm_scenario(path: Path, size: tuple[int, int, int], drones: int, max_turns: int) -> Path:
    """A scenario of `drones` D* drones along one side of a generated city of `size` (seed 7), each aiming at a cell
    on the far side."""
    import json

    from schema import WorldSpec
    from world.grid import build_world

    world = build_world(WorldSpec(size=size, seed=7), [])
    nx, ny, _ = size
    open_cells = [(x, y, 0) for x in range(0, nx, 2) for y in range(0, ny, 2) if not world.is_building((x, y, 0))]
    far = [(x, y, 0) for x in range(nx - 1, 0, -2) for y in range(ny - 1, 0, -2) if not world.is_building((x, y, 0))]
    path.write_text(json.dumps({
        "format": "dronesim-scenario", "version": 1, "world": {"size": list(size), "seed": 7},
        "drones": [{"id": f"D{i + 1:02d}", "start": list(c), "autopilot": "dstar"} for i, c in
                   enumerate(open_cells[:drones])],
        "targets": [f"D{i + 1:02d}={x},{y},{z}" for i, (x, y, z) in enumerate(far[:drones])],
        "max_turns": max_turns}))
    return path


def test_a_dstar_swarm_host_slower_than_the_phase_deadline_keeps_its_drones(router, tmp_path):
    """Issue 33, 8: a D* swarm host whose planning outlasted the phase deadline had every drone declared LOST at turn
    3, alive and working as it was, and the OVER that followed (naming them all) reached no other process. Here
    real D* planning (40 drones over a 128x128x16 city: their pilots made and their first searches, about a second
    on this machine) outlasts a tiny deadline, and a drone that misses one is LOST: the host says it is still
    deciding, the phase waits for it, and the game plays to its turn limit with every drone."""
    scenario = _dstar_swarm_scenario(tmp_path / "city.json", (128, 128, 16), 40, 6)
    journal = tmp_path / "city.journal"
    with Cluster(router, tmp_path) as c:
        srv = c.start("SRV", "coordinator", "--scenario", str(scenario), "--journal", str(journal),
                      "--phase-deadline", "0.5", "--lost-after", "1", "--admit-deadline", "120")
        srv.expect("coordinator ready")
        c.start("ENV", "env", "--no-draw")
        c.start("H01", "drone", "--id", "D01-D40", "--host", "H01", "--autopilot", "dstar")
        gcs = c.start("GCS", "gcs", "--scenario", str(scenario), "--quiet", "--no-draw")
        assert set(c.wait_all(timeout=180).values()) == {0}, [p.text for p in c.procs]
    srv.expect(r"turn 1: H01 is still deciding")  # (its planning did outlast the deadline)
    records = journal_records(journal)
    lost = [r for r in records if r.get("lost")]
    assert not lost, ("no drone LOST: first at turn " + str(lost[0].get("turn")) + "\ncoordinator:\n" + srv.text[-6000:]
                      + "\nswarm host:\n" + next(p.text[-6000:] for p in c.procs if p.name == "H01"))
    assert records[-1]["reason"] == "TURN_LIMIT"
    gcs.expect("GAME OVER at turn 6: TURN_LIMIT")


def test_a_hung_swarm_host_loses_its_drones_at_the_deadline_and_the_over_reaches_everyone(router, tmp_path):
    """Issue 33, 8: a hung host (its token alive, no word, no move) still misses its phases at the deadline and its
    drones are LOST after `--lost-after` misses; the OVER that then names forty lost drones reaches every process
    (it used to exceed its key's size limit: each waited 30 s for the coordinator and exited 2)."""
    with Cluster(router, tmp_path) as c:
        srv, journal = start(c, tmp_path, "--phase-deadline", "0.5", "--lost-after", "2", "--size", "14,14,2",
                             "--drones", "40")
        env = c.start("ENV", "env", "--no-draw")
        host = c.start("H01", "drone", "--id", "D01-D40", "--host", "H01", "--autopilot", "seed")
        host.expect("You are connected as H01")
        host.p.send_signal(signal.SIGSTOP)  # hung before the game starts (it starts once the GCS is there)
        try:
            gcs = c.start("GCS", "gcs", "--targets", "0,0,0", "--quiet", "--no-draw")
            gcs.expect("GAME OVER at turn 2: NO_DRONE_ALIVE")
            env.expect("OVER: no drone alive")
        finally:
            host.p.send_signal(signal.SIGCONT)
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    records = journal_records(journal)
    turns = [r for r in records if r.get("record") == "turn"]
    assert [len(r.get("hovered", ())) for r in turns] == [40, 40] and len(turns[-1]["lost"]) == 40
    assert records[-1]["reason"] == "NO_DRONE_ALIVE" and records[-1]["text"].endswith("more")
