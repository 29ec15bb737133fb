"""Flood benchmark (issue 18, "Floods cannot move a game"): the same game clean and under two floods.

    dronesim bench flood                   # 16 seed drones on 64x64x16, 1000 measured turns (under a minute)
    dronesim bench flood --write           # ... and updates "## Floods" in BENCHMARKS.md
    dronesim bench flood --quick           # a tiny game and small floods (used by the tests)

In one run, each game as `dronesim bench perf` plays it (`benchmarks.games.play_distributed`: a
loopback `dronesim router` process, secured as docs/security.md says (TLS, user/password, the access
control generated from the key table; `--plain`: none of these) with the flood filters generated from
the key table (`schema.acl.flood_filters`), every process with its own credentials; the coordinator,
the environment and one swarm host (H01) flying every drone with the seed autopilot, each a process;
this process the scripted ground station; the coordinator keeps a journal), the games of the same
scenario:

1. clean;
2. flood (a): once the warm-up turns are over, an attacker process (`benchmarks.flooder nps`, a client
   of the router authenticated as H01, the principal D01's keys belong to) publishes 200,000 well-formed
   NPS for turn 1 from D01 on D01's own key, as fast as it can: what an authenticated drone may do on its
   own key under access control (the attacker runs at niceness 19, `--attacker-nice`: it stands for a
   client on a host of its own, so the game's processes go first on this machine's cores; the router,
   which takes the whole flood, runs as the game does);
3. flood (b): the attacker sends 300 ASKs of 32,768 cells from D01 to the environment at once and waits
   for their replies;
4. flood (c), (d): 2,000,000 stale DONEs on the ground station's key, 2,000,000 stale TGTs on D01's (what any peer
   may do on a plain router; under access control, a buggy ground station: the attacker is a second session of
   the GCS); flood (e): 20,000 CONNECT queries with invented sessions, naming D01, D02... in turn (any peer allowed
   to connect: a drone under access control), all at once (issue 33); flood (f): 20,000 requests for the
   environment's map from D01, all at once (any peer allowed to ask for it). The attacker runs in a session of its own
   (`--attacker-session`), as a program started apart from the game would: Linux schedules each session as a
   group (autogroup), so it takes its share of the machine as any other program does (in the game's session it
   took its CPU from the game's share: `--attacker-session game`);
5. `--floods busy` adds the control (g): the attacker connects as for (e) and sends nothing, a busy loop as long as
   a CONNECT flood lasts here: what any program taking a core as an equal costs the game on this machine, the ratio
   each flood's is to be read beside;
6. clean again (the machine's speed drifts: the clean speed is the mean of the first and last clean games).
`--floods nps,done` plays only those floods.

For each: turns/s over the measured turns, and turns/s during the flood (over the turns it overlaps:
from the last turn begun before the attacker's first message to the first begun after its last message
or reply), its ratio to the clean speed (target ≥ 0.5), whether the journal is byte-identical to the
first clean game's (the journal leaves out the game identity each coordinator draws) and every drone's
state after every turn equal, the rejections the coordinator and the environment report in their last
lines, and the exit codes. `--repeat N` plays the games N times and gives the ratios' range.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

from benchmarks import add_write_args, command_line, replace_section
from benchmarks.games import Case, Game, Secured, Variant, make_scenario, play_distributed
from benchmarks.measure import Row, busy_seconds, render
from dronesim import child_env
from schema import Keys

SECTION = "## Floods"
TARGET = 0.5  # flooded turns/s ÷ clean turns/s, at least
SIZE = (64, 64, 16)
DRONES = 16
#: (c), (d): 2,000,000 stale DONEs or TGTs: 200,000 went by in 0.1-1.3 s, a few dozen turns, so that their ratio
#: measured this shared machine's pauses in that fraction of a second more than the flood; these outlast most games.
FLOODS = {"nps": 200_000, "ask": 300, "done": 2_000_000, "tgt": 2_000_000, "connect": 20_000, "map": 20_000}
#: The control (not in the default list, `--floods busy`): no message, a busy loop of this many milliseconds (about
#: as long as a CONNECT flood lasts here): what any program that takes a core as an equal costs the game on this
#: machine, to set each flood's ratio beside.
CONTROL = {"busy": 5_000}
QUICK_CONTROL = {"busy": 300}
#: On the secured router, the principal each flood comes as: D01's keys and queries belong to the swarm host flying
#: it; the ground station's keys (DONE, TGT) to the GCS (a buggy ground station: a second session of it).
ATTACKERS = {"nps": "H01", "ask": "H01", "connect": "H01", "done": "GCS", "tgt": "GCS", "map": "H01",
             "busy": "H01"}
#: --quick: small floods
QUICK_FLOODS = {"nps": 2_000, "ask": 100, "done": 2_000, "tgt": 2_000, "connect": 500, "map": 500}
#: What each flood sends, for the table.
FLOOD_NAMES = {"nps": "{:,} stale NPS", "ask": "{:,} ASKs of 32,768 cells", "done": "{:,} stale DONEs",
               "tgt": "{:,} stale TGTs", "connect": "{:,} CONNECTs with invented sessions",
               "map": "{:,} requests for the map", "busy": "no message, a busy loop of {:,} ms (the control)"}
#: The attacker's niceness: it stands for a client on a host of its own (an authenticated drone), so the game's
#: processes go first on this machine's cores; the router, which takes the whole flood, runs as the game does.
#: `--attacker-nice 0`: an attacker that shares the game's cores as an equal (on 2 cores it takes one of them).
ATTACKER_NICE = 19
#: Where the attacker runs: "own", a session of its own (setsid), as a program started apart from the game is (Linux
#: schedules each session as a group, autogroup, each with the same share of the machine); "game", the game's session
#: (this process's): then it is scheduled as one of the game's own processes, and takes its CPU from the game's share.
ATTACKER_SESSIONS = ("own", "game")


#: Each flood's letter in the table.
LETTERS = dict(zip([*FLOODS, *CONTROL], "abcdefg"))


def quick_case() -> Case:
    """--quick: a tiny game."""
    return Case(4, (10, 10, 10), 3, 150)


@dataclass(slots=True)
class Played:
    name: str
    flood: str | None  # a key of FLOODS, or None (clean)
    game: Game
    journal: bytes = b""
    rejected: dict[str, str] = field(default_factory=dict)  # process -> its "rejected inputs" report
    attacker: dict = field(default_factory=dict)  # the flooder's JSON line
    attacker_error: str = ""
    ratio: float = float("nan")  # turns/s during the flood ÷ clean


def rejections(log: Path) -> str:
    """The last "rejected inputs: ..." report in a process's log ("" if none)."""
    found = re.findall(r"rejected inputs: (.*)", log.read_text(errors="replace")) if log.exists() else []
    return found[-1].strip() if found else ""


def play(name: str, flood: str | None, count: int, case: Case, scenario: Path, logs: Path,
         secured: Secured | None, nice: int = ATTACKER_NICE, session: str = "own") -> Played:
    """One game, with the attacker `flood` (`benchmarks.flooder`, at niceness `nice`, in a session of its own or
    the game's: `ATTACKER_SESSIONS`) started once its warm-up is over."""
    logs.mkdir()
    attackers: list[subprocess.Popen] = []
    went: list[int] = []  # the turn it was told to go at

    def on_status(locator: str, keys: Keys, turn: int) -> None:
        """At the first STATUS (a warm-up turn: the game waits), the attacker is started and connects; at
        the last warm-up turn's, it is told to go."""
        if flood is None:
            return
        if turn == 1:
            creds = secured.flags(ATTACKERS[flood]) if secured is not None else []
            a = subprocess.Popen([sys.executable, "-m", "benchmarks.flooder", flood, "--mode", "client", "--connect",
                                  locator, "--root", keys.root, "--count", str(count), *creds],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 env=child_env(), preexec_fn=partial(os.nice, nice),
                                 start_new_session=session == "own")
            attackers.append(a)
            line = a.stdout.readline() if a.stdout else ""
            if line.strip() != "ready":
                raise RuntimeError(f"the attacker did not start: {line.strip()}")
        elif turn == case.warmup and attackers and attackers[0].stdin:
            attackers[0].stdin.write("go\n")
            attackers[0].stdin.flush()
            went.append(turn)

    try:
        game = play_distributed(case, scenario, logs, variant=Variant(journal=True, secured=secured),
                                on_status=on_status)
    finally:
        outputs = []
        for a in attackers:
            if not went:  # the game failed before: no flood after it
                a.kill()
            try:
                outputs.append(a.communicate(timeout=180)[0])
            except subprocess.TimeoutExpired:
                a.kill()
                outputs.append(a.communicate()[0])
    played = Played(name, flood, game)
    journal = logs / "journal.jsonl"
    played.journal = journal.read_bytes() if journal.exists() else b""
    played.rejected = {n: rejections(logs / f"{n}.log") for n in ("coordinator", "env")}
    if flood is not None:
        lines = outputs[0].strip().splitlines() if outputs else []
        try:
            played.attacker = json.loads(lines[-1])
        except (IndexError, ValueError):
            played.attacker_error = "the attacker did not start" if not outputs else \
                "the attacker failed: " + " | ".join(line.strip() for line in lines[-2:])
    return played


def measured_rate(game: Game, case: Case) -> float:
    """Turns/s over the measured turns (1 / the mean turn)."""
    return 1 / statistics.fmean(game.latencies) if game.latencies else float("nan")


def flood_window(game: Game, case: Case, first: float, last: float) -> tuple[list[float], bool]:
    """The STATUS arrival times bounding the turns the flood overlaps: from the last turn begun at or before its
    first message to the first begun at or after its last message or reply (a turn begins when the STATUS of the
    one before arrives); and whether it was cut: the flood outlasted the measured turns (then up to the last)."""
    stamps = sorted(game.arrived[t] for t in range(case.warmup, case.end_turn) if t in game.arrived)
    before = [s for s in stamps if s <= first]
    lo = before[-1] if before else stamps[0]
    after = [s for s in stamps if s >= last and s > lo]  # a flood within one turn: that turn
    hi = after[0] if after else stamps[-1]
    return [s for s in stamps if lo <= s <= hi], not after


def flood_rate(game: Game, case: Case, first: float, last: float) -> tuple[float, int, float, bool]:
    """(turns/s, turns, seconds, cut) over the turns the flood overlaps (`flood_window`)."""
    window, cut = flood_window(game, case, first, last)
    turns, seconds = sum(s > window[0] for s in window), window[-1] - window[0]
    return (turns / seconds if seconds > 0 else float("nan")), turns, seconds, cut


def longest_turn(game: Game, case: Case, first: float, last: float) -> float:
    """Seconds of the longest of the turns the flood overlaps (`flood_window`)."""
    window, _ = flood_window(game, case, first, last)
    return max((b - a for a, b in zip(window, window[1:])), default=float("nan"))


def _states(game: Game) -> dict[int, object]:
    return {t: st.drones for t, st in game.statuses.items()}


COLUMNS = (
    ("game", "game"), ("tps", "turns/s (measured turns)"), ("during", "turns/s during the flood (turns, s)"),
    ("ratio", "÷ clean"), ("target", f"target ≥ {TARGET:g}"), ("same", "same journal / states"),
    ("attacker", "attacker: sent / answered / refused (its CPU s)"), ("srv", "rejected by the coordinator"),
    ("env", "rejected by the environment"), ("cpu", "CPU ms per turn: router / coordinator / environment"),
    ("resent", "station's DONEs sent again: announced / timed out"), ("longest", "longest turn in the flood (ms)"),
    ("codes", "exit codes"),
)


def rows_of(games: list[Played], case: Case) -> tuple[list[Row], list[str]]:
    clean = [p for p in games if p.flood is None and not p.game.error]
    reference = clean[0] if clean else None
    clean_rate = statistics.fmean(measured_rate(p.game, case) for p in clean) if clean else float("nan")
    rows, errors = [], []
    for p in games:
        g = p.game
        cells = {"codes": " / ".join(f"{g.codes.get(n)}" for n in ("coordinator", "env", "swarm")),
                 "srv": p.rejected.get("coordinator") or "-", "env": p.rejected.get("env") or "-"}
        ok = not g.error and not p.attacker_error and all(c == 0 for c in g.codes.values())
        if g.error:
            cells["target"] = "FAILED: " + g.error.splitlines()[0]
            errors.append(f"{p.name}: {g.error}")
        else:
            cells["tps"] = f"{measured_rate(g, case):.1f}"
            cells["resent"] = f"{g.resent.get('announced', 0)} / {g.resent.get('timed out', 0)}"
            cells["cpu"] = " / ".join(f"{g.cpu.get(n, float('nan')) * 1e3:.2f}"
                                      for n in ("router", "coordinator", "env"))
            if reference is not None:
                same_journal = p.journal == reference.journal and bool(p.journal)
                same_states = _states(g) == _states(reference.game)
                cells["same"] = f"{'yes' if same_journal else 'NO'} / {'yes' if same_states else 'NO'}"
                ok = ok and same_journal and same_states
        if p.flood is not None:
            if p.attacker_error:
                cells["target"] = p.attacker_error
                errors.append(f"{p.name}: {p.attacker_error}")
            elif p.attacker:
                a = p.attacker
                cells["attacker"] = f"{a['sent']:,} / {a['answered']:,} / {a['refused']:,} ({a['cpu']:.2f})" + (
                    f", {a['unanswered']:,} unanswered" if a.get("unanswered") else "")
                if not g.error:
                    rate, turns, seconds, cut = flood_rate(g, case, a["first"], a["last"])
                    ratio = rate / clean_rate
                    cells["during"] = f"{rate:.1f} ({turns}, {seconds:.2f}{', cut' if cut else ''})"
                    cells["ratio"] = f"{ratio:.2f}"
                    cells["longest"] = f"{longest_turn(g, case, a['first'], a['last']) * 1e3:.1f}"
                    p.ratio = ratio
                    cells["target"] = ("control" if p.flood in CONTROL else
                                       "met" if ratio >= TARGET else "MISSED")
        rows.append(Row(p.name, cells, ok=ok))
    return rows, errors


def run(args: argparse.Namespace) -> tuple[list[Row], dict]:
    case = quick_case() if args.quick else Case(DRONES, SIZE, 10, args.turns)
    counts = {**QUICK_FLOODS, **QUICK_CONTROL} if args.quick else {**FLOODS, **CONTROL}
    logs = Path(tempfile.mkdtemp(prefix="dronesim-flood-"))
    facts: dict = {"logs": logs, "case": case, "counts": counts}
    busy0, t0 = busy_seconds(), time.perf_counter()
    scenario = logs / "scenario.json"
    scen = make_scenario(case)
    if scen is None:
        raise SystemExit(f"{case.drones} drones do not fit in {case.size}")
    scenario.write_text(json.dumps(scen), encoding="utf-8")
    secured = None if args.plain else Secured.make(logs / "certs", [d["id"] for d in scen["drones"]], "H01")
    facts["secured"] = secured is not None
    facts["nice"] = args.attacker_nice
    facts["session"] = args.attacker_session
    floods = [f for f in [*FLOODS, *CONTROL] if f in args.floods]
    facts["games"] = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six", 7: "seven"}.get(len(floods) + 2,
                                                                                         str(len(floods) + 2))
    plan = [("clean", None), *((f"flood ({LETTERS[f]}): {FLOOD_NAMES[f].format(counts[f])}", f) for f in floods),
            ("clean again", None)]
    rows: list[Row] = []
    facts["errors"], facts["loads"], facts["ratios"] = [], [], {flood: [] for _, flood in plan if flood}
    for k in range(1, args.repeat + 1):
        facts["loads"].append(os.getloadavg()[0])
        games = [play(f"run {k}: {name}" if args.repeat > 1 else name, flood, counts.get(flood or "", 0), case,
                      scenario, logs / f"run{k}-game{i}", secured, args.attacker_nice, args.attacker_session)
                 for i, (name, flood) in enumerate(plan)]
        more, errors = rows_of(games, case)
        rows += more
        facts["errors"] += errors
        for p in games:
            if p.flood is not None:
                facts["ratios"][p.flood].append(p.ratio)
    facts["seconds"] = time.perf_counter() - t0
    (b0, m0), (b1, m1) = busy0, busy_seconds()
    facts["others"] = max(0.0, (b1 - b0) - (m1 - m0)) / max(facts["seconds"], 1e-9)
    facts["load_after"] = os.getloadavg()
    return rows, facts


def legend(facts: dict) -> str:
    case: Case = facts["case"]
    return (
        f"Legend. One scenario ({case.drones} seed drones on {'x'.join(map(str, case.size))}, {case.warmup} warm-up "
        f"turns, {case.turns} measured), played {facts['games']} times in this run as `dronesim bench perf` plays a "
        "game: a "
        "loopback `dronesim router` process (" + (
            "the secured router of docs/security.md: TLS, user/password, the access control generated from the key "
            "table for the game's root, every process with its own credentials, the attacker a second "
            "session of H01, the swarm host flying D01, whose keys it may write; "
            if facts["secured"] else "the plain router: no TLS, no authentication, no access control; ")
        + "the flood filters generated from the key table, `low_pass_filter` and `downsampling`), coordinator "
        "(with a journal), environment and "
        "one swarm host as processes, this process the scripted ground station. When the warm-up is over, an "
        f"attacker process (`benchmarks/flooder.py`, a client of the router, at niceness {facts['nice']}"
        + (": it stands for a client on a host of its own, so the game's processes go first on this machine's "
           "cores, while the router takes the whole flood" if facts["nice"] > 0 else
           ": it shares this machine's cores with the game as an equal")
        + ("; in a session of its own, as a program started apart from the game: Linux schedules each session as a "
           "group, autogroup, so it takes its share of the machine as any other program does"
           if facts["session"] == "own" else "; in the game's session: scheduled as one of the game's processes, it "
           "takes its CPU from the game's share") + ") floods as D01: (a) NPS for turn 1 on "
        "D01's own key, as fast as it can; (c), (d) stale DONEs on the ground station's key, stale TGTs on D01's, "
        "as a second session of the GCS; (e) CONNECTs with invented sessions, all at once; (f), the control: "
        "no message, a busy loop (what any program taking a core as an equal costs the game here); (b) ASKs of 32,768 "
        "cells to the environment, all at once, then waits "
        "for their replies (\"unanswered\": queries that finished with none, having reached the environment after "
        "the game's end, when it had left: only when the flood was cut). Turns/s (measured turns) = 1 ÷ the mean "
        "time between consecutive STATUS; during the "
        "flood = the turns it overlaps (from the last turn begun before the attacker's first message to the first "
        "begun after its last message or reply; \"cut\": the flood outlasted the measured turns, counted to the "
        "last) ÷ their time; ÷ clean = that ÷ the mean of the two clean games' turns/s. Same "
        "journal: byte-identical to the first clean game's; same states: every drone's state after every turn "
        "equal. Rejected: the coordinator's and the environment's last report (by reason, then by origin). "
        "CPU: user + system time of each process over the measured turns ÷ turns; the attacker's CPU "
        "seconds during its flood are in its column: it runs on this machine, beside the router (which receives "
        "every message of the flood and drops most) and the game's processes, so on a machine of few cores a "
        "flood costs the game CPU as well as whatever reaches it (the attacker's CPU seconds ÷ the flood's "
        "seconds: the cores it took; `--attacker-nice 0` measures an attacker that takes them as an equal). "
        "Station's DONEs sent again (the whole game): \"announced\", an answer ahead lost on the way (its phase "
        "announced all the same, answered again: a round trip), \"timed out\", a phase's DONE whose STATUS did not "
        "come in time (`DONE_RETRY_TURNS` turns, 20 ms at least, then twice as long), `entities.gcs.Station.resent`: "
        "a router's budget of puts a session keeps the first of DONEs that travel together. Longest turn: the longest "
        "of the turns the flood overlaps. Exit codes: coordinator / environment / swarm host."
    )


def _span(values: list[float]) -> str:
    lo, hi = min(values), max(values)
    return f"{lo:.2f}" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}–{hi:.2f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dronesim bench flood", description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help=f"a tiny game ({quick_case().name}, {quick_case().turns} turns) and small floods "
                             f"({QUICK_FLOODS['nps']:,} NPS, {QUICK_FLOODS['ask']} ASKs), for the tests")
    parser.add_argument("--turns", type=int, default=1000,
                        help="measured turns per game (default 1000: the floods end within them)")
    parser.add_argument("--plain", action="store_true",
                        help="the plain router (flood filters, no TLS, no authentication, no access control) instead "
                             "of the secured one")
    parser.add_argument("--attacker-nice", type=int, default=ATTACKER_NICE,
                        help=f"the attacker's niceness (default {ATTACKER_NICE}: it stands for a client on a host of "
                             "its own; 0: it shares this machine's cores with the game as an equal). With Linux's "
                             "autogroup on (/proc/sys/kernel/sched_autogroup_enabled) and the attacker in a session of "
                             "its own, its niceness ranks it only within its own group and changes nothing: measure a "
                             "niced attacker with --attacker-session game")
    parser.add_argument("--attacker-session", choices=ATTACKER_SESSIONS, default="own",
                        help="the attacker in a session of its own (default: as a program started apart from the "
                             "game, scheduled as a group of its own, autogroup) or in the game's (scheduled as one "
                             "of the game's processes, taking the game's share)")
    parser.add_argument("--floods", default=",".join(FLOODS), type=lambda v: [f for f in v.split(",") if f],
                        help=f"the floods to play, of {','.join(FLOODS)} (default: all), and busy: the control, "
                             "an equal process that sends nothing")
    parser.add_argument("--repeat", type=int, default=1, help="play the games this many times (default 1)")
    parser.add_argument("--keep-logs", action="store_true", help="keep the processes' logs (kept anyway on failure)")
    add_write_args(parser)
    args = parser.parse_args(argv)
    if args.turns < 2 or args.repeat < 1:
        parser.error("--turns must be >= 2 and --repeat >= 1")
    if not args.floods or set(args.floods) - set(FLOODS) - set(CONTROL):
        parser.error(f"--floods takes some of {','.join([*FLOODS, *CONTROL])}")
    rows, facts = run(args)
    table = render(rows, COLUMNS)
    print(table)
    print()
    print(legend(facts))
    for err in facts["errors"]:
        print(f"\n{err}", file=sys.stderr)
    for row in rows:
        if not row.ok:
            print(f"not ok: {row.name}: " + "; ".join(f"{k} {v}" for k, v in row.cells.items()), file=sys.stderr)
    ok = all(r.ok for r in rows)
    missed = [r.name for r in rows if r.cells.get("target") == "MISSED"]
    if ok and not args.keep_logs:
        shutil.rmtree(facts["logs"], ignore_errors=True)
    else:
        print(f"logs: {facts['logs']}", file=sys.stderr)
    others = facts["others"]
    befores = ", ".join(f"{v:.2f}" for v in facts["loads"])
    load = (f"Load average (1 min) before {'each' if len(facts['loads']) > 1 else 'the'} run {befores}, after "
            f"{facts['load_after'][0]:.2f}; other processes "
            f"used {others:.2f} cores on average during the run"
            + (" (other work ran alongside: absolute numbers are pessimistic)." if others > 0.2 else "."))
    verdict = ("Target (flooded turns/s ≥ 0.5 × clean, journal unchanged): "
               + ("met." if ok and not missed else
                  "MISSED" + (f" ({', '.join(missed)})" if missed else "")
                  + ("; a game failed or its journal changed" if not ok else "") + "."))
    ranges = "; ".join(f"{'control' if flood in CONTROL else 'flood'} ({LETTERS[flood]}) ÷ clean: {_span(values)}"
                       for flood, values in facts["ratios"].items() if values)
    verdict += f" Over {args.repeat} run{'s' if args.repeat > 1 else ''}: {ranges}." if ranges else ""
    print(f"\n{load}\n{verdict}", file=sys.stderr)
    if args.write:
        body = (f"{command_line('flood', argv, facts['seconds'])} {load}\n\n{verdict}\n\n{table}\n\n"
                f"{legend(facts)}\n")
        replace_section(args.output, SECTION, body)
        print(f"wrote {SECTION!r} in {args.output}", file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
