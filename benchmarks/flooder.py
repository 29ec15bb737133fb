"""The attacker of `dronesim bench flood` (a separate process, a Zenoh client of the game's router).

    python -m benchmarks.flooder nps --mode client --connect tcp/127.0.0.1:PORT --root ROOT --count 200000
    python -m benchmarks.flooder ask --mode client --connect tcp/127.0.0.1:PORT --root ROOT --count 300

(and, on a secured router, D01's credentials: --tls-ca FILE --user D01 --password-file FILE).

* ``nps``: `count` well-formed NPS for a past turn (turn 1) from D01 on D01's own key, as fast as it can
  (BLOCK congestion control): what an authenticated drone may do on its own key under access control.
* ``done`` / ``tgt``: `count` stale DONEs (turn 1) on the ground station's key / stale targets for D01 on D01's
  TGT key, as fast as it can: what any peer may do on a plain router, or a buggy ground station under access control.
* ``connect``: `count` CONNECT queries with invented sessions (naming D01, D02, ... in turn), all at once, waiting
  for every one to finish: what any peer allowed to connect may do (a drone under access control).
* ``map``: `count` requests for the environment's map (ENV/MAP) from D01, all at once, waiting for every one to
  finish: what any peer allowed to ask the map may do (a drone or the ground station under access control).
* ``busy``: no message: a busy loop of `count` milliseconds, the control (what any program taking a core as an
  equal costs the game on this machine, whatever it sends).
* ``ask``: `count` ASKs of `Ask.MAX_CELLS` cells from D01 to the environment, all sent at once; it waits
  for every query to finish (answered, refused with an error reply, or with no reply: one that reached the
  environment after it left, the game over) up to `--timeout`.

Once connected, with its messages ready, it prints "ready" and waits for a line on stdin: the flood
starts then (the bench starts it as the measured turns begin). Its last line on stdout is JSON:
{"sent", "answered", "refused", "unanswered", "first", "last", "cpu"}: "first" and "last" the `time.monotonic()`
(system-wide on Linux) of the first message sent and of the last message sent or reply received (the
flood's window, which the bench compares with the game's turns), "cpu" the CPU seconds it used
meanwhile (all its threads).
"""

from __future__ import annotations

import argparse
import json
import secrets
import sys
import threading
import time
from collections.abc import Callable

import zenoh

from network.transport import add_zenoh_args, open_session, zenoh_config
from schema import Ask, Connect, Done, Keys, MapRequest, Nps, Phase, Role, Target, drone_id, encode

SENDER = "D01"


def go() -> None:
    """Says it is ready, then waits for the word."""
    print("ready", flush=True)
    sys.stdin.readline()


def flood_puts(session: zenoh.Session, key: str, payload: bytes, count: int) -> dict:
    """`count` copies of `payload` on `key`, as fast as it can (BLOCK congestion control)."""
    pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    go()
    first, cpu = time.monotonic(), time.process_time()
    for _ in range(count):
        pub.put(payload)
    return {"sent": count, "answered": 0, "refused": 0, "unanswered": 0, "first": first, "last": time.monotonic(),
            "cpu": time.process_time() - cpu}


def flood_nps(session: zenoh.Session, keys: Keys, count: int) -> dict:
    return flood_puts(session, keys.nps(SENDER), encode(Nps(turn=1, sender=SENDER, pos=(0, 0, 1))), count)


def flood_done(session: zenoh.Session, keys: Keys, count: int) -> dict:
    """Stale DONEs (turn 1) from the ground station, on its own key."""
    return flood_puts(session, keys.gcs_done, encode(Done(turn=1, sender="GCS", phase=Phase.GCS)), count)


def flood_tgt(session: zenoh.Session, keys: Keys, count: int) -> dict:
    """Stale targets (turn 1) for D01 from the ground station, on D01's TGT key."""
    return flood_puts(session, keys.tgt(SENDER), encode(Target(turn=1, sender="GCS", drone=SENDER, pos=(1, 1, 1))),
                      count)


def flood_queries(session: zenoh.Session, key: str, payloads: Callable[[int], bytes], count: int,
                  timeout: float) -> dict:
    """`count` queries on `key` (the i-th with `payloads(i)`), all sent at once; waits for every one to finish."""
    lock = threading.Lock()
    done = threading.Event()
    got = {"answered": 0, "refused": 0, "finished": 0, "last": 0.0}

    def on_reply(reply: zenoh.Reply) -> None:
        with lock:
            got["answered" if reply.ok is not None else "refused"] += 1
            got["last"] = time.monotonic()

    def on_finished() -> None:  # a query is over: with its reply, or with none (no one left to answer it)
        with lock:
            got["finished"] += 1
            if got["finished"] >= count:
                done.set()

    ready = [payloads(i) for i in range(count)]
    go()
    first, cpu = time.monotonic(), time.process_time()
    for payload in ready:
        session.get(key, zenoh.handlers.Callback(on_reply, on_finished), payload=payload, timeout=timeout)
    done.wait(timeout)
    with lock:
        unanswered = got.pop("finished") - got["answered"] - got["refused"]
        return {"sent": count, **got, "unanswered": unanswered, "first": first,
                "last": got["last"] or time.monotonic(), "cpu": time.process_time() - cpu}


def flood_ask(session: zenoh.Session, keys: Keys, count: int, timeout: float) -> dict:
    big = encode(Ask(turn=0, sender=SENDER, cells=tuple((x % 10, x // 10 % 10, x // 100 % 10)
                                                        for x in range(Ask.MAX_CELLS))))
    return flood_queries(session, keys.ask, lambda _: big, count, timeout)


def flood_connect(session: zenoh.Session, keys: Keys, count: int, timeout: float) -> dict:
    """CONNECTs with invented sessions, naming D01 and then, one by one, other drones (no token is seen for any:
    the coordinator refuses them all)."""
    def hello(i: int) -> bytes:
        d = drone_id(1 + i % 60_000)
        return encode(Connect(turn=0, sender=d, role=Role.DRONE, drones=(d,), autopilot="seed",
                              session=secrets.token_hex(16)))

    return flood_queries(session, keys.connect, hello, count, timeout)


def busy(session: zenoh.Session, keys: Keys, count: int) -> dict:
    """No message: `count` milliseconds of a busy loop (connected as the others are, so that only the sending
    differs)."""
    go()
    first, cpu = time.monotonic(), time.process_time()
    end = first + count / 1000
    while time.monotonic() < end:
        pass
    return {"sent": 0, "answered": 0, "refused": 0, "unanswered": 0, "first": first, "last": time.monotonic(),
            "cpu": time.process_time() - cpu}


def flood_map(session: zenoh.Session, keys: Keys, count: int, timeout: float) -> dict:
    """Requests for the environment's whole map from D01 (a process asks once: the map is static)."""
    request = encode(MapRequest(turn=0, sender=SENDER))
    return flood_queries(session, keys.map, lambda _: request, count, timeout)


PUTS = {"nps": flood_nps, "done": flood_done, "tgt": flood_tgt, "busy": busy}
QUERIES = {"ask": flood_ask, "connect": flood_connect, "map": flood_map}
KINDS = (*PUTS, *QUERIES)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.flooder", description=__doc__.split("\n")[0])
    p.add_argument("kind", choices=KINDS)
    add_zenoh_args(p)
    p.add_argument("--count", type=int, required=True, help="messages or queries to send; busy: milliseconds")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the ASKs' replies")
    args = p.parse_args(argv)
    with open_session(zenoh_config(args)) as session:
        keys = Keys(args.root)
        if args.kind in PUTS:
            result = PUTS[args.kind](session, keys, args.count)
        else:
            result = QUERIES[args.kind](session, keys, args.count, args.timeout)
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
