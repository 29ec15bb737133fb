"""The attacker of `dronesim bench flood` (a separate process, a Zenoh client of the game's router).

    python -m benchmarks.flooder nps --mode client --connect tcp/127.0.0.1:PORT --root ROOT --count 200000
    python -m benchmarks.flooder ask --mode client --connect tcp/127.0.0.1:PORT --root ROOT --count 300

(and, on a secured router, D01's credentials: --tls-ca FILE --user D01 --password-file FILE).

* ``nps``: `count` well-formed NPS for a past turn (turn 1) from D01 on D01's own key, as fast as it can
  (BLOCK congestion control): what an authenticated drone may do on its own key under access control.
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
import sys
import threading
import time

import zenoh

from network.transport import add_zenoh_args, open_session, zenoh_config
from schema import Ask, Keys, Nps, encode

SENDER = "D01"


def go() -> None:
    """Says it is ready, then waits for the word."""
    print("ready", flush=True)
    sys.stdin.readline()


def flood_nps(session: zenoh.Session, keys: Keys, count: int) -> dict:
    stale = encode(Nps(turn=1, sender=SENDER, pos=(0, 0, 1)))
    pub = session.declare_publisher(keys.nps(SENDER), congestion_control=zenoh.CongestionControl.BLOCK)
    go()
    first, cpu = time.monotonic(), time.process_time()
    for _ in range(count):
        pub.put(stale)
    return {"sent": count, "answered": 0, "refused": 0, "unanswered": 0, "first": first, "last": time.monotonic(),
            "cpu": time.process_time() - cpu}


def flood_ask(session: zenoh.Session, keys: Keys, count: int, timeout: float) -> dict:
    big = encode(Ask(turn=0, sender=SENDER, cells=tuple((x % 10, x // 10 % 10, x // 100 % 10)
                                                        for x in range(Ask.MAX_CELLS))))
    lock = threading.Lock()
    done = threading.Event()
    got = {"answered": 0, "refused": 0, "finished": 0, "last": 0.0}

    def on_reply(reply: zenoh.Reply) -> None:
        with lock:
            got["answered" if reply.ok is not None else "refused"] += 1
            got["last"] = time.monotonic()

    def on_finished() -> None:  # a query is over: with its reply, or with none (no environment to answer it)
        with lock:
            got["finished"] += 1
            if got["finished"] >= count:
                done.set()

    go()
    first, cpu = time.monotonic(), time.process_time()
    for _ in range(count):
        session.get(keys.ask, zenoh.handlers.Callback(on_reply, on_finished), payload=big, timeout=timeout)
    done.wait(timeout)
    with lock:
        unanswered = got.pop("finished") - got["answered"] - got["refused"]
        return {"sent": count, **got, "unanswered": unanswered, "first": first,
                "last": got["last"] or time.monotonic(), "cpu": time.process_time() - cpu}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.flooder", description=__doc__.split("\n")[0])
    p.add_argument("kind", choices=("nps", "ask"))
    add_zenoh_args(p)
    p.add_argument("--count", type=int, required=True, help="messages (nps) or queries (ask) to send")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the ASKs' replies")
    args = p.parse_args(argv)
    with open_session(zenoh_config(args)) as session:
        keys = Keys(args.root)
        if args.kind == "nps":
            result = flood_nps(session, keys, args.count)
        else:
            result = flood_ask(session, keys, args.count, args.timeout)
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
