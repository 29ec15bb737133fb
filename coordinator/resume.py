"""Resuming a game from its journal: a restarted coordinator's engine in the state of the last whole turn,
each journaled turn replayed as the observer played it and checked against the state hash it recorded."""

from __future__ import annotations

import logging

import numpy as np

from schema import Cause, DroneState, Intent, Note, UsageError
from schema.tables import code_of

from .engine import Engine, GameConfig, Stage, state_hash


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
    turn = 0
    for r in records[1:]:
        if r.get("record") == "over":
            raise UsageError(f"the journal's game is over (turn {r.get('turn')}): nothing to resume (a journal "
                             "holds one game: give another --journal for a new one)")
        if r.get("record") == "turn":
            turn = _restore_turn(engine, r)
    engine.turn, engine.stage = turn, Stage.RESUMING
    logger.info("restored turn %d from the journal", turn)
    return engine


def _restore_turn(engine: Engine, r: dict) -> int:
    """Apply one journaled turn to the engine's state; its turn."""
    fleet, row = engine.fleet, engine.fleet.index
    alive = fleet.alive_rows()
    for d, p in r.get("targets", {}).items():
        fleet.aim(row[d], tuple(p))
    if "intent" in r:
        engine.intent = Intent(r["intent"])
        engine.final = engine.intent is Intent.FINAL
    for d, p in r.get("moves", {}).items():
        fleet.pos[row[d]] = p
    for d, n in r.get("notes", {}).items():
        fleet.note[row[d]] = code_of(Note(n))
    engine.age(alive, [row[d] for d in r.get("gave_way", ())])  # the arbitration's priorities
    hovered = np.isin(alive, [row[d] for d in r.get("hovered", ())])
    fleet.misses[alive] = np.where(hovered, fleet.misses[alive] + 1, 0)
    for d, cause in r.get("deaths", {}).items():
        fleet.end(row[d], DroneState.DEAD, Cause(cause))
    for d in r.get("lost", ()):
        fleet.end(row[d], DroneState.LOST, Cause.LOST)
    turn = r["turn"]
    if state_hash(engine.status(turn)) != r.get("state"):
        raise UsageError(f"the journal's turn {turn} does not replay to its recorded state")
    return turn
