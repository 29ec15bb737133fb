"""Resuming a game from its journal: a restarted coordinator's engine in the state of the last whole turn,
each journaled turn replayed as the observer played it and checked against the state hash it recorded."""

from __future__ import annotations

import logging

from .config import GameConfig
from .engine import Engine


def restore(config: GameConfig, records: list[dict], logger: logging.Logger, game: str = "") -> Engine:
    """An engine restored from a journal's records (`Engine.resume`), waiting (RESUMING) for the entities to connect
    again, then playing the turn after the journal's last (`game`: its new identity, see `Engine`). UsageError if
    the journal is not this game's, is over, or does not replay to its recorded states."""
    engine = Engine(config, logger, game=game)
    turn = engine.resume(records)
    logger.info("restored turn %d from the journal", turn)
    return engine
