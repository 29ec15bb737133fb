"""``dronesim gcs --web [HOST:]PORT``: the ground station as a web page; ``--replay JOURNAL`` plays a journal.

Live mode holds a Zenoh session like the terminal ground station (same admission, same protocol: each GCS
phase, a TGT per alive drone with its last target, then DONE with their count and intent CONTINUE, or QUIT
from the page's button). One main thread owns the `GroundState`: it drains one queue fed by the Zenoh
callbacks (TURN, STATUS, OVER, presence) and by the HTTP threads (the human's commands, each answered
through its own reply queue). After every change it publishes the state to the `Hub`, which streams it
to every page (Server-Sent Events). After OVER it serves the final state, then exits 0 (or keeps the page
up for ``--linger`` seconds).
"""

from __future__ import annotations

import argparse
import logging
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass

import zenoh

from dronesim.entity import Membership
from dronesim.schema import Connect, EndReason, Keys, Over, Phase, Role, Status, Turn, UsageError
from dronesim.transport import Inbox, Outbox, Presence, Received, session_id, zenoh_config

from ..gcs import Ground, Plan, gcs_done
from .model import GroundState, Rejected, check_pace_arg, world_json
from .server import Hub, WebServer, parse_address

#: Seconds an HTTP thread waits for the main thread to carry out a command.
COMMAND_TIMEOUT = 10.0
#: Seconds to wait after OVER for the last STATUS (published before OVER, but on another key).
FINAL_STATUS_WAIT = 5.0
#: End reasons whose last turn produced a STATUS (GCS_QUIT and ABORTED end a turn before its STATUS).
_OBSERVED_ENDS = {EndReason.NO_DRONE_ALIVE, EndReason.ALL_REACHED, EndReason.SETTLED, EndReason.TURN_LIMIT}


def add_web_args(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("web ground station (docs/web-gcs.md)")
    g.add_argument("--web", metavar="[HOST:]PORT",
                   help="serve the ground station as a web page on this address instead of the terminal "
                        "(host 127.0.0.1 unless given; port 0: any free port)")
    g.add_argument("--replay", metavar="JOURNAL", help="with --web: play this journal in the page (no network)")
    g.add_argument("--pace", type=float, default=0.5,
                   help="with --web: at most one turn every PACE seconds, so a human can follow (default 0.5)")
    g.add_argument("--linger", type=float, default=0.0,
                   help="with --web: keep serving the final state this many seconds after OVER (default 0); "
                        "with --replay: serve this long (default: until interrupted)")


def wants_web(args: argparse.Namespace) -> bool:
    return getattr(args, "web", None) is not None or getattr(args, "replay", None) is not None


# --------------------------------------------------------------------------- live mode: the bridge


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
        self._world: dict | None = None

    def set_world(self, world: dict) -> None:
        self._world = world

    def world(self) -> dict:
        if self._world is None:
            raise Rejected("the ground station is still connecting", 503)
        return self._world

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


def carry_out(state: GroundState, cmd: Command) -> None:
    try:
        if cmd.action == "target":
            result = state.set_target(cmd.args.get("drone"), cmd.args.get("cell"))
        else:
            result = state.control(cmd.action, cmd.args.get("value"))
    except Rejected as err:
        cmd.reply.put(err)
    except Exception as exc:  # a bug must not leave the page waiting, nor stop the game
        logging.getLogger("dronesim.GCS").exception("command %s failed", cmd.action)
        cmd.reply.put(Rejected(f"internal error: {exc}", 500))
    else:
        cmd.reply.put(result)


# --------------------------------------------------------------------------- live mode: the loop


def run_live(conf: zenoh.Config, *, keys: Keys, logger: logging.Logger, address: tuple[str, int],
             plan_texts: list[str], script: str | None, pace: float, linger: float,
             connect_timeout: float, grace: float) -> Over:
    hub = Hub()
    with zenoh.open(conf) as session:
        inbox = Inbox(session, keys, logger)
        inbox.subscribe(keys.turn, Turn)
        inbox.subscribe(keys.status, Status)
        inbox.subscribe(keys.over, Over)
        backend = LiveBackend(inbox.post)
        server = WebServer(address, backend, hub, logger)  # binds now: a taken port fails before admission
        try:
            member = Membership(session, inbox, Connect(turn=0, sender="GCS", role=Role.GCS,
                                                        session=session_id(session)),
                                logger, connect_timeout=connect_timeout, grace=grace)
            welcome = member.welcome
            ground = Ground.from_welcome(welcome, plan_texts, script)
            world, drones, plan, size = ground.world, ground.drones, ground.plan, welcome.world.size
            title = f"root {keys.root}"
            state = GroundState(world, welcome.starts.cells(), pace=pace, title=title)
            state.note("info", f"{welcome.text}; world {'x'.join(map(str, size))} with "
                               f"{int(world.grid.sum())} building cells; drones {', '.join(drones)}")
            backend.set_world(world_json(world, mode="live", title=title))
            hub.publish(state.snapshot())
            server.start()
            print(f"web ground station: {server.url} (world {'x'.join(map(str, size))}, "
                  f"drones {', '.join(drones)})", flush=True)
            over = _play(state, inbox, Outbox(session), member, keys, plan, hub, logger)
            _finish(state, inbox, member, backend, hub, over)
            if inbox.rejects.total:
                logger.info("rejected inputs: %s", inbox.rejects.snapshot())
            member.close()
        except BaseException:
            backend.close()
            server.stop(drain=1.0)
            raise
    print(f"GAME OVER at turn {over.turn}: {over.reason.value} - {over.text}", flush=True)
    for d, v in state.drones.items():
        print(f"  {d}: {v.status} at {v.pos}, {len(v.trail) - 1} moves, target {v.target}", flush=True)
    try:
        if linger > 0:
            print(f"web ground station: serving the final state on {server.url} for {linger:g} s", flush=True)
            threading.Event().wait(linger)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return over


def _play(state: GroundState, inbox: Inbox, out: Outbox, member: Membership, keys: Keys,
          plan: Plan, hub: Hub, logger: logging.Logger) -> Over:
    published = state.seq
    while state.over is None:
        waits = [w for w in (state.due(time.monotonic()), member.timeout()) if w is not None]
        event = inbox.get(min(waits) if waits else None)
        if not member.clock.screen(event, inbox.rejects):
            continue
        now = time.monotonic()
        match event:
            case None:
                member.check()
            case Command() as cmd:
                carry_out(state, cmd)
            case Presence() as presence:
                if member.on_presence(presence) is not None:
                    state.note("info", "the coordinator came back: connected again")
            case Received(_, Turn() as turn):
                state.on_turn(turn, now)
                if turn.phase is Phase.GCS and plan.items:
                    state.schedule(turn.turn, plan.at(turn.turn), plan.last_turn)
            case Received(_, Status() as status):
                state.on_status(status)
            case Received(_, Over() as over):
                state.on_over(over)
        if state.due(now) == 0.0:
            turn_no, targets, intent = state.answer(now)
            out.put(keys.gcs_done, gcs_done(turn_no, targets, intent, state.in_force()))
            logger.debug("turn %d: sent %d targets, %s", turn_no, len(targets), intent.value)
        if state.seq != published:
            hub.publish(state.snapshot())
            published = state.seq
    assert state.over is not None
    return state.over


def _finish(state: GroundState, inbox: Inbox, member: Membership, backend: LiveBackend, hub: Hub,
            over: Over) -> None:
    """After OVER: take the last STATUS if it is still on its way, refuse the commands left, publish."""
    if over.reason in _OBSERVED_ENDS:
        end = time.monotonic() + FINAL_STATUS_WAIT
        while state.status_turn < over.turn and time.monotonic() < end:
            event = inbox.get(end - time.monotonic())
            if not member.clock.screen(event, inbox.rejects):
                continue
            match event:
                case Received(_, Status() as status):
                    state.on_status(status)
                case Command() as cmd:
                    carry_out(state, cmd)  # refused: the game is over
    backend.close()
    while (event := inbox.get(0)) is not None:
        if isinstance(event, Command):
            carry_out(state, event)
    hub.publish(state.snapshot())


# --------------------------------------------------------------------------- replay mode


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


def run_replay(path: str, *, address: tuple[str, int], linger: float, logger: logging.Logger) -> None:
    from .replay import Replay

    replay = Replay(path)
    server = WebServer(address, ReplayBackend(replay), Hub(), logger)
    server.start()
    print(f"web ground station: {server.url} (replay of {path}: {len(replay.frames) - 1} turns)", flush=True)
    try:
        threading.Event().wait(linger if linger > 0 else None)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop(drain=1.0)


# --------------------------------------------------------------------------- command line


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def run_web(args: argparse.Namespace, logger: logging.Logger) -> int:
    """`dronesim gcs --web ...`: 0 after OVER (or at the end of a replay), 2 on a usage error."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _interrupt)  # a terminated replay or lingering page exits cleanly
    try:
        if args.web is None:
            raise UsageError("--replay needs --web [HOST:]PORT")
        address = parse_address(args.web)
        if args.linger < 0:
            raise UsageError(f"--linger must be >= 0, got {args.linger:g}")
        if args.replay is not None:
            run_replay(args.replay, address=address, linger=args.linger, logger=logger)
            return 0
        pace = check_pace_arg(args.pace)
        targets = list(args.targets)
        if getattr(args, "scenario", None):
            from dronesim.scenario import Scenario

            targets = [*Scenario.load(args.scenario).targets, *targets]
        run_live(zenoh_config(args), keys=Keys(args.root), logger=logger, address=address, plan_texts=targets,
                 script=args.script, pace=pace, linger=args.linger,
                 connect_timeout=args.connect_timeout, grace=getattr(args, "grace", 30.0))
    except UsageError as err:
        logger.error("%s", err)
        return 2
    except KeyboardInterrupt:
        logger.warning("interrupted")
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run it as: dronesim gcs --web [HOST:]PORT")
