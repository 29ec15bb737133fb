"""``dronesim gcs --web [HOST:]PORT``: the ground station as a web page; ``--replay JOURNAL`` plays a journal.

Live mode is the terminal ground station's admission and protocol (`station_link.play`, `entities.gcs.Station`)
on one main thread that owns the `GroundState`: it drains one queue fed by the Zenoh callbacks and by the
HTTP threads (the human's commands, each answered through its own reply queue), and publishes the state to
the `Hub` after every change. After OVER it serves the final state, then exits 0 (after ``--linger`` seconds).
"""

from __future__ import annotations

import argparse
import logging
import queue
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import zenoh

from network.signals import over_status, waking
from network.transport import Inbox, Outbox, open_session, zenoh_config
from schema import Cell, Keys, Over, UsageError
from schema.tuning import COMMAND_TIMEOUT, MAX_WAIT_S, STREAMS_STOP_S, WEB_PACE_S

from ..gcs import Ground
from ..station_link import join, listen, play, publisher
from .model import GroundState, Refresh, Rejected, check_pace_arg, world_json
from .server import Hub, WebServer, parse_address


def add_web_args(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("web ground station (docs/web-gcs.md)")
    g.add_argument("--web", metavar="[HOST:]PORT",
                   help="serve the ground station as a web page on this address instead of the terminal "
                        "(host 127.0.0.1 unless given; port 0: any free port)")
    g.add_argument("--replay", metavar="JOURNAL", help="with --web: play this journal in the page (no network)")
    g.add_argument("--pace", type=float, default=WEB_PACE_S,
                   help=f"with --web: at most one turn every PACE seconds, so a human can follow "
                        f"(default {WEB_PACE_S:g})")
    g.add_argument("--linger", type=float, default=0.0,
                   help="with --web: keep serving the final state this many seconds after OVER (default 0); "
                        "with --replay: serve this long (default: until interrupted)")


@dataclass(frozen=True, slots=True)
class Command:
    """A human's command from an HTTP thread, answered on `reply` (a dict, or the `Rejected` error)."""

    action: str
    args: dict
    reply: queue.SimpleQueue


class LiveBackend:
    """The HTTP threads' side of the bridge: commands go to the main thread and wait for its answer."""

    mode = "live"

    def __init__(self, post) -> None:
        self._post = post
        self._lock = threading.Lock()
        self._closed = False
        self.static_world: dict | None = None  # set once admitted

    def world(self) -> dict:
        if self.static_world is None:
            raise Rejected("the ground station is still connecting", 503)
        return self.static_world

    def replay(self) -> dict:
        raise Rejected("this ground station is live: GET /api/state or /api/events", 404)

    def command(self, action: str, args: dict) -> dict:
        reply: queue.SimpleQueue = queue.SimpleQueue()
        with self._lock:
            if self._closed:
                raise Rejected("the game is over", 409)
            self._post(Command(action, args, reply))
        try:
            result = reply.get(timeout=COMMAND_TIMEOUT)
        except queue.Empty:
            raise Rejected("the ground station did not answer in time: try again", 503) from None
        if isinstance(result, Rejected):
            raise result
        return result

    def close(self) -> None:
        """No more commands; those already posted are in the queue, before anything posted later."""
        with self._lock:
            self._closed = True


def carry_out(state: GroundState, cmd: object) -> None:
    """Carry out a command posted by an HTTP thread (anything else in the queue is a bug: logged)."""
    log = logging.getLogger("dronesim.GCS")
    if not isinstance(cmd, Command):
        log.error("unexpected event %r", cmd)
        return
    try:
        if cmd.action == "target":
            result: dict | Rejected = state.set_target(cmd.args.get("drone"), cmd.args["cell"])
        else:
            result = state.control(cmd.action, cmd.args.get("value"))
    except Rejected as err:
        result = err
    except Exception as exc:  # a bug must not leave the page waiting, nor stop the game
        log.exception("command %s failed", cmd.action)
        result = Rejected(f"internal error: {exc}", 500)
    cmd.reply.put(result)


def run_live(args: argparse.Namespace, logger: logging.Logger, address: tuple[str, int]) -> Over:
    conf, keys, pace, hub = zenoh_config(args), Keys(args.root), check_pace_arg(args.pace), Hub()
    with open_session(conf) as session:
        inbox = listen(session, keys, logger, every_phase=True)
        backend = LiveBackend(inbox.post)
        server = WebServer(address, backend, hub, logger)  # binds now: a taken port fails before admission
        try:
            with waking(partial(inbox.post, None)):  # a signal ends any wait (a phase held for the human)
                member = join(session, inbox, logger, connect_timeout=args.connect_timeout, grace=args.grace)
                ground = Ground.from_welcome(member.welcome, args.targets, args.script)
                state = GroundState(ground, pace=pace, title=f"root {keys.root}", intro=member.welcome.text)
                backend.static_world = world_json(ground.world, mode="live", title=state.title)
                hub.publish(state.snapshot())
                server.start()
                print(f"web ground station: {server.url} ({state.describe()})", flush=True)
                send = publisher(Outbox(session), keys, logger, lambda text: state.note("info", text))
                take = ros2_goals(args, session, inbox, ground, state, logger) if args.ros2 else None
                over = play(state, inbox, member, lambda e: hub.publish(state.snapshot()) if isinstance(e, Refresh)
                            else send(e), other=lambda e: None if take is not None and take(e) else carry_out(state, e))
            backend.close()  # the commands still queued are refused: the game is over
            for cmd in inbox.drain():
                carry_out(state, cmd)
            hub.publish(state.snapshot())
            if inbox.rejects.total:
                logger.info("rejected inputs: %s", inbox.rejects.snapshot())
            member.close()
        except BaseException:
            backend.close()
            server.stop(drain=STREAMS_STOP_S)
            raise
    print(state.station.report(draw=False), flush=True)
    try:
        if args.linger > 0:
            print(f"web ground station: serving the final state on {server.url} for {args.linger:g} s", flush=True)
            threading.Event().wait(args.linger)
    finally:
        server.stop()
    return over


def ros2_goals(args: argparse.Namespace, session: zenoh.Session, inbox: Inbox, ground: Ground, state: GroundState,
               logger: logging.Logger) -> Callable[[object], bool]:
    """ROS 2 goals beside the page's targets (`--ros2`): each a target as if clicked on the page (the same checks),
    its fate in the page's log."""
    from ..ros2.node import take_goals

    def set_target(drone: str, cell: Cell) -> None:
        try:
            state.set_target(drone, cell)
        except Rejected as err:
            raise UsageError(str(err)) from None

    return take_goals(args, session, inbox, ground, set_target, lambda text: state.note("info", text), logger)


class ReplayBackend:
    mode = "replay"

    def __init__(self, replay) -> None:
        self._world = replay.world_json()
        self._replay = replay.replay_json()

    def world(self) -> dict:
        return self._world

    def replay(self) -> dict:
        return self._replay

    def command(self, action: str, args: dict) -> dict:
        raise Rejected("this is a replay: it takes no targets nor commands", 409)


def run_replay(args: argparse.Namespace, logger: logging.Logger, address: tuple[str, int]) -> None:
    from .replay import Replay

    replay = Replay(args.replay)
    server = WebServer(address, ReplayBackend(replay), Hub(), logger)
    server.start()
    print(f"web ground station: {server.url} (replay of {args.replay}: {len(replay.frames) - 1} turns)", flush=True)
    try:
        threading.Event().wait(args.linger if args.linger > 0 else None)
    finally:
        server.stop(drain=STREAMS_STOP_S)


def run_web(args: argparse.Namespace, logger: logging.Logger) -> int:
    """`dronesim gcs --web ...` (its targets, scenario's included, in `args.targets`): 0 after OVER (75 after
    OVER JOURNAL_FAILED: `network.signals.over_status`) or at the
    end of a replay's `--linger`; a UsageError for bad flags. Stopped by a signal (gcs_node.cli), it exits
    with 128 + its number, the page's server stopped."""
    if args.web is None:
        raise UsageError("--replay needs --web [HOST:]PORT")
    address = parse_address(args.web)
    if not 0 <= args.linger <= MAX_WAIT_S:  # (nan too: kept forever; inf overflowed the wait)
        raise UsageError(f"--linger must be in 0..{MAX_WAIT_S:g} seconds (a day), got {args.linger:g}")
    run = run_live if args.replay is None else run_replay
    return over_status(run(args, logger, address))


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run it as: dronesim gcs --web [HOST:]PORT")
