"""Floods cannot move a game (issue 18): a client of the router publishes 200,000 well-formed NPS for a
past turn on a drone's key while the game runs, as an authenticated drone may on its own key under the
router's access control. The router forwards at most `PUT_RATE` of them a second (its
`downsampling`, from the key table), and the coordinator refuses those on arrival, unread beyond their
first bytes, so the turn's messages never wait behind them: the journal is byte-identical to a clean
run's, every process exits 0, and the coordinator's log stays a few summary lines long while it counts
every one it refused, by origin. And a flood of big ASKs from one drone does not starve another's."""

from __future__ import annotations

import re
import threading
from collections.abc import Callable

import pytest
import zenoh

from benchmarks.flood import flood_rate
from benchmarks.games import Case, Game
from schema import Done, Keys, Message, Nps, Phase, encode
from tests.harness import Cluster, Proc, ScriptedGCS, client_config, embedded_router, play_to_the_end

pytestmark = pytest.mark.integration

TARGETS = {"D01": (9, 9, 9)}
FLOOD = 200_000
START = 3  # the GCS phase after which the flood starts
GAME = ("--seed", "7", "--admit-deadline", "60", "--phase-deadline", "2", "--pace", "0.1")


def start(c: Cluster, tmp_path):
    journal = tmp_path / f"{c.root}.journal"
    srv = c.start("SRV", "coordinator", "--journal", str(journal), *GAME)
    srv.expect("coordinator ready")
    c.start("ENV", "env", "--no-draw")
    c.start("D01", "drone", "--id", "D01")
    return journal


def flood(locator: str, key: str, stale: bytes, sent: list[int]) -> None:
    with zenoh.open(client_config(locator)) as s:
        pub = s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        for _ in range(FLOOD):
            pub.put(stale)
            sent[0] += 1


def flooded_game(tmp_path, key: Callable[[Keys], str], stale: Message) -> tuple[Proc, int]:
    """The game clean, then again with FLOOD copies of `stale` put on `key` from the turn after START: every
    process exits 0, the attacker sent them all, the journal is byte-identical to the clean one's. The
    coordinator's process, and how many the coordinator refused from the key's origin."""
    with embedded_router() as router:
        with Cluster(router, tmp_path) as clean:
            expected = start(clean, tmp_path)
            play_to_the_end(clean, TARGETS)
        with Cluster(router, tmp_path) as c:
            journal = start(c, tmp_path)
            keys = Keys(c.root)
            gcs = ScriptedGCS(router, c.root, TARGETS)
            sent = [0]
            attacker = threading.Thread(target=flood, args=(router, key(keys), encode(stale), sent))
            try:
                gcs.play_until(START)
                attacker.start()
                gcs.play_until()
            finally:
                gcs.close()
                attacker.join()
            codes = c.wait_all()
        assert set(codes.values()) == {0}, [p.text for p in c.procs]
        assert sent[0] == FLOOD
        assert journal.read_bytes() == expected.read_bytes(), "the flood changed the game"
        srv = c.procs[0]
        report = next(line for line in srv.err if "rejected inputs:" in line)
        found = re.search(rf"'{keys.origin_of(key(keys))}': (\d+)", report)
        return srv, int(found.group(1)) if found else 0


def test_200000_stale_dones_on_the_ground_stations_key_change_nothing_and_most_stop_at_the_router(tmp_path):
    """Issue 33, 6: a second session floods the ground station's DONE key with stale DONEs (any peer on a plain
    router). The router keeps at most PUT_RATE of them a second from that session (`downsampling`); they all used
    to reach the coordinator, and the game waited behind them on its link."""
    _, counted = flooded_game(tmp_path, lambda keys: keys.gcs_done, Done(turn=1, sender="GCS", phase=Phase.GCS))
    assert 0 < counted < FLOOD, "the router dropped none"


def test_200000_stale_nps_on_a_drones_key_change_nothing(tmp_path):
    srv, counted = flooded_game(tmp_path, lambda keys: keys.nps("D01"), Nps(turn=1, sender="D01", pos=(0, 0, 1)))
    report = next(line for line in srv.err if "rejected inputs:" in line)
    assert "stale-turn" in report and counted > 0, report
    logged = [line for line in srv.err if "rejected" in line and line is not report]
    assert len(logged) < max(10, counted // 10), f"{len(logged)} lines of log for {counted} rejections"


def test_a_flood_of_big_asks_from_one_drone_does_not_starve_another_drones_ask(tmp_path):
    """300 ASKs of 32,768 cells each from D01, then one small ASK from D02: the environment answers D02
    after at most its share of D01's (`ORIGIN_SHARE`) and those already being read, never after the
    flood; what D01 sends past its budget is refused unread, with an error reply."""
    from schema import Ask
    from schema.tuning import ORIGIN_BYTES, ORIGIN_SHARE

    big = encode(Ask(turn=0, sender="D01", cells=tuple((x % 10, x // 10 % 10, x // 100 % 10)
                                                       for x in range(Ask.MAX_CELLS))))
    order: list[str] = []  # "D01" / "D01 refused" / "D02", as the replies come
    lock = threading.Lock()

    def reply_to(who: str):
        def on_reply(reply: zenoh.Reply) -> None:
            with lock:
                order.append(who if reply.ok is not None else f"{who} refused")
        return on_reply

    with embedded_router() as router, Cluster(router, tmp_path) as c:
        start(c, tmp_path)
        keys = Keys(c.root)
        gcs = ScriptedGCS(router, c.root, TARGETS)
        try:
            gcs.play_until(START)
            with zenoh.open(client_config(router)) as s:
                for _ in range(300):
                    s.get(keys.ask, reply_to("D01"), payload=big, timeout=120)
                small = encode(Ask(turn=0, sender="D02", cells=((1, 1, 1),)))
                done = threading.Event()

                def on_d02(reply: zenoh.Reply) -> None:
                    reply_to("D02")(reply)
                    done.set()

                s.get(keys.ask, on_d02, payload=small, timeout=120)
                assert done.wait(120), "D02's ASK was never answered"
            gcs.play_until()
        finally:
            gcs.close()
        assert set(c.wait_all().values()) == {0}, [p.text for p in c.procs]
    answered_before = order[:order.index("D02")].count("D01")
    queued_at_most = ORIGIN_BYTES // len(big) + 1
    assert answered_before <= queued_at_most + ORIGIN_SHARE, order
    assert "D01 refused" in order, "past its budget, D01's ASKs are refused unread"


def test_the_flood_rate_counts_the_turns_its_window_overlaps():
    """`dronesim bench flood`: a flood within one turn counts that turn; one over several counts them all;
    one that outlasts the measured turns is cut at the last."""
    case = Case(drones=1, size=(10, 10, 10), warmup=3, turns=4)
    game = Game(arrived={t: float(t) for t in range(1, case.end_turn)})  # turn t's STATUS at t s
    assert flood_rate(game, case, 3.0, 3.1) == (1.0, 1, 1.0, False)  # within the turn from 3 s to 4 s
    assert flood_rate(game, case, 3.5, 3.5) == (1.0, 1, 1.0, False)
    assert flood_rate(game, case, 3.2, 5.5) == (1.0, 3, 3.0, False)
    rate, turns, seconds, cut = flood_rate(game, case, 4.5, 99.0)
    assert (turns, seconds, cut) == (case.end_turn - 1 - 4, case.end_turn - 1 - 4.0, True)
