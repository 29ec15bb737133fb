"""Hostile peers (issue 33, items 6 and 7): floods of CONNECTs with invented sessions hold bounded memory, and on
a plain router no entity wedges on one absurd message (a TURN, STATUS or OVER at turn 2^40, an answer to CONNECT
from a session that is not the coordinator)."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import subprocess
import sys
import threading

import pytest
import zenoh

from coordinator.admission import Presences
from dronesim import child_env
from dronesim.certs import GameCredentials
from network.clock import TurnClock
from network.transport import add_zenoh_args, client_config, zenoh_config
from schema import Connect, Keys, Over, Phase, Refused, Role, Status, Turn, decode, encode
from schema.errors import OTHERS, RejectCounter, RemoteInputError, StaleTurn, WrongSender
from schema.messages import EndReason
from schema.samples import SAMPLES
from schema.tuning import CONNECT_WAITING, CONNECT_WAITING_PER_SENDER, REJECT_ORIGINS

from .harness import Cluster, embedded_router
from .test_integration import start_game

ABSURD = 2 ** 40


def hello(sender: str, session: str) -> Connect:
    return Connect(turn=0, sender=sender, role=Role.DRONE, drones=(sender,), autopilot="seed", session=session)


def test_connects_with_invented_sessions_wait_in_bounded_numbers_and_the_rest_are_refused_at_once() -> None:
    """A flood of CONNECTs whose presence token never comes held every query (about 25 KB each) for 5 s: now at
    most CONNECT_WAITING wait, CONNECT_WAITING_PER_SENDER naming one sender; the rest are refused (`flood`) at once,
    and a CONNECT whose token is there is still admitted at once."""
    p: Presences[int] = Presences()
    refused = 0
    for i in range(20_000):
        sender = "D01" if i % 2 else f"D{i % 60_000 + 1:02d}"
        try:
            assert p.connect(i, hello(sender, f"s{i}"), now=0.0) == []
        except RemoteInputError as err:
            assert err.reason == "flood"
            refused += 1
        assert p.waiting() <= CONNECT_WAITING
    assert p.waiting() == CONNECT_WAITING and refused == 20_000 - CONNECT_WAITING
    assert sum(1 for _, _, m in p._waiting if m.sender == "D01") <= CONNECT_WAITING_PER_SENDER
    p.presence("D02", "real", True)
    assert p.connect("q", hello("D02", "real"), now=0.0) == [("q", hello("D02", "real"))]
    assert len(p.expired(now=10.0)) == CONNECT_WAITING and p.waiting() == 0


def test_rejections_from_ever_new_origins_are_counted_in_bounded_structures() -> None:
    """A query names its sender itself: rejections naming a new one each time are counted whole, under "(others)"
    beyond REJECT_ORIGINS origins, and the log windows stay bounded."""
    now = [0.0]
    rejects = RejectCounter(logging.getLogger("dronesim.tests.hostile"), clock=lambda: now[0])
    for i in range(20_000):
        now[0] = i * 0.001
        rejects.reject("CONNECT", WrongSender("no presence token"), f"D{i + 1:02d}")
    assert rejects.total == 20_000
    assert len(rejects._origins) == REJECT_ORIGINS + 1 and rejects._origins[OTHERS] == 20_000 - REJECT_ORIGINS
    assert len(rejects._windows) <= REJECT_ORIGINS + 1


def status(turn: int) -> Status:
    return dataclasses.replace(SAMPLES["status"], turn=turn, game="g")  # type: ignore[type-var]


def test_a_turn_far_in_the_future_is_refused_and_the_clock_goes_on() -> None:
    """One STATUS (the environment takes any later one), TURN or OVER at turn 2^40 used to move an entity's clock
    past every real message to come. Given the time, the clock refuses what no game can have reached yet."""
    for skips in (False, True):
        clock = TurnClock(game="g", skips_status=skips, now=100.0)
        clock.admit(Turn(turn=1, sender="SRV", phase=Phase.DRONES, game="g"), 100.0)
        for absurd in (status(ABSURD),
                       Turn(turn=ABSURD, sender="SRV", phase=Phase.DRONES, game="g"),
                       Over(turn=ABSURD, sender="SRV", reason=EndReason.INTERRUPTED, text="forged", game="g")):
            with pytest.raises(StaleTurn) as err:
                clock.admit(absurd, 100.5)  # type: ignore[arg-type]
            assert err.value.reason in ("future-turn", "stale-turn")
        clock.admit(status(1), 100.5)
        clock.admit(Turn(turn=2, sender="SRV", phase=Phase.DRONES, game="g"), 100.6)
        assert clock.turn == 2
    late = TurnClock(game="g", skips_status=True, now=0.0, known=40)  # a resumed game, the environment idle 10 s
    late.admit(status(50_000), 10.0)
    assert late.turn == 50_001


def test_a_burst_of_genuine_turns_read_at_once_is_current() -> None:
    """A busy or descheduled process reads the turns that came meanwhile in one go: when it reads STATUS(54) says
    nothing of when it was sent. The environment (it takes the newest STATUS) of a game at 300 turns/s, admitted at
    turn 0 at time 0, reads STATUS(10) and STATUS(54) in the same millisecond, 0.3 s in: both are current (the clock
    used to measure from when it last moved and refused the second as future-turn, a false rejection in CI under a
    flood). Yet no game reaches turn 5,000 in 0.3 s."""
    clock = TurnClock(game="g", skips_status=True, now=0.0, known=0)
    clock.admit(Turn(turn=1, sender="SRV", phase=Phase.DRONES, game="g"), 0.003)
    clock.admit(status(10), 0.3)
    clock.admit(status(54), 0.3)
    assert clock.turn == 55
    with pytest.raises(StaleTurn) as err:
        clock.admit(status(5_000), 0.3)
    assert err.value.reason == "future-turn"
    assert clock.turn == 55


@pytest.fixture
def router():
    with embedded_router() as locator:
        yield locator


def test_a_hostile_peer_on_a_plain_router_wedges_no_entity(router, tmp_path) -> None:
    """On a plain router a peer answers every CONNECT with REFUSED (it has no coordinator's presence) and, once the
    game runs, publishes a STATUS, TURNs and an OVER of this game at turn 2^40: every entity ignores them (counted),
    the game ends as it would have, every process exits 0 with the journal of an unattacked game."""

    def play(root: str, hostile: bool) -> tuple[bytes, Cluster]:
        keys, stop = Keys(root), threading.Event()
        with zenoh.open(client_config(router)) as s, Cluster(router, tmp_path, root=root) as c:
            if hostile:
                def lie(query: zenoh.Query) -> None:
                    query.reply(query.key_expr, encode(Refused(turn=0, sender="SRV", text="forged: go away")))

                def forge(sample: zenoh.Sample) -> None:
                    from schema import decode

                    real = decode(sample.payload.to_bytes(), Status)
                    if stop.is_set() or real.turn < 2:
                        return
                    stop.set()
                    s.put(keys.status, encode(Status(turn=ABSURD, sender="OBS", drones=real.drones, game=real.game)))
                    for phase in (Phase.GCS, Phase.DRONES, Phase.ENV):
                        s.put(keys.turn_of(phase), encode(Turn(turn=ABSURD, sender="SRV", phase=phase, game=real.game)))
                    s.put(keys.over, encode(Over(turn=ABSURD, sender="SRV", reason=EndReason.INTERRUPTED,
                                                 text="forged", game=real.game)))

                s.declare_queryable(keys.connect, lie)
                s.declare_subscriber(keys.status, forge)
            journal = start_game(c, tmp_path, coord_args=("--seed", "3", "--pace", "0.05"))
            codes = c.wait_all()
            assert set(codes.values()) == {0}, [p.text for p in c.procs]
            assert stop.is_set() == hostile
            return journal.read_bytes(), c

    clean, _ = play("clean" + tmp_path.name[-6:], hostile=False)
    attacked, c = play("hostile" + tmp_path.name[-6:], hostile=True)
    assert attacked == clean
    for p in c.procs[1:]:  # ENV, D01, GCS: none took the forged REFUSED (all admitted), each refused the absurd turns
        assert not any("connection refused" in line for line in p.err), p.text
        assert any("future-turn" in line for line in p.err), p.text


def run_up(tmp_path, name: str, *flags: str, attack=None) -> tuple[int, bytes, str]:
    """`dronesim up` (a scripted game, paced so that the attacker acts while it runs): its exit code, its journal
    and its output; `attack(locator, credentials folder)` runs once the router is up."""
    journal, creds = tmp_path / f"{name}.journal", tmp_path / f"{name}-credentials"
    proc = subprocess.Popen([sys.executable, "-m", "dronesim", "up", "--targets", "9,9,0", "--max-turns", "40",
                             "--pace", "0.05", "--quiet", "--journal", str(journal), "--credentials", str(creds),
                             *flags], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=child_env())
    assert proc.stdout is not None
    first = proc.stdout.readline()
    locator = first.split("router on ")[1].split(",")[0]
    if attack is not None:
        attack(locator, creds)
    out = first + proc.stdout.read()
    return proc.wait(timeout=120), journal.read_bytes(), out


def forge(locator: str, conf: zenoh.Config, root: str = "sim") -> bool:
    """From a session on `conf`: a forged REFUSED to every CONNECT, and once a STATUS of turn 2 or more is seen,
    a STATUS, TURNs and an OVER of the game at turn 2^40 (what a peer can send on a plain router)."""
    keys, done = Keys(root), threading.Event()
    with zenoh.open(conf) as s:
        s.declare_queryable(keys.connect, lambda q: q.reply(q.key_expr, encode(Refused(turn=0, sender="SRV",
                                                                                       text="forged"))))

        def on_status(sample: zenoh.Sample) -> None:
            real = decode(sample.payload.to_bytes(), Status)
            if real.turn >= 2 and not done.is_set():
                s.put(keys.status, encode(Status(turn=ABSURD, sender="OBS", drones=real.drones, game=real.game)))
                for phase in (Phase.GCS, Phase.DRONES, Phase.ENV):
                    s.put(keys.turn_of(phase), encode(Turn(turn=ABSURD, sender="SRV", phase=phase, game=real.game)))
                s.put(keys.over, encode(Over(turn=ABSURD, sender="SRV", reason=EndReason.INTERRUPTED, text="forged",
                                             game=real.game)))
                done.set()

        s.declare_subscriber(keys.status, on_status)
        return done.wait(30)


def assert_forged(locator: str) -> None:
    assert forge(locator, client_config(locator))


def client(locator: str, *flags: str) -> zenoh.Config:
    parser = argparse.ArgumentParser()
    add_zenoh_args(parser)
    return zenoh_config(parser.parse_args(["--mode", "client", "--connect", locator, *flags]))


def test_dronesim_up_is_secured_by_default_and_attacks_that_break_a_plain_game_change_nothing(tmp_path) -> None:
    """By default `dronesim up` makes the game's credentials and access control: a peer without credentials cannot
    even open a session (TLS and a password), and one holding another principal's (a drone's) cannot answer CONNECT
    nor forge STATUS, TURN or OVER (the router drops them). On a plain router (`--insecure`) the same peer's forged
    REFUSED and turns at 2^40 are ignored (no entity wedges). Each game ends as an unattacked one."""
    code, clean, out = run_up(tmp_path, "clean", "--insecure")
    assert code == 0, out

    def attack_secured(locator: str, creds) -> None:
        assert locator.startswith("tls/")
        for flags in ((), ("--tls-ca", str(creds / "ca.pem")), ("--tls-ca", str(creds / "ca.pem"), "--user", "GCS",
                                                                 "--password-file", str(creds / "D01.password"))):
            with pytest.raises(zenoh.ZError):  # no credentials, or a wrong password: no session
                zenoh.open(client(locator, *flags)).close()
        with pytest.raises(zenoh.ZError):
            zenoh.open(client(locator.replace("tls/", "tcp/"))).close()
        assert forge(locator, client(locator, *GameCredentials(creds).flags("D01")))  # a drone's credentials

    code, secured, out = run_up(tmp_path, "secured", attack=attack_secured)
    assert code == 0 and secured == clean, out
    assert "future-turn" not in out  # (the router dropped them: no process had to refuse them)

    code, plain, out = run_up(tmp_path, "plain", "--insecure", attack=lambda loc, _: assert_forged(loc))
    assert code == 0 and plain == clean, out
