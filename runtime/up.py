"""``dronesim up``: the whole simulation on one machine with one command.

An embedded Zenoh router runs in this process; the coordinator, the environment, the drones (one
process each, or one swarm host) and the ground station run as separate processes connected to it
in client mode, exactly as they would across hosts. The ground station's output (the world, each
turn, the final paths and summary) is this command's output; the exit status is 0 only if every
process exited 0.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys

import zenoh

from dronesim.schema import UsageError
from dronesim.transport import router_config, router_locators

from dronesim.scenario import Scenario, swarm_hosts
from dronesim.schema import drone_id


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="dronesim up", description=__doc__)
    p.add_argument("--seed", type=int, default=7, help="world seed (default 7)")
    p.add_argument("--size", default="10,10,10", help="world size nx,ny,nz (default 10,10,10)")
    p.add_argument("--world", help="a world file (JSON) instead of a generated world")
    p.add_argument("--scenario", help="a scenario file: world, drones with starts and autopilots, targets")
    p.add_argument("--drones", type=int, default=1, help="number of drones (default 1)")
    p.add_argument("--starts", default="", help='start cells "x,y,z;x,y,z" (default: a row along y)')
    p.add_argument("--autopilot", default="seed", help="v1, seed or dstar (default seed)")
    p.add_argument("--swarm", action="store_true", help="fly all drones from one swarm host process")
    p.add_argument("--targets", action="append", default=[], metavar="[Dnn=]x,y,z[@turn]",
                   help="scripted targets; without --targets or --script the ground station is interactive")
    p.add_argument("--script", help="a file of scripted targets")
    p.add_argument("--max-turns", type=int, default=200)
    p.add_argument("--pace", type=float, default=0.0, metavar="SECONDS",
                   help="start a turn at most every SECONDS, to watch the game (default: full speed)")
    p.add_argument("--journal", help="write the journal to this file")
    p.add_argument("--root", default="sim", help="key root (default sim)")
    p.add_argument("--listen", default="tcp/127.0.0.1:0", help="the embedded router's endpoint (default: a free port)")
    p.add_argument("--quiet", action="store_true", help="do not print every turn")
    p.add_argument("--web", metavar="[HOST:]PORT",
                   help="the ground station is a web page on this address (see docs/web-gcs.md)")
    p.add_argument("--log-level", default="WARNING", help="log level of the entity processes (default WARNING)")
    return p


def commands(args: argparse.Namespace, locator: str) -> list[tuple[str, list[str]]]:
    """(name, argv) of every entity process, connected as clients to `locator`."""
    base = [sys.executable, "-m", "dronesim"]
    common = ["--mode", "client", "--connect", locator, "--root", args.root, "--log-level", args.log_level]
    coord = [*base, "coordinator", *common, "--seed", str(args.seed), "--size", args.size,
             "--drones", str(args.drones), "--max-turns", str(args.max_turns), "--admit-deadline", "60",
             "--pace", str(args.pace)]
    if args.world:
        coord += ["--world", args.world]
    if args.starts:
        coord += ["--starts", args.starts]
    if args.journal:
        coord += ["--journal", args.journal]
    if args.scenario:
        coord += ["--scenario", args.scenario]
    procs = [("SRV", coord), ("ENV", [*base, "env", *common, "--no-draw"])]
    if args.scenario:
        pilots = Scenario.load(args.scenario).autopilots
    else:
        pilots = {drone_id(n): args.autopilot for n in range(1, args.drones + 1)}
    if args.swarm:  # one swarm host per autopilot
        for host, (pilot, ids) in swarm_hosts(pilots).items():
            procs.append((host, [*base, "drone", *common, "--id", ",".join(ids), "--host", host, "--autopilot", pilot]))
    else:
        procs += [(d, [*base, "drone", *common, "--id", d, "--autopilot", pilots[d]]) for d in sorted(pilots)]
    gcs = [*base, "gcs", *common]
    if args.scenario:
        gcs += ["--scenario", args.scenario]
    for t in args.targets:
        gcs += ["--targets", t]
    if args.script:
        gcs += ["--script", args.script]
    if args.quiet:
        gcs.append("--quiet")
    if args.web:
        gcs += ["--web", args.web]
    procs.append(("GCS", gcs))
    return procs


def main(args: argparse.Namespace) -> int:
    interactive = not args.targets and not args.script and not args.scenario and not args.web
    with zenoh.open(router_config(args.listen)) as router:
        locator = router_locators(router)[0]
        what = f"scenario {args.scenario}" if args.scenario else \
            f"seed {args.seed}, {args.drones} drone(s), autopilot {args.autopilot}"
        print(f"dronesim up: router on {locator}, {what}", flush=True)
        running: list[tuple[str, subprocess.Popen]] = []
        try:
            for name, argv in commands(args, locator):
                stdin = None if (name == "GCS" and interactive) else subprocess.DEVNULL
                running.append((name, subprocess.Popen(argv, stdin=stdin)))
            codes = {name: proc.wait() for name, proc in running}
        except KeyboardInterrupt:
            for _, proc in running:
                proc.send_signal(signal.SIGINT)
            codes = {name: proc.wait() for name, proc in running}
        failed = {n: c for n, c in codes.items() if c != 0}
        if failed:
            print(f"dronesim up: processes failed: {failed}", file=sys.stderr)
            return 1
        print(f"dronesim up: all {len(codes)} processes exited 0", flush=True)
        return 0


def cli(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return main(args)
    except UsageError as err:
        print(f"dronesim up: {err}", file=sys.stderr)
        return 2
