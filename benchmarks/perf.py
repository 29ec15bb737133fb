"""Performance benchmark: turn latency against the Zenoh floor, turns per second up to 1000 drones.

    dronesim bench perf                    # everything, prints one table (a few minutes)
    dronesim bench perf --write            # ... and updates "## Performance" in BENCHMARKS.md
    dronesim bench perf --quick            # a tiny subset (used by the tests), under a minute
    dronesim bench perf --only '128|floor' # only the rows whose name matches the regex
    dronesim bench perf --profile DIR      # also py-spy (if installed) every process, raw stacks in DIR

In one run, through a loopback router process (`dronesim router`, tcp/127.0.0.1, a free port):

1. The floor: a pub/sub ping-pong and a query round trip between this process and a helper process
   (`benchmarks.pingpong`), small payloads, BLOCK congestion control, after a warm-up.
2. Whole games: the coordinator, the environment and one swarm host flying every drone with the
   seed's smart autopilot, each a separate process (`dronesim coordinator|env|drone`), and this
   process as the ground station, with the scripted GCS's own core (`entities.gcs.Station`, as
   `dronesim gcs --scenario`): a DONE carrying the targets that change, and, when its plan has nothing
   new for the next turns, their DONEs at once, ahead (the coordinator then opens and closes those GCS
   phases without a round trip, and without announcing them). It timestamps each STATUS(t - 1), which begins turn t:
   turn latency = time between consecutive STATUS, turns/s = 1 / mean. After the warm-up turns
   and the measured ones it samples the processes' peak memory (VmHWM) and answers DONE QUIT; every
   process must then exit 0.
3. The same scenarios in-process (`dronesim.local.simulate`, no network): same game, same timing
   point (the GCS phase), so in-process / distributed is the distribution overhead.
4. World generation time for 512x512x64 (`World.generate`, seeded), in-process.
5. The anchor: POGEMA, in-process, with as many agents as each game has drones (`benchmarks/pogema.py`;
   installed once into a cached virtual environment of its own; `--no-pogema` skips it).
6. The speed-ups that remain (`MECHANISMS`): each one's lines of code, counted from the code it names,
   and, where a switch is cheap and honest, its games played with it on and off, alternated, in this
   run (`--only mechanism` plays only these); the others say why they are not switched off.

Scenarios (one JSON file per case, dronesim/scenario.py format): starts on an even grid over the near
half of the ground floor (x < nx/2, lanes every other y), kept free by the world generation and checked with
`build_world`; each drone climbs to its own altitude (1 + its rank in its lane modulo nz - 1) and flies
to the far half (x + nx/2), then back one floor higher, and so on, a leg every nx/2 + 3 turns (the
first: nx/2 + nz + 1), so drones keep flying over cells they do not know yet (a seed drone over known
cells wanders sideways: it prefers unknown ones) and neighbouring lanes are a floor apart. A late drone
turns back before it arrives; after nz - 1 legs (only in 10x10x10) several drones stay at their last
target (a lone drone goes on). Seed drones do not avoid each other: the
few that collide die, and the table says how many are alive at the end.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import functools
import importlib.metadata
import json
import math
import os
import platform
import queue
import re
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from benchmarks import add_write_args, pogema, replace_section
from dronesim import child_env
from network.transport import client_config
from schema.tuning import ANSWER_AHEAD

SECTION = "## Performance"
WORLDS: tuple[tuple[int, int, int], ...] = ((10, 10, 10), (64, 64, 16), (256, 256, 32))
DRONES: tuple[int, ...] = (1, 16, 128, 1000)
WORLD_SEED = 3
GEN_SIZE = (512, 512, 64)
PHASE_DEADLINE = 60.0  # seconds: a benchmark measures, it does not test deadlines
EVENT_TIMEOUT = 180.0  # seconds without any event from the game before the run is declared stalled
#: The share of its turns/s a game keeps with a ROS 2 viewer publishing it (issue 35).
ROS2_KEEPS = 0.9
TARGETS = {"latency": 4.0, "tps128": 200.0, "pogema128": 0.25, "tps1000": 20.0, "kib_per_drone": 1.0,
           "per_world_byte": 2.0}

# --------------------------------------------------------------------------- helpers


def _pct(values: Sequence[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def _mib(kib: int | None) -> str:
    return "-" if kib is None else f"{kib / 1024:.0f}"


def _size_text(size: Sequence[int]) -> str:
    return "x".join(map(str, size))


def _bytes_text(n: int) -> str:
    if n < 1024 * 1024:
        return f"{n / 1024:.1f} KiB"
    return f"{n / 1024 / 1024:.1f} MiB"


def proc_status(pid: int) -> dict[str, int]:
    """VmHWM, VmRSS... of a process, in KiB (empty if it is gone)."""
    out: dict[str, int] = {}
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Vm") and line.rstrip().endswith("kB"):
                    name, value = line.split(":", 1)
                    out[name] = int(value.split()[0])
    except OSError:
        pass
    return out


def cpu_seconds(pid: int | str = "self") -> float:
    """User + system CPU time of a process (all its threads) so far, in seconds (nan if it is gone)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def busy_seconds() -> tuple[float, float]:
    """(CPU seconds every process of the machine used so far, this process and its waited-for children's)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    mine = os.times()
    total = (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")  # user..steal; guest time is inside user
    return total, mine.user + mine.system + mine.children_user + mine.children_system


def machine() -> dict[str, str]:
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    try:
        zv = importlib.metadata.version("eclipse-zenoh")
    except importlib.metadata.PackageNotFoundError:
        zv = "?"
    return {"nproc": str(os.cpu_count()), "cpu": cpu, "python": platform.python_version(), "zenoh": zv,
            "arch": platform.machine()}




@dataclass(frozen=True, slots=True)
class Router:
    locator: str
    pid: int


@contextlib.contextmanager
def loopback_router(config: Path | None = None, *, scheme: str = "tcp", flags: Sequence[str] = ()) -> Iterator[Router]:
    """A Zenoh router process (`dronesim router`) on <scheme>/127.0.0.1:<free port>, loopback only, as in a
    deployment: no entity shares its process (an entity's Python callbacks run on Zenoh's threads and
    would hold up a router living in the same process); `config`: its zenoh configuration file; `flags`:
    more of `dronesim router`'s (e.g. `Secured.router_flags`)."""
    conf = ["--config", str(config)] if config is not None else []
    p = subprocess.Popen([sys.executable, "-m", "dronesim", "router", "--listen", f"{scheme}/127.0.0.1:0", *conf,
                          *flags, "--log-level", "WARNING"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                         text=True, env=child_env())
    try:
        line = p.stdout.readline() if p.stdout else ""
        found = re.search(rf"listening on ({scheme}/127\.0\.0\.1:\d+)", line)
        if not found:
            raise RuntimeError(f"the router did not start on loopback: {line!r}")
        yield Router(found.group(1), p.pid)
    finally:
        p.terminate()
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


class Procs:
    """Child processes with their output in log files (no reader threads in this process)."""

    def __init__(self, logs: Path) -> None:
        self.logs = logs
        self.procs: dict[str, subprocess.Popen] = {}
        self._files: list = []

    def start(self, name: str, argv: list[str]) -> subprocess.Popen:
        log = open(self.logs / f"{name}.log", "w", encoding="utf-8")  # noqa: SIM115 - closed in close()
        self._files.append(log)
        p = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                             env=child_env(PYTHONUNBUFFERED="1"))
        self.procs[name] = p
        return p

    def dead(self) -> list[str]:
        return [f"{n} exited {p.returncode}" for n, p in self.procs.items() if p.poll() is not None]

    def wait(self, timeout: float) -> dict[str, int | None]:
        end = time.monotonic() + timeout
        codes: dict[str, int | None] = {}
        for name, p in self.procs.items():
            try:
                codes[name] = p.wait(max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                codes[name] = None
        return codes

    def tail(self, name: str, lines: int = 15) -> str:
        with contextlib.suppress(OSError):
            return "\n".join((self.logs / f"{name}.log").read_text(errors="replace").splitlines()[-lines:])
        return ""

    def close(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
        for f in self._files:
            f.close()


# --------------------------------------------------------------------------- 1. the floor


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
    from network.membership import await_presence

    root = f"perf{uuid.uuid4().hex[:8]}"
    procs = Procs(logs)
    results: list[Floor] = []
    payload_len = 16
    try:
        with loopback_router() as router, zenoh.open(client_config(router.locator)) as session:
            loc = router.locator
            helper = procs.start("pingpong", [sys.executable, "-m", "benchmarks.pingpong", "--connect", loc,
                                     "--root", root])
            if not await_presence(session, f"{root}/ready", 60.0):
                raise RuntimeError(f"the pingpong helper did not start:\n{procs.tail('pingpong')}")
            for mode in pubsub:
                got: queue.SimpleQueue[bytes] = queue.SimpleQueue()
                sub = session.declare_subscriber(f"{root}/{mode}/pong", _payloads_into(got))
                pub = session.declare_publisher(f"{root}/{mode}/ping",
                                                congestion_control=zenoh.CongestionControl.BLOCK,
                                                reliability=zenoh.Reliability.RELIABLE)
                rtts: list[float] = []
                i = 0
                cpu0 = None
                while len(rtts) < rounds:
                    i += 1
                    if i == warmup + 1:
                        cpu0 = (cpu_seconds(helper.pid), cpu_seconds())
                    msg = i.to_bytes(payload_len, "big")
                    t0 = time.perf_counter()
                    pub.put(msg)
                    try:
                        back = got.get(timeout=5.0)
                    except queue.Empty:  # routes not yet established during the warm-up: ping again
                        if i > warmup:
                            raise RuntimeError("pub/sub ping lost after the warm-up") from None
                        continue
                    dt = time.perf_counter() - t0
                    while back != msg:  # a late pong of a timed-out warm-up ping
                        back = got.get(timeout=5.0)
                        dt = time.perf_counter() - t0
                    if i > warmup:
                        rtts.append(dt)
                cpu = _cpu_per_round(cpu0, helper.pid, len(rtts))
                sub.undeclare()
                pub.undeclare()
                replies = "callback" if mode == "cb" else "main thread"
                results.append(Floor(f"floor: pub/sub round trip ({replies} replies)", rtts, cpu))
            for mode in query:
                querier = session.declare_querier(f"{root}/{mode}/query", timeout=5.0,
                                                  consolidation=zenoh.ConsolidationMode.NONE)
                rtts = []
                i = 0
                cpu0 = None
                while len(rtts) < rounds:
                    i += 1
                    if i == warmup + 1:
                        cpu0 = (cpu_seconds(helper.pid), cpu_seconds())
                    msg = i.to_bytes(payload_len, "big")
                    t0 = time.perf_counter()
                    ok = False
                    for reply in querier.get(payload=msg):
                        ok = ok or (reply.ok is not None and reply.ok.payload.to_bytes() == msg)
                    dt = time.perf_counter() - t0
                    if not ok:
                        if i > warmup:
                            raise RuntimeError("query without an answer after the warm-up")
                        continue
                    if i > warmup:
                        rtts.append(dt)
                cpu = _cpu_per_round(cpu0, helper.pid, len(rtts))
                querier.undeclare()
                replies = "callback" if mode == "cb" else "main thread"
                results.append(Floor(f"floor: query round trip ({replies} replies)", rtts, cpu))
            session.put(f"{root}/quit", b"")
            code = procs.wait(30.0)["pingpong"]
    finally:
        procs.close()
    for r in results:
        r.exit_code = code
    return results


# --------------------------------------------------------------------------- 2. scenarios


@dataclass(slots=True)
class Case:
    drones: int
    size: tuple[int, int, int]
    warmup: int
    turns: int  # measured

    @property
    def name(self) -> str:
        return f"{self.drones} drone{'s' if self.drones > 1 else ''} @ {_size_text(self.size)}"

    @property
    def end_turn(self) -> int:
        """The GCS phase at which the ground station quits (turns 1..end_turn - 1 are played)."""
        return self.warmup + self.turns + 1


def start_cells(size: Sequence[int]) -> list[tuple[int, int, int]]:
    """Candidate starts: the near half of the ground floor (x < nx/2), every other y."""
    nx, ny, _ = size
    return [(x, y, 0) for x in range(max(1, nx // 2)) for y in range(0, ny, 2)]


def spread(size: Sequence[int], n: int) -> list[tuple[int, int, int]]:
    """`n` start cells on an even grid over the candidates (lanes every other y, x < nx/2)."""
    lanes = list(range(0, size[1], 2))
    xs = list(range(max(1, size[0] // 2)))
    a = min(len(lanes), max(1, math.ceil(math.sqrt(n * len(lanes) / len(xs)))))  # lanes used
    b = math.ceil(n / a)  # drones per lane
    if b > len(xs):
        b = len(xs)
        a = math.ceil(n / b)
    pick_lanes = [lanes[i] for i in np.linspace(0, len(lanes) - 1, a).round().astype(int)] if a > 1 else [0]
    pick_xs = [xs[i] for i in np.linspace(0, len(xs) - 1, b).round().astype(int)] if b > 1 else [0]
    return [(x, y, 0) for y in pick_lanes for x in pick_xs][:n]


def _free_near(world, cell: tuple[int, int, int], used: set) -> tuple[int, int, int]:
    """The first free, unused cell at or above `cell`, else in the columns further along x, then back."""
    nx, _, nz = world.size
    x0, y, z0 = cell
    for fx in [*range(x0, nx), *range(x0 - 1, -1, -1)]:
        for fz in range(z0, nz):
            c = (fx, y, fz)
            if not world.is_building(c) and c not in used:
                return c
    raise AssertionError(f"no free target near {cell}")


def make_scenario(case: Case, seed: int = WORLD_SEED) -> dict | None:
    """The scenario file's JSON for `case`, or None if the drones do not fit (see module docstring)."""
    from schema import WorldSpec, drone_id
    from world.grid import build_world

    nx, ny, nz = case.size
    n = case.drones
    if n > len(start_cells(case.size)):
        return None
    starts = spread(case.size, n)
    world = build_world(WorldSpec(size=case.size, seed=seed), starts)
    for s in starts:
        if world.is_building(s):
            raise AssertionError(f"start {s} is inside a building")
    half = max(1, nx // 2)
    # Leg k flies at the lane's altitude 1 + (lane + k) mod (nz - 1): a seed drone flying over cells it
    # already knows wanders off sideways (it prefers unknown cells), so each leg goes through new cells;
    # neighbouring lanes are always a floor apart. Even legs end in the far half, odd ones back home.
    # After nz - 1 legs (small worlds only) several drones stay at their last target; a lone one goes on.
    switches = [1]
    t = 1 + (nz - 1) + half + 2  # the first leg includes the climb from the ground
    while t <= case.end_turn and (n == 1 or len(switches) < max(1, nz - 1)):  # then every floor is flown: stay
        switches.append(t)
        t += half + 3  # one floor up, then across
    targets = []
    for k, t0 in enumerate(switches):
        used: set[tuple[int, int, int]] = set()
        for i, (x, y, _) in enumerate(starts):
            z = 1 + (y // 2 + k) % (nz - 1) if nz > 1 else 0
            if k % 2:  # home: above a free ground cell, so free (buildings rise from the ground)
                cell = (x, y, z)
            else:
                cell = _free_near(world, (min(x + half, nx - 1), y, z), used)
            used.add(cell)
            targets.append(f"{drone_id(i + 1)}={cell[0]},{cell[1]},{cell[2]}@{t0}")
    return {"format": "dronesim-scenario", "version": 1,
            "world": {"size": list(case.size), "seed": seed},
            "drones": [{"id": drone_id(i + 1), "start": list(s), "autopilot": "seed"} for i, s in enumerate(starts)],
            "targets": targets, "max_turns": case.end_turn + 10}


# --------------------------------------------------------------------------- distributed game


@dataclass(slots=True)
class Game:
    latencies: list[float] = field(default_factory=list)  # seconds, consecutive GCS phases
    answers: list[float] = field(default_factory=list)  # seconds from TURN(GCS) to the DONE sent, measured turns
    memory: dict[str, dict[str, int]] = field(default_factory=dict)  # process -> /proc status (KiB)
    codes: dict[str, int | None] = field(default_factory=dict)
    cpu: dict[str, float] = field(default_factory=dict)  # process -> CPU seconds per measured turn
    alive: int = 0
    last_status: object = None
    statuses: dict = field(default_factory=dict)  # turn -> STATUS
    arrived: dict[int, float] = field(default_factory=dict)  # turn -> when its STATUS came (time.monotonic())
    error: str = ""
    over: str = ""


ROLES = ("coordinator", "env", "swarm")


def shared_memory_configs(folder: Path) -> tuple[Path, Path]:
    """Zenoh configuration files with shared memory on (zenoh's default, which this project turns off),
    the rest as our defaults (network/transport.py): the router's (its flood filters, its admin space
    readable) and the other processes'."""
    from schema.acl import flood_filters

    base = {"scouting": {"multicast": {"enabled": False}}, "transport": {"shared_memory": {"enabled": True}}}
    router = {**base, **flood_filters(["**"]),
              "adminspace": {"enabled": True, "permissions": {"read": True, "write": False}}}
    paths = folder / "shared-memory-router.json5", folder / "shared-memory.json5"
    for path, conf in zip(paths, (router, base)):
        path.write_text(json.dumps(conf), encoding="utf-8")
    return paths


@dataclass(frozen=True, slots=True)
class Secured:
    """The secured deployment (docs/security.md) on loopback: TLS, user/password, the router's access control
    generated from the key table for the game's root; every process with its own credentials, from a kit
    made by `dronesim certs` in `folder` (`make`)."""

    folder: Path

    @staticmethod
    def make(folder: Path, drones: Sequence[str], host: str) -> Secured:
        from dronesim import certs

        certs.make(folder, drones=drones, hosts=[host], passwords=True)
        return Secured(folder)

    def flags(self, entity: str) -> list[str]:
        """An entity process's credentials (flags of every `dronesim` role)."""
        return ["--tls-ca", str(self.folder / "ca.pem"), "--user", entity,
                "--password-file", str(self.folder / f"{entity}.password")]

    def router_flags(self, root: str, drones: Sequence[str], host: str) -> list[str]:
        """`dronesim router`'s: its certificate, the users, and the access control of `root` for `drones`
        flown by the swarm host `host` (each drone also a principal of its own)."""
        from schema import acl

        block = acl.access_control(drones, roots=[root], identity="usrpwd", hosts={host: tuple(drones)})
        acl_file = self.folder / f"acl-{root}.json5"
        acl_file.write_text(acl.render(block), encoding="utf-8")
        f = self.folder
        return ["--tls-ca", str(f / "ca.pem"), "--tls-cert", str(f / "router.pem"), "--tls-key", str(f / "router.key"),
                "--users-file", str(f / "users.txt"), "--acl", str(acl_file)]

    def session(self, locator: str, entity: str) -> zenoh.Config:
        """A client session's config as `entity`, as its process would make it."""
        from network.transport import add_zenoh_args, zenoh_config

        parser = argparse.ArgumentParser()
        add_zenoh_args(parser)
        return zenoh_config(parser.parse_args(["--mode", "client", "--connect", locator, *self.flags(entity)]))


@dataclass(frozen=True, slots=True)
class Variant:
    """How a game is played: every mechanism on (the default), or one of them off (see MECHANISMS)."""

    ahead: int = ANSWER_AHEAD  # GCS phases the ground station answers ahead
    chart: bool = True  # the drone processes keep a chart (else `--no-chart`: every question to the environment)
    swarm_min: int | None = None  # the swarm host's `--swarm-pilot-min` (None: its default)
    upd_listener: bool = False  # someone subscribes to the environment's UPD (this process, a no-op callback)
    journal: bool = False  # the coordinator keeps a journal (`--journal`, in the game's log folder)
    shared_memory: bool = False  # every process and the router with shared memory on (shared_memory_configs)
    per_drone: bool = False  # one process per drone (`dronesim drone --id Dnn`) instead of one swarm host
    secured: Secured | None = None  # TLS, user/password and access control (with one swarm host, H01)
    autopilot: str = "seed"  # the drones' autopilot (`dronesim drone --autopilot`)
    hosts: int = 1  # swarm hosts H01, H02, ... (processes "swarm", or "swarm1", "swarm2", ...), drones in id order
    statuses: bool = True  # keep every STATUS (`Game.statuses`; False: only the last, `Game.last_status`)
    env_follows: bool = False  # the environment takes every STATUS (`dronesim env --follow-status`)
    ros2: bool = False  # a `dronesim ros2` viewer publishes the game to ROS 2 beside it, every topic subscribed


def play_distributed(case: Case, scenario_file: Path, logs: Path, profile: Path | None = None,
                     variant: Variant = Variant(), *, on_status: Callable[[str, Any, int], None] | None = None) -> Game:
    """One game over a loopback router with this process as the ground station; see the module docstring.
    `variant`: how it is played (with `per_drone`, the swarm's CPU is that of every drone process summed,
    its memory the peak of the largest). `on_status(locator, keys, turn)`, if given, is called on each STATUS
    as it arrives (e.g. to start a flood at a given turn: `benchmarks/flood.py`); the game waits for it."""
    import logging

    from dronesim.scenario import Scenario
    from entities.gcs import End, Ground, SendDone, Station
    from entities.station_link import join, listen, publisher
    from network.membership import Answered, await_presence
    from network.transport import Outbox, Presence, Received
    from schema import Keys, Status, Turn, drone_id
    from schema.keys import RosKeys

    scenario = Scenario.load(scenario_file)
    root = f"perf{uuid.uuid4().hex[:8]}"
    keys = Keys(root)
    log = logging.getLogger("dronesim.bench.gcs")
    game = Game()
    procs = Procs(logs)
    spies: list[subprocess.Popen] = []
    last_drone = drone_id(case.drones)
    ids = "D01" if case.drones == 1 else f"D01-{last_drone}"
    router_config, config = shared_memory_configs(logs) if variant.shared_memory else (None, None)
    secured = variant.secured
    if secured is not None and (variant.per_drone or variant.hosts > 1):
        raise ValueError("a secured game is flown by one swarm host")
    creds = secured.flags if secured is not None else (lambda _entity: [])
    router_flags = [] if secured is None else secured.router_flags(
        root, [drone_id(n) for n in range(1, case.drones + 1)], "H01")
    try:
        with loopback_router(router_config, scheme="tcp" if secured is None else "tls", flags=router_flags) as router:
            loc = router.locator
            base = [sys.executable, "-m", "dronesim"]
            common = ["--mode", "client", "--connect", loc, "--root", root]
            common += [] if config is None else ["--config", str(config)]
            journal = ["--journal", str(logs / "journal.jsonl")] if variant.journal else []
            procs.start("coordinator", [*base, "coordinator", *common, "--scenario", str(scenario_file),
                                        "--phase-deadline", str(PHASE_DEADLINE), *journal, *creds("SRV")])
            procs.start("env", [*base, "env", *common, "--no-draw", "--connect-timeout", "120", *creds("ENV"),
                                *["--follow-status"] * variant.env_follows])
            flying = [*base, "drone", *common, "--autopilot", variant.autopilot, "--connect-timeout", "120"]
            flying += [] if variant.chart else ["--no-chart"]
            flying += [] if variant.swarm_min is None else ["--swarm-pilot-min", str(variant.swarm_min)]
            if variant.per_drone:
                for number in range(1, case.drones + 1):
                    procs.start(drone_id(number), [*flying, "--id", drone_id(number)])
            elif variant.hosts > 1:
                for h, part in enumerate(np.array_split(np.arange(1, case.drones + 1), variant.hosts), 1):
                    procs.start(f"swarm{h}", [*flying, "--id", f"{drone_id(int(part[0]))}-{drone_id(int(part[-1]))}",
                                              "--host", f"H{h:02d}"])
            else:
                procs.start("swarm", [*flying, "--id", ids, "--host", "H01", *creds("H01")])
            if variant.ros2:  # an observer: it hears STATUS and OVER, publishes to ROS 2 at its own rate
                procs.start("ros2", [*base, "ros2", *common, "--log-level", "WARNING"])
            conf = client_config(loc) if secured is None else secured.session(loc, "GCS")
            if config is not None:
                conf.insert_json5("transport/shared_memory/enabled", "true")
            with zenoh.open(conf) as session:
                if variant.upd_listener:  # the environment then follows the ENV phase and reports it
                    session.declare_subscriber(keys.upd, lambda _sample: None)
                if variant.ros2:  # a ROS 2 user subscribed to every topic of domain 0 (RViz's are a few)
                    session.declare_subscriber("0/**", lambda _sample: None)
                    # the viewer's node token comes once it hears OVER: a game played before would leave it waiting
                    if not await_presence(session, RosKeys().node_tokens("dronesim"), 120.0):
                        raise RuntimeError("the ROS 2 viewer did not appear within 120 s")
                inbox = listen(session, keys, log)
                member = join(session, inbox, log, connect_timeout=120.0, grace=30.0)
                # the scripted ground station's protocol (`dronesim gcs --scenario`), quitting after the measure
                station = Station(Ground.from_welcome(member.welcome, scenario.targets, None), quit_at=case.end_turn,
                                  ahead=variant.ahead)
                send = publisher(Outbox(session), keys, log, print)
                if profile is not None:
                    spies = _spy(procs, profile, case)
                stamps: dict[tuple[str, int], float] = {}
                pids: dict[str, int | str] = {name: proc.pid for name, proc in procs.procs.items()}
                pids |= {"router": router.pid, "bench": "self"}
                idle_since = time.monotonic()
                end: End | None = None
                measured_to: list[int] = []  # the turn whose GCS phase ended the measure (the game's end, if sooner)

                def measured(turn: int) -> None:
                    game.cpu = {n: cpu_seconds(pid) - game.cpu.get(n, 0.0) for n, pid in pids.items()}
                    for name, proc in procs.procs.items():
                        game.memory[name] = proc_status(proc.pid)
                    measured_to.append(turn)

                while end is None:
                    due = station.wake(time.monotonic())  # (its DONEs go out paced)
                    event = inbox.get(1.0 if due is None else min(1.0, due))
                    now = time.perf_counter()
                    effects: list = []
                    match event:
                        case None:
                            if procs.dead():
                                raise RuntimeError("a process ended during the game: " + ", ".join(procs.dead()))
                            if time.monotonic() - idle_since > EVENT_TIMEOUT:
                                raise RuntimeError(f"the game stalled: no event for {EVENT_TIMEOUT:g} s")
                        case Presence() | Answered():
                            if (welcome := member.on_event(event)) is not None:
                                effects = station.admitted(welcome)
                        case Received(_, Status() as st):
                            stamps[("STATUS", st.turn)] = now  # turn st.turn + 1 begins
                            game.last_status = st
                            game.statuses[st.turn] = st if variant.statuses else None
                            game.arrived[st.turn] = time.monotonic()  # before on_status, which may start a flood
                            if on_status is not None:
                                on_status(loc, keys, st.turn)
                            if st.turn == case.warmup:  # CPU time over the measured turns: from here...
                                game.cpu = {n: cpu_seconds(pid) for n, pid in pids.items()}
                        case Received(_, Turn() as turn):
                            stamps[("GCS", turn.turn)] = now
                            if turn.turn >= case.end_turn and not measured_to:  # ... to here
                                measured(case.end_turn)
                    if isinstance(event, Received):
                        effects = station.receive(event.msg, time.monotonic())
                    if event is not None:
                        idle_since = time.monotonic()
                    for effect in [*effects, *station.tick(time.monotonic())]:
                        send(effect)
                        if (isinstance(effect, SendDone) and isinstance(event, Received)
                                and isinstance(event.msg, Turn) and effect.msg.turn == event.msg.turn):
                            stamps[("DONE", effect.msg.turn)] = time.perf_counter()  # not answered ahead
                        elif isinstance(effect, End):
                            end = effect
                            if not measured_to and case.warmup in game.statuses:  # over before the measure's end
                                measured(max(game.statuses) + 1)
                game.over = f"{end.over.reason.value} at turn {end.over.turn}"
                member.close()
            game.codes = procs.wait(60.0)
    except Exception as exc:  # noqa: BLE001 - reported in the table, the run goes on
        game.error = f"{type(exc).__name__}: {exc}"
        game.codes = {n: p.poll() for n, p in procs.procs.items()}
    finally:
        procs.close()
        if spies:
            spies[-1].send_signal(signal.SIGINT)  # this process's py-spy: it writes its output on SIGINT
        for spy in spies:
            with contextlib.suppress(subprocess.TimeoutExpired):
                spy.wait(30)
            if spy.poll() is None:
                spy.kill()
    if variant.per_drone:
        _as_one_swarm(game)
    if game.error:
        for n in [r for r in procs.procs if r in ROLES or r.startswith("swarm")]:
            game.error += f"\n--- {n} ({logs / (n + '.log')}):\n{procs.tail(n)}"
        return game
    first, last = case.warmup + 1, measured_to[0] if measured_to else case.end_turn
    begins = [stamps.get(("STATUS", t - 1)) for t in range(first, last + 1)]  # STATUS(t - 1): turn t begins
    if None in begins:
        game.error = "missing STATUS"
        return game
    game.latencies = [b - a for a, b in zip(begins, begins[1:])]  # type: ignore[operator]
    game.answers = [stamps[("DONE", t)] - stamps[("GCS", t)] for t in range(first, last) if ("DONE", t) in stamps]
    game.cpu = {n: v / (last - first) for n, v in game.cpu.items()}
    game.alive = len(game.last_status.drones.alive()) if game.last_status else 0  # type: ignore[attr-defined]
    return game


def _as_one_swarm(game: Game) -> None:
    """The drone processes of a game played process by process, as one swarm host in the table: CPU
    summed, the largest peak, the worst exit code."""
    drones = [n for n in game.codes if n not in ROLES]
    game.cpu["swarm"] = sum(game.cpu.pop(n, 0.0) for n in drones)
    peaks = [game.memory.pop(n) for n in drones if n in game.memory]
    if peaks:
        game.memory["swarm"] = max(peaks, key=lambda m: m.get("VmHWM", 0))
    codes = [game.codes.pop(n) for n in drones]
    known = [c for c in codes if c is not None]
    game.codes["swarm"] = None if len(known) < len(codes) else max(known, key=abs)


def _spy(procs: Procs, out: Path, case: Case) -> list[subprocess.Popen]:
    """py-spy record on each entity process until it exits, and on this one until the game is over (raw
    collapsed stacks, one file each)."""
    exe = shutil.which("py-spy")
    if exe is None:
        print("note: --profile needs py-spy (pip install py-spy); not profiling", file=sys.stderr)
        return []
    out.mkdir(parents=True, exist_ok=True)
    tag = f"{case.drones}-{_size_text(case.size)}"
    pids = {n: p.pid for n, p in procs.procs.items()} | {"bench": os.getpid()}
    return [subprocess.Popen([exe, "record", "--pid", str(pid), "--rate", "250", "--format", "raw",
                              "--output", str(out / f"{tag}-{n}.txt"), "--nonblocking"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for n, pid in pids.items()]


# --------------------------------------------------------------------------- 3. in-process


@dataclass(slots=True)
class Local:
    latencies: list[float]
    statuses: dict  # turn -> STATUS
    moving: float  # drones that moved, per measured turn


def play_local(case: Case, scenario_file: Path) -> Local:
    """The same game in-process (`dronesim.local.simulate`), timed at each GCS phase as the distributed one."""
    import logging

    from dronesim.local import Inputs, simulate
    from dronesim.scenario import Scenario
    from schema import Intent

    class TimedInputs(Inputs):
        """Timestamps the GCS phase: simulate asks for the intent once per turn, in that phase."""

        def intent(self, turn: int) -> Intent:
            self.stamps[turn] = time.perf_counter()  # type: ignore[attr-defined]
            return super().intent(turn)

    sc = Scenario.load(scenario_file)
    inputs = TimedInputs(plan=sc.plan(), intents={1: Intent.CONTINUE, case.end_turn: Intent.QUIT}, scripted=False)
    inputs.stamps = {}  # type: ignore[attr-defined]
    quiet = logging.getLogger("dronesim.bench.local")
    quiet.setLevel(logging.ERROR)
    res = simulate(sc.game_config(phase_deadline=PHASE_DEADLINE), sc.autopilots, inputs, quiet, keep_statuses=True,
                   verify_env=False,  # as the distributed game: the coordinator does not check UPD by default
                   swarm=True)  # and its drones flown by one swarm host
    st = inputs.stamps  # type: ignore[attr-defined]
    ts = [st[t] for t in range(case.warmup + 1, case.end_turn + 1)]
    measured = [r for r in res.records
                if r.get("record") == "turn" and case.warmup < r.get("turn", 0) < case.end_turn]
    moving = statistics.fmean(len(r.get("moves", {})) for r in measured) if measured else 0.0
    return Local([b - a for a, b in zip(ts, ts[1:])], {st.turn: st for st in res.statuses}, moving)


# --------------------------------------------------------------------------- 4. memory baseline, world gen


def python_baseline_kib() -> int:
    """VmHWM of an idle entity process: Python with the coordinator, environment and drone modules
    imported, numpy's random generators loaded (the coordinator and the environment build their world
    with one, whatever its size; numpy loads that module on first use) and a Zenoh client session on
    the loopback router that has sent and received 500 small messages: the fixed cost of any running
    process, whatever its world and drones."""
    code = ("import os, sys, queue, zenoh, numpy, coordinator.node, entities.env_node, "
            "entities.drone_node; from network.transport import client_config\n"
            "numpy.random.default_rng(0)\n"
            "s = zenoh.open(client_config(sys.argv[1])); got = queue.SimpleQueue()\n"
            "sub = s.declare_subscriber('baseline/echo', lambda m: got.put(m.payload.to_bytes()))\n"
            "pub = s.declare_publisher('baseline/echo', congestion_control=zenoh.CongestionControl.BLOCK)\n"
            "for i in range(500):\n    pub.put(bytes(200)); got.get(timeout=10)\n"  # warm, as a running entity
            "print(open(f'/proc/{os.getpid()}/status').read()); s.close()")
    with loopback_router() as router:
        text = subprocess.run([sys.executable, "-c", code, router.locator], capture_output=True, text=True,
                              check=True, timeout=60).stdout
    m = re.search(r"VmHWM:\s+(\d+) kB", text)
    return int(m.group(1)) if m else 0


def world_generation(size: tuple[int, int, int], repeat: int = 3) -> list[float]:
    from world.grid import World

    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        World.generate(size, np.random.default_rng(WORLD_SEED))
        times.append(time.perf_counter() - t0)
    return times


# --------------------------------------------------------------------------- the table


@dataclass(slots=True)
class Row:
    name: str
    cells: dict[str, str] = field(default_factory=dict)
    ok: bool = True  # every process exited 0 (or nothing to check)


COLUMNS = (
    ("name", "row"),
    ("array", "world array"),
    ("turns", "turns (warm-up + measured)"),
    ("tps", "turns/s"),
    ("lat", "turn (or round trip) ms median / p99"),
    ("split", "ground station's answer ms (median)"),
    ("cpu", "CPU ms per turn coordinator / env / swarm / router / ground station"),
    ("ltps", "in-process turns/s"),
    ("lratio", "in-process ÷ distributed"),
    ("floor", "turn ÷ pub/sub RTT"),
    ("pogema", "turns/s ÷ POGEMA's steps/s (same N)"),
    ("growth", "per-turn cost growth 128→1000 ÷ N growth"),
    ("srv", "coordinator MiB (÷ model)"),
    ("env", "environment MiB (÷ model)"),
    ("swarm", "swarm host MiB"),
    ("alive", "alive at end, moving per turn, same game in-process"),
    ("codes", "exit codes"),
    ("target", "target"),
)


def memory_growth(peaks: dict[tuple[str, int, tuple[int, int, int]], int]) -> list[Row]:
    """The memory target as what it bounds, the growth: "2 x the world array + 1 KiB per drone" above
    the cost of the process itself. Per drone: (peak with 1000 drones - peak with 128) / 872 on the same
    world: two swarms, which run the same code. A game of a few drones takes the small-size paths (a turn
    of one drone sorts nothing, say) and never touches the array code a swarm runs, so the first swarm
    costs a process some hundreds of KiB once (library code pages, allocator arenas): that step is shown,
    as the slope from 1 drone to 1000, but it is no cost per drone. Per world byte: (peak on the largest
    world - peak on the smallest) / the arrays' difference, with 1 drone. Both are slopes over differences
    of megabytes, which the run-to-run spread of a process's peak (a few hundred KiB) does not decide;
    each game row's ratio to the idle-process model is shown as well."""
    rows = []
    for size in WORLDS:
        slopes = _slopes(peaks, (128, size), (1000, size), 1000 - 128)  # KiB per drone
        if slopes:
            rows.append(_slope_row(f"memory per drone (128 → 1000 drones @ {_size_text(size)})", slopes,
                                   "KiB/drone", TARGETS["kib_per_drone"],
                                   f"≤ {TARGETS['kib_per_drone']:g} KiB per drone"))
        slopes = _slopes(peaks, (1, size), (1000, size), 999)
        if slopes:
            rows.append(_slope_row(f"memory per drone from 1 drone (1 → 1000 drones @ {_size_text(size)})", slopes,
                                   "KiB/drone", None, "— (includes the first swarm's one-time cost: see the legend)"))
    small, large = WORLDS[0], WORLDS[-1]
    grown = int(np.prod(large)) - int(np.prod(small))
    slopes = _slopes(peaks, (1, small), (1, large), grown / 1024)  # bytes per world byte
    if slopes:
        row = _slope_row(f"memory per world byte (1 drone, {_size_text(small)} → {_size_text(large)})", slopes,
                         "bytes/byte", TARGETS["per_world_byte"], f"≤ {TARGETS['per_world_byte']:g} × the world array")
        row.cells["array"] = f"+{_bytes_text(grown)}"
        rows.append(row)
    return rows


def _slopes(peaks: dict[tuple[str, int, tuple[int, int, int]], int], low: tuple, high: tuple,
            per: float) -> dict[str, float]:
    """For each role measured in both games (drones, world) `low` and `high`: its peak's growth (KiB)
    from one to the other, divided by `per`; keyed by the role's column."""
    return {key: (peaks[(role, *high)] - peaks[(role, *low)]) / per for key, role in _MEMORY_ROLES
            if (role, *high) in peaks and (role, *low) in peaks}


#: The processes the memory target is about: (table column, process name).
_MEMORY_ROLES = (("srv", "coordinator"), ("env", "env"))


def _slope_row(name: str, slopes: dict[str, float], unit: str, target: float | None, what: str) -> Row:
    """A memory row: each role's slope, and the verdict on the worse one (no target: `what` alone)."""
    cells = {key: f"{v:.2f} {unit}" for key, v in slopes.items()}
    cells["target"] = what if target is None else _verdict(max(slopes.values()), target, True, what)
    return Row(name, cells)


def versus_pogema(rate: float, anchor: float | None, drones: int) -> tuple[str, list[str]]:
    """A game row's turns/s against POGEMA's steps/s with as many agents: the cell, and the verdict
    where the issue sets a target (128 drones: at least 25 %)."""
    if not anchor:
        return "-", []
    ratio = rate / anchor
    verdicts = [_verdict(ratio, TARGETS["pogema128"], False, f"≥ {TARGETS['pogema128']:.0%} of POGEMA's "
                                                            f"{anchor:.0f} steps/s")] if drones == 128 else []
    return f"{ratio:.0%}", verdicts


def render(rows: list[Row], columns: tuple[tuple[str, str], ...] = COLUMNS) -> str:
    lines = ["| " + " | ".join(h for _, h in columns) + " |", "|" + "---|" * len(columns)]
    for r in rows:
        vals = [r.name] + [r.cells.get(k, "") for k, _ in columns[1:]]
        lines.append("| " + " | ".join(v.replace("|", "/") if v else "—" for v in vals) + " |")
    return "\n".join(lines)


def _verdict(value: float, target: float, at_most: bool, what: str) -> str:
    if value != value:  # nan
        return f"{what}: not measured"
    met = value <= target if at_most else value >= target
    return f"{what}: {'met' if met else 'UNMET'}"


# --------------------------------------------------------------------------- mechanisms, on and off


#: The repository's root (where the `code` of each mechanism is read).
ROOT = Path(__file__).resolve().parent.parent


def code_lines(specs: Sequence[str], root: Path = ROOT) -> int:
    """Lines of code a mechanism's `specs` name, each line counted once: ``path::Name`` or
    ``path::Class.method`` is a definition's lines (a def, a class or an assignment at module level,
    decorators, docstring and comments included), ``path:/regex/`` the lines of `path` the regex finds,
    ``path`` the whole file. KeyError if a name or a file is not there (the table must stay true)."""
    import ast

    lines: set[tuple[str, int]] = set()
    for spec in specs:
        if "::" in spec:
            path, name = spec.split("::", 1)
            lines.update((path, n) for n in _definition(ast.parse((root / path).read_text(encoding="utf-8")),
                                                        name.split("."), spec))
        elif ":/" in spec:
            path, pattern = spec.split(":/", 1)
            regex = re.compile(pattern.removesuffix("/"))
            text = (root / path).read_text(encoding="utf-8").splitlines()
            found = {i for i, line in enumerate(text, 1) if regex.search(line)}
            if not found:
                raise KeyError(f"{spec}: no line matches")
            lines.update((path, i) for i in found)
        else:
            lines.update((spec, i) for i in range(1, len((root / spec).read_text(encoding="utf-8").splitlines()) + 1))
    return len(lines)


def _definition(tree, names: list[str], spec: str) -> range:
    import ast

    body = tree.body
    for i, name in enumerate(names):
        for node in body:
            assigned = getattr(node, "targets", [getattr(node, "target", None)])
            targets = [t.id for t in assigned if isinstance(t, ast.Name)]
            if getattr(node, "name", None) == name or name in targets:
                if i == len(names) - 1:
                    first = min([node.lineno, *(d.lineno for d in getattr(node, "decorator_list", []))])
                    return range(first, node.end_lineno + 1)
                body = node.body
                break
        else:
            raise KeyError(f"{spec}: no definition named {name!r}")
    raise KeyError(spec)


@dataclass(frozen=True, slots=True)
class Mechanism:
    """A speed-up that remains: the code that exists only for it, and the games played with it on and
    off in the same run (`off`), or, when it is not switched off, why (`why`)."""

    name: str
    code: tuple[str, ...]  # see code_lines
    off: Variant | None = None
    games: tuple[tuple[int, tuple[int, int, int]], ...] = ()  # (drones, world) played on and off
    switch: str = ""  # how it is switched off, or why it is not (and what measured it)
    warmup: int = 0  # warm-up turns of its 1000-drone games, if more than the game rows' (a process starting)


MECHANISMS: tuple[Mechanism, ...] = (
    Mechanism(
        "The ENV phase is pipelined (the coordinator judges the moves with its own copy of the world)",
        ("coordinator/engine.py::Engine._upd", "coordinator/engine.py::Engine._kind",
         "coordinator/engine.py:/_upd_due|verify_env|UPD_WINDOW/", "coordinator/node.py:/verify.env/",
         "schema/tuning.py::UPD_WINDOW", "entities/environment.py:/_early/"),
        switch="not switched off: without it the ENV phase would close on the environment's verdict, a second "
               "way to end a turn in the engine (the first version's); it saved 2 of that version's 8 hops a turn "
               "(one drone 3.1–3.6 ms then), about 0.22 ms each as traced (docs/performance.md)"),
    Mechanism(
        "Answers ahead (a scripted ground station answers the coming phases with nothing new)",
        ("entities/gcs.py::turns_to_answer_ahead", "entities/gcs.py::Station._ahead",
         "entities/gcs.py:/ahead|answered/", "coordinator/engine.py::Engine._hold",
         "coordinator/engine.py:/_early|AHEAD_MAX|ahead/", "schema/tuning.py::AHEAD_MAX",
         "schema/tuning.py::ANSWER_AHEAD", "entities/station_link.py:/ahead/", "coordinator/engine.py::_drones_first",
         "coordinator/engine.py:/_drones_first/"),
        Variant(ahead=0), ((1, (64, 64, 16)), (128, (64, 64, 16))),
        "the station answers each phase when it opens (`Station(ahead=0)`)"),
    Mechanism(
        "Sensing from a chart (a drone process answers its autopilot from the map the environment gave)",
        ("entities/drone.py::Chart", "entities/drone.py::occupancy_of", "entities/drone.py::_ball",
         "entities/drone.py::_cells_of", "entities/drone.py::DroneProcess.start",
         "entities/drone.py::DroneProcess._poll_map", "entities/drone.py::DroneProcess._map_answered",
         "entities/drone.py::DroneProcess._prefetch", "entities/drone.py:/chart|_map_|occupancy/",
         "schema/tuning.py::CHART_FEW_CELLS", "schema/tuning.py::ASK_AHEAD_REACH",
         "schema/tuning.py::ASK_AHEAD_MAX_DRONES", "schema/tuning.py::MAP_TRIES", "schema/tuning.py::PREFETCH_CHUNK"),
        Variant(chart=False), ((1, (64, 64, 16)), (128, (64, 64, 16))),
        "`dronesim drone --no-chart`: every question goes to the environment in an ASK"),
    Mechanism(
        "The seed autopilot for a whole swarm (SeedSwarm: one pilot over arrays)",
        ("entities/autopilots/seed.py::SeedSwarm", "entities/autopilots/base.py::fly_swarm",
         "entities/autopilots/base.py::SwarmPilot", "entities/autopilots/__init__.py::make_swarm",
         "entities/drone.py:/self\\.swarm|swarm_min|fly_swarm/", "entities/drone_node.py:/swarm.pilot.min|swarm_min/",
         "schema/tuning.py::SWARM_MIN"),
        Variant(swarm_min=1_000_000), ((128, (64, 64, 16)), (1000, (64, 64, 16))),
        "`dronesim drone --swarm-pilot-min 1000000`: one SeedPilot per drone"),
    Mechanism(
        "A swarm host: one process and one MOVES a turn for all its drones",
        ("schema/messages.py::Moves", "schema/messages.py::StepTable", "schema/messages.py::Step",
         "coordinator/engine.py::Engine._moves_of_host", "coordinator/engine.py::Engine._host_move",
         "coordinator/admission.py:/host/", "entities/drone_node.py:/host/"),
        Variant(per_drone=True), ((16, (64, 64, 16)),),
        "one process per drone (`dronesim drone --id Dnn`, the seed's layout), each sending its NPS"),
    Mechanism(
        "The UPD report only for a listener (the environment follows the ENV phase only then)",
        ("entities/environment.py::EnvironmentProcess.listened", "entities/environment.py::Follow",
         "entities/environment.py:/_listened/", "entities/env_node.py:/Matching|matching|Follow|watch/",
         "network/transport.py::Matching", "network/transport.py::Outbox.watch",
         "coordinator/node.py:/Matching|matching|env_followed/", "coordinator/engine.py:/env_followed/"),
        Variant(upd_listener=True), ((128, (64, 64, 16)), (1000, (64, 64, 16))),
        "a subscriber to ENV/UPD (in this process, a callback that does nothing)"),
    Mechanism(
        "The environment takes the newest STATUS when a query needs it, not every one",
        ("network/transport.py::Inbox.newest", "network/membership.py:/skips_status/",
         "entities/environment.py::EnvironmentProcess.start", "entities/environment.py::EnvironmentProcess._follow",
         "entities/environment.py::EnvironmentProcess._following",
         "entities/environment.py:/self\\._all|taken already/", "entities/env_node.py::Effects._follow",
         "entities/env_node.py:/newest|follow/"),
        Variant(env_follows=True), ((1, (64, 64, 16)), (128, (64, 64, 16))),
        "`dronesim env --follow-status`: it takes every STATUS as it comes"),
    Mechanism(
        "Turn records without a journal skip what they would only drop",
        ("coordinator/engine.py:/journaled/",),
        Variant(journal=True), ((1000, (64, 64, 16)),),
        "`dronesim coordinator --journal FILE` (the gain then includes writing the journal)"),
    Mechanism(
        "Zenoh's shared-memory transport is off",
        ("network/transport.py:/shared_memory|shared.memory/",),
        Variant(shared_memory=True), ((1000, (64, 64, 16)),),
        "every process and the router with a `--config` turning it on (shared_memory_configs)"),
    Mechanism(
        "ROS 2 is published by an observer of its own, never by the game (the newest turn at its rate, DROP)",
        ("entities/ros2/node.py::Viewer", "entities/ros2/node.py:/newest|DROP/", "schema/tuning.py::ROS_RATE",
         "schema/tuning.py::ROS_CPU_SHARE", "schema/tuning.py::ROS_SLOWEST"),
        Variant(ros2=True), ((1000, (64, 64, 16)),),
        f"a `dronesim ros2` viewer publishing the game beside it, every topic subscribed (a callback that does "
        f"nothing in this process; turns/s with it ≥ {ROS2_KEEPS:.0%} of without; "
        "measured after 100 warm-up turns: its start, 1000 publishers and their graph tokens declared, is not "
        "the steady cost)", warmup=100),
    Mechanism(
        "Tables (schema version 2+): swarm-sized data as fixed rows checked by numpy",
        ("schema/tables.py",),
        switch="not switched off: the records path they replaced is gone (tables are the one form of swarm-sized "
               "data); measured then: a 128-drone STATUS decoded in about 25 µs instead of 200 as records"),
    Mechanism(
        "The engine's drones are columns (fleet.py; the observer judges a turn in array operations)",
        ("coordinator/fleet.py", "coordinator/observer.py::judge", "coordinator/engine.py::_in_batch"),
        switch="not switched off: the per-drone records it replaced are gone (observer.deaths, the rules drone by "
               "drone, stays as the reference of a property test); measured then: coordinator CPU per turn "
               "1.7 → 1.1 ms at 128 drones, 9 → 3 ms at 1000"),
    Mechanism(
        "A few rows or cells are taken one by one, below a threshold where numpy's fixed cost dominates",
        ("schema/tuning.py::FEW_ROWS", "schema/tuning.py::SURVEY_FEW_CELLS", "schema/tuning.py::CHART_FEW_CELLS",
         "schema/tuning.py::SMALL_FLEET", "coordinator/engine.py:/FEW_ROWS/",
         "entities/environment.py:/SURVEY_FEW_CELLS/", "entities/drone.py:/CHART_FEW_CELLS/",
         "coordinator/fleet.py::Fleet.column", "coordinator/fleet.py::nonzero", "coordinator/fleet.py::Fleet.whole",
         "schema/tuning.py::CHECK_FEW_ROWS", "schema/tables.py::Table._why_few", "schema/tables.py:/CHECK_FEW_ROWS/",
         "schema/tables.py:/ROW|AT\\b/"),
        switch="not switched off: a constant each (the lines counted are those naming it, the fleet's readers of a "
               "small fleet and the tables' _why_few: a branch's other lines are not); schema/tuning.py gives "
               "each one's measurement, e.g. a MOVES of 2 moves taken in 171 µs instead of 184, an ASK of 6 cells "
               "answered in 12 µs instead of 46, a 1-row STATUS table checked in 10 µs instead of 34 (a one-drone "
               "turn 5 to 20 % faster, alternated)"),
    Mechanism(
        "A few drones' turn is played over Python lists (the engine's `_judge_few`, up to TURN_FEW_DRONES)",
        ("schema/tuning.py::TURN_FEW_DRONES", "coordinator/engine.py::Engine._judge_few",
         "coordinator/engine.py::Engine._missed", "coordinator/engine.py::Engine._died",
         "coordinator/engine.py::Engine._journal_few", "coordinator/engine.py::_set_rows",
         "coordinator/observer.py::deaths_of_moves", "coordinator/observer.py::_meet",
         "coordinator/engine.py:/TURN_FEW_DRONES|whole|took/"),
        switch="not switched off: a constant (tests/test_engine_turn.py plays random games with the lists always "
               "and the arrays always: the same journals); schema/tuning.py gives its measurement, a whole turn "
               "of 1 drone 10 µs instead of 64, 16: 25 instead of 88, 64: 78 instead of 117"),
    Mechanism(
        "The ground station sends only the targets that change (the coordinator keeps them)",
        ("entities/gcs.py:/in_force|keep = |keep\\.get/",),
        switch="not switched off: re-sending every target would be a second way to answer; a DONE with no "
               "target is what a turn of a swarm flying to its targets costs (not measured on its own)"),
    Mechanism(
        "Each phase on its own key (`SRV/TURN/<PHASE>`): each process hears only its phase",
        ("schema/keys.py::Keys.turn_of",),
        switch="not switched off: one key for every phase would make each process decode and drop the others' "
               "TURNs (the drones' carries every order); not measured on its own"),
    Mechanism(
        "The packer's first buffer is 1 KiB (`PACK_BUFFER`)",
        ("schema/tuning.py::PACK_BUFFER", "schema/messages.py:/PACK_BUFFER/"),
        switch="not switched off: a constant; msgpack's default allocates 256 KiB for every message packed"),
    Mechanism(
        "A scenario's drone entries made compact as they are parsed (`object_hook`)",
        ("dronesim/scenario.py::_compact", "dronesim/scenario.py:/object_hook/"),
        switch="not switched off: measured then, a 1000-drone scenario leaves +612 KiB in the coordinator "
               "instead of +932"),
)

#: Games of each mechanism on and off, alternated (on, off, on, off...): the machine's speed drifts.
MECHANISM_REPEAT = 2


@dataclass(slots=True)
class Pair:
    """One mechanism's games, on and off, on one (drones, world)."""

    mechanism: Mechanism
    case: Case
    on: list[Game] = field(default_factory=list)
    off: list[Game] = field(default_factory=list)


def play_mechanisms(selected: Callable[[str], bool], quick: bool, turns: int, logs: Path) -> list[Pair]:
    """Each mechanism that has a switch, its games played on and off, alternated (MECHANISM_REPEAT times
    each; --quick: once, 4 drones on 10x10x10, which only checks that each switch plays the same game)."""
    pairs: list[Pair] = []
    for m in MECHANISMS:
        if m.off is None or not selected(f"mechanism: {m.name}"):
            continue
        games = ((4, (10, 10, 10)),) if quick else m.games
        for drones, size in games:
            case = Case(drones, size, 3, min(turns, 20)) if quick else (
                Case(drones, size, max(5, m.warmup), max(10, turns // 4)) if drones >= 1000
                else Case(drones, size, 10, turns))
            pair = Pair(m, case)
            path = logs / f"mechanism-scenario-{drones}-{_size_text(size)}.json"
            path.write_text(json.dumps(make_scenario(case)), encoding="utf-8")
            for i in range(1 if quick else MECHANISM_REPEAT):  # (mechanism_legend says how many)
                for variant, into in ((Variant(), pair.on), (m.off, pair.off)):
                    folder = logs / f"mechanism-{len(pairs)}-{'off' if variant is m.off else 'on'}-{i}"
                    folder.mkdir()
                    print(f"  mechanism {m.name[:40]}..., {case.name}, {'off' if variant is m.off else 'on'}",
                          file=sys.stderr, flush=True)
                    into.append(play_distributed(case, path, folder, variant=variant))
            pairs.append(pair)
    return pairs


MECHANISM_COLUMNS = (
    ("name", "mechanism"),
    ("lines", "lines of code"),
    ("switch", "switched off by"),
    ("game", "game"),
    ("tps", "turns/s on / off"),
    ("lat", "turn ms (median) on / off"),
    ("cpu", "CPU ms per turn, all processes, on / off"),
    ("mem", "peak MiB (coordinator, env, swarm) on / off"),
    ("gain", "gain (off ÷ on)"),
    ("same", "same game"),
)


def mechanism_rows(pairs: list[Pair], selected: Callable[[str], bool]) -> tuple[list[Row], list[str]]:
    """The mechanisms' table: a row per game played on and off, a row per mechanism not switched off;
    and the errors met."""
    rows: list[Row] = []
    errors: list[str] = []
    by_mechanism: dict[str, list[Pair]] = {}
    for p in pairs:
        by_mechanism.setdefault(p.mechanism.name, []).append(p)
    for m in MECHANISMS:
        if not selected(f"mechanism: {m.name}"):
            continue
        lines = str(code_lines(m.code))
        if m.off is None:
            rows.append(Row(m.name, {"lines": lines, "switch": m.switch}))
            continue
        for k, p in enumerate(by_mechanism.get(m.name, [])):
            cells = {"lines": lines if k == 0 else "″", "switch": m.switch if k == 0 else "″", "game": p.case.name}
            failed = [g.error for g in p.on + p.off if g.error]
            ok = not failed and all(c == 0 for g in p.on + p.off for c in g.codes.values())
            if failed:
                cells["gain"] = "FAILED: " + failed[0].splitlines()[0]
                errors += [f"{m.name}, {p.case.name}: {e}" for e in failed]
                rows.append(Row(m.name if k == 0 else "″", cells, ok=False))
                continue
            on, off = _summary(p.on), _summary(p.off)
            cells["tps"] = f"{_span(on['tps'], '.0f')} / {_span(off['tps'], '.0f')}"
            cells["lat"] = f"{_span(on['lat'], '.2f')} / {_span(off['lat'], '.2f')}"
            cells["cpu"] = f"{_span(on['cpu'], '.2f')} / {_span(off['cpu'], '.2f')}"
            cells["mem"] = f"{on['mem']} / {off['mem']}"
            turn = statistics.fmean(off["mean"]) / statistics.fmean(on["mean"])
            cpu_on, cpu_off = statistics.fmean(on["cpu"]), statistics.fmean(off["cpu"])
            # (CPU times come in clock ticks: a short game may have used less than one, on or off)
            cpu = f"{cpu_off / cpu_on:.2f}x" if cpu_on > 0 and cpu_off > 0 else "below the clock tick"
            cells["gain"] = f"turn {turn:.2f}x, CPU {cpu}"
            if m.off.ros2:  # the switch adds a viewer: the game must keep its speed
                keeps = 1 / turn
                cells["gain"] += f"; keeps {keeps:.0%} of its turns/s (target ≥ {ROS2_KEEPS:.0%})"
                ok = ok and (keeps >= ROS2_KEEPS or p.case.drones < 1000)  # (judged on the swarm it is for)
            if m.off.shared_memory:
                cells["gain"] += f", peak memory {off['hwm'] - on['hwm']:+.0f} MiB off (the three processes)"
            base = _states(p.on[0].statuses)
            same = all(_states(g.statuses) == base for g in p.on + p.off)
            cells["same"] = "yes" if same else "NO"
            if not same:
                errors.append(f"{m.name}, {p.case.name}: the games on and off differ")
            rows.append(Row(m.name if k == 0 else "″", cells, ok=ok and same))
    return rows, errors


def _states(statuses: dict) -> dict[int, object]:
    """Every drone's state after each turn, from the STATUS of each turn: what two plays of one game
    agree on (each coordinator draws its own game identity, which its STATUS carries)."""
    return {t: st.drones for t, st in statuses.items()}


def _summary(games: list[Game]) -> dict:
    means = [statistics.fmean(g.latencies) for g in games]
    mem = [[g.memory.get(n, {}).get("VmHWM", 0) / 1024 for n in ROLES] for g in games]
    peak = [max(col) for col in zip(*mem)]
    return {"mean": means, "tps": [1 / m for m in means], "lat": [statistics.median(g.latencies) * 1e3 for g in games],
            "cpu": [sum(g.cpu.values()) * 1e3 for g in games], "mem": ", ".join(f"{v:.0f}" for v in peak),
            "hwm": sum(peak)}


def _span(values: list[float], fmt: str) -> str:
    lo, hi = min(values), max(values)
    return format(lo, fmt) if format(lo, fmt) == format(hi, fmt) else f"{lo:{fmt}}–{hi:{fmt}}"


MECHANISMS_TITLE = "### The speed-ups that remain, each switched off beside on"


def mechanism_legend(repeat: int = MECHANISM_REPEAT) -> str:
    return (
        "Legend. Each mechanism that remains (docs/performance.md says what each does and why the game is the "
        "same). Lines of code: the lines that exist only for it, each counted once: the definitions named in "
        "`benchmarks/perf.py`'s MECHANISMS (a function, class or constant, docstring and comments included) and, "
        "where it is woven into shared code, the lines there that name it (a regex over the file), counted when "
        "the table is made. A mechanism with a switch is played with it on and off, alternated "
        f"({repeat} game{'s' if repeat > 1 else ''} each{': on, off, on, off' if repeat > 1 else ''}), in this run, "
        "on the same scenario as the game "
        "rows above (same warm-up and measured turns); each cell is the range over its games. CPU: user + "
        "system time of the coordinator, environment, drone processes, router and this process, summed, "
        "per measured turn. Peak: VmHWM, the largest over the games. Gain: off ÷ on of the mean turn and of "
        "the CPU per turn (above 1: the mechanism saves that); for shared memory, the peaks' sum off − on. "
        "Same game: every drone's state after every turn equal in all the games, on and off."
    )


# --------------------------------------------------------------------------- main


def cases(quick: bool, turns: int) -> list[Case]:
    if quick:
        return [Case(n, (10, 10, 10), 3, min(turns, 20)) for n in (1, 16, 128)]
    out = []
    for size in WORLDS:
        for n in DRONES:
            if n >= 1000:
                out.append(Case(n, size, 5, max(10, turns // 4)))
            else:
                out.append(Case(n, size, 10, turns))
    return out


#: Seconds POGEMA runs just before and just after each game (its anchor for that game's ratio).
ADJACENT_POGEMA_SECONDS = 1.0
#: Round trips (and warm-up) of the pub/sub floor measured just before and after each one-drone game.
ADJACENT_FLOOR = (300, 100)


@dataclass(slots=True)
class Adjacent:
    """The anchors measured just before and just after one game, so that its ratios compare measurements
    made within seconds of each other: the machine's speed drifts by up to 2x over a run, and a ratio
    to an anchor measured a minute earlier would measure the drift."""

    pogema: list[float] = field(default_factory=list)  # steps/s, with as many agents as the game has drones
    floor: list[float] = field(default_factory=list)  # pub/sub round trips (callback replies), seconds

    def measure(self, drones: int, *, with_pogema: bool, with_floor: bool, logs: Path) -> None:
        if with_pogema:
            try:
                self.pogema.append(pogema.steps_per_second([drones], ADJACENT_POGEMA_SECONDS)[drones])
            except pogema.Unavailable as exc:  # the POGEMA rows stand in
                print(f"note: POGEMA around the game not measured: {exc}", file=sys.stderr)
        if with_floor:
            try:
                self.floor += measure_floor(*ADJACENT_FLOOR, logs, pubsub=("cb",), query=())[0].rtts
            except Exception as exc:  # noqa: BLE001 - the pooled floor rows stand in
                print(f"note: round trips around the game not measured: {exc}", file=sys.stderr)

    @property
    def pogema_rate(self) -> float | None:
        return statistics.fmean(self.pogema) if self.pogema else None

    @property
    def floor_median(self) -> float | None:
        return statistics.median(self.floor) if self.floor else None


def run(args: argparse.Namespace) -> tuple[list[Row], dict]:
    """Everything selected by `args`; returns the table rows and facts for the legend."""
    only = re.compile(args.only) if args.only else None
    selected = lambda name: only is None or only.search(name) is not None  # noqa: E731
    logs = Path(tempfile.mkdtemp(prefix="dronesim-perf-"))
    facts: dict = {"logs": str(logs), "load_before": os.getloadavg(), "busy_before": busy_seconds()}
    rows: list[Row] = []
    t_start = time.perf_counter()

    # 1. the floor: half the round trips now, half at the end of the run (pooled: the machine drifts)
    want_floor = selected("floor: pub/sub round trip") or selected("floor: query round trip")
    rounds, warm = (150, 100) if args.quick else (max(1, args.rounds // 2), 300)
    floor_runs: list[list[Floor]] = []

    def floor_now() -> None:
        try:
            floor_runs.append(measure_floor(rounds, warm, logs))
        except Exception as exc:  # noqa: BLE001 - reported in the table
            rows.append(Row("floor", {"target": f"FAILED: {exc}"}, ok=False))

    if want_floor:
        floor_now()
    # (row, median turn, drones, the pub/sub RTT measured around it): "turn ÷ RTT" filled at the end
    ratio_cells: list[tuple[Row, float, int, float | None]] = []

    # the anchor: POGEMA in-process, same machine, same run
    pogema_rates: dict[int, float] = {}
    agents = sorted({c.drones for c in cases(args.quick, args.turns) if selected(c.name)}
                    | (set(DRONES) if selected("POGEMA in-process") else set()))
    if args.pogema and not args.quick and agents:
        try:
            pogema_rates = pogema.steps_per_second(agents)
        except pogema.Unavailable as exc:
            rows.append(Row("POGEMA", {"target": f"not measured: {exc}"}))
        for n, rate in pogema_rates.items():
            rows.append(Row(f"POGEMA in-process, {n} agent{'s' if n > 1 else ''} @ 64x64", {
                "array": _bytes_text(pogema.SIZE * pogema.SIZE), "tps": f"{rate:.1f}",
                "lat": f"{1e3 / rate:.3f} / -", "target": "anchor (random actions)"}))

    # 2-3. games
    baseline = python_baseline_kib()
    facts["baseline_kib"] = baseline
    per_turn: dict[tuple[int, tuple[int, int, int]], float] = {}
    lper_turn: dict[tuple[int, tuple[int, int, int]], float] = {}
    peaks: dict[tuple[str, int, tuple[int, int, int]], int] = {}  # (role, drones, world) -> VmHWM KiB
    for case in cases(args.quick, args.turns):
        if not selected(case.name):
            continue
        scen = make_scenario(case)
        if scen is None:
            rows.append(Row(case.name, {"array": _bytes_text(int(np.prod(case.size))),
                                        "target": f"skipped: {case.drones} drones do not fit "
                                                  f"({len(start_cells(case.size))} start cells)"}))
            continue
        path = logs / f"scenario-{case.drones}-{_size_text(case.size)}.json"
        path.write_text(json.dumps(scen), encoding="utf-8")
        case_logs = logs / f"{case.drones}-{_size_text(case.size)}"
        case_logs.mkdir()
        print(f"  {case.name}: distributed ...", file=sys.stderr, flush=True)
        adjacent = Adjacent()
        measure_around = functools.partial(adjacent.measure, case.drones, with_pogema=bool(pogema_rates),
                                           logs=case_logs, with_floor=want_floor and case.drones == 1)
        measure_around()
        t0 = time.perf_counter()
        game = play_distributed(case, path, case_logs, Path(args.profile) if args.profile else None)
        t1 = time.perf_counter()
        measure_around()
        print(f"  {case.name}: distributed {t1 - t0:.0f} s; in-process ...", file=sys.stderr, flush=True)
        local = play_local(case, path)
        print(f"  {case.name}: in-process {time.perf_counter() - t1:.0f} s", file=sys.stderr, flush=True)
        array = int(np.prod(case.size))
        cells: dict[str, str] = {"array": _bytes_text(array), "turns": f"{case.warmup} + {case.turns}"}
        codes = "/".join("?" if game.codes.get(n) is None else str(game.codes[n]) for n in ROLES)
        cells["codes"] = codes
        ok = not game.error and all(game.codes.get(n) == 0 for n in ROLES)
        lmean = statistics.fmean(local.latencies) if local.latencies else float("nan")
        lper_turn[(case.drones, case.size)] = lmean
        cells["ltps"] = f"{1 / lmean:.1f}"
        verdicts = []
        if game.error:
            cells["target"] = "FAILED: " + game.error.splitlines()[0]
            facts.setdefault("errors", []).append(f"{case.name}: {game.error}")
        else:
            mean = statistics.fmean(game.latencies)
            per_turn[(case.drones, case.size)] = mean
            med = statistics.median(game.latencies)
            cells["tps"] = f"{1 / mean:.1f}"
            cells["lat"] = f"{med * 1e3:.2f} / {_pct(game.latencies, 99) * 1e3:.2f}"
            cells["split"] = f"{statistics.median(game.answers) * 1e3:.2f}" if game.answers else "-"
            cells["cpu"] = " / ".join(f"{game.cpu.get(n, float('nan')) * 1e3:.1f}"
                                      for n in (*ROLES, "router", "bench"))
            cells["lratio"] = f"{mean / lmean:.1f}x" if lmean == lmean else "-"
            model = 2 * array + 1024 * case.drones + baseline * 1024
            for key, name in _MEMORY_ROLES:
                hwm = game.memory.get(name, {}).get("VmHWM")
                cells[key] = "-" if hwm is None else f"{hwm / 1024:.1f} ({hwm * 1024 / model:.2f})"
                if hwm is not None:
                    peaks[(name, case.drones, case.size)] = hwm
            cells["swarm"] = _mib(game.memory.get("swarm", {}).get("VmHWM"))
            ours, theirs = _states(game.statuses), _states(local.statuses)
            differ = sorted(t for t in set(ours) | set(theirs) if ours.get(t) != theirs.get(t))
            same = "yes" if not differ else f"NO (from turn {differ[0]})"
            if differ:
                t = differ[0]
                a, b = game.statuses.get(t), local.statuses.get(t)
                diff = [f"{x} != {y}" for x, y in zip(getattr(a, "drones", ()), getattr(b, "drones", ())) if x != y]
                facts.setdefault("errors", []).append(f"{case.name}: STATUS({t}) differs from the in-process run: "
                                                      + "; ".join(diff[:5]))
            cells["alive"] = f"{game.alive}/{case.drones}, {local.moving:.1f} moving per turn, {same}"
            cells["pogema"], against = versus_pogema(1 / mean, adjacent.pogema_rate or pogema_rates.get(case.drones),
                                                     case.drones)
            if case.drones == 128:
                verdicts.append(_verdict(1 / mean, TARGETS["tps128"], False, f"≥ {TARGETS['tps128']:g} turns/s"))
            verdicts += against
            if case.drones == 1000:
                verdicts.append(_verdict(1 / mean, TARGETS["tps1000"], False, f"≥ {TARGETS['tps1000']:g} turns/s"))
                small = per_turn.get((128, case.size))
                lsmall = lper_turn.get((128, case.size))
                growth = []
                if small:
                    growth.append(f"{(mean / small) / (1000 / 128):.2f}")
                if lsmall:
                    growth.append(f"in-process {(lmean / lsmall) / (1000 / 128):.2f}")
                cells["growth"] = ", ".join(growth) or "-"
            cells["target"] = "; ".join(verdicts) if verdicts else "—"
        rows.append(Row(case.name, cells, ok=ok))
        if not game.error:
            ratio_cells.append((rows[-1], statistics.median(game.latencies), case.drones, adjacent.floor_median))

    rows += memory_growth(peaks)

    # the mechanisms that remain, each switched off beside on (MECHANISMS)
    pairs = play_mechanisms(selected, args.quick, args.turns, logs)
    facts["mechanisms"], errors = mechanism_rows(pairs, selected)
    facts.setdefault("errors", []).extend(errors)

    # 5. world generation
    gen_size = (64, 64, 16) if args.quick else GEN_SIZE
    name = f"world generation {_size_text(gen_size)}"
    if selected(name):
        times = world_generation(gen_size, 2 if args.quick else 3)
        rows.append(Row(name, {"array": _bytes_text(int(np.prod(gen_size))),
                               "turns": f"{len(times)} runs",
                               "lat": f"{statistics.median(times) * 1e3:.0f} / {max(times) * 1e3:.0f}",
                               "target": "in-process, seed 3"}))
    # 6. the MAVLink ground station's CPU per turn, 100 vehicles streaming (benchmarks/mavlink.py)
    name = "MAVLink ground station, 100 vehicles"
    if selected(name):
        rows.append(mavlink_row(name, turns=50 if args.quick else 300))
    # 1 (end). the second half of the floor, the floor rows first in the table, the ratios to it
    if want_floor and floor_runs:
        floor_now()
    floors = [Floor(f.name, [r for run_ in floor_runs for r in run_[i].rtts],
                    tuple(statistics.fmean(run_[i].cpu[k] for run_ in floor_runs) for k in (0, 1)),  # type: ignore[arg-type]
                    max((run_[i].exit_code or 0 for run_ in floor_runs), default=None))
              for i, f in enumerate(floor_runs[0])] if floor_runs else []
    floor_rows = []
    for i, f in enumerate(floors):
        if not selected(f.name):
            continue
        halves = ", ".join(f"{statistics.median(run_[i].rtts) * 1e3:.3f}" for run_ in floor_runs)
        floor_rows.append(Row(f.name, {
            "turns": f"{len(f.rtts)} round trips (median of each half: {halves})",
            "tps": f"{1 / statistics.fmean(f.rtts):.0f}/s",
            "lat": f"{f.median * 1e3:.3f} / {_pct(f.rtts, 99) * 1e3:.3f}",
            "cpu": f"helper {f.cpu[0] * 1e3:.3f} / this process {f.cpu[1] * 1e3:.3f}",
            "codes": f"helper {f.exit_code}",
        }, ok=f.exit_code == 0))
    rows[:0] = floor_rows
    pubsub = floors[0].median if floors else float("nan")
    facts["pubsub"] = pubsub
    for row, med, drones, near in ratio_cells:
        ratio = med / (near or pubsub)
        row.cells["floor"] = f"{ratio:.1f}" if ratio == ratio else "-"
        if drones == 1:
            verdict = _verdict(ratio, TARGETS["latency"], True, f"≤ {TARGETS['latency']:g}x RTT")
            before = row.cells.get("target", "—")
            row.cells["target"] = verdict if before == "—" else f"{verdict}; {before}"
    facts["seconds"] = time.perf_counter() - t_start
    facts["load_after"] = os.getloadavg()
    (t0, m0), (t1, m1) = facts["busy_before"], busy_seconds()
    facts["others"] = max(0.0, (t1 - t0) - (m1 - m0)) / max(facts["seconds"], 1e-9)  # cores used by other work
    return rows, facts


def mavlink_row(name: str, turns: int) -> Row:
    """The bridge's CPU per turn (benchmarks/mavlink.py); without pymavlink (the mavlink extra), not measured."""
    try:
        from .mavlink import TARGET_TPS, bridge_cpu

        r = bridge_cpu(100, turns)
    except ImportError as exc:
        return Row(name, {"target": f"not measured: {exc}"})
    tps = 1 / r["cpu"]
    return Row(name, {"turns": f"20 + {turns:.0f} in-process, {r['messages']:.0f} MAVLink messages "
                               f"in {r['datagrams']:.0f} datagrams a turn",
                      "tps": f"{tps:.0f}/s (CPU-bound)", "cpu": f"ground station {r['cpu'] * 1e3:.2f}",
                      "target": _verdict(tps, TARGET_TPS, False, f"≥ {TARGET_TPS:g} turns/s")})


def legend(facts: dict) -> str:
    base = facts.get("baseline_kib", 0) / 1024
    return (
        "Legend. The MAVLink row: benchmarks/mavlink.py (the bridge in this process, 100 vehicles flying, every "
        "message encoded and sent; CPU a turn, and the turn rate that CPU allows). "
        "Floor rows: round trips between this process and a helper process through the router, 16-byte "
        "payloads, BLOCK congestion control, after a warm-up, half of them at the start of the run and half at "
        "the end (\"callback replies\": the helper answers from "
        "Zenoh's callback thread, the bare floor; "
        "\"main thread replies\": it hands each message to its main thread first, as every process of a game does); "
        "their ms column is the round trip, their CPU column the CPU time per round trip of the helper and of this "
        "process (the router is a process of its own). Game rows: coordinator, environment and "
        "one swarm host (seed autopilot, every drone) are separate processes (coordinator with --phase-deadline "
        f"{PHASE_DEADLINE:g}), this process is the ground "
        "station (as the scripted GCS: the targets that change, and the next turn's DONE ahead when its plan "
        "has nothing new for it); a turn is the time between "
        "two consecutive STATUS arrivals (STATUS(t - 1) begins turn t), turns/s = 1 / mean, p99 over the "
        "measured turns. The ground "
        "station's answer: from TURN(GCS) arriving to its DONE sent, when not answered ahead. CPU: user + system time "
        "of each process (all threads) over the measured turns ÷ turns. In-process: `dronesim.local.simulate` on the "
        "same scenario and layout (one swarm host, one MOVES a turn), timed at the same point; "
        "\"in-process ÷ distributed\" = distributed mean turn ÷ in-process mean turn. \"turn ÷ pub/sub RTT\" = "
        "median turn ÷ median pub/sub round trip (callback replies), the round trips measured just before and just "
        f"after that game ({ADJACENT_FLOOR[0]} each, for the one-drone games; the pooled floor rows for the others): "
        "the "
        "machine's speed drifts by up to 2x over a run, and both sides of a ratio are measured within seconds of "
        "each other. Growth (1000-drone rows) = (mean turn at "
        "1000 ÷ mean turn at 128, same world) ÷ (1000 ÷ 128): 1.00 is linear in N, above is worse than "
        "linear. POGEMA rows: the anchor of the issue, POGEMA "
        f"{pogema.VERSION} in its own virtual environment on this machine in this run: a {pogema.SIZE}x{pogema.SIZE} "
        f"grid, obstacle density {pogema.DENSITY:g}, observation radius {pogema.OBS_RADIUS}, every agent a random "
        "action every step, agents staying on the grid at their targets, 2 s per agent count after 20 warm-up "
        "steps; \"turns/s ÷ POGEMA's\" compares a game row with POGEMA at the same number of agents (POGEMA in "
        f"one process, ours across processes and a router), POGEMA run for {ADJACENT_POGEMA_SECONDS:g} s just before "
        "and just after that game (the mean of the two; the POGEMA rows, measured at the start, when that fails). "
        "Memory: VmHWM (peak resident set) sampled just before the ground station quits. The target is "
        "checked as growth, by the \"memory per\" rows: per drone = (VmHWM with 1000 drones − VmHWM with 128, same "
        "world) ÷ 872, two swarms running the same code (a game of a few drones takes the small-size paths and "
        "never touches the array code a swarm runs, so the first swarm costs a process a few hundred KiB once, "
        "library code pages and allocator arenas: the \"from 1 drone\" rows show the slope with that step "
        "in, for reference); per world byte = (VmHWM on the largest world − on the smallest, 1 drone) ÷ the difference "
        "of their arrays (nx·ny·nz, one bool per cell). A game row's ratio = VmHWM ÷ (2 × world array bytes + "
        f"1 KiB × N + {base:.0f} MiB), the last being the VmHWM of an idle entity process (the coordinator, "
        "environment and drone modules imported, numpy's random generators loaded as every world build loads "
        "them, a Zenoh client session on the router that has sent and received 500 small messages); a running "
        "process's peak differs from run to run by a few hundred KiB (code pages first touched, allocator "
        "arenas), which decides ratios near 1.00 but not the slopes over megabytes. Alive at end: drones alive in the "
        "last STATUS (seed drones do not avoid each other); "
        "moving per turn: drones that moved, mean over the measured turns (in-process journal); \"same game\": "
        "every STATUS's drones equal the in-process one's. Exit codes: coordinator/environment/swarm "
        "host (floor rows: the helper)."
    )


def write_section(path: Path, body: str) -> None:
    """Replace (or append) this benchmark's section of `path`, leaving the others alone."""
    replace_section(path, SECTION, body)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dronesim bench perf", description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="a tiny subset (for tests): 10x10x10, 20 turns")
    parser.add_argument("--turns", type=int, default=600,
                        help="measured turns per case (default 600; 1000-drone cases: a quarter, at least 10)")
    parser.add_argument("--rounds", type=int, default=2000, help="round trips per floor measurement (default 2000)")
    parser.add_argument("--only", metavar="PATTERN", help="only rows whose name matches this regex, e.g. '128|floor'")
    parser.add_argument("--profile", metavar="DIR", help="py-spy record every entity process into DIR (raw stacks)")
    parser.add_argument("--no-pogema", dest="pogema", action="store_false",
                        help="do not measure the POGEMA anchor (it installs POGEMA into a cached virtual "
                             "environment the first time; --quick never measures it)")
    parser.add_argument("--keep-logs", action="store_true",
                        help="keep the processes' logs and the scenario files (kept anyway when something failed)")
    add_write_args(parser)
    args = parser.parse_args(argv)
    if args.turns < 1 or args.rounds < 1:
        parser.error("--turns and --rounds must be >= 1")

    mach = machine()
    rows, facts = run(args)
    table = render(rows)
    mechanisms = render(facts["mechanisms"], MECHANISM_COLUMNS) if facts["mechanisms"] else ""
    repeat = 1 if args.quick else MECHANISM_REPEAT
    print()
    print(table)
    print()
    print(legend(facts))
    if mechanisms:
        print(f"\n{MECHANISMS_TITLE}\n\n{mechanisms}\n\n{mechanism_legend(repeat)}")
    for err in facts.get("errors", []):
        print(f"\n{err}", file=sys.stderr)
    failed = [r.name for r in [*rows, *facts["mechanisms"]] if not r.ok]
    for name in failed:
        print(f"not ok: {name} (a process exited non-zero, a game failed or differs: its logs are kept)",
              file=sys.stderr)
    ok = not failed
    if ok and not args.keep_logs:
        shutil.rmtree(facts["logs"], ignore_errors=True)
        where = "removed (--keep-logs keeps them)"
    else:
        where = facts["logs"]
    print(f"\nlogs and scenarios: {where}; {facts['seconds']:.0f} s; other processes used "
          f"{facts['others']:.2f} cores on average during the run", file=sys.stderr)
    if args.write:
        cmd = "dronesim bench perf " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
        lb, others = facts["load_before"], facts["others"]
        body = (
            f"Command: `{cmd.strip()}`, run {_dt.date.today().isoformat()} on {mach['cpu']} ({mach['arch']}, "
            f"nproc = {mach['nproc']}), Python {mach['python']}, eclipse-zenoh {mach['zenoh']}, "
            f"{facts['seconds']:.0f} s in all. Load average (1 min) before the run {lb[0]:.2f}; other processes "
            f"used {others:.2f} cores on average during the run"
            + (" (other work ran alongside: absolute numbers are pessimistic)." if others > 0.2 else ".")
            + "\n\nTargets (issue \"Performance: turn latency near the Zenoh floor, scale to 1000 drones\"): "
            "1-drone turn ≤ 4 × pub/sub round trip (checked on every 1-drone row), ≥ 200 turns/s at 128 drones "
            "and ≥ 25 % of POGEMA's in-process speed at 128 agents (measured in the same run), "
            "≥ 20 turns/s at 1000 drones, coordinator and environment memory ≤ 2 × the world array + 1 KiB per "
            "drone above what the process costs anyway (checked as growth: the \"memory per\" rows). Where the time "
            "goes: `dronesim bench perf --only '128 drones @ 64' "
            "--profile DIR` writes py-spy stacks of every process; the CPU column splits a turn by process.\n\n"
            f"{table}\n\n{legend(facts)}\n"
            + (f"\n{MECHANISMS_TITLE}\n\n{mechanisms}\n\n{mechanism_legend(repeat)}\n" if mechanisms else "")
        )
        write_section(args.output, body)
        print(f"\nwrote {SECTION!r} in {args.output}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
