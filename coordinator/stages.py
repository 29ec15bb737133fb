"""The turn engine's state machine as tables (in the manner of h11's `_state.py`): its stages, the stages each may
go to (`TRANSITIONS`), and the messages each stage takes, for which turn, and the engine's method that takes each
(`TAKES`). coordinator/engine.py's `Engine` is driven by them: it changes stage only as `TRANSITIONS` allows
(`Engine._enter`) and takes a message only as `TAKES` says (`Engine.receive`; any other is stale, refused).

One turn (the seed's cycle GCS -> D01 -> ENV -> OBS -> GCS):

  stage    the engine publishes           it waits for                      then
  -------  -----------------------------  --------------------------------  ----------------------
  GCS      TURN(t, GCS)                   TGT*, DONE from the GCS           DRONES
  DRONES   TURN(t, DRONES, orders)        one NPS per alive drone           the ENV phase
  (ENV)    TURN(t, ENV, moves)            - (its UPD is checked on arrival)  the observer
  (OBS)    STATUS(t)                      -                                 GCS of t+1, or OVER
"""

from __future__ import annotations

import enum

from schema import Done, Message, Moves, Nps, Target, Upd


class Stage(enum.Enum):
    ADMITTING = "ADMITTING"
    RESUMING = "RESUMING"  # restarted from a journal: waiting for the entities to connect again
    GCS = "GCS"
    DRONES = "DRONES"
    OVER = "OVER"

    __hash__ = object.__hash__  # (a member is its one instance; Enum's hash is a Python call, `_enter`'s each turn)


class When(enum.Enum):
    """A message's turn against the engine's: the turn being played, a coming one (up to `AHEAD_MAX` on), or any
    (its handler checks it)."""

    NOW = "NOW"
    AHEAD = "AHEAD"
    ANY = "ANY"
    OTHER = "OTHER"  # a past turn, or one too far on: taken in no stage


#: The stage changes: each stage and the stages it may go to. The turn cycle GCS -> DRONES -> GCS (the ENV and OBS
#: phases are effects of the drones' phase closing); admission (or resuming) opens the first turn's GCS phase, or
#: its drones' phase when no ground station is there; a GCS phase opens the next one when a whole turn is played
#: in one call (`play`); any stage ends in OVER (an end, a fault, a signal), which is final.
TRANSITIONS: dict[Stage, frozenset[Stage]] = {
    Stage.ADMITTING: frozenset({Stage.GCS, Stage.DRONES, Stage.RESUMING, Stage.OVER}),
    Stage.RESUMING: frozenset({Stage.GCS, Stage.DRONES, Stage.OVER}),
    Stage.GCS: frozenset({Stage.DRONES, Stage.GCS, Stage.OVER}),
    Stage.DRONES: frozenset({Stage.GCS, Stage.OVER}),
    Stage.OVER: frozenset(),
}

#: The messages the engine takes, in which stage and for which turn, and the method that takes each
#: (stage None: any stage; its method checks the stage and turn itself, after the sender). Any other
#: (stage, message, turn) is stale: refused (`StaleTurn`), changing nothing.
TAKES: dict[tuple[Stage | None, type[Message], When], str] = {
    (None, Target, When.ANY): "_target",  # the GCS's targets: WrongSender before StaleTurn
    (None, Upd, When.ANY): "_upd",  # the environment's report of a recent ENV phase
    (Stage.GCS, Done, When.NOW): "_gcs_done",  # the GCS phase's end
    (Stage.GCS, Done, When.AHEAD): "_hold",  # a DONE for a coming GCS phase, held for it
    (Stage.DRONES, Done, When.AHEAD): "_hold",
    (Stage.DRONES, Done, When.NOW): "_done_again",  # the GCS phase's DONE again (the station repeats it)
    (Stage.GCS, Moves, When.NOW): "_hold_moves",  # a swarm host's MOVES before its phase opened, held for it
    (Stage.DRONES, Nps, When.NOW): "_nps",  # a drone's move
    (Stage.DRONES, Moves, When.NOW): "_moves_of_host",  # a swarm host's moves
}
