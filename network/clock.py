"""The turn an entity believes the game is at (`TurnClock`), pure: what it lets through of the coordinator's TURN,
STATUS and OVER. `network.membership` screens every entity's inbox with it."""

from __future__ import annotations

from schema import Message, Over, Status, Turn
from schema.errors import StaleTurn
from schema.tuning import TURNS_PER_S_MAX


class TurnClock:
    """The turn an entity believes the game is at, learnt from the coordinator's TURN, STATUS and OVER.

    Once it has seen one, it refuses those messages when they cannot be current (a replayed or garbled TURN
    must not make a drone plan, nor a STATUS move the world): a TURN for a past turn or one more than a turn
    ahead, a STATUS for other than the turn just played (or a repeat of the one before), an OVER far from now,
    or a repeat (same message, phase and turn) that differs from the first (a repeat re-sent to a process that
    connected again is identical and passes). TURN(t) and STATUS(t - 1) are current while turn t is played; so
    are OVER(t - 1) after STATUS(t - 1) and OVER of any later turn (a frozen process learns the end late). Each
    must be of this entity's `game` (from its WELCOME): another game's, or an earlier coordinator's, is foreign,
    whatever its turn. (A forged message for the right turn is spoofing: the router's access control stops it.)
    With `skips_status` (the environment, which reads only the newest STATUS, when it needs one), a STATUS of any
    later turn is current too. Given the time (`now`, seconds), nothing is current that is further ahead than a game
    can have gone (`TURNS_PER_S_MAX`) since the clock's anchor: the coordinator was at turn `known` at most when
    the entity asked to join (`now` at construction: when its CONNECT left, which the WELCOME naming `known`
    answered). One absurd message cannot wedge it. (The anchor stays: when a message is read says nothing of when
    it was sent -- a busy or descheduled process reads a burst of turns at once -- so a clock that moved its anchor
    to each message's reading refused genuine turns.)"""

    def __init__(self, turn: int | None = None, *, game: str = "", skips_status: bool = False,
                 now: float | None = None, known: int = 0) -> None:
        self.turn: int | None = turn or None  # the turn being played (after STATUS(t): t + 1, the next)
        self.game, self.skips_status = game, skips_status
        self._seen: dict[tuple[str, object, int], Message] = {}
        # (a turn the coordinator was at most at a time: the WELCOME's, when the CONNECT left), for `now`'s bound
        self._anchor = (max(turn or 0, known), now)

    def admit(self, msg: Turn | Status | Over, now: float | None = None) -> None:
        """Check `msg` against the clock (StaleTurn if it cannot be current) and advance the clock."""
        if msg.game != self.game:
            raise StaleTurn(f"a {msg.TAG} of game {msg.game or '(none)'}, not this one ({self.game or '(none)'})",
                            reason="foreign-game")
        turn = msg.turn + 1 if isinstance(msg, Status) else msg.turn
        known, since = self._anchor
        if now is not None and since is not None and turn > known + 1 + TURNS_PER_S_MAX * max(0.0, now - since):
            raise StaleTurn(f"{msg.TAG} for turn {msg.turn}: no game gets there from turn {known} in "
                            f"{max(0.0, now - since):.1f} s", reason="future-turn")
        self._advance(msg, turn)

    def _advance(self, msg: Turn | Status | Over, now: int) -> None:
        if self.turn is not None:  # (STATUS(t) makes t + 1 "now"; the end may come at any turn)
            lo, hi = (self.turn - 1, float("inf")) if isinstance(msg, Over) else (self.turn, self.turn + 1)
            if self.skips_status and isinstance(msg, Status):
                hi = float("inf")
            if not lo <= now <= hi:
                raise StaleTurn(f"{msg.TAG} for turn {msg.turn} while the game is at turn {self.turn}")
        key = (msg.TAG, getattr(msg, "phase", None), msg.turn)
        if self._seen.get(key, msg) != msg:
            raise StaleTurn(f"a {msg.TAG} for turn {msg.turn} that contradicts the one received before",
                            reason="contradiction")
        self._seen = {k: m for k, m in self._seen.items() if k[2] >= now - 1}  # keep this turn and the last
        self._seen[key] = msg
        self.turn = now if self.turn is None else max(self.turn, now)
