"""Games as `dronesim bench perf` plays them (and the benchmarks built on it: floods, swarm cities, the export):
the scenarios (`Case`, `make_scenario`), a game through real processes on a loopback router with this process as
the ground station (`play_distributed`, in the ways `Variant` says), and the same game in-process (`play_local`).
The scenarios and the timing point are described in benchmarks/perf.py's docstring."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import signal
import statistics
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from benchmarks.measure import Procs, await_presence, cpu_seconds, loopback_router, proc_status, size_text
from coordinator.journal import is_turn
from network.transport import client_config
from schema.tuning import ANSWER_AHEAD, COORDINATOR_GRACE_S

WORLD_SEED = 3


PHASE_DEADLINE = 60.0  # seconds: a benchmark measures, it does not test deadlines
JOIN_S = 120.0  # seconds an entity (or the viewer) of a benchmark's game has to join it: a loaded machine starts slowly


EVENT_TIMEOUT = 180.0  # seconds without any event from the game before the run is declared stalled


@dataclass(slots=True)
class Case:
    drones: int
    size: tuple[int, int, int]
    warmup: int
    turns: int  # measured
    moving: bool = False  # the drones get new targets leg after leg until the end (else, on a big swarm, they stay
    # at their last target once every floor is flown: see make_scenario)
    autopilot: str = "seed"  # every drone's (seed drones may crash into each other: a game may end early)

    @property
    def name(self) -> str:
        return f"{self.drones} drone{'s' if self.drones > 1 else ''} @ {size_text(self.size)}"

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
    while t <= case.end_turn and (n == 1 or case.moving or len(switches) < max(1, nz - 1)):  # else every floor flown
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
            "drones": [{"id": drone_id(i + 1), "start": list(s), "autopilot": case.autopilot}
                       for i, s in enumerate(starts)],
            "targets": targets, "max_turns": case.end_turn + 10}


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
    ros_user: str = ""  # with `Variant.ros2`: what its ROS 2 user received (benchmarks/ros_user.py's last line)
    windows: list[Window] = field(default_factory=list)  # with `Variant.ros2_windows`: each window measured
    resent: dict[str, int] = field(default_factory=dict)  # the station's DONEs sent again (`Station.resent`)


ROLES = ("coordinator", "env", "swarm")


@dataclass(frozen=True, slots=True)
class Windows:
    """The ROS 2 viewer attached and detached in turn within one game (`entities.ros2.node.DETACH`/`ATTACH`, sent
    by this process as a STATUS closes a window): `quads` groups of four windows of `turns` turns each, attached,
    detached, detached, attached (ABBA: a drift of the machine's speed over a group weighs on both alike), the first
    `settle` turns of each not measured (the viewer finishing or starting a turn's publishing). They begin after
    the warm-up, once the viewer has published `published` turns (its start, its publishers declared, is over)."""

    turns: int
    quads: int
    settle: int
    published: int = 3

    @property
    def count(self) -> int:
        return 4 * self.quads

    @staticmethod
    def attached(i: int) -> bool:
        return i % 4 in (0, 3)

    @property
    def span(self) -> int:
        """Turns of the windows, all told."""
        return self.count * self.turns


@dataclass(frozen=True, slots=True)
class Window:
    """One window measured: the viewer attached or not, its turns (settling ones excluded), their seconds and the
    CPU seconds of every process of the game in them (`by` process: the game's, the router, this one, the viewer
    "ros2" and its user "rosuser")."""

    attached: bool
    turns: int
    seconds: float
    by: dict[str, float]

    @property
    def cpu(self) -> float:
        return sum(self.by.values())


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
    ros2: bool = False  # a `dronesim ros2` viewer publishes the game to ROS 2 beside it, to a ROS 2 user process
    # subscribed to every topic (benchmarks/ros_user.py)
    ros2_windows: Windows | None = None  # with `ros2`: the viewer attached and detached in windows of the game


def play_distributed(case: Case, scenario_file: Path, logs: Path, profile: Path | None = None,
                     variant: Variant = Variant(), *, on_status: Callable[[str, Any, int], None] | None = None) -> Game:
    """One game over a loopback router with this process as the ground station; see benchmarks/perf.py's docstring.
    `variant`: how it is played (with `per_drone`, the swarm's CPU is that of every drone process summed,
    its memory the peak of the largest). `on_status(locator, keys, turn)`, if given, is called on each STATUS
    as it arrives (e.g. to start a flood at a given turn: `benchmarks/flood.py`); the game waits for it."""
    from schema import Keys, drone_id

    keys = Keys(f"perf{uuid.uuid4().hex[:8]}")
    game, procs = Game(), Procs(logs)
    spies: list[subprocess.Popen] = []
    router_config, config = shared_memory_configs(logs) if variant.shared_memory else (None, None)
    secured = variant.secured
    if secured is not None and (variant.per_drone or variant.hosts > 1):
        raise ValueError("a secured game is flown by one swarm host")
    router_flags = [] if secured is None else secured.router_flags(
        keys.root, [drone_id(n) for n in range(1, case.drones + 1)], "H01")
    measured_to: list[int] = []  # the turn whose GCS phase ended the measure (the game's end, if sooner)
    stamps: dict[tuple[str, int], float] = {}
    try:
        with loopback_router(router_config, scheme="tcp" if secured is None else "tls", flags=router_flags) as router:
            _launch(procs, case, scenario_file, logs, variant, router.locator, keys.root, config)
            conf = client_config(router.locator) if secured is None else secured.session(router.locator, "GCS")
            if config is not None:
                conf.insert_json5("transport/shared_memory/enabled", "true")
            with zenoh.open(conf) as session:
                if profile is not None:
                    spies = _spy(procs, profile, case)
                pids: dict[str, int | str] = {name: proc.pid for name, proc in procs.procs.items()}
                watch = _Watch(game, case, variant, procs, pids | {"router": router.pid, "bench": "self"},
                               partial(on_status, router.locator, keys) if on_status is not None else None)
                watch.play(session, keys, scenario_file)
                stamps, measured_to = watch.stamps, watch.measured_to
            game.codes = procs.wait(60.0)
            if variant.ros2:
                game.ros_user = procs.tail("rosuser", 1).removeprefix("ros user: ")
    except Exception as exc:  # noqa: BLE001 - reported in the table, the run goes on
        game.error = f"{type(exc).__name__}: {exc}"
        game.codes = {n: p.poll() for n, p in procs.procs.items()}
    finally:
        procs.close()
        _unspy(spies)
    if variant.per_drone:
        _as_one_swarm(game)
    if game.error:
        for n in [r for r in procs.procs if r in ROLES or r.startswith("swarm")]:
            game.error += f"\n--- {n} ({logs / (n + '.log')}):\n{procs.tail(n)}"
        return game
    _timed(game, case, stamps, measured_to)
    return game


def _launch(procs: Procs, case: Case, scenario_file: Path, logs: Path, variant: Variant, loc: str, root: str,
            config: Path | None) -> None:
    """The game's processes: the coordinator, the environment, the drones' (one swarm host, several, or one
    process per drone) and, with `variant.ros2`, a ROS 2 viewer."""
    from schema import drone_id

    creds = variant.secured.flags if variant.secured is not None else (lambda _entity: [])
    base = [sys.executable, "-m", "dronesim"]
    common = ["--mode", "client", "--connect", loc, "--root", root]
    common += [] if config is None else ["--config", str(config)]
    journal = ["--journal", str(logs / "journal.jsonl")] if variant.journal else []
    procs.start("coordinator", [*base, "coordinator", *common, "--scenario", str(scenario_file),
                                "--phase-deadline", str(PHASE_DEADLINE), *journal, *creds("SRV")])
    procs.start("env", [*base, "env", *common, "--no-draw", "--connect-timeout", f"{JOIN_S:g}", *creds("ENV"),
                        *["--follow-status"] * variant.env_follows])
    flying = [*base, "drone", *common, "--autopilot", variant.autopilot, "--connect-timeout", f"{JOIN_S:g}"]
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
        ids = "D01" if case.drones == 1 else f"D01-{drone_id(case.drones)}"
        procs.start("swarm", [*flying, "--id", ids, "--host", "H01", *creds("H01")])
    if variant.ros2:  # an observer: it hears STATUS and OVER, publishes to ROS 2 at its own rate, to a ROS 2 user
        procs.start("rosuser", [sys.executable, "-m", "benchmarks.ros_user", "--connect", loc])
        procs.start("ros2", [*base, "ros2", *common, "--log-level", "WARNING"])


class _Watch:
    """This process as the game's ground station (the scripted station's core, quitting after the measure), timing
    the turns: each STATUS's, TURN(GCS)'s and DONE's arrival or sending (`stamps`), the processes' CPU and memory
    over the measured turns, `measured_to` the turn whose GCS phase ended the measure."""

    def __init__(self, game: Game, case: Case, variant: Variant, procs: Procs, pids: dict[str, int | str],
                 on_status: Callable[[int], None] | None) -> None:
        self.game, self.case, self.variant, self.procs, self.pids, self.on_status = \
            game, case, variant, procs, pids, on_status
        self.stamps: dict[tuple[str, int], float] = {}
        self.measured_to: list[int] = []
        self.clocks = [0]  # /clock samples heard (with `ros2_windows`; Zenoh's thread counts)
        self.window: tuple[int, float, dict[str, float]] | None = None  # the open window's first turn, time, CPU
        self.opened = -1  # the turn whose STATUS opened the window `len(game.windows)`

    def play(self, session: zenoh.Session, keys: Any, scenario_file: Path) -> None:
        import logging

        from dronesim.scenario import Scenario
        from entities.gcs import End, Ground, SendDone, Station
        from entities.station_link import join, listen, publisher
        from network.transport import Outbox, Received
        from schema import Turn
        from schema.keys import RosKeys

        log = logging.getLogger("dronesim.bench.gcs")
        if self.variant.upd_listener:  # the environment then follows the ENV phase and reports it
            session.declare_subscriber(keys.upd, lambda _sample: None)
        if self.variant.ros2:  # (its ROS 2 user, a process of its own as RViz is, subscribes to every topic)
            from entities.ros2.node import NODE

            # the viewer's node token comes once it hears OVER: a game played before would leave it waiting
            if not await_presence(session, RosKeys().node_tokens(NODE), JOIN_S):
                raise RuntimeError(f"the ROS 2 viewer did not appear within {JOIN_S:g} s")
            if self.variant.ros2_windows is not None:  # (one a turn it publishes: when its start is over)
                session.declare_subscriber(f"{RosKeys().domain}/clock/**", lambda _s: self.clocks.__setitem__(
                    0, self.clocks[0] + 1))
        inbox = listen(session, keys, log)
        member = join(session, inbox, log, connect_timeout=JOIN_S, grace=COORDINATOR_GRACE_S)
        station = Station(Ground.from_welcome(member.welcome, Scenario.load(scenario_file).targets, None),
                          quit_at=self.case.end_turn, ahead=self.variant.ahead)
        send, idle_since, end = publisher(Outbox(session), keys, log, print), time.monotonic(), None
        while end is None:
            due = station.wake(time.monotonic())  # (its DONEs go out paced)
            event = inbox.get(1.0 if due is None else min(1.0, due))
            if event is None:
                self.idle(idle_since)
            else:
                idle_since = time.monotonic()
            for effect in self.effects(event, member, station):
                send(effect)
                if (isinstance(effect, SendDone) and isinstance(event, Received) and isinstance(event.msg, Turn)
                        and effect.msg.turn == event.msg.turn):
                    self.stamps[("DONE", effect.msg.turn)] = time.perf_counter()  # not answered ahead
                elif isinstance(effect, End):
                    end = effect
                    if not self.measured_to and self.case.warmup in self.game.statuses:  # over before its end
                        self.measured(max(self.game.statuses) + 1)
        self.game.over = f"{end.over.reason.value} at turn {end.over.turn}"
        self.game.resent = dict(station.resent)
        member.close()

    def idle(self, since: float) -> None:
        if self.procs.dead():
            raise RuntimeError("a process ended during the game: " + ", ".join(self.procs.dead()))
        if time.monotonic() - since > EVENT_TIMEOUT:
            raise RuntimeError(f"the game stalled: no event for {EVENT_TIMEOUT:g} s")

    def effects(self, event: object, member: Any, station: Any) -> list:
        """The station's effects of `event` (and of its clock), the event timed."""
        from network.membership import Answered
        from network.transport import Presence, Received
        from schema import Status, Turn

        now, game, effects = time.perf_counter(), self.game, []
        match event:
            case Presence() | Answered():
                if (welcome := member.on_event(event)) is not None:
                    effects = station.admitted(welcome)
            case Received(_, Status() as st):
                self.stamps[("STATUS", st.turn)] = now  # turn st.turn + 1 begins
                game.last_status = st
                game.statuses[st.turn] = st if self.variant.statuses else None
                game.arrived[st.turn] = time.monotonic()  # before on_status, which may start a flood
                if self.variant.ros2_windows is not None:
                    self.windows(self.variant.ros2_windows, st.turn, now, station)
                if self.on_status is not None:
                    self.on_status(st.turn)
                if st.turn == self.case.warmup:  # CPU time over the measured turns: from here...
                    game.cpu = {n: cpu_seconds(pid) for n, pid in self.pids.items()}
            case Received(_, Turn() as turn):
                self.stamps[("GCS", turn.turn)] = now
                if turn.turn >= self.case.end_turn and not self.measured_to:  # ... to here
                    if self.variant.ros2_windows is not None:
                        raise RuntimeError(f"the viewer's windows did not end by turn {self.case.end_turn}")
                    self.measured(self.case.end_turn)
        if isinstance(event, Received):
            effects = station.receive(event.msg, time.monotonic())
        return [*effects, *station.tick(time.monotonic())]

    def windows(self, w: Windows, turn: int, now: float, station: Any) -> None:
        """At the STATUS of `turn`: the windows' bounds (see `Windows`), the viewer told to detach or attach."""
        import os

        from entities.ros2.node import ATTACH, DETACH

        game, done = self.game, len(self.game.windows)
        if done == w.count or turn < self.case.warmup:
            return
        cpu = {name: cpu_seconds(pid) for name, pid in self.pids.items()}
        if self.opened < 0:  # (the viewer starts attached, as the first window is)
            if self.clocks[0] >= w.published:
                self.opened = turn
            return
        if self.window is None and turn >= self.opened + w.settle:
            self.window = (turn, now, cpu)
        elif self.window is not None and turn >= self.opened + w.turns:
            first, since, cpu0 = self.window
            game.windows.append(Window(w.attached(done), turn - first, now - since,
                                       {n: cpu[n] - cpu0[n] for n in cpu}))
            self.window, self.opened, done = None, turn, done + 1
            if done == w.count:  # the game ends here
                station.quit_at = turn + 1
                self.measured(turn + 1)
            elif w.attached(done) != w.attached(done - 1):
                signum = ATTACH if w.attached(done) else DETACH
                assert signum is not None, "the viewer's windows need POSIX signals"
                os.kill(int(self.pids["ros2"]), signum)

    def measured(self, turn: int) -> None:
        game = self.game
        game.cpu = {n: cpu_seconds(pid) - game.cpu.get(n, 0.0) for n, pid in self.pids.items()}
        for name, proc in self.procs.procs.items():
            game.memory[name] = proc_status(proc.pid)
        self.measured_to.append(turn)


def _timed(game: Game, case: Case, stamps: dict[tuple[str, int], float], measured_to: list[int]) -> None:
    """The game's turns (consecutive STATUS arrivals), answers and CPU per turn over the measured turns."""
    first, last = case.warmup + 1, measured_to[0] if measured_to else case.end_turn
    begins = [stamps.get(("STATUS", t - 1)) for t in range(first, last + 1)]  # STATUS(t - 1): turn t begins
    if None in begins:
        game.error = "missing STATUS"
        return
    game.latencies = [b - a for a, b in zip(begins, begins[1:])]  # type: ignore[operator]
    game.answers = [stamps[("DONE", t)] - stamps[("GCS", t)] for t in range(first, last) if ("DONE", t) in stamps]
    game.cpu = {n: v / (last - first) for n, v in game.cpu.items()}
    game.alive = len(game.last_status.drones.alive()) if game.last_status else 0  # type: ignore[attr-defined]


def _unspy(spies: list[subprocess.Popen]) -> None:
    if spies:
        spies[-1].send_signal(signal.SIGINT)  # this process's py-spy: it writes its output on SIGINT
    for spy in spies:
        with contextlib.suppress(subprocess.TimeoutExpired):
            spy.wait(30)
        if spy.poll() is None:
            spy.kill()


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
    tag = f"{case.drones}-{size_text(case.size)}"
    pids = {n: p.pid for n, p in procs.procs.items()} | {"bench": os.getpid()}
    return [subprocess.Popen([exe, "record", "--pid", str(pid), "--rate", "250", "--format", "raw",
                              "--output", str(out / f"{tag}-{n}.txt"), "--nonblocking"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for n, pid in pids.items()]


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
                if is_turn(r) and case.warmup < r.get("turn", 0) < case.end_turn]
    moving = statistics.fmean(len(r.get("moves", {})) for r in measured) if measured else 0.0
    return Local([b - a for a, b in zip(ts, ts[1:])], {st.turn: st for st in res.statuses}, moving)


def states_of(statuses: dict) -> dict[int, object]:
    """Every drone's state after each turn, from the STATUS of each turn: what two plays of one game
    agree on (each coordinator draws its own game identity, which its STATUS carries)."""
    return {t: st.drones for t, st in statuses.items()}
