"""The far end of the Zenoh floor measurement in `dronesim bench perf` (a separate process).

    python -m benchmarks.pingpong --connect tcp/127.0.0.1:PORT --root ROOT

As a Zenoh client of the router it answers, on keys under ROOT:

* ``cb/ping`` -> ``cb/pong``: republishes each sample from Zenoh's callback thread (the bare floor);
* ``th/ping`` -> ``th/pong``: hands each sample to the main thread, which republishes it (what every
  process of a game does: its callbacks only enqueue, the main thread acts, see network/transport.py);
* ``cb/query`` and ``th/query``: queryables replying with the query's payload, from the callback or
  from the main thread.

Publishers use BLOCK congestion control and RELIABLE reliability, as dronesim's Outbox. It declares a
liveliness token ``ROOT/ready`` once everything is declared, and exits 0 on a sample on ``ROOT/quit``.
"""

from __future__ import annotations

import argparse
import json
import queue
import sys

import zenoh


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.pingpong", description=__doc__.split("\n")[0])
    p.add_argument("--connect", required=True, help="the router's endpoint, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--root", required=True, help="key root of this measurement")
    args = p.parse_args(argv)

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/delay", "0")
    r = args.root
    jobs: queue.SimpleQueue = queue.SimpleQueue()
    with zenoh.open(conf) as session:
        def publisher(key: str) -> zenoh.Publisher:
            return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                             reliability=zenoh.Reliability.RELIABLE)

        pub_cb, pub_th = publisher(f"{r}/cb/pong"), publisher(f"{r}/th/pong")

        def on_query_cb(query: zenoh.Query) -> None:
            query.reply(query.key_expr, query.payload.to_bytes() if query.payload is not None else b"")
            query.drop()

        handles: list[zenoh.Subscriber | zenoh.Queryable] = [
            session.declare_subscriber(f"{r}/cb/ping", lambda s: pub_cb.put(s.payload.to_bytes())),
            session.declare_subscriber(f"{r}/th/ping", lambda s: jobs.put(("pub", s.payload.to_bytes()))),
            session.declare_queryable(f"{r}/cb/query", on_query_cb, complete=True),
            session.declare_queryable(f"{r}/th/query", lambda q: jobs.put(("query", q)), complete=True),
            session.declare_subscriber(f"{r}/quit", lambda s: jobs.put(("quit", None))),
        ]
        token = session.liveliness().declare_token(f"{r}/ready")
        while True:
            kind, item = jobs.get()
            if kind == "pub":
                pub_th.put(item)
            elif kind == "query":
                item.reply(item.key_expr, item.payload.to_bytes() if item.payload is not None else b"")
                item.drop()
            else:
                break
        token.undeclare()
        for h in handles:
            h.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(main())
