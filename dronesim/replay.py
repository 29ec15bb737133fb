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

from coordinator.config import GameConfig
from coordinator.journal import Track, dumps, header_config, is_over, over_of, read, tracks, turns
from entities.gcs import Plan
from schema import Cell, EndReason, UsageError
from world.grid import World, build_world

from .local import Inputs, simulate


def inputs_of(records: Iterable[dict], size: Cell) -> Inputs:
    """The inputs a journal records: targets and intents by turn, missed deadlines, vanished drones."""
    items, intents, hovered, vanished = [], {}, {}, {}
    for r in turns(records):
        items += [(r.turn, d, p) for d, p in sorted(r.targets.items())]
        if r.intent is not None:
            intents[r.turn] = r.intent
        if r.hovered:
            hovered[r.turn] = set(r.hovered)
        if gone := set(r.lost) - set(r.hovered):
            vanished[r.turn] = gone
    return Inputs(plan=Plan(tuple(sorted(items))), intents=intents, hovered=hovered, vanished=vanished, scripted=False)


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


#: Ends that come from outside the game's inputs (a signal to the coordinator, the environment's process gone for
#: good): a re-simulation cannot replay them, so `verify` checks what came before them (`stopped_after`).
OUTSIDE_ENDS = frozenset({EndReason.INTERRUPTED.value, EndReason.ABORTED.value})


def stopped_after(records: list[dict]) -> int | None:
    """The last turn of a game ended from outside (`OUTSIDE_ENDS`: its over record's turn), else None."""
    last = records[-1]
    return int(last["turn"]) if is_over(last) and last.get("reason") in OUTSIDE_ENDS else None


def verify(path: str, records: list[dict], config: GameConfig, autopilots: dict[str, str]) -> str | None:
    """None if a fresh in-process re-simulation writes exactly this journal; else the first difference. A game
    the journal leaves unfinished (no over record: a crash, a full disk) is checked as far as it goes, and so is
    a game ended from outside (`stopped_after`) up to its over record, which must close the last turn played."""
    quiet = logging.getLogger("dronesim.replay.verify")
    result = simulate(config, autopilots, inputs_of(records, config.world.size), quiet)
    stopped = stopped_after(records)
    played = records[:-1] if stopped is not None else records
    if stopped is not None or not is_over(records[-1]):
        result.records[len(played):] = []
    for n, (mine, theirs) in enumerate(zip(played, result.records), 1):
        if dumps(mine) != dumps(theirs):
            return f"{path}:{n}: journal has\n  {dumps(mine)}\nre-simulation gives\n  {dumps(theirs)}"
    if len(played) != len(result.records):
        return f"{path}: journal has {len(played)} records, re-simulation gives {len(result.records)}"
    last = max((r.turn for r in turns(played)), default=0)
    if stopped is not None and stopped != last:
        return f"{path}: its over record ({records[-1]['reason']}) is at turn {stopped}, its last turn is {last}"
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
            for r in turns(records):
                tr, t = tracks(config, records, until=r.turn)
                print(f"turn {t}: " + ", ".join(f"{d} {x.pos} {x.state}" for d, x in tr.items()))
        tr, t = tracks(config, records, until=args.at)
        print(render(world, tr, t, compact=True if args.compact else None))
        over = over_of(records)
        print(summary(tr, over if args.at is None else None))
        if config.lifelong:
            done = sum(x.tasks for x in tr.values())
            print(f"lifelong: {done} tasks done in {t} turns, {done / max(t, 1):.3f} a turn")
        if args.verify:
            if diff := verify(args.journal, records, config, autopilots):
                print(f"VERIFY FAILED: {diff}")
                return 1
            unfinished = "" if over else f"; the game is unfinished: its last turn is {t}"
            if (stopped := stopped_after(records)) is not None:
                unfinished = f"; the game was ended from outside ({records[-1]['reason']}) after turn {stopped}: its " \
                    "over record is checked to close that turn, the re-simulation cannot replay the stop"
            print(f"verified: a fresh re-simulation writes this journal byte for byte ({len(records)} records"
                  f"{unfinished})")
    except UsageError as err:
        print(f"dronesim replay: {err}", file=sys.stderr)
        return 2
    except (KeyError, TypeError, ValueError, IndexError) as err:  # a turn record not of the journal format
        print(f"dronesim replay: {args.journal}: bad journal record: {err!r}", file=sys.stderr)
        return 2
    return 0
