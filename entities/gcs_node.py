"""The ground station process (the seed's GCS): the human's console, or a scripted plan.

Each GCS phase it sends the targets that change (`entities.gcs.Station`, the protocol every ground station
plays); after each turn it shows every drone's state; on OVER it draws the world with the drones' paths and
prints a summary. Interactive mode forces a first target, then offers each turn to change it.

This module is the terminal's Zenoh adapter and the `dronesim gcs` command, which picks the face (terminal, web);
every face connects and plays through `entities.station_link`.
"""

from __future__ import annotations

import argparse
import logging
import queue
import sys
import threading
from collections.abc import Callable, Sequence
from functools import partial
from typing import TextIO

from network.membership import add_entity_args
from network.signals import until_stopped, waking
from network.transport import (
    Outbox,
    add_zenoh_args,
    open_session,
    setup_logging,
    zenoh_config,
)
from schema import Keys, Over, UsageError

from .gcs import Console, Ground, Station
from .station_link import join, listen, play, publisher
from .tasks import Tasks


class Lines:
    """The terminal's lines, read by a thread of their own: the main thread waits for the next one in a
    queue, which a signal wakes (`network.signals.waking`), where a read of its own would wait on."""

    _WAKE = object()

    def __init__(self, stream: TextIO) -> None:
        self._q: queue.SimpleQueue[object] = queue.SimpleQueue()
        threading.Thread(target=self._pump, args=(stream,), name="stdin", daemon=True).start()

    def _pump(self, stream: TextIO) -> None:
        for line in stream:
            self._q.put(line)
        self._q.put(None)

    def wake(self) -> None:
        self._q.put(self._WAKE)

    def read(self, prompt: str) -> str:
        """`input`: the next line without its end of line, EOFError at the end."""
        print(prompt, end="", flush=True)
        while (line := self._q.get()) is self._WAKE:
            pass
        if not isinstance(line, str):
            self._q.put(None)  # the end, for the next read too
            raise EOFError
        return line.rstrip("\n")


def main(args: argparse.Namespace, logger: logging.Logger) -> Over:
    conf, keys, draw = zenoh_config(args), Keys(args.root), not args.no_draw
    with open_session(conf) as session:
        inbox = listen(session, keys, logger)
        lines = (None if args.targets or args.script or args.scenario or args.ros2  # no plan: a person
                 or args.lifelong is not None else Lines(sys.stdin))
        with waking(partial(inbox.post, None), *([lines.wake] if lines else [])):  # a signal ends any wait
            member = join(session, inbox, logger, connect_timeout=args.connect_timeout, grace=args.grace)
            ground = Ground.from_welcome(member.welcome, args.targets, args.script)
            console = Console(ground.world, list(ground.starts), read=lines.read) if lines else None
            tasks = None if args.lifelong is None else Tasks(ground.world, args.lifelong)
            station = Station(ground, console=console, verbose=not args.quiet, goals=args.ros2, tasks=tasks)
            if draw:
                print(station.opening(), flush=True)
            show = publisher(Outbox(session), keys, logger, lambda text: print(text, flush=True))
            take = None
            if args.ros2:
                from .ros2.node import take_goals

                take = take_goals(args, session, inbox, ground, lambda drone, cell: station.want({drone: cell}),
                                  lambda text: print(text, flush=True), logger)
            over = play(station, inbox, member, show, other=partial(unexpected, take, logger))
        print(station.report(draw=draw), flush=True)
        if inbox.rejects.total:
            logger.info("rejected inputs: %s", inbox.rejects.snapshot())
        member.close()
        return over


def unexpected(take: Callable[[object], bool] | None, logger: logging.Logger, event: object) -> None:
    """An event of the inbox besides the game's: a ROS 2 goal if goals are taken, else a bug (logged)."""
    if take is None or not take(event):
        logger.error("unexpected event %r", event)


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
                        "the terminal's or the web page's")
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
