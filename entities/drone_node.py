"""A drone process (the seed's D01), or a swarm host flying several drones in one process: the Zenoh adapter of
`DroneProcess` (entities/drone.py, where its protocol, sensing and chart are described).

It subscribes to the DRONES phase's TURN and to OVER, watches the coordinator's presence (`Membership`: admission,
kept through a coordinator restart) and the environment's, and hands every event to the core in batches of
everything queued. It carries out the core's effects: publishes NPS or MOVES, sends ASK and MAP queries whose
outcome comes back to the core as one event each, and keeps the core's one timer. It exits on OVER.

A swarm host whose planning of a turn goes on for a while says so (`Deciding`, a thread: the main thread is in the
plan): an empty MOVES every DECIDING_EVERY_S while its main thread computes, so that the coordinator waits for it
instead of making its drones hover and, turns later, LOST. A hung host computes nothing and says nothing. The MOVES
that follows such a word goes out again a few times (`Effects.repeat`: the router's budget may drop it).
"""

from __future__ import annotations

import argparse
import functools
import logging
import sys
import threading
import time
from collections.abc import Callable

import zenoh

from network.membership import Answered, Membership, add_entity_args
from network.signals import closing, until_stopped
from network.transport import (
    Inbox,
    Outbox,
    Presence,
    Received,
    add_zenoh_args,
    open_session,
    session_id,
    setup_logging,
    zenoh_config,
)
from schema import Ans, Ask, Connect, Keys, Moves, Nps, Over, Phase, Role, StepTable, Turn, UsageError, WorldMap
from schema.messages import drone_list, is_host_id
from schema.tuning import (
    ASK_TIMEOUT_S,
    CONNECT_TIMEOUT_S,
    COORDINATOR_GRACE_S,
    DECIDING_BUSY,
    DECIDING_EVERY_S,
    DECIDING_SILENCE_S,
    MOVES_REPEAT_S,
    PUT_GAP,
)

from .autopilots import DEFAULT, REGISTRY, SWARM_MIN, pilot_class
from .drone import Answer, DroneProcess, Effect, EnvPresence, Expired, Input, Query, Refusal, SendMoves, Timer


def main(conf: zenoh.Config, *, drones: tuple[str, ...], autopilot: str, keys: Keys, logger: logging.Logger,
         host: str | None = None, connect_timeout: float = CONNECT_TIMEOUT_S, grace: float = COORDINATOR_GRACE_S,
         ask_timeout: float = ASK_TIMEOUT_S, swarm_min: int = SWARM_MIN, chart: bool = True) -> Over:
    with open_session(conf) as session:
        inbox = Inbox(session, keys, logger)
        inbox.subscribe(keys.turn_of(Phase.DRONES), Turn)
        inbox.subscribe(keys.over, Over)
        inbox.watch_presence("ENV")
        hello = Connect(turn=0, sender=host or drones[0], role=Role.DRONE, drones=drones, autopilot=autopilot,
                        cooperative=pilot_class(autopilot).cooperative, session=session_id(session))
        member = Membership(session, inbox, hello, logger, connect_timeout=connect_timeout, grace=grace)
        core = DroneProcess(member.welcome, drones=drones, autopilot=autopilot, logger=logger, host=host,
                            swarm_min=swarm_min, patience=grace, chart=chart)
        effects = Effects(inbox, Outbox(session), ask_timeout=ask_timeout, map_timeout=grace)
        effects.run(core.start())
        pulse = Deciding(core, effects.send, thread_cpu(), repeat=effects.repeat) if host else None
        if pulse is not None:
            pulse.start()

        def handle(event: object) -> None:
            if event is None:  # nothing came in time: the coordinator's grace, or the core's timer, is over
                member.check()
                effects.run(core.receive(effects.expired()))
                return
            inputs: list[Input] = []
            for ev in (event, *inbox.drain()):
                match ev:
                    case _ if not member.screen(ev, inbox.rejects):
                        pass
                    case Presence("SRV") | Answered():
                        member.on_event(ev)
                    case Presence(_, sid, alive):
                        inputs.append(EnvPresence(sid, alive))
                    case Received(_, Turn() | Over() as msg):
                        inputs.append(msg)
                    case Answer():  # the outcome of a query
                        inputs.append(ev)
            effects.run(core.receive(inputs))

        waits = lambda: (t for t in (member.timeout(), effects.due_in()) if t is not None)  # noqa: E731
        try:
            inbox.run(handle, timeout=lambda: min(waits(), default=None), until=lambda: core.over is not None)
        finally:
            if pulse is not None:
                pulse.stop()
        assert core.over is not None
        closing(core.over)  # (a signal from now on: the game's status, not 143)
        member.close()
        return core.over


class Effects:
    """Carries out the core's effects: publications, queries (their outcome an `Answer` event), its timer."""

    def __init__(self, inbox: Inbox, out: Outbox, *, ask_timeout: float, map_timeout: float,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        self.inbox, self.out, self.keys = inbox, out, inbox.keys
        self.ask_timeout, self.map_timeout = ask_timeout, map_timeout
        self.clock, self.sleep = clock, sleep
        self._timer: tuple[float, int] | None = None  # (when, ref)
        self._sending = threading.Lock()  # the moves go out one at a time (`Deciding` sends from its thread)
        self._sent: dict[str, float] = {}  # key -> when the last put on it went out
        self._said: dict[str, int | None] = {}  # MOVES key -> the turn of its last put if a word (`Deciding`'s)
        #: MOVES key -> the MOVES that followed a word, when it first went out and when it goes out again (`repeat`)
        self._repeats: dict[str, tuple[Moves, float, float] | None] = {}

    def send(self, msg: Moves | Nps, unless: Callable[[], bool] = lambda: False) -> None:
        """Publish a swarm host's MOVES or a lone drone's NPS, unless `unless()`, asked once no other is being sent
        (`Deciding`'s word for a turn whose moves have gone out meanwhile is not sent after them), PUT_GAP s at
        least after the last put on its key (the router keeps at most PUT_RATE a second: a MOVES right after a word
        that the host is still deciding would be dropped). A host's MOVES after its word for that turn is sent
        again (`repeat`)."""
        key = (self.keys.moves if isinstance(msg, Moves) else self.keys.nps)(msg.sender)
        with self._sending:
            if not unless():
                self._put(key, msg)
                if isinstance(msg, Moves):
                    said = self._said.get(key)
                    self._said[key] = msg.turn if not len(msg.moves) else None
                    self._repeats[key] = ((msg, self._sent[key], self._sent[key] + MOVES_REPEAT_S)
                                          if len(msg.moves) and said == msg.turn else None)

    def _put(self, key: str, msg: Moves | Nps) -> None:
        if (wait := self._sent.get(key, float("-inf")) + PUT_GAP - self.clock()) > 0:
            self.sleep(wait)
        self.out.put(key, msg)
        self._sent[key] = self.clock()

    def repeat(self, deciding: int | None = None) -> None:
        """Send again, when due, a host's MOVES that followed its word that it was still deciding that turn: on a
        loaded machine both may reach the router together (its link sends what is queued in one batch), and its
        budget then keeps the word and drops the MOVES (seen: the coordinator heard the word, never the moves, and
        its drones were LOST). Again MOVES_REPEAT_S after, then twice as long each time, for as long as the
        coordinator may still wait for them (DECIDING_SILENCE_S after the word); it takes a repeat of the MOVES it
        holds as nothing new (coordinator/engine.py `Engine.receive`). Not once the host decides a later turn
        (`deciding`): that turn's TURN came, the coordinator is done with these moves (it would refuse them as
        stale)."""
        with self._sending:
            for key, due in list(self._repeats.items()):
                if due is not None and deciding is not None and deciding > due[0].turn:
                    self._repeats[key] = due = None
                if due is None or self.clock() < due[2]:
                    continue
                msg, first, at = due
                self._put(key, msg)
                later = first + 2 * (at - first)
                self._repeats[key] = (msg, first, later) if later - first <= DECIDING_SILENCE_S else None

    def run(self, effects: list[Effect]) -> None:
        for eff in effects:
            match eff:
                case SendMoves(msg):  # a swarm host's MOVES, a lone drone's NPS
                    self.send(msg)
                case Query(ref, msg):  # an ASK, or the map
                    key, reply, timeout = ((self.keys.ask, Ans, self.ask_timeout) if isinstance(msg, Ask)
                                           else (self.keys.map, WorldMap, self.map_timeout))
                    self.inbox.query(key, msg, reply, timeout=timeout, then=functools.partial(Answer, ref))
                case Timer(ref, seconds):
                    self._timer = (time.monotonic() + seconds, ref)
                case Refusal(what, err):
                    self.inbox.rejects.reject(what, err)

    def due_in(self) -> float | None:
        return None if self._timer is None else max(0.0, self._timer[0] - time.monotonic())

    def expired(self) -> list[Expired]:
        """The timer, if it ran out (then it is cleared)."""
        if self._timer is None or self._timer[0] > time.monotonic():
            return []
        ref, self._timer = self._timer[1], None
        return [Expired(ref)]


class Deciding:
    """A swarm host's word that it is still deciding a turn (an empty MOVES), every `every` seconds while the core
    decides one and the main thread computes (its CPU time, `cpu`, went on by at least `busy` of the interval since
    the last look): the coordinator then waits for its moves, up to its cap (`Engine.stretch`). On a thread of its
    own (the main thread is in the plan); a hung process (stopped, or its main thread blocked) says nothing."""

    def __init__(self, core: DroneProcess, send: Callable[..., None], cpu: Callable[[], float], *,
                 every: float = DECIDING_EVERY_S, busy: float = DECIDING_BUSY,
                 repeat: Callable[[int | None], None] = lambda deciding: None) -> None:
        self.core, self.send, self.cpu, self.every, self.busy, self.repeat = core, send, cpu, every, busy, repeat
        self._last: tuple[int | None, float] = (None, 0.0)  # the turn being decided and the CPU time, at the last look
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="deciding", daemon=True)

    def look(self) -> Moves | None:
        """The word to send now, if any: the same turn is being decided as at the last look, and worked on."""
        now = (self.core.deciding(), self.cpu())
        was, self._last = self._last, now
        if now[0] is None or now[0] != was[0] or now[1] - was[1] < self.busy * self.every:
            return None
        return Moves(turn=now[0], sender=self.core.sender, moves=StepTable.of([]))

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            if (word := self.look()) is not None:  # (not once that turn's moves went out: they close it)
                self.send(word, unless=functools.partial(self._decided, word.turn))
            self.repeat(self.core.deciding())  # (the moves that followed a word, again: `Effects.repeat`)

    def _decided(self, turn: int) -> bool:
        return self.core.deciding() != turn

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def thread_cpu() -> Callable[[], float]:
    """A clock of the calling thread's CPU time (seconds) that another thread may read (where the platform has none:
    the process's)."""
    try:
        clock = time.pthread_getcpuclockid(threading.get_ident())
        time.clock_gettime(clock)
    except (AttributeError, OSError):
        return time.process_time
    return functools.partial(time.clock_gettime, clock)


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim drone", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--id", default="D01", help="drone id(s): D01, or D01-D08 for a swarm host (default D01)")
    p.add_argument("--host", help="swarm host id Hnn (required when flying several drones)")
    p.add_argument("--autopilot", default=DEFAULT, choices=sorted(REGISTRY), help=f"default: {DEFAULT}")
    p.add_argument("--swarm-pilot-min", type=int, default=SWARM_MIN, metavar="N",
                   help="a swarm host flies its drones with the autopilot's swarm form (one pilot over arrays, same "
                        f"decisions) when it has one and flies at least N drones (default {SWARM_MIN})")
    p.add_argument("--no-chart", dest="chart", action="store_false",
                   help="keep no chart of what the environment said: ask it every question (to measure the chart)")
    add_entity_args(p)
    args = p.parse_args(argv)
    try:
        drones = drone_list(args.id)
        if len(drones) > 1 and not args.host:
            raise UsageError("several drones in one process need --host Hnn")
        if args.host is not None and not is_host_id(args.host):
            raise UsageError(f"--host {args.host!r} is not a host id (H01, H02, ...)")
        logger = setup_logging(args.log_level, args.host or drones[0])
        return until_stopped(lambda: main(zenoh_config(args), drones=drones, autopilot=args.autopilot,
                                          keys=Keys(args.root), logger=logger, host=args.host,
                                          connect_timeout=args.connect_timeout, grace=args.grace,
                                          swarm_min=args.swarm_pilot_min, chart=args.chart), logger)
    except UsageError as err:
        print(f"dronesim drone: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(cli())
