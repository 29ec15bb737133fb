"""An entity's turn clock (`network.clock.TurnClock`): what it lets through of the coordinator's messages."""

from __future__ import annotations

import pytest

from network.clock import TurnClock
from schema import EndReason, Over, Phase, StaleTurn, Status, StatusTable, Turn

GAME = "9f2c4e1a7b3d5f60"


@pytest.mark.parametrize("msg", [
    Over(turn=0, sender="SRV", reason=EndReason.ABORTED),  # replayed from a game without identity
    Over(turn=3, sender="SRV", reason=EndReason.ABORTED, game="0badc0de"),  # another game's
    Turn(turn=3, sender="SRV", phase=Phase.DRONES, game="0badc0de"),
    Status(turn=2, sender="OBS", drones=StatusTable.of([]), game="0badc0de"),
])
def test_a_message_of_another_game_is_foreign_whatever_its_turn(msg) -> None:
    for clock in (TurnClock(game=GAME), TurnClock(3, game=GAME)):  # before its first message, and during
        with pytest.raises(StaleTurn, match="not this one") as err:
            clock.admit(msg)
        assert err.value.reason == "foreign-game"
        assert clock.turn in (None, 3), "the clock did not move"


def test_the_games_own_messages_pass() -> None:
    clock = TurnClock(game=GAME)
    clock.admit(Status(turn=2, sender="OBS", drones=StatusTable.of([]), game=GAME))
    clock.admit(Turn(turn=3, sender="SRV", phase=Phase.GCS, game=GAME))
    clock.admit(Over(turn=3, sender="SRV", reason=EndReason.ALL_REACHED, game=GAME))
    assert clock.turn == 3


def test_a_clock_that_skips_status_takes_a_later_one_but_never_an_earlier_one() -> None:
    """The environment reads only the newest STATUS, when it needs one: it may be many turns on."""
    status = lambda turn: Status(turn=turn, sender="OBS", drones=StatusTable.of([]), game=GAME)  # noqa: E731
    strict, skipping = TurnClock(3, game=GAME), TurnClock(3, game=GAME, skips_status=True)
    with pytest.raises(StaleTurn, match="while the game is at turn 3"):
        strict.admit(status(9))
    skipping.admit(status(9))
    assert skipping.turn == 10
    for clock, turn in ((strict, 3), (skipping, 10)):
        with pytest.raises(StaleTurn):
            clock.admit(status(turn - 3))
        with pytest.raises(StaleTurn):
            clock.admit(Turn(turn=turn + 5, sender="SRV", phase=Phase.GCS, game=GAME))
