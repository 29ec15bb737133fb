"""MCAP export: `dronesim export` of a 1000-drone, 1000-turn journal (issue 35: at most 10 s, memory bounded
by the largest turn, not the game).

    dronesim bench export                         # three runs of each journal, prints the table
    dronesim bench export --write                 # ... and updates "## MCAP export" in BENCHMARKS.md
    dronesim bench export --drones 16 --turns 30 --runs 1   # a small one (the tests)

The journal: `dronesim bench perf`'s scenario of that many drones in its 256x256x32 city (legs across the world
and back a floor higher, every drone flying; benchmarks/perf.py), played in-process as `dronesim up --swarm`
flies it (`dronesim.local.simulate`, one swarm host) for `--turns` turns, then quit; kept in `--cache` by its
parameters. Its first tenth of turns is a second journal: the same drones and world, a tenth of the game.

Each run is `dronesim export JOURNAL --mcap OUT` in a child process, the two journals alternated: its wall
time, its CPU (user + system of all its threads, from wait4: foxglove-sdk compresses on a thread of its own) and
its peak resident memory (its VmHWM as it ends). The peak is the world's more than the game's: the buildings go
out once, as a scene message of a cube each and a marker of a point each (this city has about 250 000 building
cells; a 10x10x8 world's export peaks near 55 MiB). The machine is shared: each row says the 1-minute load
average before the run and the cores the rest of the machine used during it (/proc/stat, less the child's).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks import add_write_args, command_line, replace_section
from dronesim import child_env

SECTION = "## MCAP export"
#: Issue 35: a 1000-drone, 1000-turn journal exports in at most this many seconds.
TARGET_S = 10.0
SIZE = (256, 256, 32)
#: Cores the rest of the machine may keep busy for a wall time to be judged.
QUIET_CORES = 0.25
#: A subsection written by hand that --write keeps.
BEFORE = "### Against the exporter before"


@dataclass(frozen=True, slots=True)
class Run:
    journal: str  # "whole" or "first tenth"
    turns: int
    messages: int
    wall: float
    cpu: float
    peak_mib: float
    file_mib: float
    load: float
    others: float  # cores the rest of the machine used during the run


def make_journal(drones: int, turns: int, cache: Path) -> Path:
    """The game's journal (made once per parameters, then read from `cache`)."""
    from benchmarks.games import WORLD_SEED, Case, make_scenario
    from coordinator.journal import dumps
    from dronesim.local import Inputs, simulate
    from dronesim.scenario import Scenario
    from schema import Intent

    path = cache / f"export-{drones}x{turns}-{SIZE[0]}x{SIZE[1]}x{SIZE[2]}-seed{WORLD_SEED}.journal"
    if path.exists():
        return path
    scenario = make_scenario(Case(drones=drones, size=SIZE, warmup=0, turns=turns))
    if scenario is None:
        raise SystemExit(f"{drones} drones do not fit in {SIZE}")
    cache.mkdir(parents=True, exist_ok=True)
    spec = cache / f"{path.stem}.json"
    spec.write_text(json.dumps(scenario), encoding="utf-8")
    sc = Scenario.load(spec)
    quiet = logging.getLogger("dronesim.bench.export")
    quiet.setLevel(logging.ERROR)
    result = simulate(sc.game_config(), sc.autopilots,
                      Inputs(plan=sc.plan(), intents={1: Intent.CONTINUE, turns + 1: Intent.QUIT}, scripted=False),
                      quiet, verify_env=False, swarm=True)
    part = path.with_suffix(".part")
    part.write_text("".join(dumps(r) + "\n" for r in result.records), encoding="utf-8")
    part.replace(path)
    return path


def first_part(journal: Path, turns: int) -> Path:
    """The journal up to turn `turns` (its header and turn records; no end)."""
    from coordinator.journal import dumps, is_over, is_turn, read

    path = journal.with_name(f"{journal.stem}-first{turns}.journal")
    if not path.exists():
        with path.open("w", encoding="utf-8") as dst:
            for record in read(journal):
                if is_turn(record) and record["turn"] > turns:
                    break
                if not is_over(record):
                    dst.write(dumps(record) + "\n")  # (its line again: the journal's lines are canonical)
    return path


#: The child: `dronesim export`, then its peak resident memory (VmHWM: that of its own program; wait4's ru_maxrss
#: would count the parent's pages it was forked with, the journal just played among them).
_CHILD = ("import re, sys\nfrom dronesim.export import main\ncode = main(sys.argv[1:])\n"
          "print(re.search(r'VmHWM:\\s+(\\d+) kB', open('/proc/self/status').read()).group(1))\nsys.exit(code)")


def _busy() -> float:
    fields = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    return (sum(fields[:8]) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")


def export_once(journal: Path, label: str, out: Path) -> Run:
    load = os.getloadavg()[0]
    busy0, t0 = _busy(), time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(journal), "--mcap", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=child_env(), text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    busy = _busy() - busy0
    stdout, stderr = proc.communicate()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"dronesim export failed: {stderr.strip()}")
    words = stdout.split()  # "exported T turns, M ROS 2 messages ...", then the child's VmHWM in kB
    cpu = usage.ru_utime + usage.ru_stime
    return Run(journal=label, turns=int(words[1]), messages=int(words[3]), wall=wall, cpu=cpu,
               peak_mib=int(words[-1]) / 1024, file_mib=out.stat().st_size / 2**20, load=load,
               others=max(0.0, busy - cpu) / wall)


def table(runs: list[Run]) -> str:
    lines = ["| journal | turns | ROS 2 messages | wall s | CPU s (user + system) | peak memory MiB | file MiB "
             "| load average before | other cores busy during |",
             "|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r.journal} | {r.turns} | {r.messages} | {r.wall:.2f} | {r.cpu:.2f} | {r.peak_mib:.0f} "
              f"| {r.file_mib:.1f} | {r.load:.1f} | {r.others:.2f} |" for r in runs]
    return "\n".join(lines)


def verdicts(runs: list[Run], drones: int, turns: int) -> list[str]:
    whole = [r for r in runs if r.journal == "whole"]
    tenth = [r for r in runs if r.journal != "whole"]
    cpu, wall = statistics.median(r.cpu for r in whole), statistics.median(r.wall for r in whole)
    others = statistics.median(r.others for r in whole)
    quiet = others <= QUIET_CORES
    out = [f"Time ({drones} drones, {turns} turns; target <= {TARGET_S:.0f} s): median CPU {cpu:.2f} s "
           f"({'met' if cpu <= TARGET_S else 'missed'}); median wall {wall:.2f} s, "
           + (f"{'met' if wall <= TARGET_S else 'missed'}." if quiet else
              f"not judged: the rest of the machine kept {others:.2f} of its {os.cpu_count()} cores busy (the "
              f"export had the rest; a quiet machine's wall time is about its CPU time, the compression on a "
              f"second core).")]
    if tenth:
        peak, small = max(r.peak_mib for r in whole), max(r.peak_mib for r in tenth)
        out.append(f"Memory: peak {peak:.0f} MiB for the whole game, {small:.0f} MiB for its first tenth "
                   f"({peak / small:.2f}x for 10x the turns): bounded by a turn (and the trails kept), "
                   f"not the game." if peak <= 1.5 * small else
                   f"Memory: peak {peak:.0f} MiB for the whole game, {small:.0f} MiB for its first tenth: it grows "
                   f"with the game.")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim bench export", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--drones", type=int, default=1000)
    p.add_argument("--turns", type=int, default=1000)
    p.add_argument("--runs", type=int, default=3, help="runs of each journal (default 3)")
    p.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "dronesim-bench-export",
                   help="where the journals are kept between runs")
    add_write_args(p)
    args = p.parse_args(argv)
    started = time.perf_counter()
    journal = make_journal(args.drones, args.turns, args.cache)
    tenth = first_part(journal, max(1, args.turns // 10))
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.runs):
            runs.append(export_once(journal, "whole", Path(tmp) / "whole.mcap"))
            runs.append(export_once(tenth, "first tenth", Path(tmp) / "tenth.mcap"))
    body = "\n".join([command_line("export", argv, time.perf_counter() - started), "", __doc__.split("\n\n", 2)[2]
                      .strip(), "", table(runs), "", *(f"- {v}" for v in verdicts(runs, args.drones, args.turns))])
    print(body)
    if args.write:
        replace_section(args.output, SECTION, body, keep=BEFORE)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
