"""The turn engine: admission, the lockstep turn cycle and the observer, as a pure state machine.

No network and no clock here. The Zenoh adapter (coordinator/node.py) feeds it validated messages,
expired deadlines and vanished entities, one at a time from one thread, and carries out the effects
it returns (publish, reply to a CONNECT query, append to the journal).

One turn (the seed's cycle GCS -> D01 -> ENV -> OBS -> GCS):

  stage    the engine publishes           it waits for                      then
  -------  -----------------------------  --------------------------------  ----------------------
  GCS      TURN(t, GCS)                   TGT*, DONE from the GCS           DRONES
  DRONES   TURN(t, DRONES, orders)        one NPS per alive drone           the ENV phase
  (ENV)    TURN(t, ENV, moves)            - (its UPD is checked on arrival)  the observer
  (OBS)    STATUS(t)                      -                                 GCS of t+1, or OVER

The ENV phase is pipelined: the buildings are static and the engine holds the same world as the
environment (both build it from the game's WorldSpec), so the observer judges the moves at once
instead of waiting a round trip for the environment's UPD. The environment still applies every move
(its ASK answers for turn t+1 need them; it also takes them from STATUS(t)) and reports the changed
cells; a UPD that disagrees with the engine's world is rejected and counted.

A deadline ends a stage early: missing drones hover (and are LOST after `lost_after` misses in a row),
targets stay as they were; a vanished environment holds the drones' phase for `env_grace` seconds.
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from dronesim.schema import (
    AimTable, Cause, Cell, CellKind, Connect, Done, DroneState, EndReason, Intent, Message, Moves, MoveTable, Note, Nps,
    OrderTable, Over, Phase, Refused, RemoteInputError, Role, StartTable, Status, StatusTable, Target, Turn, Upd, Welcome, WorldSpec, encode,
)
from dronesim.entities.environment import build_world
from dronesim.entities.world import World, inside_rows
from dronesim.schema.messages import is_drone_id, is_host_id, unchecked
from dronesim.schema.errors import OutOfRange, StaleTurn, UnknownEntity, UsageError, WrongSender
from dronesim.schema.tables import code_of, drone_name

from . import arbiter, observer
from .fleet import ALIVE, CAUSES, NOTES, REACHED, UNREACHABLE, Drones, Fleet, cell_of


#: The engine's own TURN and STATUS messages, built from its state (checked when it changed) without
#: checking again, as records are (`messages.unchecked`): positional, every field given.
_turn, _status = unchecked(Turn), unchecked(Status)
NO_ORDERS, NO_MOVES = OrderTable.trusted(OrderTable.empty(0)), MoveTable.trusted(MoveTable.empty(0))
#: How many turns ahead a ground station may answer GCS phases (when it has nothing new to say).
AHEAD_MAX = 8
#: Up to this many moves in a MOVES, or targets in a DONE, are taken one by one (array operations cost
#: more than they save).
FEW = 8
#: How many turns an ENV phase's report (UPD) may lag behind and still be checked.
UPD_WINDOW = 8


class Stage(enum.Enum):
    ADMITTING = "ADMITTING"
    RESUMING = "RESUMING"  # restarted from a journal: waiting for the entities to connect again
    GCS = "GCS"
    DRONES = "DRONES"
    OVER = "OVER"


#: The state machine in one place: stage -> (phase announced, message that closes it, next stage).
STAGES: dict[Stage, tuple[Phase | None, type[Message] | tuple[type[Message], ...] | None, Stage]] = {
    Stage.ADMITTING: (None, Connect, Stage.GCS),
    Stage.RESUMING: (None, Connect, Stage.GCS),  # the turn after the journal's last
    Stage.GCS: (Phase.GCS, Done, Stage.DRONES),
    Stage.DRONES: (Phase.DRONES, (Nps, Moves), Stage.GCS),  # through the (pipelined) ENV phase and the observer
    Stage.OVER: (None, None, Stage.OVER),
}


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneSpec:
    drone: str
    start: Cell


@dataclass(frozen=True, slots=True, kw_only=True)
class GameConfig:
    world: WorldSpec
    drones: tuple[DroneSpec, ...]
    max_turns: int = 1000
    phase_deadline: float = 5.0  # seconds for the drones and the environment
    gcs_deadline: float | None = None  # None: the GCS paces the game (a human types)
    admit_deadline: float | None = None  # None: wait for every entity forever
    lost_after: int = 3  # missed DRONES deadlines in a row before a drone is LOST
    env_grace: float = 30.0  # seconds the game waits for a vanished environment to come back
    gcs_grace: float = 30.0  # seconds a resumed game waits for its ground station once the others are back

    def __post_init__(self) -> None:
        ids = [d.drone for d in self.drones]
        if not ids:
            raise UsageError("a game needs at least one drone")
        for d in ids:
            if not is_drone_id(d):
                raise UsageError(f"{d!r} is not a drone id (D01 ... D9999)")
        if len(set(ids)) != len(ids):
            raise UsageError(f"duplicate drone ids in {ids}")
        starts = [d.start for d in self.drones]
        if len(set(starts)) != len(starts):
            raise UsageError("two drones cannot start in the same cell")
        for d in self.drones:
            if not observer.inside(d.start, self.world.size):
                raise UsageError(f"{d.drone} starts at {d.start}, outside the world {self.world.size}")
        if self.max_turns < 1 or self.lost_after < 1:
            raise UsageError("max_turns and lost_after must be >= 1")


# --------------------------------------------------------------------------- effects


@dataclass(frozen=True, slots=True)
class Publish:
    msg: Message
    data: bytes | None = field(default=None, compare=False)  # its encoding, when the engine has it already


@dataclass(frozen=True, slots=True)
class Reply:
    token: object
    msg: Message


@dataclass(frozen=True, slots=True)
class Record:
    """One journal record (a JSON-able dict, written as one line)."""

    data: dict


@dataclass(frozen=True, slots=True)
class Refusal:
    """Remote input the engine refused on its own (not in answer to the message being received): the
    adapter counts and logs it like any rejected input."""

    what: str
    err: RemoteInputError


Effect = Publish | Reply | Record | Refusal


class Engine:
    """The coordinator's game: feed it events, carry out the effects it returns."""

    def __init__(self, config: GameConfig, logger: logging.Logger, world: World | None = None) -> None:
        """`world` is the game's world if the caller has already built it (else built here from the spec)."""
        self.config = config
        self._log = logger
        self.world = world if world is not None else build_world(config.world, (d.start for d in config.drones))
        if self.world.size != config.world.size:
            raise UsageError(f"the world is {self.world.size}, the game's is {config.world.size}")
        self.stage = Stage.ADMITTING
        self.turn = 0
        self.fleet = Fleet((d.drone, d.start) for d in config.drones)
        #: The drones one by one (a read-only view of the fleet).
        self.drones = Drones(self.fleet)
        self.entities: dict[str, Role] = {}  # admitted entity id -> role
        self.sessions: dict[str, str] = {}  # admitted entity id -> its Zenoh session id
        self.final = False  # the GCS said its plan is complete
        self.end: Over | None = None
        n = len(self.fleet)
        self._aimed = np.zeros(n, bool)  # whose target this GCS phase received
        self._aims = np.zeros((n, 3), np.int32)  # those targets (rows where _aimed)
        self._moved = np.zeros(n, bool)  # whose move this DRONES phase took
        self._proposed = np.zeros((n, 3), np.int32)  # the moves taken (rows where _moved)
        self._said = np.zeros(n, np.uint8)  # the notes that came with them
        self._awaiting = 0  # alive drones whose move this DRONES phase still awaits
        self._turn_log: dict = {}
        self._upd_due: dict[int, MoveTable] = {}  # ENV phases whose report is awaited: turn -> moves
        #: Whether the environment's UPD reports are checked (kept for a few turns): the adapter says.
        self.verify_env = True
        #: Whether the turn records say what each drone was told and did (targets, moves, notes, hovers,
        #: deaths) and the state's hash: the adapter turns it off when it keeps no journal (the records are
        #: then dropped).
        self.journaled = True
        self._tgt_seen = 0  # TGT messages of this GCS phase
        self._done: Done | None = None  # the GCS's DONE, once it arrived
        self._early: dict[int, Done] = {}  # the GCS's DONEs for coming turns, sent ahead
        self._phase_msg: Turn | None = None  # the TURN that opened the current stage
        self._held = False  # that TURN waits for the environment to come back
        self._intent = Intent.CONTINUE  # the GCS's last intent (journaled when it changes)

    # ------------------------------------------------------------------ queries

    @property
    def size(self) -> Cell:
        return self.config.world.size

    def alive(self) -> list[str]:
        return self.fleet.alive()

    def targets(self) -> dict[str, Cell]:
        """The targets in force, of every drone that has one."""
        return self._by_id(self.fleet.target[:, 0] >= 0, self.fleet.target)

    def aims(self) -> dict[str, Cell]:
        """The targets this GCS phase has received so far (in force once the phase ends)."""
        return self._by_id(self._aimed, self._aims)

    def moves_taken(self) -> dict[str, Cell]:
        """The moves this DRONES phase has taken so far."""
        return self._by_id(self._moved, self._proposed)

    def _by_id(self, rows: np.ndarray, cells: np.ndarray) -> dict[str, Cell]:
        """The `cells` of the drones where `rows` holds, by id."""
        ids = self.fleet.ids
        return {ids[i]: cell_of(cells[i]) for i in np.flatnonzero(rows).tolist()}

    def _hosted(self, rows: np.ndarray) -> bool:
        """Whether every drone of `rows` has a process flying it."""
        host = self.fleet.host
        return all(host[i] for i in rows.tolist())

    def _playing(self) -> bool:
        return self.stage in (Stage.GCS, Stage.DRONES)

    def _env_missing(self) -> bool:
        return self._playing() and Role.ENV not in self.entities.values()

    def clock(self) -> tuple[Stage, int, bool, bool, bool]:
        """What the current deadline is measured from: it restarts whenever this changes."""
        return self.stage, self.turn, self._done is not None, self._env_missing(), self._back_but_gcs()

    def _back_but_gcs(self) -> bool:
        """Resuming: the environment and the alive drones are back, the ground station not (yet)."""
        roles = set(self.entities.values())
        return (self.stage is Stage.RESUMING and Role.ENV in roles and Role.GCS not in roles
                and self._hosted(self.fleet.alive_rows()))

    def deadline(self) -> float | None:
        """Seconds the current stage may last before `expire` (None: no deadline)."""
        if self._env_missing():
            return self.config.env_grace
        if self._back_but_gcs():
            return self.config.gcs_grace
        match self.stage:
            case Stage.ADMITTING | Stage.RESUMING:
                return self.config.admit_deadline
            case Stage.GCS:
                if self._done is not None:  # DONE is in, some of its TGT are not: they get a drone's time
                    return self.config.phase_deadline
                return self.config.gcs_deadline
            case Stage.DRONES:
                return self.config.phase_deadline
        return None

    def status(self, turn: int | None = None) -> Status:
        """Every drone's state at the end of `turn`; by default now, i.e. during a turn, as it stood at
        the end of the previous one."""
        if turn is None:
            turn = self.turn - 1 if self._playing() else self.turn
        return _status(turn, "OBS", self.fleet.status())

    # ------------------------------------------------------------------ admission

    def connect(self, msg: Connect, token: object) -> list[Effect]:
        """Admit an entity or refuse it; start the game when everyone is there."""
        refusal = self._refusal(msg)
        if refusal:
            self._log.warning("refused %s: %s", msg.sender, refusal)
            return [Reply(token, Refused(turn=self.turn, sender="SRV", text=refusal))]
        again = msg.sender in self.entities  # the same process connecting again (its session says so)
        self.entities[msg.sender] = msg.role
        self.sessions[msg.sender] = msg.session
        fleet = self.fleet
        for d in msg.drones:
            fleet.fly(fleet.index[d], msg.sender, msg.autopilot, msg.cooperative)
        rows = sorted(range(len(fleet)) if msg.role is not Role.DRONE else [fleet.index[d] for d in msg.drones])
        starts = StartTable.empty(len(rows))
        starts["drone"], starts["pos"] = fleet.numbers[rows], fleet.pos[rows]
        what = msg.sender if msg.role is not Role.DRONE or msg.drones == (msg.sender,) else \
            f"{msg.sender} flying {', '.join(msg.drones)}"
        self._log.info("%s %s", "re-admitted" if again else "admitted", what)
        welcome = Welcome(turn=self.turn, sender="SRV", entity=msg.sender, text=f"You are connected as {what}",
                          world=self.config.world, starts=StartTable.trusted(starts))
        effects: list[Effect] = [Reply(token, welcome)]
        if self.stage in (Stage.ADMITTING, Stage.RESUMING):
            if self._everyone_here():
                effects += self._start() if self.stage is Stage.ADMITTING else self._resume()
            return effects
        effects.append(Publish(self.status()))  # a late joiner sees the state at once
        # A returning environment or ground station takes up the phase in progress.
        if msg.role is Role.ENV and self._held:
            self._held = False
            effects.append(Publish(self._phase_msg))
        elif self._phase_msg is not None and (msg.role, self.stage) == (Role.GCS, Stage.GCS):
            effects.append(Publish(self._phase_msg))
        return effects

    def _refusal(self, msg: Connect) -> str:
        if self.stage is Stage.OVER:
            return "the game is over"
        if msg.sender in self.entities:
            if msg.session and self.sessions.get(msg.sender) == msg.session and \
                    self.entities[msg.sender] is msg.role:
                return ""  # the same process again (e.g. after a cut link): welcome it back
            return f"{msg.sender} is already connected"
        match msg.role:
            case Role.ENV | Role.GCS:
                if msg.sender != msg.role.value:
                    return f"the {msg.role.value} must connect as {msg.role.value}, not {msg.sender}"
            case Role.DRONE:
                if not is_host_id(msg.sender) and msg.drones != (msg.sender,):
                    return (f"{msg.sender} cannot connect for {', '.join(msg.drones)}: a drone flies itself, "
                            "a swarm host connects as Hnn")
                if self.stage not in (Stage.ADMITTING, Stage.RESUMING):
                    return "drones cannot join a running game"
                for d in msg.drones:
                    if d not in self.fleet.index:
                        return f"unknown drone {d}: this game flies {', '.join(self.fleet.ids)}"
                    host = self.fleet.host[self.fleet.index[d]]
                    if host is not None:
                        return f"drone {d} is already taken by {host}"
        return ""

    def _everyone_here(self) -> bool:
        roles = set(self.entities.values())
        if self.stage is Stage.RESUMING:  # the alive drones, the environment and the ground station (which
            # gets `gcs_grace` seconds once the others are back: it may have left the game for good)
            return Role.ENV in roles and Role.GCS in roles and self._hosted(self.fleet.alive_rows())
        return Role.ENV in roles and Role.GCS in roles and all(self.fleet.host)

    def header(self) -> dict:
        return {
            "record": "header", "format": "dronesim-journal", "version": 1,
            "world": {"size": list(self.size), "seed": self.config.world.seed,
                      "cells": self.config.world.cells.hex()},
            "drones": [{"drone": d, "start": start, "autopilot": autopilot, "cooperative": cooperative}
                       for d, start, autopilot, cooperative in zip(self.fleet.ids, self.fleet.pos.tolist(),
                                                                   self.fleet.autopilot, self.fleet.cooperative.tolist())],
            "max_turns": self.config.max_turns, "lost_after": self.config.lost_after,
        }

    def _start(self) -> list[Effect]:
        self._log.info("all entities connected: the game starts")
        return [Record(self.header()), Publish(self.status()), *self._enter(Stage.GCS, 1)]

    def _resume(self) -> list[Effect]:
        self._log.info("entities back: the game resumes at turn %d", self.turn + 1)
        return [Publish(self.status()), *self._enter(Stage.GCS, self.turn + 1)]

    @classmethod
    def resume(cls, config: GameConfig, records: list[dict], logger: logging.Logger) -> "Engine":
        """An engine restored from a journal, waiting (RESUMING) for the entities to connect again;
        it then plays the turn after the journal's last. UsageError if the journal is not this game's."""
        engine = cls(config, logger)
        if not records or records[0].get("record") != "header":
            raise UsageError("the journal has no header: nothing to resume")
        theirs = dict(records[0])
        fleet = engine.fleet
        for d in theirs.get("drones", []):  # autopilots are learnt at admission, not configured
            i = fleet.index.get(d.get("drone"))
            if i is not None:
                fleet.autopilot[i] = d.get("autopilot", "")
                fleet.cooperative[i] = d.get("cooperative", False)
        if engine.header() != theirs:
            raise UsageError("the journal is of another game (world, drones or limits differ)")
        for r in records[1:]:
            match r.get("record"):
                case "turn":
                    engine._restore_turn(r)
                case "over":
                    raise UsageError(f"the journal's game is over (turn {r.get('turn')}): nothing to resume")
        engine.stage = Stage.RESUMING
        logger.info("restored turn %d from the journal", engine.turn)
        return engine

    def _restore_turn(self, r: dict) -> None:
        """Apply one journaled turn to the state, as `_observe` did when it was played."""
        fleet, row = self.fleet, self.fleet.index
        alive = fleet.alive_rows()
        for d, p in r.get("targets", {}).items():
            fleet.aim(row[d], tuple(p))
        if "intent" in r:
            self._intent = Intent(r["intent"])
            self.final = self._intent is Intent.FINAL
        for d, p in r.get("moves", {}).items():
            fleet.pos[row[d]] = p
        for d, n in r.get("notes", {}).items():
            fleet.note[row[d]] = code_of(Note(n))
        hovered = np.zeros(len(fleet), bool)
        hovered[[row[d] for d in r.get("hovered", ())]] = True
        fleet.misses[alive] = np.where(hovered[alive], fleet.misses[alive] + 1, 0)
        for d, cause in r.get("deaths", {}).items():
            fleet.end(row[d], DroneState.DEAD, Cause(cause))
        for d in r.get("lost", ()):
            fleet.end(row[d], DroneState.LOST, Cause.LOST)
        self.turn = r["turn"]
        state = hashlib.sha256(encode(self.status())).hexdigest()[:16]
        if state != r.get("state"):
            raise UsageError(f"the journal's turn {self.turn} does not replay to its recorded state")

    # ------------------------------------------------------------------ stages

    def _enter(self, stage: Stage, turn: int) -> list[Effect]:
        self.stage, self.turn = stage, turn
        match stage:
            case Stage.GCS:
                self._aimed[:] = False
                self._tgt_seen, self._done = 0, None
                self._turn_log = {"record": "turn", "turn": turn}
                early = self._early.pop(turn, None)
                self._early = {t: d for t, d in self._early.items() if t > turn}
                if "GCS" not in self.entities:  # no ground station: the drones keep their targets
                    return self._enter(Stage.DRONES, turn)
                self._phase_msg = _turn(turn, "SRV", Phase.GCS, NO_ORDERS, NO_MOVES)
                if early is None:
                    return [Publish(self._phase_msg)]
                try:  # the ground station answered this phase ahead: it opens and closes at once, unannounced
                    return self._gcs_done(early)  # (the station goes by STATUS: it knows the turn began)
                except RemoteInputError as err:
                    return [Refusal(f"DONE ahead for turn {turn}", err), *err.follow]
            case Stage.DRONES:
                self._moved[:] = False
                alive = self.fleet.alive_rows()
                self._awaiting = len(alive)
                orders = self.fleet.orders(alive)
                self._phase_msg = _turn(turn, "SRV", Phase.DRONES, orders, NO_MOVES)
                if self._env_missing():  # drones would ASK nobody: the turn waits for the environment
                    self._held = True
                    self._log.warning("turn %d waits for the environment to come back", turn)
                    return []
                return [Publish(self._phase_msg)]
        raise AssertionError(stage)

    def _drones_finish(self) -> list[Effect]:
        """The drones' phase is over: arbitrate, announce the ENV phase (the accepted moves), observe."""
        turn, fleet = self.turn, self.fleet
        alive = fleet.alive_rows()
        before = fleet.pos[alive]
        proposed = np.where(self._moved[alive, None], self._proposed[alive], before)
        final = proposed
        if np.count_nonzero(fleet.cooperative[alive]):
            final = self._arbitrate(alive, before, proposed)
        moving = (final != before).any(axis=1)
        if not np.count_nonzero(moving):
            return _drones_first(self._observe(alive, before, final, moving))
        rows = MoveTable.empty(np.count_nonzero(moving))
        rows["drone"], rows["src"], rows["dst"] = fleet.numbers[alive[moving]], before[moving], final[moving]
        moves = MoveTable.trusted(rows)
        if self.verify_env:
            self._upd_due[turn] = moves  # its report may come turns later (nothing waits for it): keep a few
            for old in [t for t in self._upd_due if t <= turn - UPD_WINDOW]:
                del self._upd_due[old]
        return _drones_first([Publish(_turn(turn, "SRV", Phase.ENV, NO_ORDERS, moves)),
                              *self._observe(alive, before, final, moving)])

    def _arbitrate(self, alive: np.ndarray, before: np.ndarray, proposed: np.ndarray) -> np.ndarray:
        """`proposed` after the cooperative drones gave way (see arbiter.py); the yielded are journaled."""
        ids = [self.fleet.ids[i] for i in alive.tolist()]
        was = dict(zip(ids, map(tuple, before.tolist())))
        wants = dict(zip(ids, map(tuple, proposed.tolist())))
        coop = {d for d, c in zip(ids, self.fleet.cooperative[alive].tolist()) if c}
        final = arbiter.arbitrate(was, wants, coop)
        yielded = sorted(d for d in final if final[d] != wants[d])
        if yielded:
            self._turn_log["yielded"] = yielded
        return np.array([final[d] for d in ids], np.int32).reshape(len(ids), 3)

    def _kind(self, cell: Cell) -> CellKind:
        if not self.world.contains(cell):
            return CellKind.OUTSIDE
        return CellKind.BUILDING if self.world.is_building(cell) else CellKind.EMPTY

    def receive(self, msg: Message) -> list[Effect]:
        """A message from the network, decoded and addressed correctly; raises RemoteInputError if it
        cannot be accepted now (and changes nothing then)."""
        if isinstance(msg, Target):
            return self.target(msg)
        if isinstance(msg, Upd):
            return self._upd(msg)
        if (isinstance(msg, Done) and self.turn < msg.turn <= self.turn + AHEAD_MAX
                and self.stage in (Stage.GCS, Stage.DRONES)):
            return self._hold(msg)
        expected = STAGES[self.stage][1]
        if not isinstance(msg, expected or ()) or msg.turn != self.turn:
            raise StaleTurn(f"{msg.TAG} for turn {msg.turn} from {msg.sender} while in {self.stage.value} "
                            f"of turn {self.turn}")
        match msg:
            case Done():
                return self._gcs_done(msg)
            case Nps():
                return self._nps(msg)
            case Moves():
                return self._moves_of_host(msg)
        raise StaleTurn(f"{msg.TAG} is not expected now")

    def target(self, msg: Target) -> list[Effect]:
        """A TGT from the GCS during its phase: checked (sender, turn, drone, inside the world), kept."""
        if msg.sender != "GCS":
            raise WrongSender(f"target for {msg.drone} from {msg.sender}: only the GCS sets targets")
        if self.stage is not Stage.GCS or msg.turn != self.turn:
            raise StaleTurn(f"target for turn {msg.turn} while in {self.stage.value} of turn {self.turn}")
        self._tgt_seen += 1  # counted against the DONE's count even if refused below
        try:
            self._aim(msg.drone, msg.pos)
        except RemoteInputError as err:
            err.follow = self._gcs_check()  # the target is refused; the phase it was awaited for goes on
            raise
        return self._gcs_check()

    def _aim(self, d: str, pos: Cell) -> None:
        """Keep a target for this GCS phase, or raise (and keep nothing)."""
        i = self.fleet.index.get(d)
        if i is None:
            raise UnknownEntity(f"target for unknown drone {d}")
        if self.fleet.state[i] != ALIVE:
            raise UnknownEntity(f"target for {d}, which is {self.fleet.view(i).state.value}")
        if not observer.inside(pos, self.size):
            raise OutOfRange(f"target {pos} for {d} is outside the world {self.size}")
        self._aimed[i] = True
        self._aims[i] = pos

    def _hold(self, msg: Done) -> list[Effect]:
        """The GCS's answer to a coming GCS phase (up to AHEAD_MAX turns on), sent ahead because it had
        nothing new to say: kept, and taken as that phase opens, checked then like any DONE (no round
        trip to the ground station)."""
        if msg.sender != "GCS" or msg.phase is not Phase.GCS:
            raise WrongSender(f"DONE({msg.phase.value}) ahead from {msg.sender}")
        if msg.count:
            raise StaleTurn(f"a DONE ahead for turn {msg.turn} carries its targets itself, it cannot count TGTs")
        if msg.turn in self._early:
            raise StaleTurn(f"second DONE ahead for turn {msg.turn}")
        self._early[msg.turn] = msg
        return []

    def _gcs_done(self, msg: Done) -> list[Effect]:
        if msg.sender != "GCS" or msg.phase is not Phase.GCS:
            raise WrongSender(f"DONE({msg.phase.value}) from {msg.sender} in the GCS phase")
        if self._done is not None:
            raise StaleTurn(f"second DONE from the GCS in turn {self.turn}")
        self._done = msg
        return _with_refusals(self._take_aims(msg.targets), self._gcs_check())

    def _take_aims(self, aims: AimTable) -> list[RemoteInputError]:
        """Keep a DONE's targets: each is kept or refused on its own, as if sent as a TGT. A big batch is
        checked as a whole first (the checks of `_aim`, in array operations); what that refuses, and a
        batch of a few, goes through `_aim` row by row, which says why."""
        fleet, numbers, pos = self.fleet, aims.numbers, aims.column("pos")

        def whole() -> np.ndarray:
            rows = fleet.row_of_number[numbers]
            ok = (rows >= 0) & inside_rows(pos, self.size)
            ok[ok] = fleet.state[rows[ok]] == ALIVE
            self._aimed[rows[ok]] = True
            self._aims[rows[ok]] = pos[ok]
            return ok

        return _in_batch(len(aims), whole, lambda j: self._aim(drone_name(int(numbers[j])), cell_of(pos[j])))

    def _gcs_check(self) -> list[Effect]:
        """The GCS phase ends when its DONE and all the TGT it counted have arrived (in any order)."""
        if self._done is None or self._tgt_seen < self._done.count:
            return []
        return self._gcs_finish(self._done)

    def _gcs_finish(self, msg: Done) -> list[Effect]:
        fleet = self.fleet
        if self._aimed.any():  # (most GCS phases bring no target)
            changed = np.flatnonzero(self._aimed & (fleet.target != self._aims).any(axis=1))
            fleet.aim(changed, self._aims[changed])
            if len(changed) and self.journaled:
                self._turn_log["targets"] = dict(zip([fleet.ids[i] for i in changed.tolist()],
                                                     self._aims[changed].tolist()))
        if msg.intent is not self._intent:
            self._turn_log["intent"] = msg.intent.value
            self._intent = msg.intent
        if msg.intent is Intent.QUIT:
            return [Record(self._turn_log), *self._over(EndReason.GCS_QUIT, "the ground station ended the game")]
        self.final = msg.intent is Intent.FINAL
        return self._enter(Stage.DRONES, self.turn)

    def _nps(self, msg: Nps) -> list[Effect]:
        self._move(msg.sender, msg.pos, msg.note)
        return self._drones_check()

    def _moves_of_host(self, msg: Moves) -> list[Effect]:
        """A swarm host's moves: each is taken or refused on its own, as if sent as an NPS. A big batch is
        checked as a whole first (the checks of `_move`, in array operations); what that refuses, and a
        batch of a few moves, goes through `_host_move` row by row, which says why."""
        fleet, steps = self.fleet, msg.moves
        numbers, pos, notes = steps.numbers, steps.column("pos"), steps.column("note")

        def whole() -> np.ndarray:
            rows = fleet.row_of_number[numbers]
            known = rows >= 0
            rows = np.where(known, rows, 0)
            ok = (known & (fleet.host_code[rows] == fleet.hosts.get(msg.sender, -2)) & (fleet.state[rows] == ALIVE)
                  & ~self._moved[rows] & (np.abs(pos - fleet.pos[rows]).sum(axis=1) <= 1))
            take = rows[ok]
            self._proposed[take], self._moved[take], self._said[take] = pos[ok], True, notes[ok]
            self._awaiting -= len(take)
            return ok

        refused = _in_batch(len(steps), whole, lambda j: self._host_move(
            msg.sender, drone_name(int(numbers[j])), cell_of(pos[j]), NOTES[notes[j]]))
        return _with_refusals(refused, self._drones_check())

    def _host_move(self, sender: str, d: str, pos: Cell, note: Note) -> None:
        """Take a move a swarm host sent for one of its drones, or raise (and take nothing)."""
        i = self.fleet.index.get(d)
        host = None if i is None else self.fleet.host[i]
        if host != sender:
            raise WrongSender(f"MOVES from {sender} for {d}, which {host or 'nobody'} flies")
        self._move(d, pos, note)

    def _move(self, d: str, pos: Cell, note: Note) -> None:
        """Take a drone's move for this phase, or raise (and take nothing)."""
        fleet = self.fleet
        i = fleet.index.get(d)
        if i is None or fleet.state[i] != ALIVE:
            raise UnknownEntity(f"NPS from {d}, which is not an alive drone of this game")
        if self._moved[i]:
            raise StaleTurn(f"second NPS from {d} in turn {self.turn}")
        x, y, z = here = cell_of(fleet.pos[i])
        if abs(pos[0] - x) + abs(pos[1] - y) + abs(pos[2] - z) > 1:
            # refused: the drone may still send a valid move, or hover at the deadline
            raise OutOfRange(f"{d} cannot move from {here} to {pos}: one cell per turn, 6-connectivity")
        self._proposed[i], self._moved[i], self._said[i] = pos, True, code_of(note)
        self._awaiting -= 1

    def _drones_check(self) -> list[Effect]:
        if self._awaiting <= 0:  # every alive drone has moved (also when none is left alive)
            return self._drones_finish()
        return []

    def _upd(self, msg: Upd) -> list[Effect]:
        """The environment's report of a recent ENV phase: checked against the engine's world; it
        changes nothing (the observer has already judged the turn)."""
        if msg.sender != "ENV":
            raise WrongSender(f"UPD from {msg.sender}")
        turn, moves = msg.turn, self._upd_due.get(msg.turn)
        if moves is None:
            raise StaleTurn(f"UPD for turn {msg.turn}, which had no ENV phase awaiting its report")
        expected = {c: self._kind(c) for m in moves for c in (m.src, m.dst) if self.world.contains(c)}
        reported = {c.pos: c.kind for c in msg.cells}
        if reported != expected:
            wrong = sorted(c for c in expected.keys() | reported.keys() if reported.get(c) != expected.get(c))
            raise OutOfRange(f"UPD of turn {turn} disagrees with the world at {wrong[:5]}: the environment's "
                             "world or drones differ from the coordinator's")
        del self._upd_due[turn]
        return []

    def _observe(self, alive: np.ndarray, before: np.ndarray, after: np.ndarray, moved: np.ndarray) -> list[Effect]:
        """The observer's turn: `alive` drones went from `before` to `after` (`moved`: the rows that differ)."""
        fleet, ids = self.fleet, self.fleet.ids
        any_moved = np.count_nonzero(moved) > 0
        if any_moved:
            building = np.zeros(len(alive), bool)
            enter = moved & inside_rows(after, self.size)
            building[enter] = self.world.grid[tuple(after[enter].T)]
            cause = observer.judge(self.size, before, after, building)
        else:  # where the drones were, alive and apart, they still are
            cause = np.zeros(len(alive), np.uint8)
        took = self._moved[alive]
        fleet.pos[alive] = after
        said = alive[took & (self._said[alive] != fleet.note[alive])]
        fleet.note[said] = self._said[said]
        hovered = alive[~took]
        fleet.misses[alive[took]] = 0
        fleet.misses[hovered] += 1
        lost = hovered[fleet.misses[hovered] >= self.config.lost_after]
        dead = alive[cause != 0]
        fleet.state[dead], fleet.cause[dead] = code_of(DroneState.DEAD), cause[cause != 0]
        for i in dead.tolist():
            self._log.warning("turn %d: %s died (%s) at %s", self.turn, ids[i], CAUSES[fleet.cause[i]].value,
                              cell_of(fleet.pos[i]))
        for i in lost.tolist():
            if fleet.state[i] == ALIVE:
                self._lose(ids[i])
        log = self._turn_log
        if self.journaled:  # what the turn did, drone by drone
            if any_moved:
                log["moves"] = dict(zip([ids[i] for i in alive[moved].tolist()], after[moved].tolist()))
            if len(said):
                log["notes"] = {ids[i]: NOTES[c].value for i, c in zip(said.tolist(), fleet.note[said].tolist())}
            if len(hovered):
                log["hovered"] = [ids[i] for i in hovered.tolist()]
            if len(dead):
                log["deaths"] = {ids[i]: CAUSES[c].value for i, c in zip(dead.tolist(), fleet.cause[dead].tolist())}
        status = self.status(self.turn)
        data = encode(status)
        if self.journaled:
            log["state"] = hashlib.sha256(data).hexdigest()[:16]
        self._log.debug("turn %d observed: %s", self.turn, log)
        effects: list[Effect] = [Record(log), Publish(status, data)]
        end = self._end_reason(status.drones)
        if end:
            return effects + self._over(*end)
        return effects + self._enter(Stage.GCS, self.turn + 1)

    def _lose(self, d: str) -> None:
        i = self.fleet.index[d]
        self.fleet.end(i, DroneState.LOST, Cause.LOST)
        if self.stage is Stage.DRONES and not self._moved[i]:
            self._awaiting -= 1
        self._turn_log.setdefault("lost", []).append(d)
        self._log.warning("turn %d: %s is LOST at %s", self.turn, d, cell_of(self.fleet.pos[i]))

    def _end_reason(self, status: StatusTable) -> tuple[EndReason, str] | None:
        """Whether the game ends with the turn whose STATUS is `status`, and why."""
        alive = status.alive_mask()
        if not np.count_nonzero(alive):
            causes = ", ".join(f"{d} {r.state.value.lower()} ({r.cause.value.lower()}) at {r.pos}"
                               for d, r in self.drones.items())
            return EndReason.NO_DRONE_ALIVE, f"no drone alive: {causes}"
        if self.final:
            notes = status.column("note")[alive]
            if np.count_nonzero(notes == REACHED) == len(notes):
                return EndReason.ALL_REACHED, f"every drone reached its target in {self.turn} turns"
            if np.count_nonzero((notes == REACHED) | (notes == UNREACHABLE)) == len(notes):
                ids = status.ids()
                stuck = [ids[i] for i in alive.nonzero()[0][notes == UNREACHABLE].tolist()]
                return EndReason.SETTLED, f"targets reached, except unreachable for {', '.join(stuck)}"
        if self.turn >= self.config.max_turns:
            return EndReason.TURN_LIMIT, f"turn limit {self.config.max_turns} reached"
        return None

    def _over(self, reason: EndReason, text: str) -> list[Effect]:
        self.stage = Stage.OVER
        self.end = Over(turn=self.turn, sender="SRV", reason=reason, text=text)
        self._log.info("game over at turn %d: %s", self.turn, text)
        return [Record({"record": "over", "turn": self.turn, "reason": reason.value, "text": text}),
                Publish(self.end)]

    # ------------------------------------------------------------------ faults

    def expire(self, stage: Stage, turn: int, *_: object) -> list[Effect]:
        """The deadline of (stage, turn) passed; ignored if the game has moved on since."""
        if stage is not self.stage or turn != self.turn:
            return []
        if self._env_missing():
            return self._over(EndReason.ABORTED,
                              f"the environment vanished and did not come back within {self.config.env_grace:g} s")
        match stage:
            case Stage.RESUMING if self._back_but_gcs():
                self._log.warning("the ground station did not come back within %g s: the game resumes without it",
                                  self.config.gcs_grace)
                return self._resume()
            case Stage.ADMITTING | Stage.RESUMING:
                missing = [d for d, host in zip(self.fleet.ids, self.fleet.host) if host is None]
                missing += [r.value for r in (Role.ENV, Role.GCS) if r not in set(self.entities.values())]
                return self._over(EndReason.ABORTED, f"entities never connected: {', '.join(missing)}")
            case Stage.GCS:
                if self._done is not None:
                    self._log.warning("turn %d: %d of the GCS's %d targets arrived in time", turn,
                                      self._tgt_seen, self._done.count)
                    return self._gcs_finish(self._done)
                self._log.warning("turn %d: the GCS did not finish in time; targets unchanged", turn)
                self._aimed[:] = False
                return self._enter(Stage.DRONES, turn)
            case Stage.DRONES:
                alive = self.fleet.alive_rows()
                late = [self.fleet.ids[i] for i in alive[~self._moved[alive]].tolist()]
                self._log.warning("turn %d: no move from %s in time: hovering", turn, ", ".join(late))
                return self._drones_finish()
        return []

    def vanished(self, entity: str, session: str = "") -> list[Effect]:
        """An admitted entity's presence token disappeared (its process died or was cut off).

        Only the admitted process's own token counts: another process's (a refused impostor's) does not."""
        if entity not in self.entities or (session and self.sessions.get(entity) not in ("", session)):
            return []
        role = self.entities.pop(entity)
        self.sessions.pop(entity, None)
        if self.stage is Stage.OVER:
            return []
        self._log.warning("%s vanished", entity)
        match role:
            case Role.GCS:
                self._early.clear()  # what it said ahead goes with it
                if self.stage is Stage.GCS and self._done is not None:
                    return self._gcs_finish(self._done)  # its DONE is in: what arrived of its targets holds
                if self.stage is Stage.GCS:
                    self._aimed[:] = False
                    return self._enter(Stage.DRONES, self.turn)
            case Role.ENV:
                pass  # the game waits for it (deadline: env_grace); a returning one resyncs from STATUS
            case Role.DRONE:
                fleet = self.fleet
                gone = [i for i, host in enumerate(fleet.host) if host == entity]
                if self.stage in (Stage.ADMITTING, Stage.RESUMING):
                    for i in gone:
                        fleet.unhost(i)
                    return []
                for i in gone:
                    if fleet.state[i] == ALIVE:
                        self._lose(fleet.ids[i])
                if self.stage is Stage.DRONES:
                    return self._drones_check()
        return []


def opens_drones_phase(effect: Effect) -> bool:
    return isinstance(effect, Publish) and isinstance(effect.msg, Turn) and effect.msg.phase is Phase.DRONES


def _drones_first(effects: list[Effect]) -> list[Effect]:
    """The next turn's drones' phase first, when a turn ends and the next one's GCS phase was answered
    ahead: it is what the next turn waits for. The rest keeps its order (STATUS before the GCS phase
    it informs; the ENV phase before its STATUS)."""
    return sorted(effects, key=lambda e: not opens_drones_phase(e))  # stable: only the drones' phase moves


def _in_batch(n: int, whole: Callable[[], np.ndarray], one: Callable[[int], None]) -> list[RemoteInputError]:
    """Take a batch of `n` items (a MOVES's moves, a DONE's targets), each on its own: `one(j)` takes item j
    or raises why not. Up to FEW items go one by one; a bigger batch is taken as a whole first (`whole()`
    takes, in array operations, every item `one` would take, and says which), then the others one by one,
    which gives the reason of each refusal. The refusals, in order."""
    return _each(range(n) if n <= FEW else np.flatnonzero(~whole()).tolist(), one)


def _each(items, take) -> list[RemoteInputError]:
    """`take` each item of a batch; the refusals (each changed nothing), in order."""
    refused = []
    for item in items:
        try:
            take(item)
        except RemoteInputError as err:
            refused.append(err)
    return refused


def _with_refusals(refused: list[RemoteInputError], effects: list[Effect]) -> list[Effect]:
    """The effects of a batch; if some of it was refused, raised as one error that carries them."""
    if not refused:
        return effects
    first = refused[0]
    more = f" (and {len(refused) - 1} more: {'; '.join(map(str, refused[1:4]))})" if len(refused) > 1 else ""
    err = type(first)(f"{first}{more}")
    err.follow = effects
    raise err


def replace_config(config: GameConfig, **changes: object) -> GameConfig:
    return dataclasses.replace(config, **changes)
