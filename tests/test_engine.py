"""The turn engine, driven with messages directly (no network, no clock)."""

from __future__ import annotations

import dataclasses
import json
import logging
import re

import numpy as np
import pytest

from coordinator import journal
from coordinator.config import DroneSpec, GameConfig, replace_config
from coordinator.effects import Publish, Record, Refusal, ReplyToConnect
from coordinator.engine import Engine
from coordinator.resume import restore
from coordinator.stages import TAKES, TRANSITIONS, Stage, When
from entities.gcs import describe
from entities.web.model import view_of
from schema import (
    Aim,
    AimTable,
    Cause,
    CellInfo,
    CellKind,
    Connect,
    Done,
    DroneState,
    EndReason,
    Intent,
    Message,
    Move,
    Moves,
    Note,
    Nps,
    Order,
    OutOfRange,
    Over,
    Phase,
    Refused,
    RemoteInputError,
    Role,
    StaleTurn,
    Status,
    Step,
    Target,
    Turn,
    UnknownEntity,
    Upd,
    UsageError,
    Welcome,
    WorldSpec,
    WrongSender,
    decode,
    encode,
)
from schema.keys import size_limit
from schema.messages import drone_id
from schema.tables import rank_steps
from schema.tuning import AHEAD_MAX, DECIDING_SILENCE_S, FEW_ROWS

SIZE = (5, 5, 5)
LOG = logging.getLogger("dronesim.tests.engine")


def world(buildings=()) -> WorldSpec:
    """A SIZE world with exactly these building cells."""
    grid = np.zeros(SIZE, dtype=bool)
    for c in buildings:
        grid[c] = True
    return WorldSpec(size=SIZE, cells=np.packbits(grid.ravel()).tobytes())


def config(*drones: tuple[str, tuple[int, int, int]], buildings=(), **kw) -> GameConfig:
    drones = drones or (("D01", (0, 0, 0)),)
    return GameConfig(world=world(buildings), drones=tuple(DroneSpec(drone=d, start=s) for d, s in drones), **kw)


class Token:
    """A stand-in for a Zenoh query: any object will do."""

    def __init__(self, name: str) -> None:
        self.name = name


def pubs(effects: list, kind: type[Message] | None = None) -> list[Message]:
    out = [e.msg for e in effects if isinstance(e, Publish)]
    return [m for m in out if kind is None or isinstance(m, kind)]


def records(effects: list) -> list[dict]:
    return [e.data for e in effects if isinstance(e, Record)]


def refused(effects: list, error: type[RemoteInputError] = RemoteInputError, match: str = "") -> RemoteInputError:
    """The one refusal among `effects` (the engine refused the input): an `error`, its text matching `match`."""
    errors = [e.err for e in effects if isinstance(e, Refusal)]
    assert len(errors) == 1, effects
    assert isinstance(errors[0], error), errors[0]
    assert re.search(match, str(errors[0])), f"{errors[0]} does not match {match!r}"
    return errors[0]


def reply(effects: list) -> Message:
    replies = [e for e in effects if isinstance(e, ReplyToConnect)]
    assert len(replies) == 1
    return replies[0].msg


def connect(sender: str, role: Role, drones: tuple[str, ...] = (), autopilot: str = "") -> Connect:
    return Connect(turn=0, sender=sender, role=role, drones=drones, autopilot=autopilot)


class Game:
    """An engine plus the effects it produced, with shorthands for each entity's messages."""

    def __init__(self, cfg: GameConfig | None = None, *, hosts: dict[str, tuple[str, ...]] | None = None,
                 gcs: bool = True) -> None:
        self.engine = Engine(cfg or config(), LOG)
        self.effects: list = []
        self.last: list = []
        if hosts is None:
            hosts = {d: (d,) for d in self.engine.drones}
        self.feed(self.engine.connect(connect("ENV", Role.ENV), Token("ENV")))
        if gcs:
            self.feed(self.engine.connect(connect("GCS", Role.GCS), Token("GCS")))
        for host, ds in hosts.items():
            self.feed(self.engine.connect(connect(host, Role.DRONE, ds, "seed"), Token(host)))

    def feed(self, effects: list) -> list:
        self.last = effects
        self.effects += effects
        return effects

    @property
    def turn(self) -> int:
        return self.engine.turn

    @property
    def stage(self) -> Stage:
        return self.engine.stage

    def tgt(self, drone: str, pos, *, sender: str = "GCS", turn: int | None = None) -> list:
        t = self.turn if turn is None else turn
        return self.feed(self.engine.receive(Target(turn=t, sender=sender, drone=drone, pos=pos)))

    def done(self, intent: Intent = Intent.CONTINUE, *, sender: str = "GCS", phase: Phase = Phase.GCS) -> list:
        return self.feed(self.engine.receive(Done(turn=self.turn, sender=sender, phase=phase, intent=intent)))

    def gcs(self, targets: dict | None = None, intent: Intent = Intent.CONTINUE) -> list:
        assert self.stage is Stage.GCS
        for d, p in (targets or {}).items():
            self.tgt(d, p)
        return self.done(intent)

    def nps(self, drone: str, pos, note: Note = Note.NONE, *, turn: int | None = None) -> list:
        t = self.turn if turn is None else turn
        return self.feed(self.engine.receive(Nps(turn=t, sender=drone, pos=pos, note=note)))

    def env_turn(self) -> Turn:
        turns = [t for t in pubs(self.effects, Turn) if t.phase is Phase.ENV]
        assert turns, self.effects
        return turns[-1]

    def upd(self, *, skip: frozenset = frozenset(), wrong: frozenset = frozenset(), sender: str = "ENV") -> list:
        """The environment's report of the last TURN(ENV) (every source and in-world destination, kinds
        from the world, except `wrong` ones), checked by the engine; returns the effects that ended the
        turn (the report itself changes nothing)."""
        env = self.env_turn()
        cells = set()
        for m in env.moves:
            cells.add(m.src)
            if all(0 <= c < s for c, s in zip(m.dst, SIZE)) and m.dst not in skip:
                cells.add(m.dst)
        kinds = {c: self.engine.reports.kind(c) for c in cells}
        for c in wrong:
            kinds[c] = CellKind.EMPTY if kinds.get(c) is CellKind.BUILDING else CellKind.BUILDING
        upd = Upd(turn=env.turn, sender=sender, cells=tuple(CellInfo(pos=c, kind=kinds[c]) for c in sorted(kinds)))
        report = self.engine.receive(upd)
        assert all(isinstance(e, Refusal) for e in report), "the report itself changes nothing"
        return report or self.last

    def status(self, drone: str):
        return next(s for s in self.engine.status().drones if s.drone == drone)

    def snapshot(self) -> tuple:
        e = self.engine
        return (e.stage, e.turn, e.final, e.aims(), e.moves_taken(),
                {d: (r.pos, r.state, r.target, r.note, r.misses) for d, r in e.drones.items()})


def play_turn(g: Game, moves: dict, targets: dict | None = None, intent: Intent = Intent.CONTINUE) -> list:
    g.gcs(targets, intent)
    start = len(g.effects)
    for d, p in moves.items():
        g.nps(d, p)
    return g.effects[start:]


# --------------------------------------------------------------------------- config


def test_config_validation() -> None:
    with pytest.raises(UsageError, match="at least one drone"):
        GameConfig(world=WorldSpec(size=SIZE), drones=())
    with pytest.raises(UsageError, match="duplicate"):
        config(("D01", (0, 0, 0)), ("D01", (1, 0, 0)))
    with pytest.raises(UsageError, match="same cell"):
        config(("D01", (0, 0, 0)), ("D02", (0, 0, 0)))
    with pytest.raises(UsageError, match="outside"):
        config(("D01", (5, 0, 0)))
    with pytest.raises(UsageError, match="max_turns"):
        config(max_turns=0)
    with pytest.raises(UsageError, match="lost_after"):
        config(lost_after=0)
    assert replace_config(config(), max_turns=7).max_turns == 7


# --------------------------------------------------------------------------- admission


def test_a_hosts_drones_are_named_as_runs_of_numbers() -> None:
    from coordinator.admission import id_ranges

    assert id_ranges(["D07", "D01", "D02", "D03", "D100", "D09", "D10"]) == "D01-D03, D07, D09-D10, D100"
    assert id_ranges([f"D{n:02d}" for n in range(1, 2001)]) == "D01-D2000"


def test_welcome_texts_and_starts() -> None:
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0))), LOG)
    w = reply(e.connect(connect("ENV", Role.ENV), Token("a")))
    assert isinstance(w, Welcome)
    assert w.text == "You are connected as ENV"
    assert w.entity == "ENV" and w.sender == "SRV" and w.turn == 0
    assert w.world == world()
    assert [s.drone for s in w.starts] == ["D01", "D02"]
    w = reply(e.connect(connect("GCS", Role.GCS), Token("b")))
    assert w.text == "You are connected as GCS"
    assert [(s.drone, s.pos) for s in w.starts] == [("D01", (0, 0, 0)), ("D02", (1, 0, 0))]
    effects = e.connect(connect("D02", Role.DRONE, ("D02",)), Token("c"))
    w = reply(effects)
    assert w.text == "You are connected as D02"
    assert [(s.drone, s.pos) for s in w.starts] == [("D02", (1, 0, 0))]
    assert effects == [ReplyToConnect(effects[0].token, w)], "no game before everyone is there"
    assert e.stage is Stage.ADMITTING


def test_reply_goes_to_the_asking_token() -> None:
    e = Engine(config(), LOG)
    tok = Token("query")
    effects = e.connect(connect("ENV", Role.ENV), tok)
    assert effects[0].token is tok


def test_game_starts_when_everyone_is_there() -> None:
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0))), LOG)
    assert e.connect(connect("D01", Role.DRONE, ("D01",), "v1"), 1)[1:] == []
    assert e.connect(connect("GCS", Role.GCS), 2)[1:] == []
    assert e.connect(connect("D02", Role.DRONE, ("D02",), "seed"), 3)[1:] == []
    effects = e.connect(connect("ENV", Role.ENV), 4)
    assert isinstance(effects[0], ReplyToConnect) and isinstance(effects[0].msg, Welcome)
    header, status, turn = effects[1:]
    assert isinstance(header, Record)
    data = dict(header.data)
    drones = data.pop("drones")
    expected = {
        "record": "header", "format": "dronesim-journal", "version": 1,
        "world": {"size": [5, 5, 5], "seed": 0, "cells": world().cells.hex()},
        "max_turns": 1000,
    }
    assert {k: data.get(k) for k in expected} == expected  # (the header may carry more settings)
    assert [{k: d[k] for k in ("drone", "start", "autopilot")} for d in drones] == [
        {"drone": "D01", "start": [0, 0, 0], "autopilot": "v1"},
        {"drone": "D02", "start": [1, 0, 0], "autopilot": "seed"}]
    assert isinstance(status, Publish) and isinstance(status.msg, Status)
    assert status.msg.turn == 0
    assert [(s.drone, s.pos, s.state, s.target) for s in status.msg.drones] == [
        ("D01", (0, 0, 0), DroneState.ALIVE, None), ("D02", (1, 0, 0), DroneState.ALIVE, None)]
    assert turn == Publish(Turn(turn=1, sender="SRV", phase=Phase.GCS))
    assert e.stage is Stage.GCS and e.turn == 1


@pytest.mark.parametrize("second", [
    connect("ENV", Role.ENV),
    connect("GCS", Role.GCS),
])
def test_duplicate_role_refused(second: Connect) -> None:
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0))), LOG)
    e.connect(connect("ENV", Role.ENV), 1)
    e.connect(connect("GCS", Role.GCS), 2)
    before = dict(e.entities)
    r = reply(e.connect(second, 3))
    assert isinstance(r, Refused)
    assert r.text == f"{second.sender} is already connected"
    assert r.sender == "SRV"
    assert e.entities == before


@pytest.mark.parametrize("msg,text", [
    (connect("GCS", Role.ENV), "the ENV must connect as ENV, not GCS"),
    (connect("D01", Role.GCS), "the GCS must connect as GCS, not D01"),
    (connect("D09", Role.DRONE, ("D09",)), "unknown drone D09: this game flies D01, D02"),
    (connect("H01", Role.DRONE, ("D01", "D09")), "unknown drone D09"),
    (connect("D02", Role.DRONE, ("D01",)), "D02 cannot connect for D01: a drone flies itself"),
    (connect("D01", Role.DRONE, ("D01", "D02")),
     "D01 cannot connect for D01, D02: a drone flies itself, a swarm host connects as Hnn"),
])
def test_bad_connects_refused(msg: Connect, text: str) -> None:
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0))), LOG)
    r = reply(e.connect(msg, 1))
    assert isinstance(r, Refused)
    assert text in r.text
    assert e.entities == {}
    assert all(d.host is None for d in e.drones.values())


@pytest.mark.parametrize("sender", ["ENV", "GCS", "SRV", "OBS"])
def test_fixed_id_cannot_host_drones(sender: str) -> None:
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0))), LOG)
    r = reply(e.connect(connect(sender, Role.DRONE, ("D01", "D02")), 1))
    assert isinstance(r, Refused)


def test_single_drone_for_fixed_id_refused() -> None:
    e = Engine(config(), LOG)
    assert isinstance(reply(e.connect(connect("ENV", Role.DRONE, ("D01",)), 1)), Refused)


def test_swarm_host_flies_several_drones() -> None:
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0)), ("D03", (2, 0, 0))), LOG)
    w = reply(e.connect(connect("H01", Role.DRONE, ("D01", "D02"), "dstar"), 1))
    assert isinstance(w, Welcome)
    assert w.text == "You are connected as H01 flying D01-D02"
    assert [s.drone for s in w.starts] == ["D01", "D02"]
    assert e.drones["D01"].host == e.drones["D02"].host == "H01"
    assert e.drones["D01"].autopilot == "dstar"
    # the drones it flies are taken
    r = reply(e.connect(connect("D01", Role.DRONE, ("D01",)), 2))
    assert isinstance(r, Refused) and r.text == "drone D01 is already taken by H01"
    r = reply(e.connect(connect("H02", Role.DRONE, ("D02", "D03")), 3))
    assert isinstance(r, Refused) and "D02 is already taken by H01" in r.text
    assert e.drones["D03"].host is None, "a refused CONNECT changes nothing"
    w = reply(e.connect(connect("H02", Role.DRONE, ("D03",)), 4))
    assert w.text == "You are connected as H02 flying D03"


def test_second_gcs_refused_while_first_connected_then_rejoins() -> None:
    g = Game()
    assert g.stage is Stage.GCS
    r = reply(g.engine.connect(connect("GCS", Role.GCS), 9))
    assert isinstance(r, Refused) and "already connected" in r.text
    g.feed(g.engine.vanished("GCS"))
    assert g.stage is Stage.DRONES  # its phase ended with it
    effects = g.engine.connect(connect("GCS", Role.GCS), 10)
    w = reply(effects)
    assert isinstance(w, Welcome) and w.text == "You are connected as GCS"
    assert pubs(effects) == [g.engine.status()], "a late GCS sees the state at once"


def test_no_joining_a_running_or_finished_game() -> None:
    g = Game()
    r = reply(g.engine.connect(connect("D02", Role.DRONE, ("D02",)), 1))
    assert isinstance(r, Refused)
    g.feed(g.engine.vanished("ENV"))
    assert g.stage is Stage.GCS, "the game waits for the environment to come back"
    assert g.engine.deadline() == g.engine.config.env_grace
    g.feed(g.engine.expire(*g.engine.deadline_key()))
    assert g.stage is Stage.OVER and g.engine.end.reason is EndReason.ABORTED
    effects = g.engine.connect(connect("ENV", Role.ENV), 2)
    assert isinstance(reply(effects), Refused) and reply(effects).text == "the game is over"
    assert pubs(effects) == [g.engine.end], "who comes back after the end is told the end again"
    g3 = Game()
    g3.engine.entities.pop("D01")
    r = reply(g3.engine.connect(connect("D01", Role.DRONE, ("D01",)), 4))
    assert isinstance(r, Refused) and r.text == "drones cannot join a running game"


def test_a_restarted_environment_rejoins_and_takes_up_the_phase() -> None:
    g = Game()
    g.gcs({"D01": (2, 0, 0)})
    assert g.stage is Stage.DRONES
    g.feed(g.engine.vanished("ENV"))
    effects = g.engine.connect(connect("ENV", Role.ENV), 3)
    assert isinstance(reply(effects), Welcome)
    assert pubs(effects) == [g.engine.status()], "it resyncs from the last STATUS; the DRONES turn is already out"
    assert g.engine.status().turn == g.turn - 1


def test_after_a_lost_link_the_phase_goes_out_again_once_every_entity_has_connected_again() -> None:
    """Every presence token back ends the hold and the phase goes out again; but a token back does not say that the
    router has the entity's subscriptions yet (seen: a drone never heard that TURN and hovered). The last of them to
    connect again has it sent once more, and a drone that answers it with its move again is not refused."""
    entities = {"ENV": (Role.ENV, ()), "GCS": (Role.GCS, ()), "D01": (Role.DRONE, ("D01",)),
                "D02": (Role.DRONE, ("D02",))}

    def hello(who: str) -> list:  # each process's CONNECT, the same session each time
        role, drones = entities[who]
        msg = Connect(turn=0, sender=who, role=role, drones=drones, autopilot="seed" if drones else "",
                      session=f"z{who.lower()}")
        return g.engine.connect(msg, Token(who))

    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))), hosts={}, gcs=False)
    g.engine.entities.pop("ENV")
    for who in entities:
        g.feed(hello(who))
    g.gcs()
    g.nps("D02", (4, 4, 3))
    phase = pubs(g.effects, Turn)[-1]
    assert phase.phase is Phase.DRONES and g.stage is Stage.DRONES
    assert g.engine.link_lost() == []
    for who in entities:
        assert g.engine.vanished(who, f"z{who.lower()}") == [], "away, not gone"
    back = [e for who in entities for e in g.engine.present(who, f"z{who.lower()}")]
    assert pubs(back) == [g.engine.status(), phase]
    for who in ("GCS", "D01", "ENV"):
        effects = hello(who)
        assert isinstance(reply(effects), Welcome) and pubs(effects) == [g.engine.status()]
    last = hello("D02")
    assert pubs(last) == [g.engine.status(), phase], "the last one to connect again: the phase once more"
    assert g.nps("D02", (4, 4, 3)) == [], "the same move again: nothing, not refused"
    refused(g.nps("D02", (3, 4, 4)), StaleTurn, "second NPS")
    assert g.engine.moves_taken() == {"D02": (4, 4, 3)}
    assert pubs(hello("D01")) == [g.engine.status()], "only once"


def test_drone_host_vanishing_during_admission_frees_its_drones() -> None:
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0))), LOG)
    e.connect(connect("H01", Role.DRONE, ("D01", "D02")), 1)
    assert e.vanished("H01") == []
    assert all(d.host is None for d in e.drones.values())
    assert isinstance(reply(e.connect(connect("D01", Role.DRONE, ("D01",)), 2)), Welcome)


def test_admission_deadline_aborts() -> None:
    e = Engine(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0)), admit_deadline=3.0), LOG)
    e.connect(connect("ENV", Role.ENV), 1)
    e.connect(connect("D01", Role.DRONE, ("D01",)), 2)
    assert e.deadline() == 3.0
    effects = e.expire(Stage.ADMITTING, 0)
    over = pubs(effects, Over)[0]
    assert over.reason is EndReason.ABORTED
    assert "D02" in over.text and "GCS" in over.text and "ENV" not in over.text
    assert e.stage is Stage.OVER and e.end == over
    assert records(effects) == [], "no game began: no header, and no over record alone (a journal without header)"


# --------------------------------------------------------------------------- the turn cycle


def test_full_turn_cycle() -> None:
    g = Game()
    assert g.tgt("D01", (2, 0, 0)) == []
    effects = g.done()
    assert effects == [Publish(Turn(turn=1, sender="SRV", phase=Phase.DRONES,
                                    orders=(Order(drone="D01", pos=(0, 0, 0), target=(2, 0, 0)),)))]
    assert g.stage is Stage.DRONES
    effects = g.nps("D01", (1, 0, 0))
    env, rec, status, turn = effects
    assert env == Publish(Turn(turn=1, sender="SRV", phase=Phase.ENV,
                               moves=(Move(drone="D01", src=(0, 0, 0), dst=(1, 0, 0)),)))
    assert g.upd() is effects, "the environment's report is checked; the turn did not wait for it"
    assert isinstance(rec, Record)
    assert rec.data["record"] == "turn" and rec.data["turn"] == 1
    assert rec.data["targets"] == {"D01": [2, 0, 0]}
    assert rec.data["moves"] == {"D01": [1, 0, 0]}
    assert len(rec.data["state"]) == 16
    assert status.msg.turn == 1
    s = status.msg.drones[0]
    assert (s.pos, s.state, s.target, s.note) == ((1, 0, 0), DroneState.ALIVE, (2, 0, 0), Note.NONE)
    assert turn == Publish(Turn(turn=2, sender="SRV", phase=Phase.GCS))
    assert g.stage is Stage.GCS and g.turn == 2
    # turn 2: the GCS sends nothing new; the order carries the target in force
    effects = g.done()
    assert pubs(effects, Turn)[0].orders == (Order(drone="D01", pos=(1, 0, 0), target=(2, 0, 0)),)


def test_without_a_journal_the_records_skip_what_each_drone_did() -> None:
    """`journaled` off (no journal to write): the same game and STATUS, and turn records without the
    per-drone targets, moves, notes, hovers, deaths or state hash (which would only be dropped)."""
    records = {}
    for journaled in (True, False):
        g = Game()
        g.engine.journaled = journaled
        g.tgt("D01", (2, 0, 0))
        g.done()
        env, rec, status, _ = g.nps("D01", (1, 0, 0))
        records[journaled] = (rec.data, status.msg)
    full, bare = records[True][0], records[False][0]
    assert records[True][1] == records[False][1]
    assert {"targets", "moves", "state"} <= set(full)
    assert not {"targets", "moves", "notes", "hovered", "deaths", "state"} & set(bare)
    assert {k: v for k, v in full.items() if k not in ("targets", "moves", "state")} == bare


def test_drones_phase_waits_for_every_alive_drone() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
    g.gcs({"D01": (4, 0, 0)})
    orders = pubs(g.last, Turn)[0].orders
    assert orders == (Order(drone="D01", pos=(0, 0, 0), target=(4, 0, 0)),
                      Order(drone="D02", pos=(4, 4, 4), target=None))
    assert g.nps("D02", (4, 4, 3)) == []
    assert g.stage is Stage.DRONES
    g.nps("D01", (1, 0, 0))
    assert g.env_turn().moves == (Move(drone="D01", src=(0, 0, 0), dst=(1, 0, 0)),
                                  Move(drone="D02", src=(4, 4, 4), dst=(4, 4, 3)))


def test_targets_only_change_on_done_and_last_one_wins() -> None:
    g = Game()
    g.tgt("D01", (1, 1, 1))
    g.tgt("D01", (2, 2, 2))
    assert g.engine.drones["D01"].target is None
    g.done()
    assert g.engine.drones["D01"].target == (2, 2, 2)


@pytest.mark.parametrize("msg,error", [
    (Target(turn=1, sender="GCS", drone="D01", pos=(5, 0, 0)), OutOfRange),
    (Target(turn=1, sender="GCS", drone="D01", pos=(0, 0, 99)), OutOfRange),
    (Target(turn=1, sender="GCS", drone="D09", pos=(1, 0, 0)), UnknownEntity),
    (Target(turn=1, sender="D01", drone="D01", pos=(1, 0, 0)), WrongSender),
    (Target(turn=1, sender="ENV", drone="D01", pos=(1, 0, 0)), WrongSender),
    (Target(turn=2, sender="GCS", drone="D01", pos=(1, 0, 0)), StaleTurn),
    (Target(turn=0, sender="GCS", drone="D01", pos=(1, 0, 0)), StaleTurn),
])
def test_bad_targets_change_nothing(msg: Target, error: type) -> None:
    g = Game()
    g.gcs({"D01": (3, 3, 3)})
    g.nps("D01", (0, 0, 0))  # no move: the turn ends at once
    assert g.stage is Stage.GCS and g.turn == 2
    msg = Target(turn=msg.turn + 1, sender=msg.sender, drone=msg.drone, pos=msg.pos)
    before = g.snapshot()
    assert str(refused(g.engine.receive(msg), error))
    assert g.snapshot() == before
    g.done()
    assert pubs(g.last, Turn)[0].orders[0].target == (3, 3, 3)


def gcs_done(g: Game, count: int, intent: Intent = Intent.CONTINUE) -> list:
    return g.feed(g.engine.receive(Done(turn=g.turn, sender="GCS", phase=Phase.GCS, intent=intent, count=count)))


def test_done_waits_for_the_targets_it_counts() -> None:
    """TGT and DONE travel on different keys: a DONE may overtake its targets."""
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), gcs_deadline=None, phase_deadline=2.0))
    assert g.engine.deadline() is None
    assert gcs_done(g, 2) == []
    assert g.stage is Stage.GCS
    assert g.engine.deadline() == 2.0, "the missing targets get a drone's time, not the human's"
    assert g.tgt("D02", (0, 4, 4)) == []
    effects = g.tgt("D01", (4, 0, 0))
    assert g.stage is Stage.DRONES
    assert pubs(effects, Turn)[0].orders == (Order(drone="D01", pos=(0, 0, 0), target=(4, 0, 0)),
                                             Order(drone="D02", pos=(4, 4, 4), target=(0, 4, 4)))


def test_done_after_its_targets_ends_the_phase() -> None:
    g = Game()
    g.tgt("D01", (1, 1, 1))
    gcs_done(g, 1)
    assert g.stage is Stage.DRONES
    assert g.engine.drones["D01"].target == (1, 1, 1)


def test_second_done_refused() -> None:
    g = Game()
    gcs_done(g, 1)
    before = g.snapshot()
    refused(gcs_done(g, 0), StaleTurn, "second DONE")
    assert g.snapshot() == before


def test_expire_with_done_in_applies_the_targets_that_arrived() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
    gcs_done(g, 2, Intent.FINAL)
    g.tgt("D02", (0, 4, 4))
    g.feed(g.engine.expire(Stage.GCS, 1))
    assert g.stage is Stage.DRONES
    assert g.engine.drones["D02"].target == (0, 4, 4)
    assert g.engine.drones["D01"].target is None
    assert g.engine.final, "the DONE's intent holds"


def test_refused_last_counted_target_does_not_stall_the_phase() -> None:
    g = Game()
    gcs_done(g, 1)
    refused(g.tgt("D01", (9, 9, 9)), OutOfRange)
    assert g.stage is Stage.DRONES


def test_the_tables_drive_the_engine() -> None:
    """Every stage has its changes in TRANSITIONS, every stage but OVER (final) is left and reached from ADMITTING;
    every method TAKES names is the engine's; a message of a (stage, turn) that TAKES does not list is refused as
    stale, changing nothing, and a stage change it does not list is the engine's bug."""
    assert set(TRANSITIONS) == set(Stage) and TRANSITIONS[Stage.OVER] == frozenset()
    reached, frontier = {Stage.ADMITTING}, [Stage.ADMITTING]
    while frontier:
        new = TRANSITIONS[frontier.pop()] - reached
        reached |= new
        frontier += new
    assert reached == set(Stage)
    assert all(callable(getattr(Engine, name, None)) for name in TAKES.values())
    g = Game()  # in the GCS phase: a drone's move is not taken there
    assert (Stage.GCS, Nps, When.NOW) not in TAKES
    before = g.snapshot()
    refused(g.nps("D01", (0, 0, 1)), StaleTurn)
    assert g.snapshot() == before
    with pytest.raises(AssertionError):
        g.engine._enter(Stage.RESUMING)


def test_target_outside_the_gcs_phase_is_stale() -> None:
    g = Game()
    g.done()
    before = g.snapshot()
    refused(g.tgt("D01", (1, 1, 1)), StaleTurn)
    assert g.snapshot() == before


def test_target_for_a_dead_drone_refused() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), buildings={(1, 0, 0)}))
    play_turn(g, {"D01": (1, 0, 0), "D02": (4, 4, 4)})
    assert g.status("D01").state is DroneState.DEAD
    refused(g.tgt("D01", (2, 2, 2)), UnknownEntity, "DEAD")


@pytest.mark.parametrize("pos", [(2, 0, 0), (1, 1, 0), (0, 0, 2), (4, 4, 4), (-1, -1, 0)])
def test_nps_jump_refused_and_changes_nothing(pos) -> None:
    g = Game()
    g.gcs({"D01": (4, 0, 0)})
    before = g.snapshot()
    refused(g.nps("D01", pos), OutOfRange, "one cell per turn")
    assert g.snapshot() == before
    g.nps("D01", (1, 0, 0))  # the drone may still send a valid move
    assert g.stage is Stage.GCS and g.turn == 2


def test_duplicate_nps_refused() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
    g.gcs()
    g.nps("D01", (1, 0, 0))
    before = g.snapshot()
    refused(g.nps("D01", (0, 1, 0)), StaleTurn, "second NPS")
    assert g.snapshot() == before
    assert g.engine.moves_taken() == {"D01": (1, 0, 0)}


def test_misplaced_messages_refused() -> None:
    g = Game()
    snap = g.snapshot()
    refused(g.nps("D01", (1, 0, 0)), StaleTurn)  # in the GCS phase
    refused(g.done(sender="D01"), WrongSender)
    refused(g.done(phase=Phase.DRONES), WrongSender)
    refused(g.engine.receive(Done(turn=2 + AHEAD_MAX, sender="GCS", phase=Phase.GCS)), StaleTurn)
    assert g.snapshot() == snap
    g.done()
    snap = g.snapshot()
    refused(g.done(Intent.FINAL), StaleTurn)  # in the DRONES phase (the same DONE again: nothing, not refused)
    refused(g.nps("D01", (1, 0, 0), turn=2), StaleTurn)
    refused(g.engine.receive(Nps(turn=1, sender="D09", pos=(0, 0, 0))), UnknownEntity)
    refused(g.engine.receive(Upd(turn=1, sender="ENV", cells=())), StaleTurn)
    assert g.snapshot() == snap
    g.nps("D01", (1, 0, 0))
    snap = g.snapshot()
    refused(g.upd(sender="D01"), WrongSender)
    refused(g.engine.receive(Upd(turn=2, sender="ENV", cells=())), StaleTurn)
    assert g.snapshot() == snap
    g.upd()
    refused(g.upd(), StaleTurn, "no ENV phase")  # a second report of the same ENV phase


def test_no_move_turn_skips_the_env_phase() -> None:
    g = Game()
    g.gcs({"D01": (0, 0, 0)})
    effects = g.nps("D01", (0, 0, 0), Note.REACHED)
    assert [type(m) for m in pubs(effects)] == [Status, Turn]
    assert all(t.phase is not Phase.ENV for t in pubs(effects, Turn))
    assert g.stage is Stage.GCS and g.turn == 2
    rec = records(effects)[0]
    assert "moves" not in rec and "hovered" not in rec
    assert g.status("D01").note is Note.REACHED


def test_the_env_phase_is_made_only_while_someone_follows_it_or_its_report_is_checked() -> None:
    """Nobody following the ENV phase (the environment does while someone listens to its UPD) and its
    report not checked, the turn's moves take effect all the same, but no TURN(ENV) is made."""
    for followed, verify, announced in ((True, False, True), (False, True, False), (False, False, False)):
        g = Game()
        g.engine.env_followed, g.engine.verify_env = followed, verify
        g.gcs()
        effects = g.nps("D01", (1, 0, 0))
        assert any(t.phase is Phase.ENV for t in pubs(effects, Turn)) is announced, (followed, verify)
        assert g.status("D01").pos == (1, 0, 0) and g.stage is Stage.GCS and g.turn == 2
        assert (1 in g.engine.reports.due) is verify  # a report checked needs the moves kept


def test_upd_disagreeing_with_the_world_refused() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
    g.gcs()
    g.nps("D01", (1, 0, 0))
    g.nps("D02", (4, 4, 3))
    assert g.stage is Stage.GCS and g.turn == 2, "the turn did not wait for the environment"
    before = g.snapshot()
    refused(g.upd(skip=frozenset({(4, 4, 3)})), OutOfRange, r"\(4, 4, 3\)")
    refused(g.upd(wrong=frozenset({(1, 0, 0)})), OutOfRange, r"\(1, 0, 0\)")
    assert g.snapshot() == before
    g.upd()


def test_death_by_building_ends_a_single_drone_game() -> None:
    g = Game(config(buildings={(1, 0, 0)}))
    effects = play_turn(g, {"D01": (1, 0, 0)}, {"D01": (2, 0, 0)})
    s = g.status("D01")
    assert (s.state, s.cause, s.pos) == (DroneState.DEAD, Cause.BUILDING, (1, 0, 0))
    over = pubs(effects, Over)
    assert len(over) == 1 and over[0].reason is EndReason.NO_DRONE_ALIVE
    assert "D01" in over[0].text and "building" in over[0].text
    assert g.stage is Stage.OVER and g.engine.end == over[0]
    recs = records(effects)
    assert recs[0]["deaths"] == {"D01": "BUILDING"}
    assert recs[-1] == {"record": "over", "turn": 1, "reason": "NO_DRONE_ALIVE", "text": over[0].text}
    assert all(t.turn == 1 for t in pubs(effects, Turn)), "no turn 2"
    assert g.engine.deadline() is None


def test_death_outside_the_world() -> None:
    g = Game()
    g.gcs()
    g.nps("D01", (-1, 0, 0))
    assert g.env_turn().moves == (Move(drone="D01", src=(0, 0, 0), dst=(-1, 0, 0)),)
    effects = g.upd()
    s = g.status("D01")
    assert (s.state, s.cause, s.pos) == (DroneState.DEAD, Cause.OUTSIDE, (-1, 0, 0))
    assert pubs(effects, Over)[0].reason is EndReason.NO_DRONE_ALIVE


def test_collision_kills_both_and_others_play_on() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (2, 0, 0)), ("D03", (4, 4, 4))))
    effects = play_turn(g, {"D01": (1, 0, 0), "D02": (1, 0, 0), "D03": (4, 4, 4)})
    assert g.status("D01").cause is g.status("D02").cause is Cause.VERTEX
    assert g.status("D03").state is DroneState.ALIVE
    assert records(effects)[0]["deaths"] == {"D01": "VERTEX", "D02": "VERTEX"}
    assert g.stage is Stage.GCS and g.turn == 2
    g.done()
    assert [o.drone for o in pubs(g.last, Turn)[0].orders] == ["D03"], "the dead get no orders"


def test_swap_kills_both() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0))))
    play_turn(g, {"D01": (1, 0, 0), "D02": (0, 0, 0)})
    assert g.status("D01").cause is g.status("D02").cause is Cause.SWAP
    assert g.stage is Stage.OVER and g.engine.end.reason is EndReason.NO_DRONE_ALIVE


def test_final_and_reached_ends_all_reached() -> None:
    g = Game()
    play_turn(g, {"D01": (1, 0, 0)}, {"D01": (2, 0, 0)}, Intent.FINAL)
    assert g.stage is Stage.GCS, "not there yet"
    effects = play_turn(g, {"D01": (2, 0, 0)}, intent=Intent.FINAL)
    assert g.status("D01").note is Note.REACHED
    over = pubs(effects, Over)[0]
    assert over.reason is EndReason.ALL_REACHED and over.turn == 2
    assert g.stage is Stage.OVER


def test_reached_without_final_goes_on() -> None:
    g = Game()
    play_turn(g, {"D01": (1, 0, 0)}, {"D01": (1, 0, 0)})
    assert g.status("D01").note is Note.REACHED
    assert g.stage is Stage.GCS and g.turn == 2


def test_final_with_unreachable_settles() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
    g.gcs({"D01": (1, 0, 0), "D02": (0, 4, 4)}, Intent.FINAL)
    g.nps("D01", (1, 0, 0))
    g.nps("D02", (4, 4, 4), Note.UNREACHABLE)
    g.upd()
    assert g.engine.end is not None
    assert g.engine.end.reason is EndReason.SETTLED
    assert "D02" in g.engine.end.text


def test_a_drone_pushed_off_its_target_on_the_last_turn_is_not_said_to_have_reached_it() -> None:
    """Issue 33 (3): the end of the game reads where the drones are after the turn's moves. D02, parked on its
    target, says REACHED; D01, stuck (UNREACHABLE, so ahead of the drones at home: arbiter.STUCK), takes D02's
    cell in the final turn and the arbitration pushes D02 aside. That REACHED, said before the push, is no
    verdict: no SETTLED ("targets reached, except unreachable for D01"), the STATUS says NONE for D02 off its
    target; the game goes on, and ends SETTLED once D02 is back on it, as the STATUS then says. (PIBT's push, made
    here by hand; a crowd under the default arbitration: tests/test_cooperation.py.)"""
    g = Game(config(("D01", (0, 0, 0)), ("D02", (1, 0, 0)), arbiter="pibt"), hosts={})
    for d in ("D01", "D02"):
        g.feed(g.engine.connect(Connect(turn=0, sender=d, role=Role.DRONE, drones=(d,), autopilot="dstar",
                                        cooperative=True), Token(d)))
    g.gcs({"D01": (4, 4, 4), "D02": (1, 0, 0)})
    g.feed(g.engine.receive(Nps(turn=1, sender="D01", pos=(0, 0, 0), note=Note.UNREACHABLE)))
    g.feed(g.engine.receive(Nps(turn=1, sender="D02", pos=(1, 0, 0), note=Note.REACHED)))
    assert g.stage is Stage.GCS and g.turn == 2, "D01 hovers stuck (its priority STUCK now), D02 parked"
    g.gcs(intent=Intent.FINAL)
    # the final turn: D01 offers D02's cell only; D02 stays, else steps aside (+y)
    g.feed(g.engine.receive(Nps(turn=2, sender="D01", pos=(1, 0, 0), note=Note.UNREACHABLE,
                                ranked=rank_steps([(1, 0, 0)]))))
    effects = g.feed(g.engine.receive(Nps(turn=2, sender="D02", pos=(1, 0, 0), note=Note.REACHED,
                                          ranked=rank_steps([(0, 0, 0), (0, 1, 0)]))))
    assert records(effects)[0]["moves"] == {"D01": [1, 0, 0], "D02": [1, 1, 0]}, "no push: the test is void"
    assert not pubs(effects, Over), f"a false verdict: {pubs(effects, Over)}"
    assert g.engine.end is None and g.stage is Stage.GCS and g.turn == 3
    status = pubs(effects, Status)[-1]
    assert {s.drone: (s.pos, s.note) for s in status.drones} == {"D01": ((1, 0, 0), Note.UNREACHABLE),
                                                                 "D02": ((1, 1, 0), Note.NONE)}
    # the ground stations show the STATUS: the terminal's line and the page's drone say it is not there
    assert describe(status.drones[1]) == "D02 at (1, 1, 0): alive, target (1, 0, 0)"
    assert view_of(status.drones[1]) == "alive"
    g.gcs(intent=Intent.FINAL)  # D01 steps back, D02 goes home: now the verdict is true
    g.feed(g.engine.receive(Nps(turn=3, sender="D01", pos=(0, 0, 0), note=Note.UNREACHABLE,
                                ranked=rank_steps([(-1, 0, 0)]))))
    effects = g.feed(g.engine.receive(Nps(turn=3, sender="D02", pos=(1, 0, 0), ranked=rank_steps([(0, -1, 0)]))))
    assert records(effects)[0]["moves"] == {"D01": [0, 0, 0], "D02": [1, 0, 0]}
    assert pubs(effects, Over) == [g.engine.end]
    end = g.engine.end
    assert (end.reason, end.text) == (EndReason.SETTLED, "targets reached, except unreachable for D01")
    assert records(effects)[-1]["reason"] == "SETTLED"


def test_new_target_clears_the_note() -> None:
    g = Game()
    g.gcs({"D01": (3, 3, 3)})
    g.nps("D01", (0, 0, 0), Note.UNREACHABLE)
    assert g.status("D01").note is Note.UNREACHABLE
    g.gcs({"D01": (1, 1, 1)})
    assert g.status("D01").note is Note.NONE


def test_quit_ends_the_game() -> None:
    g = Game()
    effects = g.gcs({"D01": (1, 1, 1)}, Intent.QUIT)
    assert pubs(effects) == [Over(turn=1, sender="SRV", reason=EndReason.GCS_QUIT,
                                  text="the ground station ended the game")]
    assert g.stage is Stage.OVER
    refused(g.nps("D01", (1, 0, 0)), StaleTurn)


def test_turn_limit() -> None:
    g = Game(config(max_turns=2))
    play_turn(g, {"D01": (1, 0, 0)}, {"D01": (4, 0, 0)})
    assert g.stage is Stage.GCS
    effects = play_turn(g, {"D01": (2, 0, 0)})
    over = pubs(effects, Over)[0]
    assert over.reason is EndReason.TURN_LIMIT and over.turn == 2
    assert g.stage is Stage.OVER


def test_game_without_a_gcs_phase_when_no_gcs() -> None:
    g = Game()
    g.feed(g.engine.vanished("GCS"))
    assert g.stage is Stage.DRONES
    g.nps("D01", (0, 0, 1))
    g.upd()
    turns = pubs(g.last, Turn)
    assert turns[0].phase is Phase.DRONES and turns[0].turn == 2, "no GCS: straight to the drones"


# --------------------------------------------------------------------------- deadlines and faults


def test_deadlines_per_stage() -> None:
    cfg = config(phase_deadline=2.0, gcs_deadline=9.0, admit_deadline=30.0)
    e = Engine(cfg, LOG)
    assert e.deadline() == 30.0
    g = Game(cfg)
    assert g.engine.deadline() == 9.0
    g.done()
    assert g.engine.deadline() == 2.0
    g.nps("D01", (1, 0, 0))
    assert g.engine.deadline() == 9.0, "the turn is over: the GCS phase of the next"
    assert Game().engine.deadline() is None  # by default the GCS paces the game


def test_expire_drones_makes_missing_drones_hover() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
    g.gcs({"D01": (2, 0, 0), "D02": (0, 4, 4)})
    g.nps("D01", (1, 0, 0))
    g.feed(g.engine.expire(Stage.DRONES, 1))
    assert g.env_turn().moves == (Move(drone="D01", src=(0, 0, 0), dst=(1, 0, 0)),)
    effects = g.upd()
    assert records(effects)[0]["hovered"] == ["D02"]
    s = g.status("D02")
    assert (s.pos, s.state) == ((4, 4, 4), DroneState.ALIVE)
    assert g.engine.drones["D02"].misses == 1


def test_missing_drone_lost_after_lost_after_misses() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), lost_after=2))
    for turn in (1, 2):
        g.gcs()
        g.nps("D01", (0, 0, 0))
        effects = g.feed(g.engine.expire(Stage.DRONES, turn))
    s = g.status("D02")
    assert (s.state, s.cause, s.pos) == (DroneState.LOST, Cause.LOST, (4, 4, 4))
    assert records(effects)[0]["lost"] == ["D02"]
    assert g.stage is Stage.GCS and g.turn == 3, "the game goes on with D01"
    g.done()
    assert [o.drone for o in pubs(g.last, Turn)[0].orders] == ["D01"]


def test_misses_must_be_in_a_row() -> None:
    g = Game(config(("D01", (0, 0, 0)), lost_after=2))
    g.gcs()
    g.feed(g.engine.expire(Stage.DRONES, 1))
    g.gcs()
    g.nps("D01", (0, 0, 1))
    g.upd()
    g.gcs()
    g.feed(g.engine.expire(Stage.DRONES, 3))
    assert g.status("D01").state is DroneState.ALIVE
    assert g.stage is Stage.GCS


def test_lone_drone_lost_ends_the_game() -> None:
    g = Game(config(lost_after=1))
    g.gcs()
    effects = g.feed(g.engine.expire(Stage.DRONES, 1))
    assert g.status("D01").state is DroneState.LOST
    assert pubs(effects, Over)[0].reason is EndReason.NO_DRONE_ALIVE


@pytest.mark.parametrize("stage,turn", [
    (Stage.DRONES, 1), (Stage.GCS, 0), (Stage.GCS, 2), (Stage.ADMITTING, 0), (Stage.OVER, 1),
])
def test_stale_expire_is_ignored(stage: Stage, turn: int) -> None:
    g = Game()
    before = g.snapshot()
    assert g.engine.expire(stage, turn) == []
    assert g.snapshot() == before


def test_expire_gcs_keeps_targets() -> None:
    g = Game(config(gcs_deadline=1.0))
    play_turn(g, {"D01": (1, 0, 0)}, {"D01": (3, 0, 0)})
    g.tgt("D01", (0, 4, 0))  # sent, but no DONE in time
    g.feed(g.engine.expire(Stage.GCS, 2))
    assert g.stage is Stage.DRONES
    assert pubs(g.last, Turn)[0].orders == (Order(drone="D01", pos=(1, 0, 0), target=(3, 0, 0)),)


def test_vanished_drone_is_lost() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
    g.gcs()
    g.nps("D01", (1, 0, 0))
    effects = g.feed(g.engine.vanished("D02"))
    assert g.status("D02").state is DroneState.LOST and g.status("D02").cause is Cause.LOST
    assert pubs(effects, Turn)[0].moves == (Move(drone="D01", src=(0, 0, 0), dst=(1, 0, 0)),), \
        "the last missing drone left: the phase goes on"
    assert records(effects)[0]["lost"] == ["D02"]
    assert g.stage is Stage.GCS


def test_vanished_swarm_host_loses_all_its_drones() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), ("D03", (2, 2, 2))),
             hosts={"H01": ("D01", "D02"), "D03": ("D03",)})
    g.feed(g.engine.vanished("H01"))
    assert [g.status(d).state for d in ("D01", "D02", "D03")] == [
        DroneState.LOST, DroneState.LOST, DroneState.ALIVE]
    g.done()
    assert [o.drone for o in pubs(g.last, Turn)[0].orders] == ["D03"]


def test_vanished_lone_drone_ends_the_game() -> None:
    g = Game()
    g.gcs()
    effects = g.feed(g.engine.vanished("D01"))
    assert pubs(effects, Over)[0].reason is EndReason.NO_DRONE_ALIVE
    assert g.stage is Stage.OVER


def test_vanished_gcs_during_its_phase_keeps_targets() -> None:
    g = Game()
    play_turn(g, {"D01": (1, 0, 0)}, {"D01": (3, 0, 0)})
    g.tgt("D01", (0, 4, 0))
    effects = g.feed(g.engine.vanished("GCS"))
    assert g.stage is Stage.DRONES
    assert pubs(effects, Turn)[0].orders == (Order(drone="D01", pos=(1, 0, 0), target=(3, 0, 0)),)
    g.nps("D01", (2, 0, 0))
    g.upd()
    assert g.stage is Stage.DRONES and g.turn == 3, "the game goes on without a ground station"


def test_vanished_gcs_outside_its_phase() -> None:
    g = Game()
    g.done()
    before = g.snapshot()
    assert g.engine.vanished("GCS") == []
    assert g.snapshot() == before


def test_vanished_env_aborts_after_its_grace_and_unknown_or_late_vanish_ignored() -> None:
    g = Game()
    assert g.engine.vanished("H77") == []
    assert g.feed(g.engine.vanished("ENV")) == []
    effects = g.feed(g.engine.expire(*g.engine.deadline_key()))
    assert pubs(effects, Over)[0].reason is EndReason.ABORTED
    assert g.engine.vanished("D01") == []
    assert g.engine.vanished("GCS") == []


def test_only_the_admitted_session_can_vanish() -> None:
    e = Engine(config(("D01", (0, 0, 0)),), LOG)
    e.connect(Connect(turn=0, sender="GCS", role=Role.GCS, session="aa"), 1)
    assert "GCS" in e.entities
    assert e.vanished("GCS", "bb") == [] and "GCS" in e.entities, "an impostor's token going away changes nothing"
    e.vanished("GCS", "aa")
    assert "GCS" not in e.entities


def test_the_same_process_may_connect_again_an_impostor_may_not() -> None:
    e = Engine(config(("D01", (0, 0, 0)),), LOG)
    assert isinstance(reply(e.connect(Connect(turn=0, sender="GCS", role=Role.GCS, session="aa"), 1)), Welcome)
    assert isinstance(reply(e.connect(Connect(turn=0, sender="GCS", role=Role.GCS, session="aa"), 2)), Welcome)
    r = reply(e.connect(Connect(turn=0, sender="GCS", role=Role.GCS, session="bb"), 3))
    assert isinstance(r, Refused) and "already connected" in r.text


# --------------------------------------------------------------------------- journal and determinism


def scenario(order: int) -> list:
    """The same game fed with arrivals in a different order (connections, targets, NPS)."""
    cfg = config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), ("D03", (2, 2, 2)), buildings={(2, 1, 1)}, max_turns=4)
    e = Engine(cfg, LOG)
    out: list = []
    conns = [connect("ENV", Role.ENV), connect("GCS", Role.GCS), connect("H01", Role.DRONE, ("D01", "D02"), "seed"),
             connect("D03", Role.DRONE, ("D03",), "seed")]
    for c in (conns if order == 0 else conns[::-1]):
        out += e.connect(c, object())
    plan = [
        ({"D01": (3, 0, 0), "D02": (4, 4, 0)}, {"D01": (1, 0, 0), "D02": (4, 4, 3), "D03": (2, 2, 2)}),
        ({"D03": (0, 0, 0)}, {"D01": (2, 0, 0), "D02": (4, 4, 2), "D03": (2, 1, 2)}),
        ({}, {"D01": (2, 1, 0), "D02": (4, 4, 2), "D03": (2, 1, 1)}),
        ({}, {"D01": (3, 1, 0)}),  # D03 died in turn 3; D02 misses this one
    ]
    for turn, (targets, moves) in enumerate(plan, 1):
        items = sorted(targets.items())
        for d, p in (items if order == 0 else items[::-1]):
            out += e.receive(Target(turn=turn, sender="GCS", drone=d, pos=p))
        out += e.receive(Done(turn=turn, sender="GCS", phase=Phase.GCS))
        nps = sorted(moves.items())
        for d, p in (nps if order == 0 else nps[::-1]):
            out += e.receive(Nps(turn=turn, sender=d, pos=p))
        if e.stage is Stage.DRONES:
            out += e.expire(Stage.DRONES, turn)
    assert e.stage is Stage.OVER
    return out


def test_journal_records_are_json() -> None:
    effects = scenario(0)
    recs = records(effects)
    assert recs[0]["record"] == "header"
    assert [r["record"] for r in recs[1:-1]] == ["turn"] * 4
    assert recs[-1]["record"] == "over" and recs[-1]["reason"] == "TURN_LIMIT"
    for r in recs:
        line = journal.dumps(r)
        assert "\n" not in line
        assert json.loads(line) == r
    assert recs[3]["deaths"] == {"D03": "BUILDING"}
    assert recs[4]["hovered"] == ["D02"]
    assert recs[1]["targets"] == {"D01": [3, 0, 0], "D02": [4, 4, 0]}


def test_two_engines_with_the_same_inputs_write_identical_journals() -> None:
    a, b = scenario(0), scenario(1)
    assert [journal.dumps(r) for r in records(a)] == [journal.dumps(r) for r in records(b)]
    assert [encode(m) for m in pubs(a)] == [encode(m) for m in pubs(b)]


def test_journal_round_trip(tmp_path) -> None:
    recs = records(scenario(0))
    path = tmp_path / "game.jsonl"
    with journal.JournalWriter(path) as w:
        for r in recs:
            w.append(r)
    assert list(journal.read(path)) == recs


# --------------------------------------------------------------------------- batches (a swarm's messages)


def test_done_carries_the_targets_and_refuses_bad_ones_one_by_one() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), ("D03", (2, 2, 2))))
    done = Done(turn=1, sender="GCS", phase=Phase.GCS, targets=(
        Aim(drone="D01", pos=(3, 0, 0)), Aim(drone="D02", pos=(9, 9, 9)), Aim(drone="D09", pos=(1, 1, 1)),
        Aim(drone="D03", pos=(2, 2, 0))))
    refused(g.feed(g.engine.receive(done)), OutOfRange, r"outside the world.*and 1 more: target for unknown drone D09")
    assert g.stage is Stage.DRONES, "the refused entries changed nothing; the phase went on"
    assert pubs(g.last, Turn)[0].orders == (Order(drone="D01", pos=(0, 0, 0), target=(3, 0, 0)),
                                            Order(drone="D02", pos=(4, 4, 4), target=None),
                                            Order(drone="D03", pos=(2, 2, 2), target=(2, 2, 0)))


@pytest.mark.parametrize("n", [8, 9, 40])
def test_a_big_done_takes_its_targets_as_if_sent_one_by_one(n: int) -> None:
    """A DONE of more than FEW_ROWS targets is checked in array operations, a few row by row: the same targets
    kept, the same refusals (a dead drone, outside the world, an unknown drone) in the same order."""
    starts = [(f"D{i:02d}", (i % 5, i // 5 % 5, i // 25)) for i in range(1, n + 1)]  # in the 5x5x5 world
    rng = np.random.default_rng(n)
    aims = {d: tuple(int(v) for v in rng.integers(0, 5, 3)) for d, _ in starts}
    aims["D02"] = (5, 0, 0)  # outside the world
    aims["D99"] = (1, 1, 1)  # nobody

    def play(batched: bool) -> tuple:
        g = Game(config(*starts))
        g.gcs()
        for d, p in starts:  # turn 1: D04 flies out of the world and dies, the others hover
            g.nps(d, (5, 0, 0) if d == "D04" else p)
        assert g.stage is Stage.GCS and g.engine.drones["D04"].state is DroneState.DEAD
        if batched:
            targets = tuple(Aim(drone=d, pos=p) for d, p in sorted(aims.items()))
            effects = g.feed(g.engine.receive(Done(turn=2, sender="GCS", phase=Phase.GCS, count=0, targets=targets)))
            assert g.stage is Stage.DRONES, "the refused entries changed nothing; the phase went on"
            return g.engine.targets(), [str(refused(effects))]
        refusals = []
        for d, p in sorted(aims.items()):
            refusals += [str(e.err) for e in g.tgt(d, p) if isinstance(e, Refusal)]
        g.done()
        return g.engine.targets(), refusals

    (kept, [batched]), (single, refusals) = play(True), play(False)
    assert kept == single == {d: p for d, p in aims.items() if d not in ("D02", "D04", "D99")}
    assert [r.split(":")[0] for r in refusals] == ["target (5, 0, 0) for D02 is outside the world (5, 5, 5)",
                                                   "target for D04, which is DEAD", "target for unknown drone D99"]
    assert batched == f"{refusals[0]} (and 2 more: {refusals[1]}; {refusals[2]})"


def test_moves_of_a_swarm_host_taken_one_by_one() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), ("D03", (2, 2, 2))),
             hosts={"H01": ("D01", "D02"), "D03": ("D03",)})
    g.gcs()
    refused(g.engine.receive(Moves(turn=1, sender="H01", moves=(Step(drone="D01", pos=(1, 0, 0)),
                                                           Step(drone="D03", pos=(2, 2, 1))))),
            WrongSender, "D03, which D03 flies")
    assert g.engine.moves_taken() == {"D01": (1, 0, 0)}, "the host's own drone moved, the other's spoofed move did not"
    refused(g.engine.receive(Moves(turn=1, sender="H01", moves=(Step(drone="D01", pos=(0, 1, 0)),))),
            StaleTurn, "second NPS from D01")
    refused(g.engine.receive(Moves(turn=1, sender="H01", moves=(Step(drone="D02", pos=(4, 4, 2)),))),
            OutOfRange, "one cell per turn")
    assert g.stage is Stage.DRONES
    g.feed(g.engine.receive(Moves(turn=1, sender="H01", moves=(Step(drone="D02", pos=(4, 4, 3), note=Note.NONE),))))
    g.nps("D03", (2, 2, 1))
    assert g.stage is Stage.GCS and g.turn == 2
    assert records(g.last)[0]["moves"] == {"D01": [1, 0, 0], "D02": [4, 4, 3], "D03": [2, 2, 1]}


@pytest.mark.parametrize("size", [FEW_ROWS, FEW_ROWS + 1, 40])
def test_a_big_batch_takes_and_refuses_what_moves_one_by_one_would(size: int) -> None:
    """A MOVES above FEW_ROWS moves is checked in array operations: it takes and refuses (with the same
    errors, in the same order) what the same moves sent one MOVES each take and refuse."""
    starts = [(f"D{i:02d}", (i % 5, i // 5 % 5, i // 25)) for i in range(1, size + 3)]
    hosted = tuple(d for d, _ in starts[:size])

    def play(batched: bool) -> tuple:
        g = Game(config(*starts), hosts={"H01": hosted, "H02": tuple(d for d, _ in starts[size:])})
        g.gcs()
        steps = []
        for n, (d, (x, y, z)) in enumerate(starts[:size]):
            jump = n % 7 == 3  # two cells: refused
            steps.append(Step(drone=d, pos=(x, y, z + (2 if jump else 1)), note=Note.REACHED if n % 2 else Note.NONE))
        steps.append(Step(drone=starts[size][0], pos=(0, 0, 4)))  # H02's drone: spoofed
        steps.append(Step(drone="D99", pos=(0, 0, 4)))  # not in this game
        other = [dataclasses.replace(st, note=Note.NONE if st.note is Note.REACHED else Note.REACHED) for st in steps]
        errors: list[list[str]] = [[], [], []]
        # the moves, then the same with other notes (the moves taken are refused), then the same again (those taken
        # are nothing: a host answers a TURN sent again with the same moves)
        for again, sent in enumerate((steps, other, steps)):
            for batch in [sent] if batched else [[st] for st in sent]:
                effects = g.feed(g.engine.receive(Moves(turn=1, sender="H01", moves=tuple(batch))))
                errors[again] += [str(e.err) for e in effects if isinstance(e, Refusal)]
        return g.engine.moves_taken(), errors

    taken, (errors, errors_again, errors_same) = play(batched=True)
    one_by_one, (each, each_again, each_same) = play(batched=False)
    assert taken == one_by_one and len(taken) == size - len(range(3, size, 7))
    assert errors[0].startswith(each[0]) and f"and {len(each) - 1} more" in errors[0]
    assert "D99, which nobody flies" in each[-1] and f"{starts[size][0]}, which H02 flies" in each[-2]
    assert len(each_again) == size + 2 and sum("second NPS" in e for e in each_again) == len(taken)
    assert errors_again[0].startswith(each_again[0]) and f"and {len(each_again) - 1} more" in errors_again[0]
    assert each_same == each and errors_same == errors, "the same moves again: only what was refused is refused"


def test_batches_give_the_same_journal_as_single_messages() -> None:
    def play(batched: bool) -> list:
        g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))), hosts={"H01": ("D01", "D02")})
        for turn, (targets, moves) in enumerate([({"D01": (3, 0, 0), "D02": (4, 4, 0)},
                                                  {"D01": (1, 0, 0), "D02": (4, 4, 3)}),
                                                 ({}, {"D01": (2, 0, 0), "D02": (4, 4, 2)})], 1):
            if batched:
                g.feed(g.engine.receive(Done(turn=turn, sender="GCS", phase=Phase.GCS, targets=tuple(
                    Aim(drone=d, pos=p) for d, p in targets.items()))))
                g.feed(g.engine.receive(Moves(turn=turn, sender="H01", moves=tuple(
                    Step(drone=d, pos=p) for d, p in moves.items()))))
            else:
                play_turn(g, moves, targets)
        return records(g.effects)

    assert play(True) == play(False)


# --------------------------------------------------------------------------- answers ahead


def test_done_ahead_closes_the_next_gcs_phase_as_it_opens() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
    g.gcs({"D01": (3, 0, 0), "D02": (4, 4, 0)})
    assert g.feed(g.engine.receive(Done(turn=2, sender="GCS", phase=Phase.GCS))) == [], "held"
    g.nps("D01", (1, 0, 0))
    effects = g.nps("D02", (4, 4, 3))
    turns = pubs(effects, Turn)
    assert [(t.turn, t.phase) for t in turns] == [(2, Phase.DRONES), (1, Phase.ENV)], \
        "what the next turn waits for goes out first; a GCS phase answered ahead is not announced"
    assert g.stage is Stage.DRONES and g.turn == 2
    assert turns[0].orders == (Order(drone="D01", pos=(1, 0, 0), target=(3, 0, 0)),
                                Order(drone="D02", pos=(4, 4, 3), target=(4, 4, 0)))


def test_done_ahead_is_checked_when_its_phase_opens() -> None:
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), buildings={(1, 0, 0)}))
    g.gcs({"D01": (3, 0, 0)})
    g.feed(g.engine.receive(Done(turn=2, sender="GCS", phase=Phase.GCS, targets=(
        Aim(drone="D01", pos=(2, 2, 2)), Aim(drone="D02", pos=(0, 4, 4))))))
    g.nps("D01", (1, 0, 0))  # into a building: D01 is dead when turn 2 opens
    effects = g.nps("D02", (4, 4, 4))
    refusals = [e for e in effects if isinstance(e, Refusal)]
    assert len(refusals) == 1 and "D01, which is DEAD" in str(refusals[0].err)
    assert pubs(effects, Turn)[0].orders == (Order(drone="D02", pos=(4, 4, 4), target=(0, 4, 4)),)


def test_done_ahead_misuse_is_refused_and_changes_nothing() -> None:
    g = Game()
    g.gcs()
    snap = g.snapshot()
    refused(g.engine.receive(Done(turn=2, sender="GCS", phase=Phase.GCS, count=1)), StaleTurn, "cannot count")
    refused(g.engine.receive(Done(turn=2, sender="D01", phase=Phase.GCS)), WrongSender)
    refused(g.engine.receive(Done(turn=2 + AHEAD_MAX, sender="GCS", phase=Phase.GCS)), StaleTurn)  # too far ahead
    assert g.snapshot() == snap and not g.engine.ahead.dones
    g.feed(g.engine.receive(Done(turn=2, sender="GCS", phase=Phase.GCS)))
    refused(g.engine.receive(Done(turn=2, sender="GCS", phase=Phase.GCS, intent=Intent.QUIT)),
            StaleTurn, "second DONE ahead")
    g.feed(g.engine.vanished("GCS"))
    assert not g.engine.ahead.dones, "what a ground station said ahead leaves with it"


def test_answers_ahead_give_the_same_journal() -> None:
    def play(ahead: bool) -> list:
        g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))))
        g.gcs({"D01": (3, 0, 0), "D02": (4, 4, 0)})
        for turn, moves in enumerate([{"D01": (1, 0, 0), "D02": (4, 4, 3)}, {"D01": (2, 0, 0), "D02": (4, 4, 2)},
                                      {"D01": (3, 0, 0), "D02": (4, 4, 1)}], 1):
            if ahead and turn == 1:  # answers two turns at once, as far as its plan allows
                for t in (2, 3):
                    g.feed(g.engine.receive(Done(turn=t, sender="GCS", phase=Phase.GCS)))
            for d, p in moves.items():
                g.nps(d, p)
            if not ahead:
                g.done()
        return records(g.effects)

    assert play(True) == play(False)


def _hosted_pair(**kw) -> Game:
    return Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4)), **kw), hosts={"H01": ("D01", "D02")})


def _host_moves(turn: int, moves: dict) -> Moves:
    return Moves(turn=turn, sender="H01", moves=tuple(Step(drone=d, pos=p) for d, p in moves.items()))


def test_moves_ahead_are_taken_as_the_drones_phase_opens() -> None:
    """A host that decides from the STATUS alone (the RL environment) sends its MOVES with the GCS's DONE."""
    g = _hosted_pair()
    g.gcs({"D01": (3, 0, 0), "D02": (4, 4, 0)})
    g.feed(g.engine.receive(_host_moves(1, {"D01": (1, 0, 0), "D02": (4, 4, 3)})))
    assert g.stage is Stage.GCS and g.turn == 2
    assert g.feed(g.engine.receive(_host_moves(2, {"D01": (2, 0, 0), "D02": (4, 4, 2)}))) == [], "held"
    assert g.stage is Stage.GCS and g.turn == 2
    effects = g.done()
    turns = pubs(effects, Turn)
    assert [(t.turn, t.phase) for t in turns] == [(2, Phase.DRONES), (2, Phase.ENV), (3, Phase.GCS)], \
        "the drones' phase is announced, then taken at once"
    assert g.stage is Stage.GCS and g.turn == 3
    assert records(effects)[0]["moves"] == {"D01": [2, 0, 0], "D02": [4, 4, 2]}


def test_moves_ahead_give_the_same_journal() -> None:
    def play(ahead: bool) -> list:
        g = _hosted_pair()
        for turn, moves in enumerate([{"D01": (1, 0, 0), "D02": (4, 4, 3)}, {"D01": (2, 0, 0)},
                                      {"D01": (3, 0, 0), "D02": (4, 4, 1)}], 1):
            if ahead:
                g.feed(g.engine.receive(_host_moves(turn, moves)))
            g.gcs({"D01": (3, 0, 0), "D02": (4, 4, 0)} if turn == 1 else None)
            if not ahead:
                g.feed(g.engine.receive(_host_moves(turn, moves)))
            if turn == 2:  # D02 is late: the deadline closes the phase, ahead or not
                g.feed(g.engine.expire(Stage.DRONES, 2))
        return records(g.effects)

    assert play(True) == play(False)


def test_moves_ahead_misuse_is_refused_and_changes_nothing() -> None:
    g = _hosted_pair()
    snap = g.snapshot()
    refused(g.engine.receive(Moves(turn=1, sender="D07", moves=(Step(drone="D01", pos=(1, 0, 0)),))),
            WrongSender, "flies no drone")
    refused(g.engine.receive(_host_moves(2, {"D01": (1, 0, 0)})), StaleTurn)  # only the current turn's
    assert g.snapshot() == snap and not g.engine.ahead.moves
    g.feed(g.engine.receive(_host_moves(1, {"D01": (0, 2, 0), "D02": (4, 4, 3)})))  # D01's: two cells
    refused(g.engine.receive(_host_moves(1, {"D01": (1, 0, 0)})), StaleTurn, "second MOVES ahead")
    with pytest.raises(UsageError):  # a turn from arrays cannot jump over what came ahead
        g.engine.play(*(np.zeros((0,), np.int64), np.zeros((0, 3), np.int64)) * 2, np.zeros((0,), np.uint8))
    effects = g.done()
    assert "cannot move from (0, 0, 0) to (0, 2, 0)" in str(refused(effects, OutOfRange)), \
        "checked when the phase opens, like any MOVES"
    assert g.stage is Stage.DRONES and g.engine.moves_taken() == {"D02": (4, 4, 3)}


def test_moves_ahead_leave_with_their_host_and_wait_for_the_environment() -> None:
    g = _hosted_pair()
    g.feed(g.engine.receive(_host_moves(1, {"D01": (1, 0, 0), "D02": (4, 4, 3)})))
    g.feed(g.engine.vanished("H01"))
    assert not g.engine.ahead.moves, "a host's moves leave with it"
    g = _hosted_pair()
    g.feed(g.engine.vanished("ENV"))
    g.feed(g.engine.receive(_host_moves(1, {"D01": (1, 0, 0), "D02": (4, 4, 3)})))
    assert pubs(g.done(), Turn) == [] and g.stage is Stage.DRONES, "the drones' phase waits for the environment"
    assert g.engine.moves_taken() == {}
    effects = g.feed(g.engine.connect(connect("ENV", Role.ENV), Token("ENV2")))
    assert [(t.turn, t.phase) for t in pubs(effects, Turn)] == [(1, Phase.DRONES), (1, Phase.ENV), (2, Phase.GCS)]


def test_a_late_upd_is_still_checked() -> None:
    """Nothing waits for the environment's report, so it may come a turn or more later."""
    g = Game()
    play_turn(g, {"D01": (1, 0, 0)}, {"D01": (4, 0, 0)})
    first = g.env_turn()
    play_turn(g, {"D01": (2, 0, 0)})
    assert g.engine.receive(Upd(turn=1, sender="ENV", cells=(CellInfo(pos=(0, 0, 0), kind=CellKind.EMPTY),
                                                              CellInfo(pos=(1, 0, 0), kind=CellKind.EMPTY)))) == []
    assert first.turn == 1
    refused(g.engine.receive(Upd(turn=1, sender="ENV", cells=())), StaleTurn)  # checked once


# --------------------------------------------------------------------------- resuming


def resumed(**kw) -> tuple[Engine, list]:
    """An engine restored from a two-turn journal, with the environment and the drone back."""
    g = Game(config(**kw))
    play_turn(g, {"D01": (1, 0, 0)}, {"D01": (4, 0, 0)})
    play_turn(g, {"D01": (2, 0, 0)})
    e = restore(g.engine.config, records(g.effects), LOG)
    out = e.connect(connect("ENV", Role.ENV), Token("ENV"))
    out += e.connect(connect("D01", Role.DRONE, ("D01",), "seed"), Token("D01"))
    return e, out


def test_a_resumed_game_waits_for_its_ground_station_a_grace_period() -> None:
    e, out = resumed(gcs_grace=7.0)
    assert e.stage is Stage.RESUMING and not pubs(out, Turn), "the ground station is not back yet"
    assert e.deadline() == 7.0
    effects = e.connect(connect("GCS", Role.GCS), Token("GCS"))
    assert [(t.turn, t.phase) for t in pubs(effects, Turn)] == [(3, Phase.GCS)]


def test_a_resumed_game_goes_on_without_a_ground_station_that_does_not_come_back() -> None:
    e, _ = resumed()
    effects = e.expire(*e.deadline_key())
    assert [(t.turn, t.phase) for t in pubs(effects, Turn)] == [(3, Phase.DRONES)]
    assert pubs(effects, Turn)[0].orders == (Order(drone="D01", pos=(2, 0, 0), target=(4, 0, 0)),)


# --------------------------------------------------------------------------- a host still deciding (issue 33, 8)


def _deciding(turn: int, sender: str = "H01") -> Moves:
    """A host's word that it is still deciding `turn`: an empty MOVES."""
    return Moves(turn=turn, sender=sender, moves=())


def test_a_hosts_word_that_it_is_still_deciding_stretches_the_phase_and_changes_nothing_else() -> None:
    g = _hosted_pair(phase_deadline=0.5, phase_cap=20.0)
    g.gcs()
    assert g.stage is Stage.DRONES and g.engine.stretch() is None, "no word yet: the deadline as it is"
    snap = g.snapshot()
    assert g.feed(g.engine.receive(_deciding(1))) == [] and g.snapshot() == snap
    assert g.engine.deciding == 1 and g.engine.stretch() == (DECIDING_SILENCE_S, 20.0)
    g.feed(g.engine.receive(_host_moves(1, {"D01": (1, 0, 0)})))  # D01 decided, D02 not yet
    g.feed(g.engine.receive(_deciding(1)))
    assert g.engine.deciding == 2, "a host with a move still awaited is still deciding"
    g.feed(g.engine.receive(_host_moves(1, {"D02": (4, 4, 3)})))
    assert (g.stage, g.turn) == (Stage.GCS, 2) and g.engine.stretch() is None
    g.gcs()
    assert g.engine.deciding == 0, "each drones' phase starts without a word"
    assert g.engine.stretch() == (DECIDING_SILENCE_S, 20.0), \
        "but a host that said so in the last one is presumed as slow: its first word may come after the deadline"
    g.feed(g.engine.receive(_host_moves(2, {"D01": (2, 0, 0)})))
    assert g.engine.stretch() == (DECIDING_SILENCE_S, 20.0), "while it has a move awaited"
    g.feed(g.engine.receive(_host_moves(2, {"D02": (4, 4, 2)})))
    g.gcs()
    assert g.engine.stretch() is None, "said nothing in the last one: the deadline as it is"


def test_a_word_that_it_is_still_deciding_is_not_held_nor_taken_from_a_host_with_nothing_left_to_decide() -> None:
    g = _hosted_pair()
    refused(g.engine.receive(_deciding(1)), StaleTurn, "before turn 1's drones' phase opened")
    assert not g.engine.ahead.moves, "never held: the host's real MOVES ahead is still taken"
    g.gcs()
    refused(g.engine.receive(_deciding(1, "D07")), WrongSender, "flies no drone")
    refused(g.engine.receive(_deciding(1, "D01")), WrongSender, "flies no drone")  # (H01 flies it)
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))), hosts={"H01": ("D01",), "H02": ("D02",)})
    g.gcs()
    g.feed(g.engine.receive(_host_moves(1, {"D01": (1, 0, 0)})))
    assert g.feed(g.engine.receive(_deciding(1))) == [] and g.engine.deciding == 0, \
        "a word that crossed its host's MOVES: nothing left to wait for"
    g.feed(g.engine.receive(_deciding(1, "H02")))
    assert g.engine.deciding == 1


def test_a_hosts_moves_sent_again_after_its_word_change_nothing_and_are_not_refused() -> None:
    """A host sends again the MOVES that followed its word that it was still deciding (the router may drop a MOVES
    that reaches it in one batch with that word: entities/drone_node.py `Effects.repeat`): the MOVES taken, again,
    is nothing new, in its phase or after it; any other MOVES is refused as before (also the same MOVES again from a
    host that said nothing: test_a_big_batch_takes_and_refuses_what_moves_one_by_one_would)."""
    g = Game(config(("D01", (0, 0, 0)), ("D02", (4, 4, 4))), hosts={"H01": ("D01",), "H02": ("D02",)})
    g.gcs()
    g.feed(g.engine.receive(_deciding(1)))
    moves = _host_moves(1, {"D01": (1, 0, 0)})
    g.feed(g.engine.receive(moves))
    snap = g.snapshot()
    assert g.feed(g.engine.receive(moves)) == [] and g.snapshot() == snap, "in its phase (H02 still awaited)"
    refused(g.engine.receive(_host_moves(1, {"D01": (0, 1, 0)})))
    g.feed(g.engine.receive(Moves(turn=1, sender="H02", moves=(Step(drone="D02", pos=(4, 4, 3)),))))
    assert (g.stage, g.turn) == (Stage.GCS, 2)
    snap = g.snapshot()
    assert g.feed(g.engine.receive(moves)) == [] and g.snapshot() == snap, "after it"
    refused(g.engine.receive(_host_moves(1, {"D01": (2, 0, 0)})), StaleTurn)


def test_the_stretch_is_never_shorter_than_the_deadline() -> None:
    g = _hosted_pair(phase_deadline=90.0, phase_cap=5.0)
    g.gcs()
    g.feed(g.engine.receive(_deciding(1)))
    assert g.engine.stretch() == (90.0, 90.0)


@pytest.mark.parametrize("drones", [3, 300])
def test_an_over_naming_every_lost_drone_fits_its_key_whatever_their_number(drones: int) -> None:
    """Issue 33, 8: the OVER after a host's hundred drones were LOST named each one, exceeded its key's size limit,
    and reached no one (every other process waited 30 s and exited 2)."""
    starts = tuple((drone_id(i + 1), (i // 25 % 5, i % 5, i // 5 % 5)) for i in range(drones))
    cells = 5 * 5 * 5
    g = Game(GameConfig(world=WorldSpec(size=(5, 5, 5 * (1 + drones // cells))), drones=tuple(
        DroneSpec(drone=d, start=(x, y, z + 5 * (i // cells))) for i, (d, (x, y, z)) in enumerate(starts)),
        lost_after=1), hosts={"H01": tuple(d for d, _ in starts)})
    g.gcs()
    g.feed(g.engine.expire(Stage.DRONES, 1))
    (over,) = pubs(g.effects, Over)
    assert over.reason is EndReason.NO_DRONE_ALIVE and len(encode(over)) <= size_limit(Over)
    assert decode(encode(over)) == over, "as every receiver reads it"
    order = list(g.engine.drones)  # (the fleet's order: by id)
    named = [d for d in order if f"{d} lost" in over.text]
    assert named == order[:len(named)] and named
    assert drones == 3 or over.text.endswith(f"and {drones - len(named)} more")
    assert records(g.effects)[-1]["text"] == over.text, "the journal says what the OVER says"


def test_a_repeat_of_the_done_taken_changes_nothing_and_another_is_refused() -> None:
    """A ground station repeats its DONE until the turn is played (one may be lost on the way: a router's budget of
    puts a second, issue 33, 6): the same DONE again is taken as nothing new, in its GCS phase or after it."""
    g = Game(config(("D01", (0, 0, 0))))
    done = Done(turn=1, sender="GCS", phase=Phase.GCS, targets=AimTable.of([Aim(drone="D01", pos=(3, 0, 0))]))
    g.feed(g.engine.receive(done))
    assert g.stage is Stage.DRONES
    snap = g.snapshot()
    assert g.feed(g.engine.receive(done)) == [] and g.snapshot() == snap, "the same again: nothing"
    refused(g.engine.receive(Done(turn=1, sender="GCS", phase=Phase.GCS)), StaleTurn, "in its drones' phase")
    ahead = Done(turn=2, sender="GCS", phase=Phase.GCS)
    assert g.feed(g.engine.receive(ahead)) == [] and g.feed(g.engine.receive(ahead)) == []
    refused(g.engine.receive(Done(turn=2, sender="GCS", phase=Phase.GCS, intent=Intent.FINAL)), StaleTurn,
            "second DONE ahead")
