"""Resuming a game from its journal: a restarted coordinator's engine in the state of the last whole turn,
each journaled turn replayed as the observer played it and checked against the state hash it recorded."""

from __future__ import annotations

import logging

from schema import UsageError

from .config import GameConfig
from .engine import Engine
from .journal import over_of, turns


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
            fleet.learn([i], d.get("autopilot", ""), d.get("cooperative", False))
    if engine.header() != theirs:
        raise UsageError("the journal is of another game (world, drones or limits differ)")
    if (over := over_of(records)) is not None:
        raise UsageError(f"the journal's game is over (turn {over.get('turn')}): nothing to resume (a journal "
                         "holds one game: give another --journal for a new one)")
    try:
        turn = engine.resume(turns(records[1:]))
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise UsageError(f"the journal has a bad turn record: {exc!r}") from None
    logger.info("restored turn %d from the journal", turn)
    return engine
