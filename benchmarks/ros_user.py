"""A ROS 2 user of the game in `dronesim bench perf`'s ROS 2 row (a separate process, as RViz2 or `ros2 bag` is).

    python -m benchmarks.ros_user --connect tcp/127.0.0.1:PORT [--domain 0]

As a Zenoh client of the router it subscribes to every topic of the domain (``<domain>/**``: rmw_zenoh's keys),
counting the samples (by type) and their bytes in Zenoh's callback, until the `dronesim ros2` viewer's node
token, once seen, is gone (the viewer ends after the game's OVER); then it prints ``ros user: N samples, B bytes;
by type: {...}`` and exits 0 (1 if the viewer never appeared or never left within `--timeout` s).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading

import zenoh

from entities.ros2.node import NODE
from schema.keys import RosKeys


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.ros_user", description=__doc__.split("\n")[0])
    p.add_argument("--connect", required=True, help="the router's endpoint, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--domain", type=int, default=0, help="the ROS 2 domain (default 0)")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds at most for the viewer to come and go")
    args = p.parse_args(argv)

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    counts = [0, 0]  # samples, bytes (only Zenoh's callback thread writes them)
    seen, gone = threading.Event(), threading.Event()
    kinds: dict[str, int] = {}  # samples by DDS type name

    def on_sample(sample: zenoh.Sample) -> None:
        counts[0] += 1
        counts[1] += len(sample.payload)
        kind = str(sample.key_expr).split("/")[-2]  # <domain>/<topic>/<type>/<hash>
        kinds[kind] = kinds.get(kind, 0) + 1

    def on_token(sample: zenoh.Sample) -> None:
        (gone if sample.kind == zenoh.SampleKind.DELETE and seen.is_set() else seen).set()

    with zenoh.open(conf) as session:
        session.declare_subscriber(f"{args.domain}/**", on_sample)
        session.liveliness().declare_subscriber(RosKeys(args.domain).node_tokens(NODE), on_token, history=True)
        print("ros user: subscribed", flush=True)
        ok = gone.wait(args.timeout)
    print(f"ros user: {counts[0]} samples, {counts[1]} bytes; by type: {dict(sorted(kinds.items()))}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
