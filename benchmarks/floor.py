"""The floor of every turn: pub/sub and query round trips between this process and a helper process
(`benchmarks.pingpong`) through a loopback router (`dronesim bench perf`'s first rows, and the ratios to them)."""

from __future__ import annotations

import queue
import statistics
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import zenoh

from benchmarks.measure import Procs, cpu_seconds, loopback_router
from network.transport import client_config


@dataclass(slots=True)
class Floor:
    name: str
    rtts: list[float]  # seconds
    cpu: tuple[float, float] = (float("nan"), float("nan"))  # CPU seconds per round trip: helper, this process
    exit_code: int | None = None

    @property
    def median(self) -> float:
        return statistics.median(self.rtts) if self.rtts else float("nan")


def _cpu_per_round(cpu0: tuple[float, float] | None, pid: int, rounds: int) -> tuple[float, float]:
    if cpu0 is None or not rounds:
        return (float("nan"), float("nan"))
    return ((cpu_seconds(pid) - cpu0[0]) / rounds, (cpu_seconds() - cpu0[1]) / rounds)


def _payloads_into(q: queue.SimpleQueue[bytes]) -> Callable[[zenoh.Sample], None]:
    """A subscriber's callback putting each payload into `q`."""
    return lambda sample: q.put(sample.payload.to_bytes())


def measure_floor(rounds: int, warmup: int, logs: Path, *, pubsub: tuple[str, ...] = ("cb", "th"),
                  query: tuple[str, ...] = ("cb", "th")) -> list[Floor]:
    """Pub/sub and query round trips between this process and a pingpong helper process, the helper
    replying from its callbacks ("cb") or its main thread ("th"): a Floor for each mode asked, pub/sub first."""
    from benchmarks.measure import await_presence

    root = f"perf{uuid.uuid4().hex[:8]}"
    procs = Procs(logs)
    results: list[Floor] = []
    try:
        with loopback_router() as router, zenoh.open(client_config(router.locator)) as session:
            helper = procs.start("pingpong", [sys.executable, "-m", "benchmarks.pingpong", "--connect",
                                              router.locator, "--root", root])
            if not await_presence(session, f"{root}/ready", 60.0):
                raise RuntimeError(f"the pingpong helper did not start:\n{procs.tail('pingpong')}")
            for mode in pubsub:
                rtts, cpu = _published(session, f"{root}/{mode}", rounds, warmup, helper.pid)
                replies = "callback" if mode == "cb" else "main thread"
                results.append(Floor(f"floor: pub/sub round trip ({replies} replies)", rtts, cpu))
            for mode in query:
                rtts, cpu = _queried(session, f"{root}/{mode}", rounds, warmup, helper.pid)
                replies = "callback" if mode == "cb" else "main thread"
                results.append(Floor(f"floor: query round trip ({replies} replies)", rtts, cpu))
            session.put(f"{root}/quit", b"")
            code = procs.wait(30.0)["pingpong"]
    finally:
        procs.close()
    for r in results:
        r.exit_code = code
    return results


#: The bytes of each ping.
PAYLOAD = 16


def _published(session: zenoh.Session, prefix: str, rounds: int, warmup: int,
               helper: int) -> tuple[list[float], tuple[float, float]]:
    """`rounds` pub/sub round trips on `prefix`/ping and /pong after `warmup` ones, and the CPU of each."""
    got: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    sub = session.declare_subscriber(f"{prefix}/pong", _payloads_into(got))
    pub = session.declare_publisher(f"{prefix}/ping", congestion_control=zenoh.CongestionControl.BLOCK,
                                    reliability=zenoh.Reliability.RELIABLE)

    def trip(msg: bytes) -> float | None:
        t0 = time.perf_counter()
        pub.put(msg)
        try:
            back = got.get(timeout=5.0)
        except queue.Empty:  # routes not yet established during the warm-up: ping again
            return None
        dt = time.perf_counter() - t0
        while back != msg:  # a late pong of a timed-out warm-up ping
            back = got.get(timeout=5.0)
            dt = time.perf_counter() - t0
        return dt

    try:
        return _rounds(rounds, warmup, helper, trip, "pub/sub ping lost")
    finally:
        sub.undeclare()
        pub.undeclare()


def _queried(session: zenoh.Session, prefix: str, rounds: int, warmup: int,
             helper: int) -> tuple[list[float], tuple[float, float]]:
    """`rounds` query round trips on `prefix`/query after `warmup` ones, and the CPU of each."""
    querier = session.declare_querier(f"{prefix}/query", timeout=5.0, consolidation=zenoh.ConsolidationMode.NONE)

    def trip(msg: bytes) -> float | None:
        t0 = time.perf_counter()
        ok = False
        for reply in querier.get(payload=msg):
            ok = ok or (reply.ok is not None and reply.ok.payload.to_bytes() == msg)
        return time.perf_counter() - t0 if ok else None

    try:
        return _rounds(rounds, warmup, helper, trip, "query without an answer")
    finally:
        querier.undeclare()


def _rounds(rounds: int, warmup: int, helper: int, trip: Callable[[bytes], float | None],
            lost: str) -> tuple[list[float], tuple[float, float]]:
    """`rounds` round trips (`trip(msg)`: its seconds, None if it got no answer: only a warm-up one may) after
    `warmup` ones, and the CPU per round trip of the helper and of this process."""
    rtts: list[float] = []
    i, cpu0 = 0, None
    while len(rtts) < rounds:
        i += 1
        if i == warmup + 1:
            cpu0 = (cpu_seconds(helper), cpu_seconds())
        dt = trip(i.to_bytes(PAYLOAD, "big"))
        if dt is None:
            if i > warmup:
                raise RuntimeError(f"{lost} after the warm-up")
            continue
        if i > warmup:
            rtts.append(dt)
    return rtts, _cpu_per_round(cpu0, helper, len(rtts))
