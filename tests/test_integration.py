"""Whole games over a real Zenoh router on loopback, every entity a separate process."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys

import pytest
import zenoh

from network.membership import Membership
from network.transport import Inbox, Outbox, Received, session_id
from schema import (
    Ans,
    Ask,
    Connect,
    Done,
    Intent,
    Keys,
    Over,
    Phase,
    Role,
    Status,
    Target,
    Turn,
    Upd,
    decode,
    encode,
)
from tests.harness import Cluster, ask_until_replied, client_config, embedded_router, journal_records
from world.grid import Building, World

pytestmark = pytest.mark.integration


@pytest.fixture
def router():
    with embedded_router() as locator:
        yield locator


@pytest.fixture
def cluster(router, tmp_path):
    with Cluster(router, tmp_path) as c:
        yield c


def start_game(c: Cluster, tmp_path, *, coord_args=(), drone_args=(), gcs_args=("--targets", "9,9,0"),
               drones=("D01",), verify_env=True):
    journal = tmp_path / f"{c.root}.journal"
    srv = c.start("SRV", "coordinator", "--journal", str(journal), "--admit-deadline", "60", *coord_args,
                  verify_env=verify_env)
    srv.expect("coordinator ready")  # the queryable is declared: entities will find it at once
    c.start("ENV", "env")
    for d in drones:
        c.start(d, "drone", "--id", d, *drone_args)
    if gcs_args is not None:
        c.start("GCS", "gcs", *gcs_args)
    return journal


def test_seed_demo_reaches_target_and_everyone_exits_0(cluster, tmp_path):
    journal = start_game(cluster, tmp_path, coord_args=("--seed", "7"), drone_args=("--autopilot", "seed"))
    codes = cluster.wait_all()
    assert codes == {"SRV": 0, "ENV": 0, "D01": 0, "GCS": 0}, [p.text for p in cluster.procs]
    gcs = cluster.procs[-1]
    assert any("ALL_REACHED" in line for line in gcs.out), gcs.text
    records = journal_records(journal)
    assert records[0]["record"] == "header" and records[-1]["record"] == "over"
    assert records[-1]["reason"] == "ALL_REACHED"
    for p in cluster.procs[:3]:  # OVER reached every entity
        assert any("OVER" in line for line in p.err), p.text


def test_crash_into_building_ends_the_game_with_over_everywhere(cluster, tmp_path):
    world = tmp_path / "wall.json"
    World.from_buildings((5, 5, 1), [Building(x=1, y=0, length=1, width=5, height=1)]).save(world)
    journal = start_game(cluster, tmp_path, coord_args=("--world", str(world)), drone_args=("--autopilot", "v1"),
                         gcs_args=("--targets", "4,0,0"))
    codes = cluster.wait_all()
    assert set(codes.values()) == {0}, [p.text for p in cluster.procs]
    records = journal_records(journal)
    assert records[-1]["reason"] == "NO_DRONE_ALIVE"
    assert records[-2]["deaths"] == {"D01": "BUILDING"}
    assert records[-2]["moves"] == {"D01": [1, 0, 0]}
    for p in cluster.procs:
        assert any("OVER" in line for line in p.out + p.err), p.text


def test_drones_that_ask_every_turn_play_the_game_of_drones_that_chart(router, tmp_path):
    """Without a chart (`dronesim drone --no-chart`) every drone asks the environment each turn, and the environment
    answers from the newest STATUS, read as the ASK comes (it sleeps through the turns otherwise): the drones in the
    cells asked are those of the turn's start, which D* steps round, so the game is the charted one, turn for turn."""
    world = tmp_path / "open.json"
    World.from_buildings((10, 10, 3), [Building(x=3, y=1, length=1, width=3, height=2)]).save(world)
    played = {}
    for chart in ((), ("--no-chart",)):
        with Cluster(router, tmp_path) as c:  # (D01 and D03 head-on past D02; D* steps round the drones it is told)
            journal = start_game(c, tmp_path, coord_args=("--world", str(world), "--drones", "3", "--max-turns", "40"),
                                 drone_args=("--autopilot", "dstar", *chart), drones=("D01", "D02", "D03"),
                                 gcs_args=("--targets", "D01=0,4,0;D02=6,2,0;D03=0,0,0"))
            assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
            played[chart] = [r for r in journal_records(journal) if r["record"] == "turn"]
    assert len(played[()]) >= 5 and played[()] == played[("--no-chart",)]


def test_duplicate_roles_are_refused_with_a_clear_message(cluster, tmp_path):
    srv = cluster.start("SRV", "coordinator", "--admit-deadline", "60")
    first = cluster.start("GCS", "gcs", "--targets", "9,9,0")
    srv.expect("admitted GCS")
    second = cluster.start("GCS2", "gcs", "--targets", "1,1,0")
    assert second.wait() == 2
    second.expect("connection refused: GCS is already connected")
    cluster.start("D01", "drone", "--id", "D01")
    srv.expect("admitted D01")
    dup = cluster.start("D01b", "drone", "--id", "D01")
    assert dup.wait() == 2
    dup.expect("connection refused: D01 is already connected")
    stranger = cluster.start("D07", "drone", "--id", "D07")
    assert stranger.wait() == 2
    stranger.expect("unknown drone D07")
    cluster.start("ENV", "env")
    assert first.wait() == 0
    assert srv.wait() == 0


@pytest.fixture
def unbudgeted_router():
    """A router without budgets on the TGT keys: throw_garbage puts several TGTs on D01's key at once, more than a
    router lets through (`schema.tuning.TGT_RATE`), to see each refused by the coordinator."""
    with embedded_router(tgt_budgets=False) as locator:
        yield locator


def test_invalid_targets_and_malformed_messages_change_nothing(unbudgeted_router, tmp_path):
    """The test plays the GCS itself: it throws bad input at every key, then plays normally; the
    journal must equal a clean run's, and every process must log its rejections and exit 0."""
    router = unbudgeted_router

    def play(root: str, hostile: bool) -> tuple[bytes, Cluster]:
        c = Cluster(router, tmp_path, root=root)
        journal = start_game(c, tmp_path, coord_args=("--seed", "3", "--gcs-deadline", "30"), gcs_args=None)
        keys = Keys(root)
        import logging

        log = logging.getLogger("test-gcs")
        with zenoh.open(client_config(router)) as s:
            inbox = Inbox(s, keys, log)
            inbox.subscribe(keys.turn, Turn)
            inbox.subscribe(keys.over, Over)
            out = Outbox(s)
            member = Membership(s, inbox, Connect(turn=0, sender="GCS", role=Role.GCS, session=session_id(s)), log,
                                connect_timeout=30, grace=30)
            done = False
            while not done:
                ev = inbox.get(30)
                assert ev is not None, "the game stalled"
                match ev:
                    case Received(_, Turn(phase=Phase.GCS) as t):
                        sent = throw_garbage(s, keys, t.turn) if hostile and t.turn <= 2 else 0
                        out.put(keys.tgt("D01"), Target(turn=t.turn, sender="GCS", drone="D01", pos=(9, 9, 0)))
                        out.put(keys.gcs_done, Done(turn=t.turn, sender="GCS", phase=Phase.GCS,
                                                    intent=Intent.FINAL, count=1 + sent))
                    case Received(_, Over()):
                        done = True
            codes = c.wait_all()
            member.close()
        assert set(codes.values()) == {0}, [p.text for p in c.procs]
        return journal.read_bytes(), c

    clean, _ = play("clean" + tmp_path.name[-6:], hostile=False)
    attacked, c = play("hostile" + tmp_path.name[-6:], hostile=True)
    assert attacked == clean
    srv, env, drone = c.procs[:3]
    for reason in ("out-of-range", "unknown-entity", "wrong-sender", "stale-turn", "malformed"):
        assert any(reason in line for line in srv.err), f"SRV did not log {reason}:\n{srv.text}"
    assert any("rejected" in line for line in env.err), env.text
    assert any("rejected" in line for line in drone.err), drone.text


def throw_garbage(s: zenoh.Session, keys: Keys, turn: int) -> int:
    """Bad input on every key and queryable; returns how many TGT it sent as the GCS for this turn
    (the GCS's DONE counts them)."""
    bad_targets = [
        Target(turn=turn, sender="GCS", drone="D01", pos=(50, 0, 0)),  # outside the world
        Target(turn=turn, sender="GCS", drone="D09", pos=(1, 1, 1)),  # unknown drone
        Target(turn=turn, sender="D01", drone="D01", pos=(1, 1, 1)),  # a drone giving itself a target
        Target(turn=turn + 5, sender="GCS", drone="D01", pos=(1, 1, 1)),  # future turn
    ]
    for t in bad_targets:
        s.put(keys.tgt(t.drone), encode(t))
    s.put(keys.tgt("D02"), encode(Target(turn=turn, sender="GCS", drone="D01", pos=(1, 1, 1))))  # wrong key
    garbage = [b"", b"\xff\x00garbage", b"\x93\x01\x02\x03", json.dumps({"v": 1}).encode(),
               encode(Done(turn=turn, sender="GCS", phase=Phase.GCS))[:-3]]
    for key in (keys.turn, keys.status, keys.over, keys.tgt("D01"), keys.gcs_done, keys.nps("D01"), keys.upd):
        for g in garbage:
            s.put(key, g)
    for key in (keys.connect, keys.ask, keys.map):
        for g in garbage[:3]:
            replies = ask_until_replied(s, key, g, timeout=10)  # (CONNECTs: the router's budget a session)
            assert replies and all(r.err is not None for r in replies), key
    return 2  # the target outside the world and the one for an unknown drone


@pytest.mark.parametrize("target,error", [("10,0,0", r"\(10, 0, 0\) is outside the world"),
                                          ("1,4,0", r"\(1, 4, 0\) is inside a building: no drone can get there")])
def test_scripted_gcs_refuses_a_target_outside_the_world_or_inside_a_building(cluster, tmp_path, target, error):
    world = tmp_path / "wall.json"
    World.from_buildings((10, 10, 2), [Building(x=1, y=0, length=1, width=10, height=1)]).save(world)
    start_game(cluster, tmp_path, coord_args=("--world", str(world)), gcs_args=("--targets", target))
    gcs = cluster.procs[-1]
    assert gcs.wait() == 2
    gcs.expect(error)
    for p in cluster.procs[:-1]:
        p.kill()


@pytest.mark.parametrize("kind,signum,status", [
    ("scripted", signal.SIGTERM, 143), ("scripted", signal.SIGINT, 130), ("interactive", signal.SIGINT, 130),
    ("web", signal.SIGTERM, 143),
])
def test_a_ground_station_stopped_by_a_signal_stops_cleanly(cluster, tmp_path, kind, signum, status):
    """Ctrl-C or SIGTERM mid-game (at the console's prompt, too): no traceback, the shell's exit status."""
    start_game(cluster, tmp_path, coord_args=("--pace", "0.2"), gcs_args=None)  # the game lasts while we act
    args = {"scripted": ("--targets", "9,9,0"), "interactive": (),
            "web": ("--web", "127.0.0.1:0", "--pace", "0", "--targets", "9,9,0")}[kind]
    gcs = cluster.start("GCS", "gcs", *args, stdin=subprocess.PIPE if kind == "interactive" else subprocess.DEVNULL)
    gcs.expect(r"^turn \d+:|^web ground station: http")  # admitted and playing
    gcs.p.send_signal(signum)
    assert gcs.wait() == status, gcs.text
    gcs.expect(rf"stopped by {signal.Signals(signum).name}")
    assert "Traceback" not in gcs.text, gcs.text


def test_up_runs_the_demo_in_one_command(tmp_path):
    journal = tmp_path / "up.journal"
    p = subprocess.run([sys.executable, "-m", "dronesim", "up", "--seed", "7", "--targets", "9,9,0",
                        "--journal", str(journal)], capture_output=True, text=True, timeout=120,
                       stdin=subprocess.DEVNULL)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "GAME OVER" in p.stdout and "ALL_REACHED" in p.stdout
    assert "all 4 processes exited 0" in p.stdout
    assert "z = 0" in p.stdout and "D01" in p.stdout
    assert journal_records(journal)[-1]["reason"] == "ALL_REACHED"


def test_same_seed_twice_gives_identical_journals(router, tmp_path):
    """The conformance test every entity must pass (cf. PettingZoo's seed_test)."""
    journals = []
    for _ in range(2):
        with Cluster(router, tmp_path) as c:
            journals.append(start_game(c, tmp_path, coord_args=("--seed", "11", "--size", "12,12,6"),
                                       gcs_args=("--targets", "11,11,3", "--targets", "3,9,1@9")))
            assert set(c.wait_all().values()) == {0}
    assert journals[0].read_bytes() == journals[1].read_bytes()


def test_unreachable_target_is_reported_to_the_gcs_and_the_game_settles(cluster, tmp_path):
    """The D* drone says its target is unreachable (a walled-in cell) instead of looping; the GCS shows it."""
    world = tmp_path / "walled.json"
    # a 7x7x1 floor with a closed ring of buildings around (5, 5, 0)
    ring = [Building(x=x, y=y, length=1, width=1, height=1)
            for x in range(4, 7) for y in range(4, 7) if (x, y) != (5, 5)]
    World.from_buildings((7, 7, 1), ring).save(world)
    journal = start_game(cluster, tmp_path, coord_args=("--world", str(world)), drone_args=("--autopilot", "dstar"),
                         gcs_args=("--targets", "5,5,0"))
    codes = cluster.wait_all()
    assert set(codes.values()) == {0}, [p.text for p in cluster.procs]
    gcs = cluster.procs[-1]
    assert any("target UNREACHABLE, hovering" in line for line in gcs.out), gcs.text
    records = journal_records(journal)
    assert records[-1]["reason"] == "SETTLED"
    assert not any(r.get("deaths") for r in records)


def test_a_connect_without_its_presence_token_is_refused(cluster, tmp_path):
    """A process cannot take another's seat by writing its name in a CONNECT: the coordinator admits a
    CONNECT only once the presence token of that (sender, session) is seen."""
    from schema import Refused, Welcome, decode

    srv = cluster.start("SRV", "coordinator", "--admit-deadline", "60")
    srv.expect("coordinator ready")
    keys = Keys(cluster.root)
    with zenoh.open(client_config(cluster.locator)) as s:
        hello = Connect(turn=0, sender="GCS", role=Role.GCS, session="0badc0ffee")  # no such token
        replies = [r for r in s.get(keys.connect, payload=encode(hello), timeout=30) if r.ok is not None]
        assert len(replies) == 1
        refused = decode(replies[0].ok.payload.to_bytes(), (Welcome, Refused))
        assert isinstance(refused, Refused) and "no presence token of GCS" in refused.text
    gcs = cluster.start("GCS", "gcs", "--targets", "9,9,0")  # the real one still gets its seat
    cluster.start("ENV", "env")
    cluster.start("D01", "drone", "--id", "D01")
    assert gcs.wait() == 0
    assert srv.wait() == 0



def mid_game(cluster: Cluster, s: zenoh.Session, key: str, kind: type, name: str):
    """The messages of a paced game on `key` (decoded as `kind`), as a client of its router sees them; the
    game ending (OVER) or stalling first fails the test."""
    import logging

    keys = Keys(cluster.root)
    inbox = Inbox(s, keys, logging.getLogger(name))
    inbox.subscribe(key, kind)
    inbox.subscribe(keys.over, Over)
    while True:
        ev = inbox.get(30)
        assert ev is not None, f"nothing on {key}: the game stalled"
        match ev:
            case Received(_, Over()):
                pytest.fail(f"the game ended too soon:\n{cluster.procs[0].text}\n{cluster.procs[1].text}")
            case Received(_, msg):
                yield msg


def test_a_listener_to_the_upd_gets_each_env_phase_reported(cluster, tmp_path):
    """Someone listening to the environment's UPD mid-game (no --verify-env: the coordinator does not), the
    environment follows the ENV phase from then on, the coordinator announces it, and the UPD reports each
    drone's move: its old cell empty, its new one with the drone."""
    start_game(cluster, tmp_path, coord_args=("--pace", "0.1"), gcs_args=("--targets", "9,9,9"), verify_env=False)
    with zenoh.open(client_config(cluster.locator)) as s:
        for _, upd in zip(range(3), mid_game(cluster, s, Keys(cluster.root).upd, Upd, "test-listener")):
            assert any(c.drones == ("D01",) for c in upd.cells), upd


def test_environment_answers_about_the_drones_where_the_last_status_has_them(cluster, tmp_path):
    """Nobody listens to the environment's UPD (no --verify-env), so it does not take the ENV phase's
    moves: the drones' positions come from STATUS alone. Asked mid-game about a drone's cell, it answers
    with the drone where the last STATUS has it."""
    start_game(cluster, tmp_path, coord_args=("--pace", "0.1"), gcs_args=("--targets", "9,9,9"), verify_env=False)
    env = cluster.procs[1]
    keys = Keys(cluster.root)
    with zenoh.open(client_config(cluster.locator)) as s:
        answered = late = 0
        for st in mid_game(cluster, s, keys.status, Status, "test-asker"):
            if answered == 3:
                break
            if st.turn >= 3:
                (d01,) = [r for r in st.drones.records() if r.drone == "D01"]
                ask = Ask(turn=st.turn + 1, sender="D01", cells=(d01.pos,))  # (paced: turn + 1 is still on)
                replies = list(s.get(keys.ask, payload=encode(ask), timeout=10))
                assert len(replies) == 1, replies
                if replies[0].ok is None:  # (this process ran late: the game went on past turn + 1 meanwhile)
                    why = replies[0].err.payload.to_bytes().decode()
                    assert why.startswith(f"ASK for past turn {st.turn + 1} from D01"), why
                    late += 1
                    continue
                ans = decode(replies[0].ok.payload.to_bytes(), Ans)
                assert ans.turn == st.turn + 1 and ans.drones == ((0, "D01"),)
                answered += 1
    assert answered == 3, f"3 answers before the game's end ({late} asked too late)"
    assert set(cluster.wait_all().values()) == {0}
    refused = [line for line in env.err if "rejected" in line]
    assert len([line for line in refused if "ASK for past turn" in line]) <= late, env.text
    assert not [line for line in refused if "ASK for past turn" not in line and not re.search(
        r"rejected inputs: \{'stale-turn': \d+\}", line)], env.text
