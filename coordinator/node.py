"""The coordinator process (the seed's SRV with its observer OBS): the Zenoh adapter of `Engine`.

It serves admission (queryable SRV/CONNECT), publishes TURN/STATUS/OVER,
listens to TGT, DONE, NPS, MOVES and UPD, watches presence tokens, enforces phase deadlines and writes the
journal. `Coordinator` is that loop without Zenoh (driven by events and the time); `main` wires it up.
"""

from __future__ import annotations

import argparse
import itertools
import logging
import os
import secrets
import sys
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import zenoh

from network.progress import Progress
from network.signals import JOURNAL_FAILED_STATUS, Interrupted, exit_status, on_stop, waking
from network.transport import (
    Asked,
    Inbox,
    Matching,
    Outbox,
    Presence,
    Received,
    Sessions,
    add_zenoh_args,
    audit_sessions,
    open_session,
    session_id,
    setup_logging,
    zenoh_config,
)
from schema import (
    Cell,
    Connect,
    Done,
    Keys,
    Message,
    Moves,
    Nps,
    Over,
    Phase,
    Refused,
    RejectCounter,
    Status,
    Target,
    Turn,
    Upd,
    UsageError,
    drone_id,
    encode,
)
from schema.errors import RemoteInputError, WrongSender, excerpt, seconds
from schema.messages import WorldSpec
from schema.tuning import (
    ADMIT_DEADLINE_S,
    GCS_GRACE_S,
    LINGER_S,
    LINK_GRACE_S,
    PEER_CHECK_S,
    PHASE_CAP_S,
    PHASE_DEADLINE_S,
    SETTLE_S,
    STOP_LINGER_S,
)
from world.grid import World

from . import arbiter
from .admission import Presences
from .config import ARBITER, ARBITERS, LOST_AFTER, MAX_TURNS, SIZE, DroneSpec, GameConfig
from .effects import Publish, Record, Refusal, ReplyToConnect
from .engine import Engine
from .journal import JournalFailed, JournalWriter, held_game, read, repair_tail
from .resume import restore
from .stages import Stage


def _key_of(keys: Keys, msg: Message) -> str:
    match msg:
        case Turn():
            return keys.turn_of(msg.phase)
        case Status():
            return keys.status
        case Over():
            return keys.over
    raise AssertionError(f"the coordinator does not publish {msg.TAG}")


class Executor:
    """Carries out the engine's effects in order; with `pace`, a new turn starts at most every `pace`
    seconds (the effects from its TURN on are held until then: a watchable speed, not a synchronisation).
    The end of the game is never held: OVER sends what was held before it, at once."""

    def __init__(self, keys: Keys, out: Outbox, writer: JournalWriter, rejects: RejectCounter,
                 pace: float = 0.0, clock: Callable[[], float] = time.monotonic,
                 unrecorded: Callable[[str, int], list | None] = lambda why, turn: None) -> None:
        self.keys, self.out, self.writer, self.rejects, self.pace, self.clock = keys, out, writer, rejects, pace, clock
        #: Told when a record cannot be journaled (why, the record's turn): the effects that stand instead of the
        #: rest (`Engine.unrecorded`), or None to go on with them (the over record was lost).
        self.unrecorded = unrecorded
        self.failed: JournalFailed | None = None  # the journal failed: nothing more is written to it
        self._held: list = []  # a new turn's TURN, held until `pace` has passed, and the effects after it
        self._turn = 0  # the last turn whose first TURN went out
        self._last = float("-inf")  # when it went out

    def run(self, effects: list) -> None:
        for eff in effects:
            if self._held:
                self._held.append(eff)
                if isinstance(eff, Publish) and isinstance(eff.msg, Over):
                    self.pace = 0.0  # the game is over: nothing waits for a pace any more
                    self.release()
                continue
            match eff:
                case Publish(Turn() as turn) if self.pace and turn.turn > self._turn:
                    self._turn, self._held = turn.turn, [eff]
                    if self.clock() >= self._last + self.pace:
                        self.release()
                case Publish(msg):
                    self.out.put(_key_of(self.keys, msg), msg)
                case ReplyToConnect(query, msg):
                    self.answer(query, encode(msg))
                case Record(data) if self.failed is None:
                    try:
                        self.writer.append(data)
                    except JournalFailed as err:
                        self.failed = err
                        instead = self.unrecorded(str(err), data.get("turn", 0))
                        if instead is not None:  # what the record stood for is not sent
                            self.run(instead)
                            return
                case Refusal(what, err):
                    self.rejects.reject(what, err)

    def answer(self, query: Any, data: bytes) -> None:  # a zenoh.Query (a ReplyToConnect's token)
        """Reply to a query; the final answer: the asker stops waiting now."""
        query.reply(query.key_expr, data)
        query.drop()

    def fail(self, query: Any, text: str) -> None:  # a zenoh.Query
        """An error reply to a query (its asker may ask again); the final answer."""
        query.reply_err(excerpt(text).encode())
        query.drop()

    def due_in(self) -> float | None:
        """Seconds until held effects are due (None: nothing held)."""
        return max(0.0, self._last + self.pace - self.clock()) if self._held else None

    def release(self) -> None:
        """Send the held effects now: a new turn starts."""
        held, self._held = self._held, []
        self._last = self.clock()
        self.out.put(_key_of(self.keys, held[0].msg), held[0].msg)
        self.run(held[1:])


class Coordinator:
    """The coordinator's loop around the engine, without Zenoh: feed it the inbox's events (None when
    `timeout()` passed), until `finished()`. It admits a CONNECT once its sender's presence token is seen
    (`Presences`), keeps the deadlines, holds a vanished presence SETTLE_S before it counts (its own vanishing
    means the link is down), yields to a rival coordinator, ends the game on a signal, and after OVER waits up
    to LINGER_S for the entities to leave. When an admitted session's token vanishes or a phase's deadline
    passes, it asks the routers which sessions they connect (`audit`): one not among them has gone. Once the
    routers have answered such a question (`probe`, at start), a phase's deadline counts only when they answer
    again: if none does, nobody can be reached (a frozen router: no token vanishes, no lease has run out yet),
    and the game holds as for a lost link (`Engine.link_lost`), asking again until one answers, then goes on
    as if nothing happened (`Engine.link_back`: the phase again, its deadline anew)."""

    def __init__(self, engine: Engine, effects: Executor, rejects: RejectCounter, logger: logging.Logger, me: str,
                 clock: Callable[[], float] = time.monotonic, audit: Callable[[], None] = lambda: None,
                 stops: list[Interrupted] | None = None, progress: Progress | None = None,
                 presences: Presences[zenoh.Query] | None = None) -> None:
        self.engine, self.effects, self.rejects, self.log, self.me, self.clock = \
            engine, effects, rejects, logger, me, clock
        self.progress = progress or Progress(None)  # where the game stands, for a health check
        effects.unrecorded = engine.unrecorded  # a journal that fails ends the game
        self.audit = audit  # asks which sessions are connected: a `Sessions` event comes back
        self._auditing = self._audit_again = False
        self.presences: Presences[zenoh.Query] = presences or Presences()
        self.signal: int | None = None  # the signal that stopped the game
        self.rival: str | None = None  # another coordinator's session on this root, which this one yields to
        self._phase = engine.deadline_key()
        self._started = clock()
        self._heard = (engine.deciding, self._started)  # hosts' words that they are still deciding, the last's time
        self._vanishing: dict[tuple[str, str], float] = {}  # (entity, session) -> when its going counts
        self._linger_until: float | None = None
        # signals noted by `stop` (or, from `stops`, before this loop existed), not yet acted on
        self._stops: list[Interrupted] = [] if stops is None else stops
        self._routed = False  # a router has answered an audit: one that does not answer is unreachable
        self._deferred: tuple | None = None  # the deadline (`_mark`) whose passing waits for the routers' answer
        self._frozen = False  # the game holds because no router answers (not for a vanished presence)

    def probe(self) -> None:
        """Ask the routers once, at start: whether they answer at all (else, without a router, or with one
        that keeps its admin space closed, a deadline counts as it passes, as before)."""
        self._ask_who_is_connected()

    def stop(self, event: Interrupted) -> None:
        """A signal, from its handler (which may run while the loop holds the inbox's lock): noted only; the
        loop, woken, acts on it (`timeout` is 0 then)."""
        self._stops.append(event)

    def timeout(self) -> float | None:
        now = self.clock()
        if self._stops:
            return 0.0
        if self._linger_until is not None:
            return max(0.0, self._linger_until - now)
        end = self._deadline_end()
        left = None if end is None or self._deferred == self._mark() else max(0.0, end - now)
        vanish = max(0.0, min(self._vanishing.values()) - now) if self._vanishing else None
        delays = (left, self.effects.due_in(), self.presences.due_in(now), vanish)
        return min((d for d in delays if d is not None), default=None)

    def finished(self) -> bool:
        return self.rival is not None or (self._linger_until is not None
                                          and (not self.presences.others() or self.clock() >= self._linger_until))

    def handle(self, event: object) -> None:
        run, engine, now = self.effects.run, self.engine, self.clock()
        if isinstance(event, Interrupted):
            self.stop(event)
        while self._stops:  # a signal ends the game, and the coordinator soon after (STOP_LINGER_S)
            sig = self._stops.pop(0)
            until = now if self.signal is not None else now + STOP_LINGER_S  # a second one: at once
            self.signal = sig.signum
            run(engine.interrupt(f"the coordinator was stopped ({sig.name})"))
            self._linger_until = until if self._linger_until is None else min(self._linger_until, until)
        match event:
            case None:
                self._due(now)
            case Asked(asked, Connect() as hello):
                for gone in [k for k in self._vanishing if k[0] == hello.sender]:  # a process that replaces a
                    del self._vanishing[gone]  # vanished one: the departure counts now, not after SETTLE_S
                    run(engine.vanished(*gone))
                try:
                    ready = self.presences.connect(asked, hello, now)
                except RemoteInputError as err:  # too many wait for their token: an error reply, it asks again
                    self.rejects.reject(f"CONNECT from {hello.sender}", err, hello.sender)
                    self.effects.fail(asked, str(err))
                    ready = []
                for query, msg in ready:
                    run(engine.connect(msg, query))
            case Received(_, msg) if engine.stage is not Stage.OVER:  # after OVER: sent before it was seen
                run(engine.receive(msg))
            case Matching(_, matching):  # someone (the environment) follows the ENV phase, or no one now
                engine.env_followed = matching
            case Presence("SRV", sid, alive) if sid == self.me:
                if not alive:  # every presence vanishes with the link: nobody has left
                    self._vanishing.clear()
                    if self._frozen:  # (a router frozen past the leases: the link grace counts from now)
                        self._frozen, self._started = False, now
                    run(engine.link_lost())
            case Presence("SRV", sid, True) if engine.stage is not Stage.OVER and sid < self.me:
                self.rival = sid  # two started at once: the one with the smaller session id goes on
            case Sessions(connected, answered):
                self._auditing = False
                stale = self._audit_again  # (an answer to a question asked before the one awaited)
                self._gone_unless(connected)
                if self._audit_again:
                    self._ask_who_is_connected()
                if not stale:
                    self._reached(answered)
            case Presence(entity, sid, alive):
                for query, msg in self.presences.presence(entity, sid, alive):
                    run(engine.connect(msg, query))
                if alive:
                    self._vanishing.pop((entity, sid), None)
                    run(engine.present(entity, sid))
                else:
                    self._vanishing[(entity, sid)] = now + SETTLE_S
                    if self.engine.roster.sessions.get(entity) == sid:
                        self._ask_who_is_connected()  # its session gone too: its departure counts at once
        self._tick()
        if engine.stage is Stage.OVER and self._linger_until is None:
            self._linger_until = self.clock() + LINGER_S  # let OVER reach everyone
        if self.progress.path is not None:
            self._report()

    def _report(self) -> None:
        """The stage, the turn and, while entities are awaited, which (`network.progress`)."""
        engine = self.engine
        waiting = ""
        if engine.stage in (Stage.ADMITTING, Stage.RESUMING):
            awaited = engine.fleet.alive_rows().tolist() if engine.stage is Stage.RESUMING else None
            waiting = ", ".join(engine.roster.missing(engine.fleet, awaited))
        self.progress.note(engine.stage.value, engine.turn, waiting)

    def _gone_unless(self, connected: frozenset[str] | None) -> None:
        """Admitted entities whose session is not `connected` have gone (their token is a copy's); nothing
        is concluded from a listing that may be incomplete or that misses this coordinator itself."""
        if connected is None or self.me not in connected or self.engine.stage is Stage.OVER:
            return
        for entity, sid in sorted(self.engine.roster.sessions.items()):
            if sid and sid not in connected:
                if self._vanishing.pop((entity, sid), None) is None:
                    self.log.warning("%s's session %s is not connected to any router: its presence token is "
                                     "held by another session", entity, sid)
                self.presences.presence(entity, sid, False)
                self.effects.run(self.engine.vanished(entity, sid))

    def _reached(self, answered: bool) -> None:
        """The routers answered (or none did in time) a question asked after a deadline passed, or while the
        game holds for them: the deadline counts, the game holds (nobody can be reached), or it goes on."""
        self._routed |= answered
        deferred, self._deferred = self._deferred, None
        if self.engine.stage is Stage.OVER:
            return
        if not answered and self._routed and (deferred is not None or self._frozen):
            if not self._frozen:
                self._frozen = True
                self.log.warning("turn %d: no router answers (frozen or cut off): nobody can be reached, the "
                                 "deadline does not count", self.engine.turn)
                self.effects.run(self.engine.link_lost())
            self._ask_who_is_connected()  # again, until one answers
        elif answered and self._frozen:
            self._frozen = False
            self.effects.run(self.engine.link_back())
        elif deferred is not None and deferred == self._mark():  # (a host that spoke meanwhile: not passed)
            self.effects.run(self.engine.expire(*self._phase))

    def _tick(self) -> None:
        """The deadline restarts whenever what it is measured from changes (`Engine.deadline_key`); a host's word
        that it is still deciding (`Engine.deciding`) is noted with its time."""
        engine = self.engine
        if (phase := engine.deadline_key()) != self._phase:
            self._phase, self._started = phase, self.clock()
            self._heard = (engine.deciding, self._started)
        elif engine.deciding != self._heard[0]:
            self._heard = (engine.deciding, self.clock())

    def _deadline_end(self) -> float | None:
        """When the current deadline passes (None: it has none): its time from the stage's start, or, while a host
        says it is still deciding (`Engine.stretch`), from its last word, up to the cap from the stage's start."""
        limit = self.engine.deadline()
        if limit is None:
            return None
        end = self._started + limit
        if (stretch := self.engine.stretch()) is not None:
            wait, cap = stretch
            end = min(max(end, self._heard[1] + wait), self._started + cap)
        return end

    def _mark(self) -> tuple:
        """What a deadline that passed is: the stage's (`_phase`) and the last word of a host still deciding."""
        return self._phase, self._heard[0]

    def _due(self, now: float) -> None:
        """Whatever is due: held turns, CONNECTs without a token, vanished presences, the phase deadline."""
        if self.effects.due_in() == 0:
            self.effects.release()
        for query, msg in self.presences.expired(now):
            why = (f"no presence token of {msg.sender} (session {msg.session or '?'}): "
                   "a process connects under its own name only")
            self.rejects.reject(f"CONNECT from {msg.sender}", WrongSender(why))
            self.effects.answer(query, encode(Refused(turn=self.engine.turn, sender="SRV", text=why)))
        for entity, sid in sorted(key for key, due in self._vanishing.items() if due <= now):
            del self._vanishing[(entity, sid)]
            self.effects.run(self.engine.vanished(entity, sid))
        self._tick()  # (a departure may have changed what the deadline is measured from)
        end = self._deadline_end()
        if end is not None and now >= end and self._linger_until is None and self._deferred != self._mark():
            if self.engine.stage in (Stage.GCS, Stage.DRONES):
                self._ask_who_is_connected()  # someone missed a deadline: is everyone whose token we see connected?
                if self._routed and not self.engine.holding:
                    self._deferred = self._mark()  # and can anyone be reached? it counts once a router answers
                    return
            self.effects.run(self.engine.expire(*self._phase))

    def _ask_who_is_connected(self) -> None:
        """One audit at a time; one asked meanwhile follows its answer."""
        if self._auditing:
            self._audit_again = True  # the answer under way may predate what prompted this one
        else:
            self._auditing, self._audit_again = True, False
            self.audit()


def rival(session: zenoh.Session, keys: Keys) -> str | None:
    """The session id of a coordinator already on this root, if any."""
    for reply in session.liveliness().get(keys.alive_of("SRV"), timeout=PEER_CHECK_S):
        if reply.ok is not None:
            return keys.presence_of(str(reply.ok.key_expr))[1]
    return None


def open_game(game: GameConfig, journal: str | None, resume: bool, logger: logging.Logger) -> Engine:
    """A new game, or with `resume` the rest of the journal's (a new one if it has none yet); either way
    under a new identity (`Engine`'s `game`): what an earlier coordinator sent is foreign to it."""
    identity = secrets.token_hex(8)
    if resume and not journal:
        raise UsageError("--resume needs --journal")
    if not resume and journal and (held := held_game(journal)) is not None:  # a journal holds one game
        over, turn = held
        raise UsageError(f"{journal} holds a finished game (over at turn {turn}): give another --journal" if over
                         else f"{journal} holds an unfinished game (its last turn {turn}): resume it with --resume, "
                              "or give another --journal")
    if resume and journal and os.path.exists(journal) and os.path.getsize(journal) > 0:
        repair_tail(journal)
        return restore(game, list(read(journal)), logger, identity)
    if resume:  # e.g. a container restarted before the game began: nothing to resume yet
        logger.info("no journal at %s yet: starting a new game", journal)
    return Engine(game, logger, game=identity)


def main(conf: zenoh.Config, game: GameConfig, *, keys: Keys, journal: str | None, logger: logging.Logger,
         resume: bool = False, pace: float = 0.0, verify_env: bool = False,
         stops: list[Interrupted] | None = None) -> tuple[Over, int]:
    """Run one game to its end (or, with `resume`, the rest of the journal's game): its OVER, and the exit
    status: 0, 128 + the signal that stopped it, or JOURNAL_FAILED_STATUS when its journal could not be written
    (its OVER then says JOURNAL_FAILED, unless it was its over record that was lost). `stops`: the signals a
    handler notes from before the game opens (`cli`); the loop acts on them as it starts."""
    engine = open_game(game, journal, resume, logger)
    engine.verify_env, engine.journaled = verify_env, journal is not None
    engine.env_followed = False  # until a Matching event says someone follows the ENV phase
    # its CPU, reported at the end (benchmarks read it)
    engine.arbitration.arbiter = timed = arbiter.Timed(engine.arbitration.arbiter)
    with open_session(conf) as session:
        if (other := rival(session, keys)) is not None:
            raise UsageError(f"another coordinator (session {other}) runs on {keys.root}: one game per root")
        me, inbox = session_id(session), listening(session, keys, engine, logger, verify_env,
                                                   presences := Presences[zenoh.Query]())
        token = session.liveliness().declare_token(keys.alive("SRV", me))
        with JournalWriter(journal) as writer:
            out = Outbox(session)
            out.watch(keys.turn_of(Phase.ENV), inbox)  # (a Matching event at once if someone follows it)
            effects = Executor(keys, out, writer, inbox.rejects, pace)
            srv = Coordinator(engine, effects, inbox.rejects,
                              logger, me, audit=partial(audit_sessions, session, inbox.post), stops=stops,
                              progress=Progress.from_environment(), presences=presences)
            srv.probe()
            logger.info("coordinator ready on %s/**: waiting for ENV, GCS and %s",
                        keys.root, ", ".join(d.drone for d in game.drones))
            with on_stop(srv.stop), waking(partial(inbox.post, None)):  # a signal is noted, the loop woken
                inbox.run(srv.handle, timeout=srv.timeout, until=srv.finished)
        token.undeclare()
        closing(srv, inbox, keys, logger)
    assert engine.end is not None
    if timed.calls:
        logger.info("arbitration: %d turns, %.3f ms of CPU a turn, the longest %.3f", timed.calls,
                    1000 * timed.cpu / timed.calls, 1000 * timed.worst)
    if effects.failed is not None:
        logger.error("%s: the journal holds the game up to the turn before; once there is room, "
                     "`dronesim coordinator --resume --journal %s` plays on", effects.failed, journal)
        return engine.end, JOURNAL_FAILED_STATUS
    return engine.end, 0 if srv.signal is None else exit_status(srv.signal)


def listening(session: zenoh.Session, keys: Keys, engine: Engine, logger: logging.Logger, verify_env: bool,
              presences: Presences[zenoh.Query]) -> Inbox:
    """The coordinator's inbox: CONNECT served (those beyond the ones that may wait for their presence token,
    `presences`, are refused on Zenoh's thread, unread), the entities' messages and presences heard."""
    inbox = Inbox(session, keys, logger)
    inbox.serve(keys.connect, Connect, most=presences.room, waiting=presences.waiting)
    for key, kind in [(keys.any_tgt, Target), (keys.gcs_done, Done), (keys.any_nps, Nps),
                      (keys.any_moves, Moves)] + [(keys.upd, Upd)] * verify_env:
        # (UPD: each ENV phase's report, checked against the engine's world; the others are refused
        # unread when they are for a turn before the engine's: stale; a DONE for a later turn, an answer ahead, is
        # taken when the loop next wakes, before what woke it: it wakes the loop for nothing else, once a turn)
        inbox.subscribe(key, kind, since=None if kind is Upd else lambda: engine.turn, ahead_quiet=kind is Done)
    inbox.watch_presence()
    return inbox


def closing(srv: Coordinator, inbox: Inbox, keys: Keys, logger: logging.Logger) -> None:
    """After the game's loop: who was not waited for, a rival that started alongside (an error), the rejections."""
    if srv.signal is not None and (staying := srv.presences.others()):
        logger.info("stopped: not waiting for %s to leave (OVER went out %g s ago)", ", ".join(sorted(staying)),
                    STOP_LINGER_S)
    if srv.rival is not None:
        raise UsageError(f"another coordinator (session {srv.rival}) started on {keys.root} at the same time")
    inbox.rejects.flush(everything=True)
    if inbox.rejects.total:
        logger.info("rejected inputs: %s", inbox.rejects.report())


def parse_starts(text: str, count: int, size: Cell | None = None,
                 blocked: Callable[[Cell], bool] | None = None) -> tuple[DroneSpec, ...]:
    """``--starts "0,0,0;0,2,0"`` or, by default, every other cell along y from (0,0,0), then the next row
    of them (x + 2), then the next layer (z + 2), skipping `blocked` cells: as many as fit in `size` (a
    UsageError beyond; without `size`, one row as long as needed). A given cell that is `blocked`: UsageError."""
    if text:
        try:
            cells = [tuple(int(v) for v in part.split(",")) for part in text.split(";") if part.strip()]
        except ValueError:
            cells = []
        if len(cells) != count or any(len(c) != 3 for c in cells):
            raise UsageError(f"--starts needs {count} cells x,y,z of integers separated by ';', got {text!r}")
        for i, c in enumerate(cells):
            if blocked is not None and blocked(c):  # type: ignore[arg-type]
                raise UsageError(f"{drone_id(i + 1)} would start inside a building at {c}")
    else:
        nx, ny, nz = size or (1, 2 * count, 1)
        spots = ((x, y, z) for z in range(0, nz, 2) for x in range(0, nx, 2) for y in range(0, ny, 2))
        cells = list(itertools.islice((c for c in spots if blocked is None or not blocked(c)), max(count, 0)))
        if len(cells) < count:
            raise UsageError(f"{count} drones do not fit in a {nx}x{ny}x{nz} world one cell apart ({len(cells)} "
                             f"do): give their cells with --starts, or a bigger --size")
    return tuple(DroneSpec(drone=drone_id(i + 1), start=c) for i, c in enumerate(cells))  # type: ignore[arg-type]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="dronesim coordinator", description=__doc__)
    add_zenoh_args(p)
    p.add_argument("--seed", type=int, default=0, help="world seed (default 0)")
    p.add_argument("--size", default=",".join(map(str, SIZE)), help="world size nx,ny,nz (default %(default)s)")
    p.add_argument("--world", help="a world file (JSON) instead of a generated world")
    p.add_argument("--scenario", help="a scenario file (world, drones, starts, max turns): overrides those flags")
    p.add_argument("--drones", type=int, default=1, help="number of drones D01..Dnn (default 1)")
    p.add_argument("--starts", default="", help='start cells "x,y,z;x,y,z" (default: rows of every other cell)')
    p.add_argument("--max-turns", type=int, default=MAX_TURNS, help=f"the game's turn limit (default {MAX_TURNS})")
    p.add_argument("--phase-deadline", type=seconds, default=PHASE_DEADLINE_S,
                   help=f"seconds for drones and ENV per phase (default {PHASE_DEADLINE_S:g})")
    p.add_argument("--phase-cap", type=seconds, default=PHASE_CAP_S, metavar="SECONDS",
                   help="how long a drones' phase may last in all while a swarm host says it is still deciding (its "
                        f"deadline counts again from each such word; default {PHASE_CAP_S:g})")
    p.add_argument("--gcs-deadline", type=seconds, default=0.0, help="seconds for the GCS phase (0: wait)")
    p.add_argument("--admit-deadline", type=seconds, default=ADMIT_DEADLINE_S, metavar="SECONDS",
                   help="how long the game waits for every entity to connect (also when resumed), then ends "
                        f"ABORTED naming who never came (default {ADMIT_DEADLINE_S:g}; 0: wait forever)")
    p.add_argument("--lost-after", type=int, default=LOST_AFTER,
                   help=f"missed deadlines before a drone is LOST (default {LOST_AFTER})")
    p.add_argument("--arbiter", choices=ARBITERS, default=ARBITER,
                   help="the cooperative drones' arbitration: lacam, the complete search (default), or pibt, PIBT "
                        "alone (docs/cooperation.md)")
    p.add_argument("--lifelong", action="store_true",
                   help="a lifelong game: its ground station gives each drone a new target when it reaches its own "
                        "(dronesim gcs --lifelong SEED); the end says the tasks done and the tasks a turn")
    p.add_argument("--gcs-grace", type=seconds, default=GCS_GRACE_S, metavar="SECONDS",
                   help="with --resume: how long the game waits for its ground station once the environment "
                        f"and the drones are back (default {GCS_GRACE_S:g})")
    p.add_argument("--link-grace", type=seconds, default=LINK_GRACE_S, metavar="SECONDS",
                   help="how long the game holds when the coordinator's link is down (every presence vanished at "
                        "once, e.g. a router restart; or no router answers, e.g. one frozen) for its entities to come "
                        f"back (default {LINK_GRACE_S:g})")
    p.add_argument("--journal", help="write the game's journal to this file, missing or empty (a journal holds one "
                                     "game; --resume takes up an unfinished one)")
    p.add_argument("--pace", type=seconds, default=0.0, metavar="SECONDS",
                   help="start a turn at most every SECONDS (default 0: as fast as the entities answer)")
    p.add_argument("--verify-env", action="store_true",
                   help="check the environment's UPD of every ENV phase against the coordinator's world "
                        "(a mismatch is logged and counted as a rejected input)")
    p.add_argument("--resume", action="store_true",
                   help="restart a game from its --journal: the entities connect again and it plays on "
                        "(a missing or empty journal starts a new game)")
    return p


def parse_size(text: str) -> tuple[int, int, int]:
    try:
        size = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise UsageError(f"bad size {text!r}: expected nx,ny,nz") from None
    if len(size) == 1:
        size = size * 3
    if len(size) != 3 or min(size) < 1:
        raise UsageError(f"bad size {text!r}: expected three positive integers")
    return size


#: Reads a scenario file into the game's configuration, given the deadlines (`dronesim.scenario`, which the
#: application hands to `cli`: the coordinator reads no scenario format of its own).
ScenarioReader = Callable[..., GameConfig]


def game_config(args: argparse.Namespace, scenario: ScenarioReader | None = None) -> GameConfig:
    deadlines = dict(phase_deadline=args.phase_deadline, phase_cap=args.phase_cap,
                     gcs_deadline=args.gcs_deadline or None, admit_deadline=args.admit_deadline or None,
                     lost_after=args.lost_after, gcs_grace=args.gcs_grace, link_grace=args.link_grace,
                     arbiter=args.arbiter, lifelong=args.lifelong)
    if args.scenario:
        if scenario is None:
            raise UsageError("--scenario is read by the dronesim command: dronesim coordinator --scenario FILE")
        return scenario(args.scenario, **deadlines)

    try:
        if args.world:
            world = World.load(args.world)
            spec = WorldSpec(size=world.size, cells=world.packed())
        else:
            spec = WorldSpec(size=parse_size(args.size), seed=args.seed)
    except RemoteInputError as err:  # WorldSpec's own checks (sizes, cells, seed >= 0), as `Scenario.from_json`'s
        raise UsageError(f"bad world: {err}") from None
    drones = parse_starts(args.starts, args.drones, spec.size, world.is_building if args.world else None)
    return GameConfig(world=spec, drones=drones, max_turns=args.max_turns, **deadlines)


def cli(argv: list[str] | None = None, *, scenario: ScenarioReader | None = None) -> int:
    args = build_parser().parse_args(argv)
    logger = setup_logging(args.log_level, "SRV")
    # SIGINT and SIGTERM are noted from the start, whatever the coordinator is doing (a container's first process
    # would otherwise ignore SIGTERM): the game ends INTERRUPTED as soon as its loop runs
    stops: list[Interrupted] = []
    try:
        with on_stop(stops.append):
            over, status = main(zenoh_config(args), game_config(args, scenario), keys=Keys(args.root),
                                journal=args.journal, logger=logger, resume=args.resume, pace=args.pace,
                                verify_env=args.verify_env, stops=stops)
    except UsageError as err:
        logger.error("%s", err)
        return 2
    print(f"OVER at turn {over.turn}: {over.reason.value}: {over.text}", file=sys.stderr)
    return status
