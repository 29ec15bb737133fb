"""The ground station process (the seed's GCS): the human's console, or a scripted plan.

Each GCS phase it sends every drone's target (re-sending the last one, as the seed does) and DONE;
after each turn it shows every drone's state; on OVER it draws the world with the drones' paths and
prints a summary. Interactive mode forces a first target, then offers each turn to change it.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Callable

import zenoh

from dronesim.entity import Membership, add_entity_args
from dronesim.schema import (
    Connect, Intent, Keys, Over, Phase, Role, Status, Turn, UsageError,
)
from dronesim.transport import (
    Event, Inbox, Outbox, Presence, Received, add_zenoh_args, inline_for, session_id, setup_logging, zenoh_config,
)

from .gcs import Ground, Tracks, format_status, gcs_done, parse_command, targets_of, turns_to_answer_ahead
from .web.node import add_web_args, run_web, wants_web


class Console:
    """The seed's interactive loop over a line reader (stdin by default)."""

    def __init__(self, size: tuple[int, int, int], drones: list[str], read: Callable[[str], str] = input,
                 write: Callable[[str], None] = print) -> None:
        self.size, self.drones, self.read, self.write = size, drones, read, write

    def ask(self, turn: int, current: dict) -> tuple[dict, Intent]:
        """New targets for this turn. Drones without a target must get one (the seed forces the first)."""
        new: dict = {}
        while True:
            missing = [d for d in self.drones if d not in current and d not in new]
            if missing:
                prompt = f"turn {turn}: target for {missing[0]} (x,y,z): "
            else:
                prompt = f"turn {turn}: new target ([Dnn] x,y,z; ...), Enter to keep, q to quit: "
            try:
                line = self.read(prompt).strip()
            except EOFError:
                return new, Intent.QUIT
            if line.lower() in ("q", "quit", "exit"):
                return new, Intent.QUIT
            if not line:
                if missing:
                    self.write(f"a first target is required for {missing[0]}")
                    continue
                return new, Intent.CONTINUE
            given: dict = {}
            try:  # all or nothing: one bad item rejects the line
                for part in line.split(";"):
                    part = part.strip()
                    if missing and not part.startswith("D"):
                        part = f"{missing[0]} {part}"
                    given.update(parse_command(part, self.size, self.drones))
                    missing = [d for d in self.drones if d not in current and d not in new and d not in given]
            except UsageError as err:
                self.write(f"invalid: {err}")
                continue
            new.update(given)
            if not missing:
                return new, Intent.CONTINUE


def main(conf: zenoh.Config, *, keys: Keys, logger: logging.Logger, plan_texts: list[str], script: str | None,
         interactive: bool, quiet: bool = False, draw: bool = True, connect_timeout: float = 30.0,
         grace: float = 30.0) -> Over:
    with zenoh.open(conf) as session:
        inbox = Inbox(session, keys, logger)
        inbox.subscribe(keys.turn_of(Phase.GCS), Turn)
        inbox.subscribe(keys.status, Status)
        inbox.subscribe(keys.over, Over)
        member = Membership(session, inbox, Connect(turn=0, sender="GCS", role=Role.GCS, session=session_id(session)),
                            logger, connect_timeout=connect_timeout, grace=grace)
        welcome = member.welcome
        ground = Ground.from_welcome(welcome, plan_texts, script)
        world, drones, plan, size = ground.world, ground.drones, ground.plan, welcome.world.size
        if draw:
            print(f"World {size}, {int(world.grid.sum())} building cells; the drones' floor at start:", flush=True)
            starts = welcome.starts.cells()
            print(world.draw(starts, floors=sorted({c[2] for c in starts.values()})), flush=True)
        console = Console(size, drones) if interactive else None
        out = Outbox(session)
        current: dict = {}
        answered = 0  # the last turn whose GCS phase this station has answered (maybe ahead)
        gone: set[str] = set()

        def plan_intent(turn: int) -> Intent:
            return Intent.FINAL if turn >= plan.last_turn else Intent.CONTINUE

        def answer_ahead(turn: int, answered: int) -> int:
            """A script with nothing new in the turns after `turn` answers them now (the coordinator then
            starts them without asking, and without announcing their GCS phase); the last turn answered."""
            if console is None:
                for ahead in turns_to_answer_ahead(plan, turn, answered):
                    out.put(keys.gcs_done, gcs_done(ahead, {}, plan_intent(ahead)))
                    logger.debug("answered turn %d ahead", ahead)
                    answered = ahead
            return answered

        tracks = Tracks()
        over: Over | None = None

        def handle(event: Event | None) -> None:
            nonlocal answered, over
            if not member.clock.screen(event, inbox.rejects):
                return
            match event:
                case None:
                    member.check()
                case Presence() as presence:
                    if member.on_presence(presence) is not None:  # admitted again: the coordinator sends
                        answered = 0  # the STATUS at once, and it does not know what we said ahead
                case Received(_, Turn(phase=Phase.GCS) as turn):
                    if turn.turn > answered:
                        if console is not None:
                            new, intent = console.ask(turn.turn, current)
                        else:
                            new = plan.at(turn.turn)
                            intent = plan_intent(turn.turn)
                        current.update((d, c) for d, c in new.items() if d not in gone)
                        in_force = targets_of(tracks.last) if tracks.last is not None else None
                        out.put(keys.gcs_done, gcs_done(turn.turn, current, intent, in_force))
                    answered = max(answered, turn.turn)
                    answered = answer_ahead(turn.turn, answered)
                case Received(_, Status() as status):
                    if status.turn + 1 <= answered:  # the coming turn was answered ahead: no TURN(GCS) for it
                        answered = answer_ahead(status.turn + 1, answered)
                    tracks.add(status)
                    table = status.drones
                    ended = {d for d, alive in zip(table.ids(), table.alive_mask().tolist()) if not alive}
                    gone.update(ended)
                    for d in ended & current.keys():
                        del current[d]  # nothing more to say to a dead or lost drone
                    for d, c in targets_of(status).items():  # a late joiner takes over the targets in force
                        if d not in ended:
                            current.setdefault(d, c)
                    if not quiet:
                        print(format_status(status), flush=True)
                case Received(_, Over() as end):
                    over = end

        # A script's answers in a small game are given on Zenoh's thread (see Inbox.run); a console's wait
        # for the user.
        small = inline_for(len(drones))
        inbox.run(handle, timeout=member.timeout, until=lambda: over is not None,
                  inline=lambda event: console is None and small(event))
        # STATUS(t) is published before OVER(t) but on another key: it may arrive just after.
        end = time.monotonic() + 5.0
        while (tracks.last is None or tracks.last.turn < over.turn) and time.monotonic() < end:
            match inbox.get(end - time.monotonic()):
                case Received(_, Status() as status):
                    tracks.add(status)
        if draw and tracks.last is not None:
            last = tracks.last
            paths = tracks.paths
            print("\nFinal world with the drones' paths:")
            trail = [c for p in paths.values() for c in p if world.contains(c)]
            targets = {s.drone: s.target for s in last.drones if s.target is not None}
            floors = sorted({c[2] for c in trail} | {t[2] for t in targets.values()})
            print(world.draw({s.drone: s.pos for s in last.drones if s.alive and world.contains(s.pos)},
                             targets=targets, trail=trail, floors=floors))
        print(f"\nGAME OVER at turn {over.turn}: {over.reason.value} - {over.text}")
        if tracks.last is not None:
            for s in tracks.last.drones:
                print(f"  {s.drone}: {len(tracks.paths[s.drone]) - 1} moves, {format_status_line(s)}")
        if inbox.rejects.total:
            logger.info("rejected inputs: %s", inbox.rejects.snapshot())
        member.close()
        return over


def format_status_line(s) -> str:
    from .gcs import describe

    return describe(s).split(": ", 1)[1]


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim gcs", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--targets", action="append", default=[], metavar="[Dnn=]x,y,z[@turn]",
                   help="scripted targets (repeatable, or ';'-separated)")
    p.add_argument("--script", help="a file of scripted targets, one [Dnn=]x,y,z[@turn] per line")
    p.add_argument("--scenario", help="take the scripted targets from a scenario file")
    p.add_argument("--quiet", action="store_true", help="do not print every turn's status")
    p.add_argument("--no-draw", action="store_true", help="do not draw the world at the end")
    add_entity_args(p)
    add_web_args(p)
    args = p.parse_args(argv)
    logger = setup_logging(args.log_level, "GCS")
    if wants_web(args):  # the browser ground station (entities/web/, docs/web-gcs.md)
        return run_web(args, logger)
    interactive = not args.targets and not args.script and not args.scenario
    try:
        if args.scenario:
            from dronesim.scenario import Scenario

            args.targets = [*Scenario.load(args.scenario).targets, *args.targets]
        main(zenoh_config(args), keys=Keys(args.root), logger=logger, plan_texts=args.targets, script=args.script,
             interactive=interactive, quiet=args.quiet, draw=not args.no_draw, connect_timeout=args.connect_timeout,
             grace=args.grace)
    except UsageError as err:
        logger.error("%s", err)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(cli())
