"""The speed-ups that remain (`MECHANISMS`), each one's lines of code counted from the code it names, and, where a
switch is cheap and honest, its games played with it on and off, alternated, in the same run (`dronesim bench
perf`'s second table)."""

from __future__ import annotations

import json
import re
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from benchmarks.games import ROLES, Case, Game, Variant, Window, Windows, make_scenario, play_distributed, states_of
from benchmarks.measure import Row, size_text
from entities.autopilots import COOPERATIVE

#: The share of its turns/s a game keeps with a ROS 2 viewer publishing it (issue 35).
ROS2_KEEPS = 0.9
#: How the ROS 2 viewer's cost is measured: attached and detached in windows of one game (`Windows`).
ROS2_WINDOWS = Windows(turns=300, quads=12, settle=30)


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
    turns: int = 0  # measured turns of its 1000-drone games, if more than the game rows' quarter
    repeat: int = 0  # games on and off each, if more than MECHANISM_REPEAT
    windows: Windows | None = None  # instead of games on and off: one game (its drones moving to the end), `off`
    # switched in windows of it (only the ROS 2 viewer: `Variant.ros2_windows`)


MECHANISMS: tuple[Mechanism, ...] = (
    Mechanism(
        "The ENV phase is pipelined (the coordinator judges the moves with its own copy of the world)",
        ("coordinator/engine.py::Engine._upd", "coordinator/reports.py::Reports",
         "coordinator/engine.py:/reports|verify_env/", "coordinator/node.py:/verify.env/",
         "schema/tuning.py::UPD_WINDOW", "entities/environment.py:/_early/"),
        switch="not switched off: without it the ENV phase would close on the environment's verdict, a second "
               "way to end a turn in the engine (the first version's); it saved 2 of that version's 8 hops a turn "
               "(one drone 3.1–3.6 ms then), about 0.22 ms each as traced (docs/performance.md)"),
    Mechanism(
        "Answers ahead (a scripted ground station answers the coming phases with nothing new)",
        ("entities/gcs.py::turns_to_answer_ahead", "entities/gcs.py::Station._ahead",
         "entities/gcs.py:/ahead|answered/", "coordinator/engine.py::Engine._hold",
         "coordinator/intake.py::Ahead",
         "coordinator/engine.py:/_early|AHEAD_MAX|ahead/", "schema/tuning.py::AHEAD_MAX",
         "schema/tuning.py::ANSWER_AHEAD", "entities/station_link.py:/ahead/", "coordinator/effects.py::drones_first",
         "coordinator/engine.py:/drones_first/", "schema/tuning.py::QUIET_MOST",
         "network/transport.py:/quiet|_woken_by/", "coordinator/node.py:/ahead_quiet|answer ahead/"),
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
         "coordinator/engine.py::Engine._moves_of_host", "coordinator/intake.py::Ballot.take_all",
         "coordinator/intake.py::Ballot.take_hosted",
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
        ("coordinator/engine.py:/journaled/", "coordinator/judge.py:/journaled/"),
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
         "schema/tuning.py::ROS_CPU_SHARE", "schema/tuning.py::ROS_SLOWEST", "entities/ros2/node.py::listen",
         "schema/tuning.py::ROS_LISTEN_GAP"),
        Variant(ros2=True), ((1000, (64, 64, 16)),),
        f"a `dronesim ros2` viewer publishing the game beside it to a ROS 2 user, a process of its own subscribed "
        f"to every topic (benchmarks/ros_user.py, its CPU counted); turns/s with it ≥ {ROS2_KEEPS:.0%} of without. "
        f"Measured within one game, its drones given new targets leg after leg to the end (a trail a second for "
        f"each), after 100 warm-up turns and the viewer's first {ROS2_WINDOWS.published} turns published (its start, "
        "1000 publishers and their graph tokens declared, is not the steady cost): the viewer attached and detached "
        f"(SIGUSR2/SIGUSR1: detached, it hears no STATUS and publishes nothing) in windows of {ROS2_WINDOWS.turns} "
        f"turns, attached, detached, detached, attached (ABBA) {ROS2_WINDOWS.quads} times, a window's first "
        f"{ROS2_WINDOWS.settle} turns not measured; kept: the median over the groups of attached ÷ detached turns/s",
        warmup=100, windows=ROS2_WINDOWS),
    Mechanism(
        "Zenoh's threads keep their Python thread state (one per thread, not one per callback)",
        ("network/transport.py::_KEPT", "network/transport.py::_keep_thread_state", "network/transport.py::_kept",
         "network/transport.py:/_kept\\(/"),
        switch="not switched off: a Zenoh thread keeps its state for good once kept (a switch would be a second "
               "way to run every callback); `dronesim bench callbacks` measures a message on Zenoh's "
               "receiving thread both ways, each in a process of its own: 2.8-3.6 µs wall, 3.4-4.6 CPU kept against "
               "22.6-26.2 and 26.6-31.3 made and destroyed around each callback (6.8-7.9 x the CPU)"),
    Mechanism(
        "Tables (schema version 2+): swarm-sized data as fixed rows checked by numpy",
        ("schema/tables.py",),
        switch="not switched off: the records path they replaced is gone (tables are the one form of swarm-sized "
               "data); measured then: a 128-drone STATUS decoded in about 25 µs instead of 200 as records"),
    Mechanism(
        "The engine's drones are columns (fleet.py; the observer judges a turn in array operations)",
        ("coordinator/fleet.py", "coordinator/observer.py::judge", "coordinator/intake.py::in_batch"),
        switch="not switched off: the per-drone records it replaced are gone (observer.deaths, the rules drone by "
               "drone, stays as the reference of a property test); measured then: coordinator CPU per turn "
               "1.7 → 1.1 ms at 128 drones, 9 → 3 ms at 1000"),
    Mechanism(
        "A few rows or cells are taken one by one, below a threshold where numpy's fixed cost dominates",
        ("schema/tuning.py::FEW_ROWS", "schema/tuning.py::SURVEY_FEW_CELLS", "schema/tuning.py::CHART_FEW_CELLS",
         "schema/tuning.py::SMALL_FLEET", "coordinator/intake.py:/FEW_ROWS/", "coordinator/judge.py:/FEW_ROWS/",
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
        "A few drones' turn is played over Python lists (the judge's `_few`, up to TURN_FEW_DRONES)",
        ("schema/tuning.py::TURN_FEW_DRONES", "coordinator/judge.py::Judge._few",
         "coordinator/judge.py::Judge._missed", "coordinator/judge.py::Judge._died",
         "coordinator/judge.py::Judge._journal_few", "coordinator/judge.py::_set_rows",
         "coordinator/observer.py::deaths_of_moves", "coordinator/observer.py::_meet",
         "coordinator/engine.py:/TURN_FEW_DRONES|whole|took/", "coordinator/judge.py:/TURN_FEW_DRONES|whole|took/"),
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


#: Turns a windowed game may take beyond its windows' (its warm-up, the viewer's start), at most.
WINDOWS_SLACK = 3000

#: Games of each mechanism on and off, alternated (on, off, then off, on...): the machine's speed drifts, and the
#: second game of two may differ from the first (the first's processes ending, a cache warm): each comes first as often.
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
        if m.windows is not None and m.off is not None:  # one game, the switch flipped in windows of it
            for drones, size in games:
                w = m.windows if not quick else Windows(turns=10, quads=1, settle=2, published=1)
                # --quick: cooperative drones, which never crash: the 4 seed drones' game ends (all crashed) on turn
                # 243, within a second, before a viewer that spent its CPU share on its first turn publishes again
                case = Case(drones, size, max(5, m.warmup) if not quick else 3, w.span + WINDOWS_SLACK, moving=True,
                            autopilot=COOPERATIVE if quick else "seed")
                pair = Pair(m, case)
                path = logs / f"mechanism-scenario-{drones}-{size_text(size)}-moving.json"
                path.write_text(json.dumps(make_scenario(case)), encoding="utf-8")
                folder = logs / f"mechanism-{len(pairs)}-windows"
                folder.mkdir()
                print(f"  mechanism {m.name[:40]}..., {case.name}, {w.count} windows of one game", file=sys.stderr,
                      flush=True)
                pair.off.append(play_distributed(case, path, folder, variant=replace(m.off, ros2_windows=w)))
                pairs.append(pair)
            continue
        for drones, size in games:
            case = Case(drones, size, 3, min(turns, 20)) if quick else (
                Case(drones, size, max(5, m.warmup), max(10, turns // 4, m.turns)) if drones >= 1000
                else Case(drones, size, 10, turns))
            pair = Pair(m, case)
            path = logs / f"mechanism-scenario-{drones}-{size_text(size)}.json"
            path.write_text(json.dumps(make_scenario(case)), encoding="utf-8")
            for i in range(1 if quick else max(MECHANISM_REPEAT, m.repeat)):  # (mechanism_legend, m.switch say)
                order = ((Variant(), pair.on), (m.off, pair.off))
                for variant, into in order[::-1] if i % 2 else order:  # on, off, off, on...: a drift weighs alike
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
            if m.windows is not None:
                rows.append(_windowed_row(m, p, cells, errors, k))
                continue
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
                keeps = 1 / turn  # (each pair, a game with the viewer ÷ the game without played next to it,
                ratios = [a / b for a, b in zip(on["mean"], off["mean"])]  # shows the spread of the machine)
                cells["gain"] += (f"; keeps {keeps:.0%} of its turns/s (target ≥ {ROS2_KEEPS:.0%}; pair by pair "
                                  f"{_span([100 * r for r in ratios], '.0f')} %); the ROS 2 user got "
                                  f"{_span([_samples(g) for g in p.off], 'd')} messages a game")
                ok = ok and (keeps >= ROS2_KEEPS or p.case.drones < 1000)  # (judged on the swarm it is for)
                ok = ok and (all(_samples(g) > 0 for g in p.off) or p.case.drones < 1000)  # (the user heard it)
            if m.off.shared_memory:
                cells["gain"] += f", peak memory {off['hwm'] - on['hwm']:+.0f} MiB off (the three processes)"
            base = states_of(p.on[0].statuses)
            same = all(states_of(g.statuses) == base for g in p.on + p.off)
            cells["same"] = "yes" if same else "NO"
            if not same:
                errors.append(f"{m.name}, {p.case.name}: the games on and off differ")
            rows.append(Row(m.name if k == 0 else "″", cells, ok=ok and same))
    return rows, errors


def window_ratios(windows: list[Window]) -> list[float]:
    """Turns/s with the viewer attached ÷ detached, in each group of four windows (ABBA: the time of the two attached
    ones ÷ that of the two detached, their turns alike)."""
    ratios = []
    for q in range(0, len(windows) - 3, 4):
        group = windows[q:q + 4]
        on = [w for w in group if w.attached]
        off = [w for w in group if not w.attached]
        ratios.append((sum(w.turns for w in on) / sum(w.seconds for w in on))
                      / (sum(w.turns for w in off) / sum(w.seconds for w in off)))
    return ratios


def _windowed_row(m: Mechanism, p: Pair, cells: dict[str, str], errors: list[str], k: int) -> Row:
    """The row of a mechanism switched in windows of one game (`Mechanism.windows`): the viewer's."""
    name = m.name if k == 0 else "″"
    game = p.off[0]
    failed = game.error or ("" if game.windows and len(game.windows) % 4 == 0 else "no windows measured")
    if failed:
        cells["gain"] = "FAILED: " + failed.splitlines()[0]
        errors.append(f"{m.name}, {p.case.name}: {failed}")
        return Row(name, cells, ok=False)
    ok = all(c == 0 for c in game.codes.values())
    on = [w for w in game.windows if w.attached]
    off = [w for w in game.windows if not w.attached]

    def tps(ws: list[Window]) -> list[float]:
        return [w.turns / w.seconds for w in ws]

    def cpu(ws: list[Window]) -> float:
        return 1e3 * sum(w.cpu for w in ws) / sum(w.turns for w in ws)

    ratios = window_ratios(game.windows)
    keeps = statistics.median(ratios)
    cells["tps"] = f"{_span(tps(off), '.0f')} / {_span(tps(on), '.0f')} (windows)"  # (on: no viewer, as above)
    cells["lat"] = f"{statistics.median(game.latencies) * 1e3:.2f} (all windows)"
    cells["cpu"] = f"{cpu(off):.2f} / {cpu(on):.2f}"
    mem = [max(game.memory.get(n, {}).get("VmHWM", 0), 0) / 1024 for n in ROLES]
    cells["mem"] = ", ".join(f"{v:.0f}" for v in mem) + " (one game)"
    samples = _samples(game)
    whole = (sum(w.turns for w in on) / sum(w.seconds for w in on)) / (
        sum(w.turns for w in off) / sum(w.seconds for w in off))
    def share(ws: list[Window], name: str) -> float:  # of a core
        return sum(w.by.get(name, 0.0) for w in ws) / sum(w.seconds for w in ws)

    extra = {n: share(on, n) - share(off, n) for n in ("ros2", "rosuser", "router")}
    cells["gain"] = (f"keeps {keeps:.0%} of its turns/s attached (median of {len(ratios)} ABBA groups; target ≥ "
                     f"{ROS2_KEEPS:.0%}; group by group {_span([100 * r for r in ratios], '.0f')} %; all windows "
                     f"{whole:.0%}), CPU a turn {cpu(on) / cpu(off):.2f}x; attached − detached, % of a core: viewer "
                     f"{100 * extra['ros2']:.1f}, its user {100 * extra['rosuser']:.1f}, router "
                     f"{100 * extra['router']:.1f}; the ROS 2 user got {samples} messages")
    ok = ok and (keeps >= ROS2_KEEPS or p.case.drones < 1000) and (samples > 0 or p.case.drones < 1000)
    cells["same"] = "one game"
    return Row(name, cells, ok=ok)


def _summary(games: list[Game]) -> dict:
    means = [statistics.fmean(g.latencies) for g in games]
    mem = [[g.memory.get(n, {}).get("VmHWM", 0) / 1024 for n in ROLES] for g in games]
    peak = [max(col) for col in zip(*mem)]
    return {"mean": means, "tps": [1 / m for m in means], "lat": [statistics.median(g.latencies) * 1e3 for g in games],
            "cpu": [sum(g.cpu.values()) * 1e3 for g in games], "mem": ", ".join(f"{v:.0f}" for v in peak),
            "hwm": sum(peak)}


def _samples(game: Game) -> int:
    """The messages a game's ROS 2 user received (0 if it said nothing)."""
    words = game.ros_user.split()
    return int(words[0]) if words and words[0].isdigit() else 0


def _span(values: list[float], fmt: str) -> str:
    lo, hi = min(values), max(values)
    return format(lo, fmt) if format(lo, fmt) == format(hi, fmt) else f"{lo:{fmt}}–{hi:{fmt}}"


MECHANISMS_TITLE = "### The speed-ups that remain, each switched off beside on"


def mechanism_legend(repeat: int = MECHANISM_REPEAT) -> str:
    return (
        "Legend. Each mechanism that remains (docs/performance.md says what each does and why the game is the "
        "same). Lines of code: the lines that exist only for it, each counted once: the definitions named in "
        "`benchmarks/mechanisms.py`'s MECHANISMS (a function, class or constant, docstring and comments included) and, "
        "where it is woven into shared code, the lines there that name it (a regex over the file), counted when "
        "the table is made. A mechanism with a switch is played with it on and off, alternated "
        f"({repeat} game{'s' if repeat > 1 else ''} each{': on, off, off, on' if repeat > 1 else ''}), in this run, "
        "on the same scenario as the game "
        "rows above (same warm-up and measured turns); each cell is the range over its games. CPU: user + "
        "system time of the coordinator, environment, drone processes, router and this process, summed, "
        "per measured turn. Peak: VmHWM, the largest over the games. Gain: off ÷ on of the mean turn and of "
        "the CPU per turn (above 1: the mechanism saves that); for shared memory, the peaks' sum off − on. "
        "Same game: every drone's state after every turn equal in all the games, on and off. A mechanism switched "
        "within one game (the ROS 2 viewer's, attached and detached in windows of its turns: its switch cell says "
        "how) has each cell over its windows instead, on (no viewer) / off (the viewer attached), the machine's "
        "drift cancelled group by group of four windows (ABBA)."
    )
