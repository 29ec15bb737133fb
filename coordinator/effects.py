"""The effects the turn engine returns (coordinator/engine.py) for its adapter to carry out: publish a message,
answer a CONNECT, write a journal record, or count a `Refusal` (an input that could not be accepted, which changed
nothing). And their order: the next turn's drones' phase first (`drones_first`)."""

from __future__ import annotations

from dataclasses import dataclass

from schema import Message, Phase, Turn
from schema.errors import Refusal


@dataclass(frozen=True, slots=True)
class Publish:
    msg: Message


@dataclass(frozen=True, slots=True)
class ReplyToConnect:
    token: object
    msg: Message


@dataclass(frozen=True, slots=True)
class Record:
    data: dict  # one journal record (a JSON-able dict, written as one line)


Effect = Publish | ReplyToConnect | Record | Refusal


def opens_drones_phase(effect: Effect) -> bool:
    return isinstance(effect, Publish) and isinstance(effect.msg, Turn) and effect.msg.phase is Phase.DRONES


def drones_first(effects: list[Effect]) -> list[Effect]:
    """The next turn's drones' phase first (when the next turn's GCS phase was answered ahead): it is what
    the next turn waits for. The rest keeps its order (the ENV phase, STATUS, the GCS phase it informs)."""
    return sorted(effects, key=lambda e: not opens_drones_phase(e))  # stable: only the drones' phase moves
