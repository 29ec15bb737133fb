"""Resuming a game from its journal: a restarted coordinator's engine in the state of the last whole turn,
each journaled turn replayed as the observer played it and checked against the state hash it recorded."""

from __future__ import annotations

import logging

import numpy as np

from schema import Cause, DroneState, Intent, UsageError
from schema.tables import code_of

from .config import GameConfig
from .engine import Engine, Stage, state_hash
from .journal import TurnRecord, over_of, turns


def restore(config: GameConfig, records: list[dict], logger: logging.Logger, game: str = "") -> Engine:
    """An engine restored from a journal's records, waiting (RESUMING) for the entities to connect again, then
    playing the turn after the journal's last (`game`: its new identity, see `Engine`). UsageError if the
    journal is not this game's, is over, or does not replay to its recorded states."""
    engine = Engine(config, logger, game=game)
    if not records or records[0].get("record") != "header":
        raise UsageError("the journal has no header: nothing to resume")
    theirs = records[0]
    fleet = engine.fleet
    for d in theirs.get("drones", []):  # autopilots are learnt at admission, not configured
        i = fleet.index.get(d.get("drone"))
        if i is not None:
            fleet.autopilot[i], fleet.cooperative[i] = d.get("autopilot", ""), d.get("cooperative", False)
    if engine.header() != theirs:
        raise UsageError("the journal is of another game (world, drones or limits differ)")
    if (over := over_of(records)) is not None:
        raise UsageError(f"the journal's game is over (turn {over.get('turn')}): nothing to resume (a journal "
                         "holds one game: give another --journal for a new one)")
    turn = 0
    try:
        for r in turns(records[1:]):
            turn = _restore_turn(engine, r)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise UsageError(f"the journal has a bad turn record after turn {turn}: {exc!r}") from None
    engine.turn, engine.stage = turn, Stage.RESUMING
    logger.info("restored turn %d from the journal", turn)
    return engine


def _restore_turn(engine: Engine, r: TurnRecord) -> int:
    """Apply one journaled turn to the engine's state; its turn."""
    fleet, row = engine.fleet, engine.fleet.index
    alive = fleet.alive_rows()
    for d, p in r.targets.items():
        fleet.aim(row[d], p)
    if r.intent is not None:
        engine.intent = r.intent
        engine.final = engine.intent is Intent.FINAL
    engine.turn = r.turn
    engine.follow(alive)  # (before the moves, as the arbitration ran)
    for d, p in r.moves.items():
        fleet.pos[row[d]] = p
    for d, n in r.notes.items():
        fleet.note[row[d]] = code_of(n)
    engine.age(alive, [row[d] for d in r.gave_way])  # the arbitration's priorities
    hovered = np.isin(alive, [row[d] for d in r.hovered])
    fleet.misses[alive] = np.where(hovered, fleet.misses[alive] + 1, 0)
    for d, cause in r.deaths.items():
        fleet.end(row[d], DroneState.DEAD, cause)
    for d in r.lost:
        fleet.end(row[d], DroneState.LOST, Cause.LOST)
    if state_hash(engine.status(r.turn)) != r.state:
        raise UsageError(f"the journal's turn {r.turn} does not replay to its recorded state")
    return r.turn
