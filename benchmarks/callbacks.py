"""A message on Zenoh's receiving thread: its Python thread state kept or made and destroyed, side by side.

    dronesim bench callbacks [--messages 100000] [--repeat 3]

The thread state kept is `network.transport._direct`'s callback; made and destroyed around each callback,
zenoh-python's own `Callback(..., indirect=False)`.

Each measurement is a process of its own (a Zenoh thread keeps its state for good once kept): a router session and a
client session in it, over loopback TCP; the router publishes `--messages` small puts (BLOCK congestion control), the
client's callback counts them; the figure is the process's CPU time (every thread) and the wall time from the first
put to the last callback, per message. The two ways alternate, `--repeat` times each.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

#: The measuring process (`python -c`): argv[1] "kept" or "fresh", argv[2] the messages.
_ONE = """
import sys, threading, time, zenoh
from network.transport import _direct, client_config, router_config, router_locators
kept, n = sys.argv[1] == "kept", int(sys.argv[2])
count, done = [0], threading.Event()
def on_sample(sample):
    count[0] += 1
    if count[0] == n:
        done.set()
with zenoh.open(router_config()) as router:
    with zenoh.open(client_config(router_locators(router)[0])) as client:
        handler = _direct(on_sample) if kept else zenoh.handlers.Callback(on_sample, None, indirect=False)
        sub = client.declare_subscriber("bench/callbacks", handler)
        pub = router.declare_publisher("bench/callbacks", congestion_control=zenoh.CongestionControl.BLOCK)
        while not pub.matching_status.matching:
            time.sleep(0.01)  # (the subscription on its way to the router: before anything is measured)
        wall, cpu = time.perf_counter(), time.process_time()
        for _ in range(n):
            pub.put(b"0123456789abcdef")
        done.wait(120)
        print(count[0], (time.perf_counter() - wall) / n * 1e6, (time.process_time() - cpu) / n * 1e6)
        sub.undeclare()
        pub.undeclare()
"""


def measure(way: str, messages: int) -> tuple[float, float]:
    """(wall µs, CPU µs) a message, `way` "kept" or "fresh", in a process of its own."""
    out = subprocess.run([sys.executable, "-c", _ONE, way, str(messages)], capture_output=True, text=True, check=True)
    got, wall, cpu = out.stdout.split()
    if int(got) != messages:
        raise RuntimeError(f"{way}: {got} of {messages} messages came")
    return float(wall), float(cpu)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim bench callbacks", description=__doc__.split("\n")[0])
    p.add_argument("--messages", type=int, default=100_000, help="messages a measurement (default 100,000)")
    p.add_argument("--repeat", type=int, default=3, help="measurements of each way, alternated (default 3)")
    args = p.parse_args(argv)
    figures: dict[str, list[tuple[float, float]]] = {"kept": [], "fresh": []}
    for _ in range(args.repeat):
        for way in figures:
            figures[way].append(measure(way, args.messages))
    for way, runs in figures.items():
        walls, cpus = [w for w, _ in runs], [c for _, c in runs]
        print(f"{way:5}: {min(walls):.2f}-{max(walls):.2f} µs a message (wall), {min(cpus):.2f}-{max(cpus):.2f} CPU")
    ratio = [f / k for (_, f), (_, k) in zip(figures["fresh"], figures["kept"])]
    print(json.dumps({"fresh_over_kept_cpu": [round(r, 1) for r in ratio], "when": time.strftime("%Y-%m-%d %H:%M")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
