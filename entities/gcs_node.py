"""The ground station process (the seed's GCS): the human's console, or a scripted plan.

Each GCS phase it sends the targets that change (`entities.gcs.Station`, the protocol every ground station
plays); after each turn it shows every drone's state; on OVER it draws the world with the drones' paths and
prints a summary. Interactive mode (no plan) is the console (`entities.console`): it forces a first target, then
offers each turn to change it; with ``--ros2`` a ROS 2 goal is a target typed there.

This module is the terminal's Zenoh adapter and the `dronesim gcs` command, which picks the face (terminal, web);
every face connects and plays through `entities.station_link`.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
from collections.abc import Callable, Sequence
from functools import partial
from typing import TextIO

from network.membership import add_entity_args
from network.signals import closing, until_stopped, waking
from network.transport import (
    Outbox,
    add_zenoh_args,
    open_session,
    setup_logging,
    zenoh_config,
)
from schema import Cell, Keys, Over, UsageError

from .console import Console, Prompt, Typed
from .gcs import Effect, End, Ground, SendDone, Show, Station
from .station_link import join, listen, play, publisher
from .tasks import Tasks


def read_lines(stream: TextIO, post: Callable[[object], None]) -> None:
    """The terminal's lines, read by a thread of their own and posted (`Typed`; None at the end) where the main
    thread waits: its inbox, which a signal wakes too (`network.signals.waking`), where a read would wait on."""
    def pump() -> None:
        for line in stream:
            post(Typed(line.rstrip("\n")))
        post(Typed(None))
    threading.Thread(target=pump, name="stdin", daemon=True).start()


class Screen:
    """The terminal's output: each text on lines of its own, the console's prompt last. A text that comes while the
    prompt waits (a turn's status, a ROS 2 goal's fate) goes on a line of its own, and the prompt is shown again
    below it, unless the phase it asked about has been answered. `echoed`: a line typed ends the prompt's line (a
    terminal's echo; a pipe's lines are not shown)."""

    def __init__(self, out: TextIO, *, echoed: bool) -> None:
        self.out, self.echoed = out, echoed
        self.prompt: str | None = None  # the prompt waiting for a line
        self.open = False  # the last line shown is a prompt's, not ended

    def _write(self, text: str) -> None:
        if self.open:
            self.out.write("\n")
        self.out.write(text)
        self.out.flush()

    def show(self, text: str) -> None:
        self._write(text + "\n")
        self.open = False
        if self.prompt is not None:
            self.ask(self.prompt)

    def ask(self, prompt: str) -> None:
        self._write(prompt)
        self.prompt, self.open = prompt, True

    def answered(self) -> None:
        """The phase the prompt asked about is answered: it is not shown again."""
        self.prompt = None

    def typed(self) -> None:
        if self.echoed:
            self.open = False


class Terminal:
    """The terminal face: carries out its protocol's effects (on the `screen`, and `send`: `station_link.publisher`)
    and hands the `console`, if a person is at it, the lines typed and ROS 2's goals (`take`, with `--ros2`)."""

    def __init__(self, station: Station, console: Console | None, screen: Screen, send: Callable[[Effect], None],
                 logger: logging.Logger) -> None:
        self.station, self.console, self.screen, self.send, self.log = station, console, screen, send, logger
        self.take: Callable[[object], bool] | None = None

    def perform(self, effect: object) -> None:
        match effect:
            case Prompt(text):
                self.screen.ask(text)
            case SendDone(ahead=False):
                self.screen.answered()
                self.send(effect)
            case SendDone() | Show() | End():
                self.send(effect)

    def goal(self, drone: str, cell: Cell) -> None:
        """A ROS 2 goal read well (`take_goals`): the drone's target (a UsageError if the console refuses it)."""
        if self.console is None:
            self.station.take(drone, cell)
            return
        for effect in self.console.goal(drone, cell):
            self.perform(effect)

    def other(self, event: object) -> None:
        """An event of the inbox besides the game's: a line typed, a ROS 2 goal, else a bug (logged)."""
        if isinstance(event, Typed) and self.console is not None:
            self.screen.typed()
            for effect in self.console.line(event.text):
                self.perform(effect)
        elif self.take is None or not self.take(event):
            self.log.error("unexpected event %r", event)


def main(args: argparse.Namespace, logger: logging.Logger) -> Over:
    conf, keys, draw = zenoh_config(args), Keys(args.root), not args.no_draw
    with open_session(conf) as session:
        inbox = listen(session, keys, logger)
        person = not (args.targets or args.script or args.scenario  # no plan: a person at the console
                      or args.lifelong is not None)
        if person:
            read_lines(sys.stdin, inbox.post)
        with waking(partial(inbox.post, None)):  # a signal ends any wait (a prompt's too)
            member = join(session, inbox, logger, connect_timeout=args.connect_timeout, grace=args.grace)
            ground = Ground.from_welcome(member.welcome, args.targets, args.script)
            console = Console(ground, goals=args.ros2, verbose=not args.quiet) if person else None
            tasks = None if args.lifelong is None else Tasks(ground.world, args.lifelong)
            station = console.station if console else Station(ground, verbose=not args.quiet, goals=args.ros2,
                                                                tasks=tasks)
            screen = Screen(sys.stdout, echoed=person and sys.stdin.isatty())
            if draw:
                screen.show(station.opening())
            face = Terminal(station, console, screen, publisher(Outbox(session), keys, logger, screen.show), logger)
            if args.ros2:
                from .ros2.model import drone_topic
                from .ros2.node import take_goals

                face.take = take_goals(args, session, inbox, ground, face.goal, screen.show, logger)
                if console is not None:
                    screen.show(f"ROS 2 goals on {drone_topic(args.namespace, '<Dnn>', 'goal_pose')} (domain "
                                f"{args.domain}) are targets typed here")
            over = play(console or station, inbox, member, face.perform, other=face.other)
            closing(over)  # (a signal from now on: the game's status, not 143)
        screen.show(station.report(draw=draw))
        if inbox.rejects.total:
            logger.info("rejected inputs: %s", inbox.rejects.snapshot())
        member.close()
        return over


#: Reads a scenario file's targets and, for a lifelong game, the seed of its draws (None: not lifelong).
ScenarioPlan = Callable[[str], tuple[Sequence[str], int | None]]


def cli(argv: list[str] | None = None, *, scenario_plan: ScenarioPlan | None = None) -> int:
    """`dronesim gcs`; `scenario_plan` reads a scenario file's targets and lifelong seed (`dronesim.scenario`,
    which the application hands in: the ground station reads no scenario format of its own)."""
    from .mavlink.options import add_mavlink_args
    from .ros2.node import add_ros2_args
    from .web.node import add_web_args, run_web

    p = argparse.ArgumentParser(prog="dronesim gcs", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--targets", action="append", default=[], metavar="[Dnn=]x,y,z[@turn]",
                   help="scripted targets (repeatable, or ';'-separated)")
    p.add_argument("--script", help="a file of scripted targets, one [Dnn=]x,y,z[@turn] per line")
    p.add_argument("--scenario", help="take the scripted targets from a scenario file")
    p.add_argument("--lifelong", type=int, metavar="SEED",
                   help="a lifelong game: each drone that reaches its target gets a new one, drawn with SEED "
                        "(entities/tasks.py; the coordinator plays it with --lifelong)")
    p.add_argument("--quiet", action="store_true", help="do not print every turn's status")
    p.add_argument("--no-draw", action="store_true", help="do not draw the world at the end")
    add_entity_args(p)
    add_web_args(p)
    p.add_argument("--ros2", action="store_true",
                   help="also take targets from ROS 2 goals (/<namespace>/<Dnn>/goal_pose, docs/ros2.md), beside "
                        "the script's, the console's (a goal is a target typed there) or the web page's")
    add_ros2_args(p, viewer=False)
    add_mavlink_args(p, cell_size=False)  # (--cell-size: the ROS 2 flags')
    args = p.parse_args(argv)
    logger = setup_logging(args.log_level, "GCS")

    def run() -> object:
        if args.ros2 and (args.mavlink or args.replay is not None):
            raise UsageError("--ros2 goals go to the terminal or web ground station: not with --mavlink (its "
                             "targets are its vehicles') nor --replay (a replay takes no targets)")
        if args.scenario:
            if scenario_plan is None:
                raise UsageError("--scenario is read by the dronesim command: dronesim gcs --scenario FILE")
            targets, lifelong = scenario_plan(args.scenario)
            args.targets = [*targets, *args.targets]
            if args.lifelong is None:
                args.lifelong = lifelong
        if args.lifelong is not None and (args.web is not None or args.replay is not None or args.mavlink
                                          or args.ros2):
            raise UsageError("--lifelong is the scripted ground station's (not with --web, --mavlink or --ros2)")
        if args.lifelong is not None and args.lifelong < 0:
            raise UsageError(f"--lifelong takes a seed >= 0, got {args.lifelong}")
        if args.web is not None or args.replay is not None:  # the browser ground station (docs/web-gcs.md)
            return run_web(args, logger)
        if args.mavlink:  # every drone a MAVLink vehicle (docs/mavlink.md)
            from .mavlink.node import run_mavlink

            return run_mavlink(args, logger)
        return main(args, logger)

    try:
        return until_stopped(run, logger)  # Ctrl-C, SIGTERM: wherever the main thread waits (a prompt too)
    except UsageError as err:
        logger.error("%s", err)
        return 2


if __name__ == "__main__":
    sys.exit(cli())
