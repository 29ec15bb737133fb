"""``dronesim up``: the whole simulation on one machine with one command.

An embedded Zenoh router runs in this process; the coordinator, the environment, the drones (one process each, or one
swarm host) and the ground station run as separate processes connected to it in client mode, exactly as they would
across hosts. The ground station's output (the world, each turn, the final paths and summary) is this command's output;
the exit status is 0 only if every process exited 0.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import logging
import pathlib
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from coordinator.config import ARBITERS, SIZE, UP_MAX_TURNS, GameConfig
from dronesim import child_env
from dronesim.certs import GameCredentials, game_credentials
from dronesim.scenario import Scenario, movingai_scenario, swarm_hosts
from entities.autopilots import COOPERATIVE, DEFAULT, REGISTRY
from entities.gcs import Ground
from entities.mavlink.options import MAVLINK_FLAGS, add_mavlink_args
from network.signals import Stop, exit_status, on_stop, stop, waking
from network.transport import Inbox, Presence, add_zenoh_args, apply_flags, open_session, router_config, router_locators
from schema import UsageError, drone_id
from schema.errors import seconds
from schema.keys import ROOT, Keys
from schema.tuning import KILL_S, PHASE_DEADLINE_S, STOP_S, UP_ADMIT_DEADLINE_S, UP_ADMIT_PER_PROCESS_S, UP_START_WINDOW
from world.grid import build_world

#: The rejections its router's presence watch counts, if any (`Inbox`).
LOG = logging.getLogger("dronesim.up")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="dronesim up", description=__doc__)
    p.add_argument("--seed", type=int, default=7, help="world seed (default 7)")
    p.add_argument("--size", default=",".join(map(str, SIZE)), help="world size nx,ny,nz (default %(default)s)")
    p.add_argument("--world", help="a world file (JSON, or a MovingAI .map) instead of a generated world")
    p.add_argument("--scen", help="a MovingAI .scen on the --world .map: its agents are the drones, their goals the "
                                  "targets (the autopilot: --autopilot, default dstar here)")
    p.add_argument("--agents", type=int, help="with --scen: its first N agents (default: all)")
    p.add_argument("--scenario", help="a scenario file: world, drones with starts and autopilots, targets")
    p.add_argument("--drones", type=int, default=1, help="number of drones (default 1)")
    p.add_argument("--starts", default="", help='start cells "x,y,z;x,y,z" (default: rows of every other cell)')
    p.add_argument("--autopilot", help=f"{', '.join(REGISTRY)} (default {DEFAULT}; with --scen, {COOPERATIVE})")
    p.add_argument("--swarm", action="store_true", help="fly all drones from one swarm host process")
    p.add_argument("--targets", action="append", default=[], metavar="[Dnn=]x,y,z[@turn]",
                   help="scripted targets; without --targets or --script the ground station is interactive")
    p.add_argument("--script", help="a file of scripted targets")
    p.add_argument("--max-turns", type=int, default=UP_MAX_TURNS, help="the game's turn limit (default %(default)s)")
    p.add_argument("--arbiter", choices=ARBITERS,
                   help="the cooperative drones' arbitration (default lacam, the complete search; pibt: PIBT alone)")
    p.add_argument("--lifelong", action="store_true",
                   help="a lifelong game: each drone that reaches its target gets a new one from the ground station, "
                        "drawn with --seed (entities/tasks.py), until --max-turns; the end says the tasks done and "
                        "the tasks a turn")
    p.add_argument("--pace", type=seconds, default=0.0, metavar="SECONDS",
                   help="start a turn at most every SECONDS, to watch the game (default: full speed)")
    p.add_argument("--phase-deadline", type=seconds, metavar="SECONDS",
                   help="seconds the drones (and the environment) have for each phase "
                        f"(default: the coordinator's, {PHASE_DEADLINE_S:g})")
    p.add_argument("--journal", help="write the journal to this file")
    p.add_argument("--root", default=ROOT, help=f"key root (default {ROOT})")
    p.add_argument("--listen", default="tcp/127.0.0.1:0", help="the embedded router's endpoint (default: a free port; "
                   "tcp/ becomes tls/ unless --insecure)")
    p.add_argument("--insecure", action="store_true",
                   help="a plain router: no TLS, no passwords, no access control (by default each game makes its "
                        "own credentials and access control at its start: docs/security.md)")
    p.add_argument("--credentials", metavar="DIR",
                   help="keep the game's credentials in DIR (default: a temporary folder, removed at the end); a "
                        "remote ground station needs DIR/ca.pem and DIR/GCS.password (docs/security.md)")
    p.add_argument("--router-host", action="append", default=[], metavar="NAME",
                   help="a name or address remote processes reach the router at (in its TLS certificate)")
    p.add_argument("--quiet", action="store_true", help="do not print every turn")
    p.add_argument("--web", metavar="[HOST:]PORT",
                   help="the ground station is a web page on this address (see docs/web-gcs.md)")
    p.add_argument("--ros2", action="store_true",
                   help="publish the game to ROS 2 (rmw_zenoh) and take ROS 2 goals as targets, beside the console's "
                        "or the other targets (docs/ros2.md)")
    p.add_argument("--foxglove", metavar="[HOST:]PORT", help="serve the game live to Foxglove (docs/ros2.md)")
    p.add_argument("--log-level", default="WARNING", help="log level of the entity processes (default WARNING)")
    add_mavlink_args(p)  # the ground station as MAVLink vehicles (docs/mavlink.md)
    return p


def _passed(args: argparse.Namespace, *names: str) -> list[str]:
    """Those of the flags `names` that this command was given, to pass on: a switch alone, a value after its
    flag, a list's items each after its flag."""
    out: list[str] = []
    for name in names:
        flag, value = "--" + name.replace("_", "-"), getattr(args, name)
        if value is True:
            out.append(flag)
        elif value:
            out += [x for item in (value if isinstance(value, list) else [value]) for x in (flag, item)]
    return out


def _common(args: argparse.Namespace, locator: str) -> list[str]:
    """Every entity's flags: a client of `locator`, on the game's root."""
    return ["--mode", "client", "--connect", locator, "--root", args.root, "--log-level", args.log_level]


def admit_deadline(processes: int) -> float:
    """How long the game waits for its `processes` to connect: they start `UP_START_WINDOW` at a time."""
    return UP_ADMIT_DEADLINE_S + UP_ADMIT_PER_PROCESS_S * processes


def coordinator_flags(args: argparse.Namespace, locator: str, processes: int = 0) -> list[str]:
    """The coordinator's flags (after `dronesim coordinator`): the game it plays, with its `processes` besides."""
    return [*_common(args, locator), "--seed", str(args.seed), "--size", args.size, "--drones", str(args.drones),
            "--max-turns", str(args.max_turns), "--admit-deadline", f"{admit_deadline(processes):g}",
            "--pace", str(args.pace),
            *_passed(args, "world", "starts", "journal", "scenario", "arbiter", "lifelong"),
            *(["--phase-deadline", str(args.phase_deadline)] if args.phase_deadline is not None else [])]


def commands(args: argparse.Namespace, locator: str) -> list[tuple[str, list[str]]]:
    """(name, argv) of every entity process, connected as clients to `locator`."""
    base, common = [sys.executable, "-m", "dronesim"], _common(args, locator)
    procs = [("ENV", [*base, "env", *common, "--no-draw"])]
    pilots = (Scenario.load(args.scenario).autopilots if args.scenario
              else {drone_id(n): args.autopilot for n in range(1, args.drones + 1)})
    if args.swarm:  # one swarm host per autopilot
        for host, (pilot, ids) in swarm_hosts(pilots).items():
            procs.append((host, [*base, "drone", *common, "--id", ",".join(ids), "--host", host, "--autopilot", pilot]))
    else:
        procs += [(d, [*base, "drone", *common, "--id", d, "--autopilot", pilots[d]]) for d in sorted(pilots)]
    mavlink = ["--mavlink", *(x for name in MAVLINK_FLAGS[1:] for x in ("--" + name.replace("_", "-"),
                                                                         str(getattr(args, name))))] \
        if args.mavlink else []  # (every value, 0 too: --turn-period 0 is full speed)
    lifelong = ["--lifelong", str(args.seed)] if args.lifelong else []  # (its targets drawn with the game's seed)
    procs.append(("GCS", [*base, "gcs", *common, *_passed(args, "scenario", "targets", "script", "quiet", "web",
                                                             "ros2"), *lifelong, *mavlink]))
    if args.ros2 or args.foxglove:  # the viewer: ROS 2 topics, Foxglove live (last: it has no presence token of ours,
        # and holds its place in `supervise`'s window until it ends)
        procs.append(("ROS2", [*base, "ros2", *common, *_passed(args, "foxglove")]))
    return [("SRV", [*base, "coordinator", *coordinator_flags(args, locator, len(procs))]), *procs]


def check_game(args: argparse.Namespace) -> None:
    """Refuse here, before any process starts, a game the coordinator or the ground station would refuse with the
    flags they will be given (a UsageError: drones that do not fit, a start in a building, a bad world file, a bad
    target or script, a --web address that cannot be served...): else every process starts, and the game is stopped
    once the one that refuses has said so."""
    from coordinator import node as coordinator

    scenarios: list[Scenario] = []

    def scenario(path: str, **deadlines: object) -> GameConfig:  # (read once, with its targets, as the GCS reads it)
        scenarios.append(Scenario.load(path))
        return scenarios[-1].game_config(**deadlines)

    config = coordinator.game_config(coordinator.build_parser().parse_args(coordinator_flags(args, "tcp/127.0.0.1:0")),
                                     scenario)
    lifelong = args.lifelong or any(s.lifelong is not None for s in scenarios)
    if lifelong and (args.web or args.mavlink or args.ros2):
        raise UsageError("--lifelong is the scripted ground station's (not with --web, --mavlink or --ros2)")
    check_plan(args, config)
    if args.web:
        check_web(args.web)


def check_plan(args: argparse.Namespace, config: GameConfig) -> None:
    """The ground station's plan, checked as it will check it (`entities.gcs.Ground.plan_of`): the --script file
    (which then stands for the targets), else the --targets (after a scenario's, which `Scenario.load` checked),
    against the world and the game's drones."""
    if not args.script and not args.targets:
        return
    world = build_world(config.world, (d.start for d in config.drones))  # (as every process builds it)
    Ground.plan_of(world, [d.drone for d in config.drones], args.targets, args.script)


def check_web(text: str) -> None:
    """The --web address: well formed, and one the ground station can listen on (bound here and released: a port
    taken since is the ground station's own error, which stops the game, `supervise`)."""
    from entities.web.server import parse_address

    host, port = parse_address(text)
    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # (as the page's server binds)
            sock.bind((host, port))
    except OSError as exc:
        raise UsageError(f"cannot serve the web ground station on {host}:{port}: {exc}") from None


def main(args: argparse.Namespace) -> int:
    if args.scen:  # a MovingAI instance: played as the scenario it makes (a file the processes read)
        if args.agents is not None and args.agents < 1:
            raise UsageError(f"--agents must be >= 1 (default: all of the .scen's), got {args.agents}")
        if not args.world or args.scenario:
            raise UsageError("--scen needs --world FILE.map (and no --scenario)")
        data = movingai_scenario(args.world, args.scen, args.agents, args.autopilot, args.max_turns)
        Scenario.from_json(data)  # checked here, once: the processes would each refuse it
        with tempfile.TemporaryDirectory(prefix="dronesim-scen-") as tmp:
            path = pathlib.Path(tmp) / "scenario.json"
            path.write_text(json.dumps(data))
            return main(argparse.Namespace(**{**vars(args), "scen": None, "world": None, "scenario": str(path)}))
    if args.ros2 and args.mavlink:
        raise UsageError("--ros2 takes ROS 2 goals, which a MAVLink ground station does not (its vehicles' targets are "
                         "MAVLink's); --foxglove PORT alone runs the viewer, which publishes the game to ROS 2 too")
    check_game(args)
    if args.insecure:
        return play(args, None)
    with contextlib.ExitStack() as stack:
        folder = args.credentials or stack.enter_context(tempfile.TemporaryDirectory(prefix="dronesim-credentials-"))
        return play(args, credentials(args, folder))


def credentials(args: argparse.Namespace, folder: str) -> GameCredentials:
    """The game's credentials and access control (`dronesim.certs.game_credentials`), made now in `folder`."""
    pilots = (Scenario.load(args.scenario).autopilots if args.scenario
              else {drone_id(n): args.autopilot for n in range(1, args.drones + 1)})
    hosts = {host: ids for host, (_, ids) in swarm_hosts(pilots).items()} if args.swarm else {}
    return game_credentials(folder, drones=sorted(pilots), hosts=hosts, roots=[args.root],
                            router_hosts=args.router_host)


def secured_router(listen: str, creds: GameCredentials) -> zenoh.Config:
    """The embedded router's config with the game's TLS certificate, users and access control."""
    parser = argparse.ArgumentParser()
    add_zenoh_args(parser)
    conf = router_config("tls/" + listen.removeprefix("tcp/") if listen.startswith("tcp/") else listen)
    apply_flags(conf, parser.parse_args(creds.router_flags()), router=True)
    return conf


def play(args: argparse.Namespace, creds: GameCredentials | None) -> int:
    interactive = (not args.targets and not args.script and not args.scenario and not args.web and not args.mavlink
                   and not args.lifelong)
    with open_session(router_config(args.listen) if creds is None else secured_router(args.listen, creds)) as router:
        locator = router_locators(router)[0]
        what = f"scenario {args.scenario}" if args.scenario else \
            f"seed {args.seed}, {args.drones} drone(s), autopilot {args.autopilot}"
        print(f"dronesim up: router on {locator}, {what}", flush=True)
        running: list[tuple[str, subprocess.Popen]] = []

        def launch(name: str, argv: list[str]) -> subprocess.Popen:
            if creds is not None:  # (the viewer reads what the ground station may read)
                argv = [*argv, *creds.flags("GCS" if name == "ROS2" else name)]
            console = name == "GCS" and interactive  # it reads the terminal: it stays in its group
            return subprocess.Popen(argv, stdin=None if console else subprocess.DEVNULL, env=child_env(),
                                    start_new_session=not console)

        events = Inbox(router, Keys(args.root), LOG)
        events.watch_presence()  # (the processes' presence tokens: `supervise`'s window)
        try:
            with on_stop(stop):
                codes = supervise(commands(args, locator), launch, running, events, UP_START_WINDOW)
        except Stop as sig:
            print(f"dronesim up: {signal.Signals(sig.signum).name}: stopping the game", file=sys.stderr, flush=True)
            try:
                with on_stop(stop):
                    stop_all(running, sig.signum)
            except Stop:  # a second signal: no more waiting
                for _, proc in running:
                    proc.kill()
                    proc.wait()
            return exit_status(sig.signum)
        finally:
            events.close()
        return ending(codes)


def ending(codes: dict[str, int]) -> int:
    """This command's exit status, and its last line, from its processes' (`supervise`'s: in the order they
    ended): 0 if each exited 0; `USAGE_STATUS` if the first vital one to fail refused its input (it said why on a
    line of its own, and the game was stopped: a usage error, as if this command had refused it); else 1."""
    if failed := {n: c for n, c in codes.items() if c != 0}:
        first = next((n for n in failed if n in VITAL), None)
        if first is not None and failed[first] == USAGE_STATUS:
            print(f"dronesim up: {first} refused its input (its error above): the game was stopped", file=sys.stderr)
            return USAGE_STATUS
        print(f"dronesim up: processes failed: {failed}", file=sys.stderr)
        return 1
    print(f"dronesim up: all {len(codes)} processes exited 0", flush=True)
    return 0


#: A process's exit status for a usage error (a bad flag or file: `UsageError`), this command's own too.
USAGE_STATUS = 2
#: The processes without which the game cannot go on: one of them failing stops the game at once (a drone
#: that fails is LOST and the others play on; a ground station that refuses its targets exits 2).
VITAL = ("SRV", "GCS")


@dataclass(frozen=True, slots=True)
class Ended:
    """The process `name` exited with `code` (`supervise`'s event)."""

    name: str
    code: int


def supervise(todo: list[tuple[str, list[str]]], launch: Callable[[str, list[str]], subprocess.Popen],
              running: list[tuple[str, subprocess.Popen]], events: Inbox, window: int) -> dict[str, int]:
    """Start the processes `todo` (name, argv) in order, each with `launch`, into `running`, at most `window` at a time
    that have not connected yet (no `Presence` event of theirs from `events`, which watches the presence tokens) and
    still run; wait for every process to exit and return their exit codes. If a vital one fails while others still
    run, none more is started and the game is stopped at once (`stop_all`, as on Ctrl-C) instead of running on
    without it to its turn limit."""
    waiting, connecting, codes = collections.deque(todo), set[str](), dict[str, int]()

    def start() -> None:
        while waiting and len(connecting) < window:
            name, argv = waiting.popleft()
            proc = launch(name, argv)
            running.append((name, proc))
            connecting.add(name)
            threading.Thread(target=lambda n=name, p=proc: events.post(Ended(n, p.wait())), name=f"wait-{name}",
                             daemon=True).start()

    with waking(lambda: events.post(None)):  # a signal's handler runs at once, even while blocked in get()
        start()
        while len(codes) < len(running):
            match events.get():
                case Presence(entity, _, True):
                    connecting.discard(entity)
                case Ended(name, code):
                    connecting.discard(name)
                    codes[name] = code
                    left = [(n, p) for n, p in running if n not in codes]
                    if code != 0 and name in VITAL and (left or waiting):
                        print(f"dronesim up: {name} exited {code}: stopping the game", file=sys.stderr, flush=True)
                        waiting.clear()
                        stop_all(left, signal.SIGTERM)
                        codes.update((n, p.wait()) for n, p in left)
            start()
    return codes


def stop_all(running: list[tuple[str, subprocess.Popen]], signum: int) -> None:
    """Stop the game: the coordinator gets `signum` (it ends the game, INTERRUPTED, and closes its journal),
    the others see its OVER and exit; whoever is still running after STOP_S gets SIGTERM, then SIGKILL."""
    procs = dict(running)
    if "SRV" in procs and procs["SRV"].poll() is None:
        procs["SRV"].send_signal(signum)
    end = time.monotonic() + STOP_S
    for sig in (None, signal.SIGTERM, signal.SIGKILL):
        for proc in procs.values():
            if sig is not None and proc.poll() is None:
                proc.send_signal(sig)
        for proc in procs.values():
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(max(0.0, end - time.monotonic()))
        if all(proc.poll() is not None for proc in procs.values()):
            return
        end = time.monotonic() + KILL_S


def cli(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    args.autopilot = args.autopilot or (COOPERATIVE if args.scen else DEFAULT)
    try:
        return main(args)
    except UsageError as err:
        print(f"dronesim up: {err}", file=sys.stderr)
        return USAGE_STATUS
