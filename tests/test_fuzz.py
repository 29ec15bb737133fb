"""Hostile input at every key every entity listens to, over a real router (Hypothesis-driven).

The game is held in a GCS phase (the test plays the ground station) while Hypothesis throws random
bytes, mutated golden vectors, well-formed messages of the wrong type for the key, out-of-range cells,
stale and future turns, wrong senders and huge payloads (which the router drops) at every subscribed key
and queryable. Then the game is played to its end. Every process must survive (no crash, no hang), count and log its
rejections with a reason, and the journal must be byte-identical to an unattacked run: nothing changed.

Forging a legitimate sender in the right phase (a well-formed TGT "from the GCS" for the current turn)
is not malformed input: it is spoofing, which the router's access control stops (see the security
tests); the fuzzer does not generate it.
"""

from __future__ import annotations

import re
import time
import uuid

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schema import (
    SCHEMA_VERSION,
    Ask,
    Cause,
    CellInfo,
    CellKind,
    Done,
    DroneState,
    DroneStatus,
    EndReason,
    Keys,
    MalformedMessage,
    Move,
    Nps,
    Order,
    Over,
    Phase,
    Status,
    Target,
    Turn,
    Upd,
    decode,
    encode,
)
from schema.samples import SAMPLES
from tests.harness import Cluster, ScriptedGCS, ask_until_replied, embedded_router, play_to_the_end

pytestmark = pytest.mark.integration

TARGETS = {"D01": (9, 9, 0), "D02": (9, 0, 3)}
HOLD_TURN = 5  # the GCS phase during which the attack happens


def start(c: Cluster, tmp_path):
    journal = tmp_path / f"{c.root}.journal"
    srv = c.start("SRV", "coordinator", "--journal", str(journal), "--drones", "2", "--seed", "7",
                  "--admit-deadline", "60", "--phase-deadline", "60")
    srv.expect("coordinator ready")
    c.start("ENV", "env", "--no-draw")
    c.start("D01", "drone", "--id", "D01", "--autopilot", "dstar")
    c.start("D02", "drone", "--id", "D02", "--autopilot", "seed")
    return journal


cells = st.tuples(*[st.integers(-70000, 70000)] * 3)
turns = st.one_of(st.integers(1, HOLD_TURN - 1), st.integers(HOLD_TURN + 1, 10**6))  # stale or future
HUGE = b"HUGE"  # stands for a 5 MiB payload (kept out of Hypothesis's reports)
senders = st.sampled_from(["D01", "D02", "D99", "ENV", "GCS", "SRV", "OBS", "H01"])


def wellformed_but_wrong() -> st.SearchStrategy:
    """Decodable messages that must still be refused where they land (wrong turn, type, sender, range)."""
    small = st.tuples(*[st.integers(0, 20)] * 3)
    return st.one_of(
        st.builds(lambda t, p, s: Target(turn=t, sender=s, drone="D01", pos=p), turns, small, senders),
        st.builds(lambda p: Target(turn=HOLD_TURN, sender="D01", drone="D01", pos=p), small),  # a drone's target
        st.builds(lambda t, p: Nps(turn=t, sender="D01", pos=p), st.integers(0, 10**6), small),
        st.builds(lambda t: Done(turn=t, sender="GCS", phase=Phase.GCS), turns),
        st.builds(lambda t, s: Done(turn=t, sender=s, phase=Phase.DRONES), st.integers(1, 10**6), senders),
        st.builds(lambda t, p: Upd(turn=t, sender="ENV", cells=(CellInfo(pos=p, kind=CellKind.BUILDING,
                                                                          drones=("D01",)),)), turns, small),
        st.builds(lambda t: Turn(turn=t, sender="SRV", phase=Phase.DRONES,
                                 orders=(Order(drone="D01", pos=(0, 0, 0), target=(1, 1, 1)),)), turns),
        st.builds(lambda t: Turn(turn=t, sender="SRV", phase=Phase.ENV,
                                 moves=(Move(drone="D02", src=(5, 5, 5), dst=(5, 5, 6)),)), turns),
        st.builds(lambda t: Status(turn=t, sender="OBS", drones=(DroneStatus(
            drone="D01", pos=(3, 3, 3), state=DroneState.DEAD, cause=Cause.BUILDING),)), turns),
        st.builds(lambda t: Over(turn=t, sender="GCS", reason=EndReason.ABORTED), st.integers(0, 10**6)),
        st.builds(lambda t, c: Ask(turn=t, sender="D01", cells=(c,)), turns, cells.filter(lambda c: min(c) >= -65536
                                                                                          and max(c) <= 65536)),
    ).map(encode)


def mutated_vectors() -> st.SearchStrategy:
    golden = [encode(m) for m in SAMPLES.values()]

    def mutate(data: bytes, edits: list[tuple[int, int]], cut: int) -> bytes:
        b = bytearray(data)
        for pos, val in edits:
            b[pos % len(b)] = val
        return bytes(b[: max(1, len(b) - cut)])

    return st.builds(mutate, st.sampled_from(golden), st.lists(st.tuples(st.integers(0, 4096), st.integers(0, 255)),
                                                               max_size=4), st.integers(0, 3))


def payloads() -> st.SearchStrategy:
    return st.one_of(st.binary(max_size=256), mutated_vectors(), wellformed_but_wrong(), st.just(HUGE))


def spoofs_the_current_gcs_phase(data: bytes) -> bool:
    """A message the protocol would rightly accept (see the module docstring): not generated."""
    try:
        msg = decode(data)
    except MalformedMessage:
        return False
    return isinstance(msg, (Target, Done)) and msg.sender == "GCS" and msg.turn == HOLD_TURN


def reference(router, tmp_path) -> bytes:
    with Cluster(router, tmp_path) as c:
        journal = start(c, tmp_path)
        play_to_the_end(c, TARGETS)
    return journal.read_bytes()


def test_fuzz_every_key_changes_nothing(tmp_path):
    with embedded_router() as router:
        expected = reference(router, tmp_path)
        with Cluster(router, tmp_path) as c:
            journal = start(c, tmp_path)
            keys = Keys(c.root)
            gcs = ScriptedGCS(router, c.root, TARGETS)
            s = gcs.session
            put_keys = [keys.turn, keys.status, keys.over, keys.tgt("D01"), keys.tgt("D02"), keys.gcs_done,
                        keys.nps("D01"), keys.nps("D02"), keys.upd]
            query_keys = [keys.connect, keys.ask, keys.map]
            stats = {"put": 0, "query": 0}
            try:
                gcs.play_until(HOLD_TURN - 1)
                gcs.wait_phase("GCS", HOLD_TURN)

                @settings(max_examples=250, derandomize=True, deadline=None, database=None,
                          suppress_health_check=list(HealthCheck))
                @given(st.sampled_from(put_keys + query_keys), payloads())
                def attack(key: str, data: bytes) -> None:
                    if spoofs_the_current_gcs_phase(data):
                        return
                    huge = data == HUGE
                    if huge:
                        data = b"\x00" * (5 * 1024 * 1024)
                    if key in query_keys:
                        # (CONNECTs and MAPs asked again while the router's budget of them a session ends them
                        # unanswered)
                        budgeted = key in (keys.connect, keys.map) and not huge
                        replies = ask_until_replied(s, key, data, timeout=10) if budgeted \
                            else list(s.get(key, payload=data, timeout=10))
                        # (a huge query is dropped by the router, its low_pass_filter: nobody sees it)
                        assert bool(replies) != huge, f"{key} did not answer" if not huge else f"{key} got it"
                        stats["query"] += 1
                    else:
                        s.put(key, data)
                        stats["put"] += 1

                attack()
                # Barrier: a marker each process rejects by name, sent after the burst on keys they listen
                # to; once every process has logged it, it has worked through the whole burst.
                # The router's budget of puts a session (PUT_RATE) may drop a marker put within 1/PUT_RATE s of the
                # burst's last put on its key: it is sent again after a quiet while. (The phase's answer below comes
                # after a process logged the last marker sent: never within that time of it.)
                marker = f"MARKER{uuid.uuid4().hex[:8]}"
                deadline = time.monotonic() + 300

                def send_marker() -> None:
                    for key in (keys.turn, keys.gcs_done):
                        s.put(key, msgpack.packb({"v": SCHEMA_VERSION, "t": marker}))

                send_marker()
                for p in c.procs:
                    while True:
                        try:
                            p.expect(f"unknown message type '{marker}'", timeout=10)
                            break
                        except AssertionError:
                            if time.monotonic() > deadline or p.p.poll() is not None:
                                raise
                            send_marker()
                    assert p.p.poll() is None, f"{p.name} died under fuzzing:\n{p.text}"
                gcs.answer(HOLD_TURN)
                try:
                    gcs.play_until()
                except AssertionError:
                    for p in c.procs:
                        print(f"== {p.name} (alive: {p.p.poll() is None})")
                        print("\n".join(line for line in p.err if "rejected" not in line))
                    raise
            finally:
                gcs.close()
            codes = c.wait_all()
            assert set(codes.values()) == {0}, [p.text for p in c.procs]
        assert stats["put"] > 100 and stats["query"] > 20
        assert journal.read_bytes() == expected, "the attack changed the game"
        srv, env, d1, d2 = c.procs
        for proc in (srv, env, d1, d2):
            reasons = set(re.findall(r"rejected .*\(([a-z-]+)\)$", "\n".join(proc.err), re.M))
            assert reasons, f"{proc.name} logged no rejection:\n{proc.text[-3000:]}"
        summary = next(line for line in srv.err if "rejected inputs:" in line)
        for reason in ("malformed", "stale-turn", "wrong-type"):  # (too large: dropped by the router)
            assert reason in summary, summary
