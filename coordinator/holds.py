"""The hold for a lost link (`Outage`): when the coordinator's own presence vanishes (a router restarted, frozen,
or cut), nobody has left; the game holds until every admitted entity is back or `link_grace` has passed
(coordinator/engine.py: `Engine.link_lost`, `present`, `link_back`, `vanished`, `expire`). Pure bookkeeping of who
is still away, and then of who has not connected again yet: no clock of its own."""

from __future__ import annotations

from collections.abc import Iterable

from .admission import Roster


class Outage:
    """Who of the entities admitted in `roster` is not back yet while the link is down (`away`; None: no hold), and,
    once the hold has ended with every presence token back, who has not connected again yet (`rejoining`): a token
    back says the entity's link is up, not that the router has its subscriptions yet (what went out at once, the
    phase again, may not reach it), while its CONNECT, sent on that link after them, does say so."""

    def __init__(self, roster: Roster) -> None:
        self.roster = roster
        self.away: set[str] | None = None
        self.rejoining: set[str] = set()
        self._began: frozenset[str] = frozenset()  # who was away when the hold began

    def begin(self, entities: Iterable[str]) -> bool:
        """The link is down: `entities` (the admitted ones) are away. False if a hold was on already."""
        if self.away is not None:
            return False
        self.away = set(entities)
        self._began, self.rejoining = frozenset(self.away), set()
        return True

    def back(self, entity: str, session: str) -> bool:
        """`entity`'s presence token is there (again), from `session`: whether it was the last one away (the hold
        ends). Not an impostor's: its session must be the one admitted."""
        if self.away is None or entity not in self.away or self.roster.sessions.get(entity) not in ("", session):
            return False
        self.away.discard(entity)
        if self.away:
            return False
        self.away, self.rejoining = None, set(self._began)
        return True

    def rejoined(self, entity: str) -> bool:
        """`entity` was admitted again: whether it was the last one of those back with their tokens to connect again
        (the phase in progress, sent again when the hold ended, then goes out once more: now every one of them
        hears it)."""
        if entity not in self.rejoining:
            return False
        self.rejoining.discard(entity)
        return not self.rejoining

    def gone(self, entity: str, session: str) -> bool:
        """`entity`'s presence token vanished (from `session`): whether the hold takes it as away, not gone (until
        the hold ends), also if it was back (a router continued after a freeze drops the old links after their
        tokens)."""
        if self.away is not None and (entity in self.away or self.roster.sessions.get(entity) in ("", session)):
            self.away.add(entity)
            return True
        return False

    def end(self) -> list[str]:
        """The hold ends (the last one back, the routers answer again, or `link_grace` has passed): those still away,
        sorted."""
        gone, self.away, self.rejoining = sorted(self.away or ()), None, set()
        return gone
