"""The game's verdict: whether it ends with the turn just judged, and why (`end_reason`: the OVER's reason and
what its text says of the drones), and an end's text kept within what an OVER may carry (`over_text`, `named`,
`clipped`). Pure functions of the fleet's columns: the engine (`Engine._over`) builds the OVER and its record."""

from __future__ import annotations

import itertools

import numpy as np

from schema import EndReason
from schema.messages import MAX_OVER_TEXT

from .fleet import ALIVE, CAUSES, REACHED, STATES, UNREACHABLE, Fleet

#: Characters of the names an end's text lists (then "and N more"), within `MAX_OVER_TEXT` with room for the rest.
NAMES_ROOM = MAX_OVER_TEXT - 128


def end_reason(fleet: Fleet, arbiter: object, final: bool, turn: int, max_turns: int,
               left: int, lifelong: bool = False) -> tuple[EndReason, str] | None:
    """Whether the game ends with `turn`, just judged (leaving `left` drones alive), and why: no drone alive, the
    arbitration's search proved there is no solution (`arbiter.unsolvable`: coordinator/lacam.py; once the ground
    station's plan is `final`, and not in a `lifelong` game, whose drones get new targets as each arrives: it goes on
    to its limit), the ground station's plan is complete (`final`) and every alive drone reached its target or says it
    cannot, or the turn limit. None: the game goes on."""
    if not left:  # (from the columns: a DroneView each would cost an RL episode's end more than its turn)
        causes = named([f"{d} {STATES[s].value.lower()} ({CAUSES[c].value.lower()}) at {tuple(p)}"
                        for d, s, c, p in zip(fleet.ids, fleet.state.tolist(), fleet.cause.tolist(),
                                              fleet.pos.tolist())])
        return EndReason.NO_DRONE_ALIVE, f"no drone alive: {causes}"
    if not lifelong and final and getattr(arbiter, "unsolvable", False):  # (a proof: coordinator/lacam.py; of
        # these targets, which a ground station whose plan is not final may still change)
        away = (fleet.state == ALIVE) & (fleet.target[:, 0] >= 0) & (fleet.pos != fleet.target).any(axis=1)
        return EndReason.SETTLED, ("no solution (the search over the drones' configurations proved it): targets "
                                   "reached, except unreachable for "
                                   f"{named([fleet.ids[i] for i in np.flatnonzero(away)])}")
    if final:
        alive = fleet.state == ALIVE
        notes = fleet.notes()[alive]
        if np.count_nonzero(notes == REACHED) == len(notes):
            return EndReason.ALL_REACHED, f"every drone reached its target in {turn} turns"
        if np.count_nonzero((notes == REACHED) | (notes == UNREACHABLE)) == len(notes) and \
                not getattr(arbiter, "busy", False):  # (the search brings them home: lacam.Lacam)
            stuck = [fleet.ids[i] for i in alive.nonzero()[0][notes == UNREACHABLE].tolist()]
            return EndReason.SETTLED, f"targets reached, except unreachable for {named(stuck)}"
    if turn >= max_turns:
        return EndReason.TURN_LIMIT, f"turn limit {max_turns} reached"
    return None


def over_text(text: str, turn: int, tasks: int | None) -> str:
    """An OVER's text in `turn`: `text`, after a lifelong game's count of its `tasks` done (None: not lifelong, or
    never started), cut to fit (`clipped`)."""
    if tasks is not None:  # (first: the names an end lists are cut to fit after it)
        text = f"{tasks} tasks done in {turn} turns, {tasks / max(turn, 1):.3f} a turn; {text}"
    return clipped(text)


def named(items: list[str], room: int = NAMES_ROOM) -> str:
    """`items` joined by ", ", as many as fit in `room` characters, then "and N more": the text of an OVER (and of
    its journal record) stays within `MAX_OVER_TEXT` whatever the number of drones it names."""
    text = ", ".join(items)
    if len(text) <= room:
        return text
    shown = list(itertools.takewhile(lambda n: n < room - 24, itertools.accumulate(len(i) + 2 for i in items)))
    return f"{', '.join(items[:len(shown)])} and {len(items) - len(shown)} more"


def clipped(text: str) -> str:
    """`text` cut to `MAX_OVER_TEXT` bytes of UTF-8 (ending "..." if cut): an OVER's text (a full disk's error may
    name a long path)."""
    data = text.encode()
    return text if len(data) <= MAX_OVER_TEXT else data[:MAX_OVER_TEXT - 3].decode(errors="ignore") + "..."
