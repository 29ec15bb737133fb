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
import datetime as _dt
import functools
import json
import os
import re
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks import add_write_args, pogema, replace_section
from benchmarks.floor import Floor, measure_floor
from benchmarks.games import (
    PHASE_DEADLINE,
    ROLES,
    WORLD_SEED,
    Case,
    Game,
    Local,
    make_scenario,
    play_distributed,
    play_local,
    start_cells,
    states_of,
)
from benchmarks.measure import (
    Row,
    busy_seconds,
    bytes_text,
    loopback_router,
    machine,
    mib,
    pct,
    render,
    size_text,
    verdict,
)
from benchmarks.mechanisms import (
    MECHANISM_COLUMNS,
    MECHANISM_REPEAT,
    MECHANISMS_TITLE,
    mechanism_legend,
    mechanism_rows,
    play_mechanisms,
)

SECTION = "## Performance"


WORLDS: tuple[tuple[int, int, int], ...] = ((10, 10, 10), (64, 64, 16), (256, 256, 32))


DRONES: tuple[int, ...] = (1, 16, 128, 1000)


GEN_SIZE = (512, 512, 64)


TARGETS = {"latency": 4.0, "tps128": 200.0, "pogema128": 0.25, "tps1000": 20.0, "kib_per_drone": 1.0,
           "per_world_byte": 2.0}


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
            rows.append(_slope_row(f"memory per drone (128 → 1000 drones @ {size_text(size)})", slopes,
                                   "KiB/drone", TARGETS["kib_per_drone"],
                                   f"≤ {TARGETS['kib_per_drone']:g} KiB per drone"))
        slopes = _slopes(peaks, (1, size), (1000, size), 999)
        if slopes:
            rows.append(_slope_row(f"memory per drone from 1 drone (1 → 1000 drones @ {size_text(size)})", slopes,
                                   "KiB/drone", None, "— (includes the first swarm's one-time cost: see the legend)"))
    small, large = WORLDS[0], WORLDS[-1]
    grown = int(np.prod(large)) - int(np.prod(small))
    slopes = _slopes(peaks, (1, small), (1, large), grown / 1024)  # bytes per world byte
    if slopes:
        row = _slope_row(f"memory per world byte (1 drone, {size_text(small)} → {size_text(large)})", slopes,
                         "bytes/byte", TARGETS["per_world_byte"], f"≤ {TARGETS['per_world_byte']:g} × the world array")
        row.cells["array"] = f"+{bytes_text(grown)}"
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
    cells["target"] = what if target is None else verdict(max(slopes.values()), target, True, what)
    return Row(name, cells)


def versus_pogema(rate: float, anchor: float | None, drones: int) -> tuple[str, list[str]]:
    """A game row's turns/s against POGEMA's steps/s with as many agents: the cell, and the verdict
    where the issue sets a target (128 drones: at least 25 %)."""
    if not anchor:
        return "-", []
    ratio = rate / anchor
    verdicts = [verdict(ratio, TARGETS["pogema128"], False, f"≥ {TARGETS['pogema128']:.0%} of POGEMA's "
                                                            f"{anchor:.0f} steps/s")] if drones == 128 else []
    return f"{ratio:.0%}", verdicts


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
    return Run(args).everything()


class Run:
    """One run of the benchmark (`run`): its table's rows, and the facts its legend gives."""

    def __init__(self, args: argparse.Namespace) -> None:
        only = re.compile(args.only) if args.only else None
        self.args, self.selected = args, lambda name: only is None or only.search(name) is not None
        self.logs = Path(tempfile.mkdtemp(prefix="dronesim-perf-"))
        self.facts: dict = {"logs": str(self.logs), "load_before": os.getloadavg(), "busy_before": busy_seconds()}
        self.rows: list[Row] = []
        self.floor_runs: list[list[Floor]] = []  # the floor, half its round trips first, half last (pooled)
        self.want_floor = self.selected("floor: pub/sub round trip") or self.selected("floor: query round trip")
        # (row, median turn, drones, the pub/sub RTT measured around it): "turn ÷ RTT" filled at the end
        self.ratio_cells: list[tuple[Row, float, int, float | None]] = []
        self.pogema_rates: dict[int, float] = {}
        self.per_turn: dict[tuple[int, tuple[int, int, int]], float] = {}  # mean turn, distributed
        self.lper_turn: dict[tuple[int, tuple[int, int, int]], float] = {}  # ... in-process
        self.peaks: dict[tuple[str, int, tuple[int, int, int]], int] = {}  # (role, drones, world) -> VmHWM KiB

    def everything(self) -> tuple[list[Row], dict]:
        args, t_start = self.args, time.perf_counter()
        if self.want_floor:  # 1. the floor (half now)
            self.floor_now()
        self.anchor()
        self.facts["baseline_kib"] = python_baseline_kib()
        for case in cases(args.quick, args.turns):  # 2-3. the games
            if self.selected(case.name):
                self.game(case)
        self.rows += memory_growth(self.peaks)
        # the mechanisms that remain, each switched off beside on (MECHANISMS)
        pairs = play_mechanisms(self.selected, args.quick, args.turns, self.logs)
        self.facts["mechanisms"], errors = mechanism_rows(pairs, self.selected)
        self.facts.setdefault("errors", []).extend(errors)
        self.generation()  # 5. world generation
        name = "MAVLink ground station, 100 vehicles"  # 6. the MAVLink ground station (benchmarks/mavlink.py)
        if self.selected(name):
            self.rows.append(mavlink_row(name, turns=50 if args.quick else 300))
        if self.want_floor and self.floor_runs:  # 1 (end). the floor's second half, its rows first, the ratios
            self.floor_now()
        self.floor_rows()
        self.facts["seconds"] = time.perf_counter() - t_start
        self.facts["load_after"] = os.getloadavg()
        (t0, m0), (t1, m1) = self.facts["busy_before"], busy_seconds()
        # cores used by other work
        self.facts["others"] = max(0.0, (t1 - t0) - (m1 - m0)) / max(self.facts["seconds"], 1e-9)
        return self.rows, self.facts

    def floor_now(self) -> None:
        rounds, warm = (150, 100) if self.args.quick else (max(1, self.args.rounds // 2), 300)
        try:
            self.floor_runs.append(measure_floor(rounds, warm, self.logs))
        except Exception as exc:  # noqa: BLE001 - reported in the table
            self.rows.append(Row("floor", {"target": f"FAILED: {exc}"}, ok=False))

    def anchor(self) -> None:
        """POGEMA in-process, same machine, same run: a row per agent count."""
        args = self.args
        agents = sorted({c.drones for c in cases(args.quick, args.turns) if self.selected(c.name)}
                        | (set(DRONES) if self.selected("POGEMA in-process") else set()))
        if not args.pogema or args.quick or not agents:
            return
        try:
            self.pogema_rates = pogema.steps_per_second(agents)
        except pogema.Unavailable as exc:
            self.rows.append(Row("POGEMA", {"target": f"not measured: {exc}"}))
        for n, rate in self.pogema_rates.items():
            self.rows.append(Row(f"POGEMA in-process, {n} agent{'s' if n > 1 else ''} @ 64x64", {
                "array": bytes_text(pogema.SIZE * pogema.SIZE), "tps": f"{rate:.1f}",
                "lat": f"{1e3 / rate:.3f} / -", "target": "anchor (random actions)"}))

    def game(self, case: Case) -> None:
        """A game's row: played distributed (the anchors measured around it), then in-process."""
        scen = make_scenario(case)
        if scen is None:
            self.rows.append(Row(case.name, {"array": bytes_text(int(np.prod(case.size))),
                                             "target": f"skipped: {case.drones} drones do not fit "
                                                       f"({len(start_cells(case.size))} start cells)"}))
            return
        path = self.logs / f"scenario-{case.drones}-{size_text(case.size)}.json"
        path.write_text(json.dumps(scen), encoding="utf-8")
        case_logs = self.logs / f"{case.drones}-{size_text(case.size)}"
        case_logs.mkdir()
        print(f"  {case.name}: distributed ...", file=sys.stderr, flush=True)
        adjacent = Adjacent()
        measure_around = functools.partial(adjacent.measure, case.drones, with_pogema=bool(self.pogema_rates),
                                           logs=case_logs, with_floor=self.want_floor and case.drones == 1)
        measure_around()
        t0 = time.perf_counter()
        game = play_distributed(case, path, case_logs, Path(self.args.profile) if self.args.profile else None)
        t1 = time.perf_counter()
        measure_around()
        print(f"  {case.name}: distributed {t1 - t0:.0f} s; in-process ...", file=sys.stderr, flush=True)
        local = play_local(case, path)
        print(f"  {case.name}: in-process {time.perf_counter() - t1:.0f} s", file=sys.stderr, flush=True)
        cells: dict[str, str] = {"array": bytes_text(int(np.prod(case.size))), "turns": f"{case.warmup} + {case.turns}"}
        cells["codes"] = "/".join("?" if game.codes.get(n) is None else str(game.codes[n]) for n in ROLES)
        lmean = statistics.fmean(local.latencies) if local.latencies else float("nan")
        self.lper_turn[(case.drones, case.size)] = lmean
        cells["ltps"] = f"{1 / lmean:.1f}"
        if game.error:
            cells["target"] = "FAILED: " + game.error.splitlines()[0]
            self.facts.setdefault("errors", []).append(f"{case.name}: {game.error}")
        else:
            self.played(case, game, local, lmean, adjacent, cells)
        self.rows.append(Row(case.name, cells, ok=not game.error and all(game.codes.get(n) == 0 for n in ROLES)))
        if not game.error:
            self.ratio_cells.append((self.rows[-1], statistics.median(game.latencies), case.drones,
                                     adjacent.floor_median))

    def played(self, case: Case, game: Game, local: Local, lmean: float, adjacent: Adjacent,
               cells: dict[str, str]) -> None:
        """A game row's cells, of a game played to its end: speed, CPU, memory, the same game in-process, the
        targets."""
        mean = statistics.fmean(game.latencies)
        self.per_turn[(case.drones, case.size)] = mean
        cells["tps"] = f"{1 / mean:.1f}"
        cells["lat"] = f"{statistics.median(game.latencies) * 1e3:.2f} / {pct(game.latencies, 99) * 1e3:.2f}"
        cells["split"] = f"{statistics.median(game.answers) * 1e3:.2f}" if game.answers else "-"
        cells["cpu"] = " / ".join(f"{game.cpu.get(n, float('nan')) * 1e3:.1f}" for n in (*ROLES, "router", "bench"))
        cells["lratio"] = f"{mean / lmean:.1f}x" if lmean == lmean else "-"
        model = 2 * int(np.prod(case.size)) + 1024 * case.drones + self.facts["baseline_kib"] * 1024
        for key, name in _MEMORY_ROLES:
            hwm = game.memory.get(name, {}).get("VmHWM")
            cells[key] = "-" if hwm is None else f"{hwm / 1024:.1f} ({hwm * 1024 / model:.2f})"
            if hwm is not None:
                self.peaks[(name, case.drones, case.size)] = hwm
        cells["swarm"] = mib(game.memory.get("swarm", {}).get("VmHWM"))
        same = self.same(case, game, local)
        cells["alive"] = f"{game.alive}/{case.drones}, {local.moving:.1f} moving per turn, {same}"
        cells["pogema"], against = versus_pogema(1 / mean, adjacent.pogema_rate or self.pogema_rates.get(case.drones),
                                                 case.drones)
        verdicts = []
        if case.drones == 128:
            verdicts.append(verdict(1 / mean, TARGETS["tps128"], False, f"≥ {TARGETS['tps128']:g} turns/s"))
        verdicts += against
        if case.drones == 1000:
            verdicts.append(verdict(1 / mean, TARGETS["tps1000"], False, f"≥ {TARGETS['tps1000']:g} turns/s"))
            small, lsmall = self.per_turn.get((128, case.size)), self.lper_turn.get((128, case.size))
            growth = [f"{(mean / small) / (1000 / 128):.2f}"] if small else []
            growth += [f"in-process {(lmean / lsmall) / (1000 / 128):.2f}"] if lsmall else []
            cells["growth"] = ", ".join(growth) or "-"
        cells["target"] = "; ".join(verdicts) if verdicts else "—"

    def same(self, case: Case, game: Game, local: Local) -> str:
        """Whether every STATUS of the game is the in-process one's ("yes", or from which turn not: an error)."""
        ours, theirs = states_of(game.statuses), states_of(local.statuses)
        differ = sorted(t for t in set(ours) | set(theirs) if ours.get(t) != theirs.get(t))
        if not differ:
            return "yes"
        t = differ[0]
        a, b = game.statuses.get(t), local.statuses.get(t)
        diff = [f"{x} != {y}" for x, y in zip(getattr(a, "drones", ()), getattr(b, "drones", ())) if x != y]
        self.facts.setdefault("errors", []).append(f"{case.name}: STATUS({t}) differs from the in-process run: "
                                                   + "; ".join(diff[:5]))
        return f"NO (from turn {t})"

    def generation(self) -> None:
        gen_size = (64, 64, 16) if self.args.quick else GEN_SIZE
        name = f"world generation {size_text(gen_size)}"
        if self.selected(name):
            times = world_generation(gen_size, 2 if self.args.quick else 3)
            self.rows.append(Row(name, {"array": bytes_text(int(np.prod(gen_size))), "turns": f"{len(times)} runs",
                                        "lat": f"{statistics.median(times) * 1e3:.0f} / {max(times) * 1e3:.0f}",
                                        "target": "in-process, seed 3"}))

    def floor_rows(self) -> None:
        """The floor's rows, first in the table (both halves pooled), and each game's ratio to the floor."""
        runs = self.floor_runs
        floors = [Floor(f.name, [r for run_ in runs for r in run_[i].rtts],
                        (statistics.fmean(r[i].cpu[0] for r in runs), statistics.fmean(r[i].cpu[1] for r in runs)),
                        max((run_[i].exit_code or 0 for run_ in runs), default=None))
                  for i, f in enumerate(runs[0])] if runs else []
        floor_rows = []
        for i, f in enumerate(floors):
            if not self.selected(f.name):
                continue
            halves = ", ".join(f"{statistics.median(run_[i].rtts) * 1e3:.3f}" for run_ in runs)
            floor_rows.append(Row(f.name, {
                "turns": f"{len(f.rtts)} round trips (median of each half: {halves})",
                "tps": f"{1 / statistics.fmean(f.rtts):.0f}/s",
                "lat": f"{f.median * 1e3:.3f} / {pct(f.rtts, 99) * 1e3:.3f}",
                "cpu": f"helper {f.cpu[0] * 1e3:.3f} / this process {f.cpu[1] * 1e3:.3f}",
                "codes": f"helper {f.exit_code}",
            }, ok=f.exit_code == 0))
        self.rows[:0] = floor_rows
        pubsub = floors[0].median if floors else float("nan")
        self.facts["pubsub"] = pubsub
        for row, med, drones, near in self.ratio_cells:
            ratio = med / (near or pubsub)
            row.cells["floor"] = f"{ratio:.1f}" if ratio == ratio else "-"
            if drones == 1:
                said = verdict(ratio, TARGETS["latency"], True, f"≤ {TARGETS['latency']:g}x RTT")
                before = row.cells.get("target", "—")
                row.cells["target"] = said if before == "—" else f"{said}; {before}"


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
                      "target": verdict(tps, TARGET_TPS, False, f"≥ {TARGET_TPS:g} turns/s")})


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
    table = render(rows, COLUMNS)
    mechanisms = render(facts["mechanisms"], MECHANISM_COLUMNS) if facts["mechanisms"] else ""
    repeat = 1 if args.quick else MECHANISM_REPEAT
    tail = f"\n{MECHANISMS_TITLE}\n\n{mechanisms}\n\n{mechanism_legend(repeat)}\n" if mechanisms else ""
    print(f"\n{table}\n\n{legend(facts)}{tail.rstrip()}")
    ok = said(rows, facts, args.keep_logs)
    if args.write:
        cmd = "dronesim bench perf " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
        write_section(args.output, f"{heading(cmd.strip(), mach, facts)}\n\n{table}\n\n{legend(facts)}\n{tail}")
        print(f"\nwrote {SECTION!r} in {args.output}")
    return 0 if ok else 1


def said(rows: list[Row], facts: dict, keep_logs: bool) -> bool:
    """The errors, the rows not ok and where the logs are (removed when every row is ok, unless kept), on
    stderr; whether every row is ok."""
    for err in facts.get("errors", []):
        print(f"\n{err}", file=sys.stderr)
    failed = [r.name for r in [*rows, *facts["mechanisms"]] if not r.ok]
    for name in failed:
        print(f"not ok: {name} (a process exited non-zero, a game failed or differs: its logs are kept)",
              file=sys.stderr)
    if not failed and not keep_logs:
        shutil.rmtree(facts["logs"], ignore_errors=True)
        where = "removed (--keep-logs keeps them)"
    else:
        where = facts["logs"]
    print(f"\nlogs and scenarios: {where}; {facts['seconds']:.0f} s; other processes used "
          f"{facts['others']:.2f} cores on average during the run", file=sys.stderr)
    return not failed


def heading(cmd: str, mach: dict[str, str], facts: dict) -> str:
    """The section's first paragraphs: the command, the machine and its load, the targets."""
    lb, others = facts["load_before"], facts["others"]
    return (
        f"Command: `{cmd}`, run {_dt.date.today().isoformat()} on {mach['cpu']} ({mach['arch']}, "
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
        "--profile DIR` writes py-spy stacks of every process; the CPU column splits a turn by process."
    )


if __name__ == "__main__":
    raise SystemExit(main())
