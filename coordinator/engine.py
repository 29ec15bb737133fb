"""The turn engine: the lockstep turn cycle and the observer, as a pure state machine.

No network and no clock here: the Zenoh adapter (node.py) feeds it validated messages, expired deadlines
and vanished entities, one at a time, and carries out the effects it returns (publish, reply to a CONNECT,
journal, count a `Refusal`: an input that cannot be accepted changes nothing: effects.py). The stages it goes
through and the messages each stage takes are two tables that drive it, `TRANSITIONS` and `TAKES` (stages.py, in
the manner of h11's `_state.py`), where one turn's cycle is drawn. The engine says when each phase opens and
closes; its parts do the work: who may join (admission.py), what a phase takes in, each item checked (intake.py),
the turn's judgement (judge.py, with the arbitration of arbitration.py), whether the game ends (verdict.py), the
hold for a lost link (holds.py), the environment's reports (reports.py). A game restarted from its journal:
resume.py (through `Engine.resume`).

The ENV phase is pipelined: the engine holds the same world as the environment, so the observer judges the moves
at once instead of waiting a round trip for the environment's UPD (checked when it comes: reports.py). The
environment still applies every move (its ASK answers for turn t+1 need them; it also takes them from STATUS(t)).

A deadline ends a stage early: missing drones hover (and are LOST after `lost_after` misses in a row),
targets stay as they were; a vanished environment holds the drones' phase for `env_grace` seconds. A swarm host
still deciding its drones' moves says so (an empty MOVES): the drones' phase deadline then counts from its last
word, for up to `phase_cap` seconds in all (`stretch`; the adapter keeps the time), so that a host that is alive
and working is not taken for a hung one (which says nothing, and is LOST as before).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from schema import (
    Cell,
    Connect,
    Done,
    EndReason,
    Intent,
    Message,
    Moves,
    MoveTable,
    Nps,
    Over,
    Phase,
    Refused,
    Role,
    StartTable,
    Status,
    Target,
    Turn,
    Upd,
    Welcome,
)
from schema.errors import Refusal, RemoteInputError, StaleTurn, UsageError, WrongSender
from schema.tuning import AHEAD_MAX, DECIDING_SILENCE_S, TURN_FEW_DRONES
from world.grid import World, build_world, in_bounds, inside_rows
from world.search import STEPS, step_lengths

from .admission import Roster, id_ranges
from .arbitration import Arbitration
from .config import GameConfig, starts_of
from .effects import Effect, Publish, Record, ReplyToConnect, drones_first
from .fleet import ALIVE, Drones, Fleet, cell_of, nonzero
from .holds import Outage
from .intake import Ahead, Aims, Ballot, in_batch
from .journal import (
    TurnLog,
    TurnRecord,
    header_of,
    header_pilots,
    header_record,
    over_of,
    over_record,
    state_hash,
    turns,
)
from .judge import Cells, Codes, Judge, Rows
from .reports import Reports
from .stages import TAKES, TRANSITIONS, Stage, When
from .verdict import end_reason, named, over_text

#: (an enum's member read from its class costs ~10 times a global's in Python 3.11: those of every turn, once)
_GCS, _CONTINUE = Stage.GCS, Intent.CONTINUE


class Engine:
    """The coordinator's game: feed it events, carry out the effects it returns."""

    def __init__(self, config: GameConfig, logger: logging.Logger, world: World | None = None, game: str = "") -> None:
        """`world`: the game's world if the caller has built it already; `game`: the game's identity, which its
        WELCOME, TURN, STATUS and OVER carry (one per coordinator: an earlier one's messages are foreign)."""
        self.config, self.game, self._log, self.size = config, game, logger, config.world.size
        self.world = world if world is not None else build_world(config.world, (d.start for d in config.drones))
        if self.world.size != self.size:
            raise UsageError(f"the world is {self.world.size}, the game's is {self.size}")
        self.stage, self.turn = Stage.ADMITTING, 0
        self.fleet = Fleet(starts_of(config))
        self.drones = Drones(self.fleet)  # the drones one by one (a read-only view of the fleet)
        self.roster = Roster()
        self.entities = self.roster.roles  # the admitted entities: id -> role
        self._begin()
        # Its parts, each a module of its own (those of one game's course: `_begin`):
        self.arbitration = Arbitration(config.arbiter, self.world, len(self.fleet))  # the cooperative drones'
        self.judge = Judge(self.fleet, self.world, self.arbitration, self.ballot, config.lost_after, logger)
        self.outage = Outage(self.roster)  # while the link is down (`link_lost`): the entities not back yet
        self._turn_log = TurnLog(0)
        # The adapter's switches: the environment's UPD reports are checked; the turn records say what each drone
        # was told and did (off without a journal); someone follows the ENV phase (else its TURN is not made).
        self.verify_env = self.journaled = self.env_followed = True
        self._here = False  # the game was started here (`start_here`): it may be restarted (`restart`)

    def _begin(self) -> None:
        """The state of a game's course, as at its start (`__init__`, and `restart` for the next game)."""
        self.final = False  # the GCS said its plan is complete
        self.end: Over | None = None
        self.aiming = Aims(self.fleet, self.size)  # the targets this GCS phase received
        self.ballot = Ballot(self.fleet)  # the moves this drones' phase took
        self.ahead = Ahead()  # what came ahead of its phase: DONEs for coming turns, MOVES for this one
        self.reports = Reports(self.world)  # the environment's reports (UPD) awaited, checked against the world
        self._tgt_seen = 0  # TGT messages of this GCS phase
        self._done: Done | None = None  # the GCS's DONE, once it arrived
        self._phase_msg: Turn | None = None  # the TURN that opened the current stage
        self._held = False  # that TURN waits for the environment to come back
        self.intent = Intent.CONTINUE  # the GCS's last intent (journaled when it changes)
        #: Words from hosts still deciding this drones' phase (empty MOVES): each one restarts its deadline
        #: (`phase_cap`).
        self.deciding = 0
        #: The hosts that said so this drones' phase, and each host's first MOVES of a turn after such a word: the
        #: host sends it again (the router may drop a MOVES that reaches it with the word: entities/drone_node.py
        #: `Effects.repeat`), and a repeat of it is nothing new (`receive`).
        self._said: set[str] = set()
        self._repeated: dict[str, Moves] = {}
        #: The hosts that said so in the last drones' phase: presumed still slow, this one waits for their first word
        #: as it waits after a word (`stretch`).
        self._slow: frozenset[str] = frozenset()
        #: A lifelong game's tasks done so far: arrivals on a target given (`Fleet.tasks_done`, counted after each
        #: turn's moves, and again as a resumed game replays its journal).
        self.tasks = 0

    # ------------------------------------------------------------------ queries

    def alive(self) -> list[str]:
        return [self.fleet.ids[i] for i in self.fleet.alive_rows().tolist()]

    def targets(self) -> dict[str, Cell]:
        """The targets in force, of every drone that has one."""
        return self._by_id(self.fleet.target[:, 0] >= 0, self.fleet.target)

    def aims(self) -> dict[str, Cell]:
        """The targets this GCS phase has received so far (once it has ended: none, they are in force, `targets`)."""
        return self._by_id(self.aiming.aimed, self.aiming.cells)

    def moves_taken(self) -> dict[str, Cell]:
        """The moves this DRONES phase has taken so far."""
        return self._by_id(self.ballot.moved, self.ballot.proposed)

    def _by_id(self, rows: np.ndarray, cells: np.ndarray) -> dict[str, Cell]:
        return {self.fleet.ids[i]: cell_of(cells[i]) for i in np.flatnonzero(rows).tolist()}

    def _enter(self, stage: Stage) -> None:
        """Change stage, as `TRANSITIONS` allows (a change it does not list is a bug of the engine's)."""
        if stage not in TRANSITIONS[self.stage]:
            raise AssertionError(f"the engine cannot go from {self.stage.value} to {stage.value}")
        self.stage = stage

    def _playing(self) -> bool:
        return self.stage in (Stage.GCS, Stage.DRONES)

    def _admitting(self) -> bool:
        return self.stage in (Stage.ADMITTING, Stage.RESUMING)

    def _env_missing(self) -> bool:
        return self._playing() and not self.roster.has(Role.ENV)

    def deadline_key(self) -> tuple[Stage, int, bool, bool, bool, bool]:
        """What the current deadline is measured from: it restarts whenever this changes."""
        return (self.stage, self.turn, self._done is not None, self._env_missing(), self._back_but_gcs(),
                self.outage.away is not None)

    def _back_but_gcs(self) -> bool:
        """Resuming: the environment and the alive drones are back, the ground station not (yet)."""
        return (self.stage is Stage.RESUMING
                and self.roster.missing(self.fleet, self.fleet.alive_rows().tolist()) == [Role.GCS.value])

    def deadline(self) -> float | None:
        """Seconds the current stage may last before `expire` (None: no deadline)."""
        if self.outage.away is not None:
            return self.config.link_grace
        if self._env_missing():
            return self.config.env_grace
        if self._back_but_gcs():
            return self.config.gcs_grace
        if self._admitting():
            return self.config.admit_deadline
        if self.stage is Stage.GCS and self._done is None:
            return self.config.gcs_deadline
        # (the GCS phase once its DONE is in: the TGTs it counts that have not arrived get a drone's time)
        return self.config.phase_deadline if self._playing() else None

    def stretch(self) -> tuple[float, float] | None:
        """While a host says it is still deciding this drones' phase (`deciding`), or one that said so in the last
        one still has a move awaited (presumed as slow: its first word may come after the deadline on a loaded
        machine): how long the phase waits after its last word or its start (the deadline, at least
        `DECIDING_SILENCE_S`: one word missed or late does not end it), and how long it may last in all
        (`phase_cap`, at least the deadline). None: no such host, or the stage's deadline is not the drones'
        phase's."""
        if self.stage is not Stage.DRONES or self.outage.away is not None or self._env_missing():
            return None
        if not self.deciding and not any(self.ballot.awaits(code) for h in self._slow
                                         if (code := self.fleet.hosts.get(h)) is not None):
            return None
        deadline = self.config.phase_deadline
        return max(deadline, DECIDING_SILENCE_S), max(self.config.phase_cap, deadline)

    def status(self, turn: int | None = None) -> Status:
        """Every drone's state at the end of `turn`; by default now, i.e. during a turn, as it stood at
        the end of the previous one."""
        if turn is None:
            turn = self.turn - 1 if self._playing() else self.turn
        return Status(turn=turn, sender="OBS", drones=self.fleet.status(), game=self.game)

    # ------------------------------------------------------------------ admission

    def connect(self, msg: Connect, token: object) -> list[Effect]:
        """Admit an entity or refuse it; start the game when everyone is there."""
        refusal = self.roster.refusal(msg, self.fleet, over=self.stage is Stage.OVER, admitting=self._admitting())
        if refusal:
            expected = self.roster.claimed(msg, self.fleet)  # (an id taken: a replica tries the next one)
            self._log.log(logging.INFO if expected else logging.WARNING, "refused %s: %s", msg.sender, refusal)
            refused: list[Effect] = [ReplyToConnect(token, Refused(turn=self.turn, sender="SRV", text=refusal))]
            # one that comes back after the end (its link was down when OVER went out) is told the end again
            return refused + ([Publish(self.end)] if self.end is not None else [])
        again = self.roster.admit(msg)  # the same process connecting again (its session says so)
        fleet = self.fleet
        fleet.fly([fleet.index[d] for d in msg.drones], msg.sender, msg.autopilot, msg.cooperative)
        rows = sorted(range(len(fleet)) if msg.role is not Role.DRONE else [fleet.index[d] for d in msg.drones])
        starts = StartTable.build(drone=fleet.numbers[rows], pos=fleet.pos[rows])
        what = msg.sender if msg.role is not Role.DRONE or msg.drones == (msg.sender,) else \
            f"{msg.sender} flying {id_ranges(msg.drones)}"
        self._log.info("%s %s", "re-admitted" if again else "admitted", what)
        welcome = Welcome(turn=self.turn, sender="SRV", entity=msg.sender, text=f"You are connected as {what}",
                          world=self.config.world, starts=starts, game=self.game)
        effects: list[Effect] = [ReplyToConnect(token, welcome)]
        if self._admitting():
            # resuming: the alive drones (and the ground station, which may have left for good: `gcs_grace`)
            awaited = fleet.alive_rows().tolist() if self.stage is Stage.RESUMING else None
            return effects + ([] if self.roster.missing(fleet, awaited) else self._start())
        # the last of those back after a lost link to connect again (or one that vanished meanwhile, admitted anew):
        # what went out when the hold ended goes out once more (then it may not have reached them: `Outage`)
        last = self.outage.rejoined(msg.sender)
        effects.append(Publish(self.status()))  # a late joiner sees the state at once
        # A returning environment or ground station takes up the phase in progress.
        if msg.role is Role.ENV and self._held and self._phase_msg is not None:
            self._held = False
            effects += [Publish(self._phase_msg), *self._take_early_moves()]
        elif self._phase_msg is not None and (msg.role, self.stage) == (Role.GCS, Stage.GCS):
            effects.append(Publish(self._phase_msg))
        elif last:
            effects += self._phase_again()
        return effects

    def start_here(self, host: str, autopilot: str, cooperative: Sequence[int] = ()) -> None:
        """The game started for a caller in this process that is its environment, its ground station and the
        swarm host `host` flying every drone with `autopilot`, those of rows `cooperative` cooperating (dronesim/
        rl.py): each there as if it had connected, with no message built, and the first turn's GCS phase opened
        (`play` plays the turns). UsageError if someone connected already."""
        if self.stage is not Stage.ADMITTING or self.entities:
            raise UsageError("a game is started here before anyone has connected")
        for entity, role in (("ENV", Role.ENV), ("GCS", Role.GCS), (host, Role.DRONE)):
            self.roster.enter(entity, role)
        self.fleet.fly(list(range(len(self.fleet))), host, autopilot, False)
        if len(cooperative):
            self.fleet.learn(list(cooperative), autopilot, True)
        self._here = True
        self.arbitration.prepare(self.fleet)
        self._open_gcs(1)

    def restart(self, starts: np.ndarray | list[Cell]) -> None:
        """A game started here (`start_here`) begun again at its first turn, its drones at `starts` (a cell per
        fleet row, in id order): the state a new engine of this game started here would have, without building
        again what does not change (the world and its tables, the fleet's columns, the entities and who flies
        which drone; dronesim/rl.py's episodes, one after the other). `config.drones` keeps the first game's
        starts (only a new engine reads them). UsageError if the game was not started here."""
        if not self._here:
            raise UsageError("only a game started here (start_here) is restarted")
        fleet = self.fleet
        fleet.restart(starts)
        self._begin()
        if fleet.cooperating:  # (the arbiter's search holds the last game's state: a new one)
            self.arbitration = Arbitration(self.config.arbiter, self.world, len(fleet))
            self.arbitration.prepare(fleet)
        else:  # (no search to forget)
            self.arbitration.priority.fill(0)
            self.arbitration.gave_way.fill(False)
        self.judge = Judge(fleet, self.world, self.arbitration, self.ballot, self.config.lost_after, self._log)
        self.stage = Stage.ADMITTING  # (a new game's)
        self._open_gcs(1)

    def header(self) -> dict:
        """The journal's first record: what identifies the game (see resume.py). Without a journal it leaves
        out the drones and the world's cells, which would only be dropped (a swarm's: a burst of objects)."""
        fleet = self.fleet
        drones = zip(fleet.ids, fleet.pos.tolist(), fleet.autopilot, fleet.cooperative.tolist())
        return header_record(self.config, self.size, drones if self.journaled else None)

    def _start(self) -> list[Effect]:
        """Everyone is there: the game starts (its header opens the journal), or a resumed one goes on."""
        self.arbitration.prepare(self.fleet)
        if self.stage is Stage.RESUMING:
            self._log.info("entities back: the game resumes at turn %d", self.turn + 1)
            return [Publish(self.status()), *self._gcs_phase(self.turn + 1)]
        self._log.info("all entities connected: the game starts")
        return [Record(self.header()), Publish(self.status()), *self._gcs_phase(1)]

    # ------------------------------------------------------------------ stages

    def _gcs_phase(self, turn: int) -> list[Effect]:
        early = self._open_gcs(turn)
        if not self.roster.has(Role.GCS):  # no ground station: the drones keep their targets
            return self._drones_phase()
        self._phase_msg = Turn(turn=turn, sender="SRV", phase=Phase.GCS, game=self.game)
        # answered ahead, the phase opens and closes at once, unannounced (the station goes by STATUS)
        return [Publish(self._phase_msg)] if early is None else self._gcs_done(early)

    def _drones_phase(self) -> list[Effect]:
        """The drones' phase of this turn opens: no move taken yet, every alive drone's awaited."""
        self._enter(Stage.DRONES)
        self.deciding = 0
        self._slow, self._said = frozenset(self._said), set()
        alive = self.fleet.alive_rows()
        self.ballot.open(self.turn, len(alive))
        orders = self.fleet.orders(alive)
        self._phase_msg = Turn(turn=self.turn, sender="SRV", phase=Phase.DRONES, orders=orders, game=self.game)
        if self._env_missing():  # drones would ASK nobody: the turn waits for the environment
            self._held = True
            self._log.warning("turn %d waits for the environment to come back", self.turn)
            return []
        return [Publish(self._phase_msg), *self._take_early_moves()]

    def _open_gcs(self, turn: int) -> Done | None:
        """The GCS phase of `turn` begins: nothing received yet; the DONE sent ahead for it, if any."""
        if self.stage is not _GCS:  # (from the GCS phase itself: a turn of `play`'s)
            self._enter(_GCS)
        self.turn = turn  # (no target received yet: `_targets_set` and `_gcs_finish` cleared them)
        self._tgt_seen, self._done = 0, None
        self._turn_log = TurnLog(turn)
        return self.ahead.done_for(turn) if self.ahead.dones else None

    def _drones_finish(self) -> list[Effect]:
        """The drones' phase is over: judge it, announce the ENV phase (the accepted moves), then the observer's
        STATUS and the turn's journal record, and the next turn or the end."""
        turn, fleet, log = self.turn, self.fleet, self._turn_log
        moved, src, dst, alive = self.judge.rule(turn, log, self.journaled, self.env_followed or self.verify_env)
        if self.config.lifelong:
            self.tasks += fleet.tasks_done()
        effects: list[Effect] = []
        if (self.env_followed or self.verify_env) and len(moved):
            rows = MoveTable.empty(len(moved))
            rows["drone"], rows["src"], rows["dst"] = fleet.numbers[moved], src, dst
            moves = MoveTable(rows)
            if self.verify_env:  # its report may come turns later (nothing waits for it): keep a few
                self.reports.expect(turn, moves)
            if self.env_followed:
                effects.append(Publish(Turn(turn=turn, sender="SRV", phase=Phase.ENV, moves=moves, game=self.game)))
        status = self.status(turn)  # (encoded as it goes out, after the next turn's drones' phase)
        if self.journaled:
            log.state(state_hash(status))
        self._log.debug("turn %d observed: %s", turn, log.record)
        end = end_reason(fleet, self.arbitration.arbiter, self.final, turn, self.config.max_turns, alive,
                         self.config.lifelong)
        effects += [Record(log.record), Publish(status), *(self._over(*end) if end else self._gcs_phase(turn + 1))]
        return drones_first(effects)

    def receive(self, msg: Message) -> list[Effect]:
        """A message from the network, decoded and addressed correctly: its effects. One that cannot be accepted
        changes nothing but gives a `Refusal` (a refused TGT still counts towards its DONE, a batch's others go on)."""
        if type(msg) is Moves and self._repeated.get(msg.sender) == msg:
            return []  # (a host's MOVES after its word, again)
        when = When.NOW if msg.turn == self.turn else \
            When.AHEAD if self.turn < msg.turn <= self.turn + AHEAD_MAX else When.OTHER
        take = TAKES.get((None, type(msg), When.ANY)) or TAKES.get((self.stage, type(msg), when))
        try:
            if take is None:
                raise StaleTurn(f"{msg.TAG} for turn {msg.turn} from {msg.sender} while in {self.stage.value} "
                                f"of turn {self.turn}")
            effects: list[Effect] = getattr(self, take)(msg)
            return effects
        except RemoteInputError as err:  # raised before anything changed
            return [Refusal(f"{msg.TAG} from {msg.sender}", err)]

    def _target(self, msg: Target) -> list[Effect]:
        """A TGT from the GCS during its phase: checked (sender, turn, drone, inside the world), kept."""
        if msg.sender != "GCS":
            raise WrongSender(f"target for {msg.drone} from {msg.sender}: only the GCS sets targets")
        if self.stage is not Stage.GCS or msg.turn != self.turn:
            raise StaleTurn(f"target for turn {msg.turn} while in {self.stage.value} of turn {self.turn}")
        self._tgt_seen += 1  # counted against the DONE's count even if refused: the phase goes on
        return [*in_batch(msg, 1, None, lambda _: self.aiming.aim(msg.drone, msg.pos)), *self._gcs_check()]

    def _hold(self, msg: Done) -> list[Effect]:
        """The GCS's DONE for a coming GCS phase (up to AHEAD_MAX turns on): held for it (`Ahead`)."""
        self.ahead.hold_done(msg)
        return []

    def _nps(self, msg: Nps) -> list[Effect]:
        self.ballot.take(msg.sender, msg.pos, msg.note, msg.ranked)
        return self._drones_check()

    def _hold_moves(self, msg: Moves) -> list[Effect]:
        """A swarm host's MOVES for this turn, sent before its drones' phase opened: held for it (`Ahead`)."""
        self.ahead.hold_moves(msg, self.fleet.hosts)
        return []

    def _take_early_moves(self) -> list[Effect]:
        """The drones' phase is announced: the MOVES held for it are taken, in the order they came (one after an
        earlier one closed the phase is refused as stale, as it would be if sent then)."""
        return [e for msg in self.ahead.take_moves() for e in self.receive(msg)]

    def _done_again(self, msg: Done) -> list[Effect]:
        """A DONE of the turn whose GCS phase has closed: the one taken, again (a ground station repeats its DONE
        until the turn's STATUS: it may have been lost), changes nothing; any other is stale."""
        if msg != self._done:
            raise StaleTurn(f"DONE for turn {msg.turn} from {msg.sender} in its drones' phase")
        return []

    def _gcs_done(self, msg: Done) -> list[Effect]:
        if msg.sender != "GCS" or msg.phase is not Phase.GCS:
            raise WrongSender(f"DONE({msg.phase.value}) from {msg.sender} in the GCS phase")
        if self._done is not None:
            if msg == self._done:
                return []  # (the same again: a ground station repeats its DONE until the turn is played)
            raise StaleTurn(f"second DONE from the GCS in turn {self.turn}")
        self._done = msg
        return [*self.aiming.aim_all(msg), *self._gcs_check()]

    def _gcs_check(self) -> list[Effect]:
        """The GCS phase ends when its DONE and all the TGT it counted have arrived (in any order)."""
        return [] if self._done is None or self._tgt_seen < self._done.count else self._gcs_finish()

    def _gcs_finish(self) -> list[Effect]:
        """The GCS phase ends (also cut short): what arrived of its targets holds if its DONE is in, else none."""
        if self._done is None:
            self.aiming.aimed[:] = False
        elif not self._targets_set(self._done.intent):
            return [Record(self._turn_log.record), *self._over(EndReason.GCS_QUIT, "the ground station ended the game")]
        return self._drones_phase()

    def _targets_set(self, intent: Intent, aimed: bool = True) -> bool:
        """The GCS phase closes: its targets take force (`aimed`: whether it may have received any), its intent is
        noted; whether the game goes on (not QUIT)."""
        fleet = self.fleet
        if aimed and nonzero(self.aiming.aimed):  # (most GCS phases bring no target)
            changed = self.aiming.take_effect()
            if len(changed) and self.journaled:
                self._turn_log.targets([fleet.ids[i] for i in changed.tolist()], fleet.target[changed].tolist())
        if intent is not self.intent:
            self._turn_log.intent(intent)
            self.intent = intent
        if intent is Intent.QUIT:
            return False
        self.final = intent is Intent.FINAL
        return True

    def play(self, aim_rows: Rows, aims: Cells, move_rows: Rows, moves: Cells, notes: Codes,
             ranked: Codes | None = None, offsets: bool = False) -> Over | None:
        """One whole turn without messages, for a caller in this process that is the ground station and every
        drone's host (dronesim/rl.py): as if a DONE (CONTINUE) carried the targets `aims` of the rows `aim_rows`,
        then a MOVES the `moves` (cells), `notes` (Note codes) and `ranked` candidates (cooperative drones', as an
        NPS's; None: none) of the rows `move_rows` (each once; the other alive drones hover), with no message
        built and no journal record. Rows, cells and codes as arrays, or as lists (ints, (x, y, z) tuples, ints:
        what a caller playing a few drones holds). `offsets`: the `moves` are each drone's step (dx, dy, dz), not
        its cell (an RL episode's actions: the judge's pass over the moves makes them cells; the fleet's cells,
        `Fleet.cells`, are where they led).
        The turn's OVER if the game ended with it. UsageError, nothing changed, if the turn is not the GCS's (or a
        DONE or MOVES came ahead) or an input would be refused."""
        fleet = self.fleet
        if self.stage is not _GCS or self._done is not None or self.ahead.dones or self.ahead.moves:
            raise UsageError(f"a turn from arrays is played from the GCS phase, not from {self.stage.value} "
                             f"of turn {self.turn}")
        few, judge, steps, aiming = len(move_rows) <= TURN_FEW_DRONES, self.judge, None, len(aim_rows)
        whole = fleet.whole() if few else None  # (the columns as lists, read once for the turn: a small fleet's)
        if aiming and not (
                all(whole[0][i] == ALIVE and in_bounds(c, self.size) for i, c in zip(aim_rows, aims))
                if whole is not None and isinstance(aims, list) else
                np.count_nonzero(fleet.state[aim_rows] != ALIVE) == 0
                and np.count_nonzero(inside_rows(np.asarray(aims), self.size)) == len(aim_rows)):
            raise UsageError("a target for a drone not alive, or outside the world")
        rows: Rows
        cells: Cells
        codes: Codes
        if few:  # (Python's lists: an array operation's fixed cost is more than a few rows' work)
            rows = move_rows if isinstance(move_rows, list) else move_rows.tolist()
            cells = moves if isinstance(moves, list) else list(map(tuple, moves.tolist()))
            codes = notes if isinstance(notes, list) else notes.tolist()
            # every alive drone's move, in one pass (most turns of an RL episode's): else each move taken
            steps = judge.steps(rows, cells, whole, offsets) if whole and not fleet.cooperating else None
            ok = True
            if steps is None:
                took = {}
                state, pos = whole if whole else (fleet.column(fleet.state, rows), fleet.column(fleet.pos, rows))
                if offsets:  # (the cells the steps lead to; a step that is not one is refused below)
                    at = pos if whole else dict(zip(rows, pos))
                    cells = [(at[i][0] + dx, at[i][1] + dy, at[i][2] + dz) for i, (dx, dy, dz) in zip(rows, cells)]
                for k, i, cell, code in zip(rows if whole else range(len(rows)), rows, cells, codes):
                    (a, b, c), (x, y, z) = cell, pos[k]
                    ok = ok and state[k] == ALIVE and (a - x, b - y, c - z) in STEPS
                    took[i] = cell, code
        else:
            rows, cells, codes = move_rows, np.asarray(moves), np.asarray(notes)
            if offsets:
                cells = fleet.pos[rows] + cells
            ok = (np.count_nonzero(fleet.state[rows] != ALIVE) == 0
                  and step_lengths(fleet.pos[rows], cells).max() <= 1)
        if not ok:
            raise UsageError("a move for a drone not alive, or of more than one cell (6-connectivity)")
        if aiming:
            self.aiming.aimed[aim_rows], self.aiming.cells[aim_rows] = True, aims
            self._targets_set(Intent.CONTINUE)
        elif self.intent is not _CONTINUE:  # (else the phase changes nothing: no target, the same intent)
            self._targets_set(Intent.CONTINUE, False)
        cells_wanted = self.env_followed or self.verify_env
        if steps is not None:
            turn = judge.rule_steps(self.turn, self._turn_log, self.journaled, cells_wanted, steps,
                                    codes)  # type: ignore[arg-type]  # (a list: `few`)
        elif few and not fleet.cooperating:  # (only the arbitration reads the arrays then)
            turn = judge.rule(self.turn, self._turn_log, self.journaled, cells_wanted, took, whole)
        else:
            ballot = self.ballot
            ballot.moved[:] = False  # (the drones' phase, opened and closed at once)
            ballot.proposed[rows], ballot.said[rows], ballot.moved[rows] = cells, codes, True
            ballot.ranked[rows] = 0 if ranked is None else ranked
            turn = judge.rule(self.turn, self._turn_log, self.journaled, cells_wanted)
        config = self.config
        if config.lifelong:
            self.tasks += fleet.tasks_done()
        if end := end_reason(fleet, self.arbitration.arbiter, self.final, self.turn, config.max_turns, turn.alive,
                             config.lifelong):
            self._over(*end)
            return self.end
        self._open_gcs(self.turn + 1)
        return None

    def _moves_of_host(self, msg: Moves) -> list[Effect]:
        """A swarm host's moves (`Ballot.take_all`), or none: its word that it is still deciding them."""
        if not len(msg.moves):
            return self._still_deciding(msg)
        if msg.sender in self._said and getattr(self._repeated.get(msg.sender), "turn", None) != msg.turn:
            self._repeated[msg.sender] = msg
        return [*self.ballot.take_all(msg), *self._drones_check()]

    def _still_deciding(self, msg: Moves) -> list[Effect]:
        """An empty MOVES: a host whose drones' moves this phase still awaits is deciding them (alive and working,
        however slow): noted (`deciding`: the phase's deadline counts again from now, up to its cap: `stretch`). From a
        host with no move awaited it changes nothing (a word that crossed its MOVES on the way)."""
        code = self.fleet.hosts.get(msg.sender)
        if code is None:
            raise WrongSender(f"MOVES from {msg.sender}, which flies no drone of this game")
        if self.ballot.awaits(code):
            if not self.deciding:
                self._log.info("turn %d: %s is still deciding: the drones' phase waits for it (up to %g s)",
                               self.turn, msg.sender, max(self.config.phase_cap, self.config.phase_deadline))
            self.deciding += 1
            self._said.add(msg.sender)
        return []

    def _drones_check(self) -> list[Effect]:
        """The drones' phase ends once every alive drone has moved (also when none is left alive)."""
        return self._drones_finish() if self.ballot.awaiting <= 0 else []

    def _upd(self, msg: Upd) -> list[Effect]:
        """The environment's report of a recent ENV phase, checked against the engine's world (`Reports`)."""
        self.reports.check(msg)
        return []

    def _lose(self, i: int) -> None:
        if self.stage is Stage.DRONES and not self.ballot.moved[i]:
            self.ballot.awaiting -= 1
        self.judge.lose(i, self.turn, self._turn_log)

    def _over(self, reason: EndReason, text: str, turn: int | None = None) -> list[Effect]:
        """The game ends: its over record closes the journal (a game that never started has none: its journal
        stays empty, free for a new game) and OVER goes out."""
        turn = self.turn if turn is None else turn
        started = self.stage is not Stage.ADMITTING
        self._enter(Stage.OVER)
        lifelong = self.config.lifelong and started
        text = over_text(text, turn, self.tasks if lifelong else None)
        self.end = Over(turn=turn, sender="SRV", reason=reason, text=text, game=self.game)
        self._log.info("game over at turn %d: %s", turn, text)
        record = over_record(turn, reason.value, text, self.tasks if lifelong else None)
        return [*([Record(record)] if started else []), Publish(self.end)]

    # ------------------------------------------------------------------ resuming

    def resume(self, records: Sequence[dict]) -> int:
        """A game restarted from its journal's records (coordinator/resume.py reads them): its header checked
        against this game (the drones' autopilots learnt from it, as the game learnt them at admission), each
        journaled turn replayed as the observer played it and checked against the state it recorded; then the
        engine waits (RESUMING) for the entities to connect again and plays the turn after the last. The last
        turn; UsageError, if the journal is not this game's, is over, or does not replay to its recorded states."""
        if self.stage is not Stage.ADMITTING or self.entities:
            raise UsageError("a game is resumed before anyone has connected")
        theirs, fleet = header_of(records), self.fleet
        if theirs is None:
            raise UsageError("the journal has no header: nothing to resume")
        for drone, autopilot, cooperative in header_pilots(theirs):  # (learnt at admission, not configured)
            i = fleet.index.get(drone)
            if i is not None:
                fleet.learn([i], autopilot, cooperative)
        if self.header() != theirs:
            raise UsageError("the journal is of another game (world, drones or limits differ)")
        if (over := over_of(records)) is not None:
            raise UsageError(f"the journal's game is over (turn {over.get('turn')}): nothing to resume (a journal "
                             "holds one game: give another --journal for a new one)")
        try:
            for r in turns(records[1:]):
                self._replay(r)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise UsageError(f"the journal has a bad turn record: {exc!r}") from None
        self._enter(Stage.RESUMING)
        return self.turn

    def _replay(self, r: TurnRecord) -> None:
        fleet, row = self.fleet, self.fleet.index
        alive = fleet.alive_rows()
        for d, p in r.targets.items():
            fleet.aim(row[d], p)
        if r.intent is not None:
            self.intent = r.intent
            self.final = self.intent is Intent.FINAL
        self.turn = r.turn
        self.judge.replay(r, alive)
        if self.config.lifelong:
            self.tasks += fleet.tasks_done()
        if state_hash(self.status(r.turn)) != r.state:
            raise UsageError(f"the journal's turn {r.turn} does not replay to its recorded state")

    # ------------------------------------------------------------------ faults

    def expire(self, stage: Stage, turn: int, *_: object) -> list[Effect]:
        """The deadline of (stage, turn) passed; ignored if the game has moved on since."""
        if stage is not self.stage or turn != self.turn:
            return []
        if self.outage.away is not None:  # who is not back after a lost link has vanished
            gone = self.outage.end()
            self._log.warning("%s did not come back within %g s", ", ".join(gone), self.config.link_grace)
            return [e for entity in gone for e in self.vanished(entity)] + self._go_on()
        if self._env_missing():
            return self._over(EndReason.ABORTED,
                              f"the environment vanished and did not come back within {self.config.env_grace:g} s")
        if self._back_but_gcs():
            self._log.warning("the ground station did not come back within %g s: the game resumes without it",
                              self.config.gcs_grace)
            return self._start()
        if self._admitting():
            missing = named(self.roster.missing(self.fleet))
            return self._over(EndReason.ABORTED, f"entities never connected: {missing}")
        if stage is Stage.GCS:
            if self._done is None:
                self._log.warning("turn %d: the GCS did not finish in time; targets unchanged", turn)
            else:
                self._log.warning("turn %d: %d of the GCS's %d targets arrived in time", turn, self._tgt_seen,
                                  self._done.count)
            return self._gcs_finish()
        if stage is Stage.DRONES:
            alive = self.fleet.alive_rows()
            late = [self.fleet.ids[i] for i in alive[~self.ballot.moved[alive]].tolist()]
            self._log.warning("turn %d: no move from %s in time: hovering", turn, ", ".join(late))
            return self._drones_finish()
        return []

    def interrupt(self, why: str) -> list[Effect]:
        """The coordinator was told to stop (a signal): the game ends now (INTERRUPTED)."""
        if self.stage is Stage.OVER:
            return []
        return self._over(EndReason.INTERRUPTED, why, self.status().turn)  # the last turn played (and STATUS sent)

    def unrecorded(self, why: str, turn: int) -> list[Effect] | None:
        """The journal could not take the record of `turn` (`why`: a full disk, a file size limit). The game
        stops at once: OVER JOURNAL_FAILED in that turn (one the entities still take, wherever in it they are),
        without an over record (none could be written, and a journal without one resumes, `--resume`, once
        there is room, from the turn before, replaying this one); what the lost record was for is not sent.
        None if the game was over already (its over record was the one lost): its OVER goes out all the same."""
        if self.stage is Stage.OVER:
            return None
        text = f"the journal could not be written ({why}): the game stops in turn {turn}, which it does not " \
               "hold; resume it from its journal (--resume) once there is room"
        return [e for e in self._over(EndReason.JOURNAL_FAILED, text, turn) if not isinstance(e, Record)]

    def link_lost(self) -> list[Effect]:
        """The coordinator's link is down (its own presence vanished, as every other's does when the router
        restarts): nobody has left, the game holds until every admitted entity is back (`present`) or
        `link_grace` has passed (`expire`: those still away have vanished)."""
        if self.stage is Stage.OVER or not self.outage.begin(self.entities):
            return []
        self._log.warning("the link is down: the game holds up to %g s for %s to come back", self.config.link_grace,
                          ", ".join(sorted(self.entities)) or "its entities")
        return []

    @property
    def holding(self) -> bool:
        """Whether the game holds for a lost link (`link_lost`)."""
        return self.outage.away is not None

    def link_back(self) -> list[Effect]:
        """The coordinator reaches its entities again after a hold that no presence ends (a frozen router: no
        token vanished, so none comes back): the hold ends as when the last one is back (`present`)."""
        if self.outage.away is None:
            return []
        self.outage.end()
        self._log.warning("the routers answer again: turn %d goes on", self.turn)
        return self._go_on()

    def present(self, entity: str, session: str) -> list[Effect]:
        """An entity's presence token is there (again). The last admitted one back after a lost link ends the
        hold: the current STATUS and phase go out again (what was sent during the outage was lost)."""
        if not self.outage.back(entity, session):
            return []
        self._log.warning("every entity is back: turn %d goes on", self.turn)
        return self._go_on()

    def _go_on(self) -> list[Effect]:
        """What an entity that missed messages needs to go on with the current turn."""
        if not self._playing():
            return []
        return [Publish(self.status()), *self._phase_again()]

    def _phase_again(self) -> list[Effect]:
        """The phase in progress sent again (none while it waits for the environment)."""
        if self._playing() and self._phase_msg is not None and self._phase_msg.turn == self.turn and not self._held:
            return [Publish(self._phase_msg)]
        return []

    def vanished(self, entity: str, session: str = "") -> list[Effect]:
        """An admitted entity's presence token disappeared (its process died or was cut off; a refused impostor's
        token does not count). A vanished environment is waited for (`env_grace`; back, it resyncs from STATUS)."""
        if self.outage.gone(entity, session):  # the link is down: it is away, not gone (until `link_grace`)
            return []
        role = self.roster.leave(entity, session)
        if role is None or self.stage is Stage.OVER:
            return []
        self._log.warning("%s vanished", entity)
        effects = self._left(entity, role)
        if self.outage.rejoined(entity):  # the last one awaited to connect again after a lost link (`connect`)
            effects += self._go_on()
        return effects

    def _left(self, entity: str, role: Role) -> list[Effect]:
        """What an admitted entity's leaving changes (`vanished`)."""
        if role is Role.GCS:
            self.ahead.dones.clear()  # what it said ahead goes with it
            if self.stage is Stage.GCS:
                return self._gcs_finish()
        elif role is Role.DRONE:
            fleet = self.fleet
            self.ahead.moves.pop(entity, None)
            for i in [i for i, host in enumerate(fleet.host) if host == entity]:
                if self._admitting():
                    fleet.unhost(i)
                elif fleet.state[i] == ALIVE:
                    self._lose(i)
            if self.stage is Stage.DRONES:
                return self._drones_check()
        return []
