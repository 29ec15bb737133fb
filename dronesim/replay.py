"""``dronesim replay JOURNAL``: re-render a run from its journal, with no network.

Prints the world floor by floor with every drone's path, and a summary (each drone's end state, moves,
deaths). ``--turns`` prints every turn's state too; ``--at N`` renders the state after turn N.
``--verify`` re-simulates the run in-process from the journal's header and inputs (GCS targets and
intents, missed deadlines, vanished drones) and checks the result is the journal, byte for byte.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field

from coordinator.engine import DroneSpec, GameConfig
from coordinator.journal import dumps, read
from entities.gcs import Plan
from schema import Cell, Intent, RemoteInputError, UsageError, WorldSpec
from world.grid import World, build_world

from .local import Inputs, simulate


@dataclass(slots=True)
class Track:
    pos: Cell
    state: str = "ALIVE"
    cause: str = ""
    path: list[Cell] = field(default_factory=list)
    target: Cell | None = None


def header_config(header: dict) -> tuple[GameConfig, dict[str, str]]:
    if header.get("record") != "header" or header.get("format") != "dronesim-journal":
        raise UsageError("not a dronesim journal: the first record must be its header")
    try:
        w = header["world"]
        spec = WorldSpec(size=tuple(w["size"]), seed=w["seed"], cells=bytes.fromhex(w["cells"]))
        drones = tuple(DroneSpec(drone=d["drone"], start=tuple(d["start"])) for d in header["drones"])
        autopilots = {d["drone"]: d["autopilot"] for d in header["drones"]}
        config = GameConfig(world=spec, drones=drones, max_turns=header["max_turns"],
                            lost_after=header.get("lost_after", 3))
    except (KeyError, TypeError, ValueError, IndexError, RemoteInputError) as exc:
        raise UsageError(f"bad journal header: {exc}") from None
    return config, autopilots


def inputs_of(records: Iterable[dict], size: Cell) -> Inputs:
    """The inputs a journal records: targets and intents by turn, missed deadlines, vanished drones."""
    items, intents, hovered, vanished = [], {}, {}, {}
    for r in records:
        if r.get("record") != "turn":
            continue
        t = r["turn"]
        items += [(t, d, tuple(p)) for d, p in sorted(r.get("targets", {}).items())]
        if "intent" in r:
            intents[t] = Intent(r["intent"])
        if r.get("hovered"):
            hovered[t] = set(r["hovered"])
        if gone := set(r.get("lost", ())) - set(r.get("hovered", ())):
            vanished[t] = gone
    return Inputs(plan=Plan(tuple(sorted(items))), intents=intents, hovered=hovered, vanished=vanished, scripted=False)


def tracks(config: GameConfig, records: Iterable[dict], until: int | None = None) -> tuple[dict[str, Track], int]:
    out = {d.drone: Track(pos=d.start, path=[d.start]) for d in config.drones}
    last = 0
    for r in records:
        if r.get("record") != "turn" or (until is not None and r["turn"] > until):
            continue
        last = r["turn"]
        for d, p in r.get("targets", {}).items():
            out[d].target = tuple(p)
        for d, p in r.get("moves", {}).items():
            out[d].pos = tuple(p)
            out[d].path.append(tuple(p))
        for d, cause in r.get("deaths", {}).items():
            out[d].state, out[d].cause = "DEAD", cause
        for d in r.get("lost", ()):
            out[d].state, out[d].cause = "LOST", "LOST"
    return out, last


def render(world: World, tr: dict[str, Track], turn: int, *, compact: bool | None = None) -> str:
    trail = [c for t in tr.values() for c in t.path if world.contains(c)]
    targets = {d: t.target for d, t in tr.items() if t.target is not None}
    floors = sorted({c[2] for c in trail} | {c[2] for c in targets.values()})
    alive = {d: t.pos for d, t in tr.items() if t.state == "ALIVE"}
    return f"after turn {turn}:\n" + world.draw(alive, targets=targets, trail=trail, floors=floors, compact=compact)


def summary(tr: dict[str, Track], over: dict | None) -> str:
    lines = [f"OVER at turn {over['turn']}: {over['reason']} - {over['text']}"] if over else []
    for d, t in tr.items():
        end = t.state if not t.cause else f"{t.state} ({t.cause.lower()})"
        lines.append(f"  {d}: {end} at {t.pos}, {len(t.path) - 1} moves, target {t.target}")
    return "\n".join(lines)


def verify(path: str, records: list[dict], config: GameConfig, autopilots: dict[str, str]) -> str | None:
    """None if a fresh in-process re-simulation writes exactly this journal; else the first difference. A game
    the journal leaves unfinished (no over record: a crash, a full disk) is checked as far as it goes."""
    quiet = logging.getLogger("dronesim.replay.verify")
    result = simulate(config, autopilots, inputs_of(records, config.world.size), quiet)
    if records[-1].get("record") != "over":
        result.records[len(records):] = []
    for n, (mine, theirs) in enumerate(zip(records, result.records), 1):
        if dumps(mine) != dumps(theirs):
            return f"{path}:{n}: journal has\n  {dumps(mine)}\nre-simulation gives\n  {dumps(theirs)}"
    if len(records) != len(result.records):
        return f"{path}: journal has {len(records)} records, re-simulation gives {len(result.records)}"
    return None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim replay", description=__doc__)
    p.add_argument("journal")
    p.add_argument("--turns", action="store_true", help="print every turn's drone states")
    p.add_argument("--at", type=int, help="render the state after this turn (default: the end)")
    p.add_argument("--compact", action="store_true", help="one character per cell")
    p.add_argument("--verify", action="store_true", help="check the journal against a fresh re-simulation")
    args = p.parse_args(argv)
    logging.getLogger("dronesim.replay.verify").setLevel(logging.ERROR)  # the run's own events, already shown
    try:
        records = list(read(args.journal))
        if not records:
            raise UsageError(f"{args.journal} is empty")
        config, autopilots = header_config(records[0])
        world = build_world(config.world, (d.start for d in config.drones))
        if args.turns:
            for r in records[1:]:
                if r.get("record") == "turn":
                    tr, t = tracks(config, records, until=r["turn"])
                    print(f"turn {t}: " + ", ".join(f"{d} {x.pos} {x.state}" for d, x in tr.items()))
        tr, t = tracks(config, records, until=args.at)
        print(render(world, tr, t, compact=True if args.compact else None))
        over = next((r for r in records if r.get("record") == "over"), None)
        print(summary(tr, over if args.at is None else None))
        if args.verify:
            if diff := verify(args.journal, records, config, autopilots):
                print(f"VERIFY FAILED: {diff}")
                return 1
            unfinished = "" if over else f"; the game is unfinished: its last turn is {t}"
            print(f"verified: a fresh re-simulation writes this journal byte for byte ({len(records)} records"
                  f"{unfinished})")
    except UsageError as err:
        print(f"dronesim replay: {err}", file=sys.stderr)
        return 2
    except (KeyError, TypeError, ValueError, IndexError) as err:  # a turn record not of the journal format
        print(f"dronesim replay: {args.journal}: bad journal record: {err!r}", file=sys.stderr)
        return 2
    return 0
