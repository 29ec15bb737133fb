"""The whole game in one process, no network: the same Engine, Environment and autopilots as the distributed run, wired
by function calls. Given the same scenario and inputs (GCS targets and intents per turn, drones that missed a deadline
or vanished), it writes the same journal, byte for byte, as a run over Zenoh. Used to verify journals (replay --verify),
by benchmarks (the in-process baseline) and by tests."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from coordinator.arbiter import Arbiter
from coordinator.config import GameConfig
from coordinator.effects import Publish, Record, Refusal, opens_drones_phase
from coordinator.engine import Engine
from coordinator.stages import Stage
from dronesim.scenario import swarm_hosts
from entities.autopilots import make_autopilot, make_swarm, pilot_class
from entities.autopilots.base import Decision, drive, fly_pilots, fly_swarm
from entities.environment import Environment
from entities.gcs import Plan, gcs_done
from entities.tasks import Tasks
from schema import Cell, Connect, Intent, Moves, Nps, Over, Phase, Role, Status, StepTable, Turn, Upd
from schema.errors import UsageError
from schema.tables import drone_number
from schema.tuning import SWARM_MIN
from world.grid import build_world


@dataclass(slots=True)
class Inputs:
    """What a run depends on besides the scenario. `targets` as a Plan; the rest by turn."""

    plan: Plan
    intents: dict[int, Intent] = field(default_factory=dict)  # turn -> intent from then on (as journaled: changes)
    hovered: dict[int, set[str]] = field(default_factory=dict)  # turn -> drones that sent no NPS
    vanished: dict[int, set[str]] = field(default_factory=dict)  # turn -> drones whose process vanished
    scripted: bool = True  # no intents given: FINAL once the plan is over, as a scripted GCS says
    #: Lifelong: a new target for each drone that reached its own, as a lifelong ground station draws it (its
    #: intent then stays CONTINUE: the game goes on to its turn limit).
    tasks: Tasks | None = None

    def intent(self, turn: int) -> Intent:
        if self.scripted and not self.intents:
            if self.tasks is not None:
                return Intent.CONTINUE
            return Intent.FINAL if turn >= self.plan.last_turn else Intent.CONTINUE
        said = [t for t in self.intents if t <= turn]
        return self.intents[max(said)] if said else Intent.CONTINUE


@dataclass(slots=True)
class Result:
    records: list[dict]
    over: Over
    statuses: list[Status]
    final: Status | None = None  # the last STATUS
    tasks: int = 0  # a lifelong game's tasks done (`Engine.tasks`)


def simulate(config: GameConfig, autopilots: Mapping[str, str], inputs: Inputs,
             logger: logging.Logger | None = None, *, keep_statuses: bool = False, verify_env: bool = True,
             swarm: bool = False, swarm_min: int = SWARM_MIN, arbiter: Arbiter | None = None,
             pilot_options: Mapping[str, Mapping[str, object]] | None = None, journaled: bool = True) -> Result:
    """Play the game. `swarm`: the drones flown as `dronesim up --swarm` flies them, one host per
    autopilot sending one MOVES a turn, with the autopilot's swarm form from `swarm_min` drones on (the
    journal is the same; drones that miss or vanish need the layout of a process per drone).
    `arbiter` (`Arbitration.arbiter`, e.g. the former `arbiter.fixed`) and `pilot_options` (autopilot name ->
    options for each of its instances flown one per drone, e.g. D*'s `known` map) are the benchmark's, and so is
    `journaled` False: the turn records say only their turn (a long game of thousands of drones in less memory)."""
    log = logger or logging.getLogger("dronesim.local")
    if swarm and (inputs.hovered or inputs.vanished):
        raise UsageError("drones that miss a turn or vanish are played with one process per drone, not swarm hosts")
    world = build_world(config.world, (d.start for d in config.drones))
    engine = Engine(config, log, world)
    engine.verify_env, engine.journaled = verify_env, journaled
    if arbiter is not None:  # (the benchmark's; by default the engine's own)
        engine.arbitration.arbiter = arbiter
    records: list[dict] = []
    statuses: list[Status] = []
    queue: deque = deque()

    def push(effects: list) -> None:
        """Queue a batch of effects, a drones' phase after the rest: the coordinator sends it first (the next
        turn waits for it), but here the environment must see the turn's ENV phase and STATUS before the drones
        sense, as it does over the network (it answers an ASK for turn t only once STATUS(t - 1) is in)."""
        queue.extend(sorted(effects, key=opens_drones_phase))  # stable: only the drones' phase moves
    for hello in (Connect(turn=0, sender="ENV", role=Role.ENV), Connect(turn=0, sender="GCS", role=Role.GCS)):
        push(engine.connect(hello, None))
    # sender -> (autopilot, its drones): a host per autopilot, or a process per drone
    flyers = swarm_hosts(dict(autopilots)) if swarm else {d: (autopilots[d], (d,)) for d in sorted(autopilots)}
    for sender, (pilot, drones) in flyers.items():
        push(engine.connect(Connect(turn=0, sender=sender, role=Role.DRONE, drones=drones, autopilot=pilot,
                                    cooperative=pilot_class(pilot).cooperative), None))
    host_of = {d: sender for sender, (_, drones) in flyers.items() for d in drones}
    numbers = {sender: [drone_number(d) for d in drones] for sender, (_, drones) in flyers.items()}
    # host -> its swarm pilot, for the autopilots that have one; the other drones each fly their own
    swarms = {h: make_swarm(a, world_size=world.size, drones=numbers[h], least=swarm_min)
              for h, (a, _) in flyers.items()} if swarm else {}
    pilots = {d: make_autopilot(a, world_size=world.size, **(pilot_options or {}).get(a, {}))
              for d, a in autopilots.items() if swarms.get(host_of[d]) is None}
    env = Environment(world, {d.drone: d.start for d in config.drones})  # (as its WELCOME says: each at its start)
    current: dict[str, Cell] = {}
    last: Status | None = None  # the last STATUS (a lifelong ground station's draws read it)
    while queue:
        effect = queue.popleft()
        match effect:
            case Record(data):
                records.append(data)
            case Publish(Turn(phase=Phase.GCS, turn=t)):
                given = inputs.plan.at(t)
                current.update(given)
                alive = set(engine.alive())
                current = {d: c for d, c in current.items() if d in alive}
                if inputs.tasks is not None and last is not None:
                    current.update(inputs.tasks.assign(t, last, given))
                push(engine.receive(gcs_done(t, current, inputs.intent(t), engine.targets())))
            case Publish(Turn(phase=Phase.DRONES, turn=t) as turn):
                for d in sorted(inputs.vanished.get(t, ())):
                    push(engine.vanished(d))
                skip = inputs.hovered.get(t, set()) | inputs.vanished.get(t, set())
                flown: dict[str, list] = {}  # sender -> the orders of its drones flown one pilot each
                for order in turn.orders.orders(pilots):
                    if order[0] not in skip:
                        flown.setdefault(host_of[order[0]], []).append(order)
                for sender in flyers:  # each as its process would: a swarm host's MOVES, a drone's NPS
                    if (host := swarms.get(sender)) is not None:
                        mine = turn.orders.rows[np.isin(turn.orders.rows["drone"], numbers[sender])]
                        moves: StepTable | dict[str, Decision] = drive(fly_swarm(host, mine), env.kinds)
                    elif sender in flown:
                        moves = drive(fly_pilots(pilots, flown[sender], host=sender if swarm else None), env.oracle)
                    else:
                        continue
                    if not isinstance(moves, StepTable):
                        for d, dec in sorted(moves.items()):
                            push(engine.receive(Nps(turn=t, sender=d, pos=dec.pos, note=dec.note, ranked=dec.ranked)))
                    elif moves:
                        push(engine.receive(Moves(turn=t, sender=sender, moves=moves)))
                if skip:
                    push(engine.expire(Stage.DRONES, t))  # ignored if the phase already ended
            case Publish(Turn(phase=Phase.ENV, turn=t) as turn):
                if verify_env:
                    push(engine.receive(Upd(turn=t, sender="ENV", cells=env.apply(turn.moves))))
                else:
                    env.move(turn.moves)
            case Publish(Status() as status):
                env.sync(status)
                last = status
                if keep_statuses:
                    statuses.append(status)
            case Refusal(what, err):
                log.warning("rejected %s: %s", what, err)
    assert engine.end is not None
    return Result(records=records, over=engine.end, statuses=statuses, final=last, tasks=engine.tasks)

