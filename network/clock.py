"""The turn an entity believes the game is at (`TurnClock`), pure: what it lets through of the coordinator's TURN,
STATUS and OVER. `network.membership` screens every entity's inbox with it."""

from __future__ import annotations

from schema import Message, Over, Status, Turn
from schema.errors import StaleTurn


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
    later turn is current too."""

    def __init__(self, turn: int | None = None, *, game: str = "", skips_status: bool = False) -> None:
        self.turn: int | None = turn or None  # the turn being played (after STATUS(t): t + 1, the next)
        self.game, self.skips_status = game, skips_status
        self._seen: dict[tuple[str, object, int], Message] = {}

    def admit(self, msg: Turn | Status | Over) -> None:
        """Check `msg` against the clock (StaleTurn if it cannot be current) and advance the clock."""
        if msg.game != self.game:
            raise StaleTurn(f"a {msg.TAG} of game {msg.game or '(none)'}, not this one ({self.game or '(none)'})",
                            reason="foreign-game")
        now = msg.turn + 1 if isinstance(msg, Status) else msg.turn
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
