"""Key expressions: the only module that builds or parses them.

Keys follow the design card, ``<root>/<ENTITY>/<ACTION>``: the entity is the one the key is
about (``sim/D01/NPS`` is D01's new position, ``sim/D01/TGT`` is D01's target, which only the
GCS may write). `KEY_TABLE` says, for each key, its message type and which role may write it;
the access-control rules and schema/README.md are generated from it.
"""

from __future__ import annotations

import dataclasses
import re
import typing

from . import messages as m
from .tables import MAX_DRONE, Table

_ROOT = re.compile(r"[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*\Z")


@dataclasses.dataclass(frozen=True, slots=True)
class KeySpec:
    """One row of the key table."""

    template: str  # relative to the root; ``{drone}`` / ``{entity}`` are placeholders
    how: str  # "put", "query" (declared as a queryable by the owner), or "liveliness"
    message: type[m.Message] | None  # payload type (queries: request type)
    reply: type[m.Message] | tuple[type[m.Message], ...] | None
    writer: str  # role (or SRV) allowed to put / declare it
    readers: str
    doc: str


KEY_TABLE: tuple[KeySpec, ...] = (
    KeySpec("SRV/CONNECT", "query", m.Connect, (m.Welcome, m.Refused), "SRV", "ENV, GCS, drones",
            "admission: `X:SRV:CONNECT` -> \"You are connected as X\" or a refusal"),
    KeySpec("SRV/TURN/{phase}", "put", m.Turn, None, "SRV", "GCS, drones, ENV",
            "phase GCS, DRONES (orders) or ENV (moves) of turn t begins; each entity hears only its own"),
    KeySpec("SRV/OVER", "put", m.Over, None, "SRV", "all", "`SRV:X:OVER`: the game has ended"),
    KeySpec("OBS/STATUS", "put", m.Status, None, "SRV", "all", "every drone's state at the end of the turn"),
    KeySpec("{drone}/TGT", "put", m.Target, None, "GCS", "SRV",
            "`GCS:D01:TGT:x:y:z`, relayed to the drone in its order"),
    KeySpec("GCS/DONE", "put", m.Done, None, "GCS", "SRV", "`GCS:SRV:DONE`: the GCS phase is over"),
    KeySpec("ENV/ASK", "query", m.Ask, m.Ans, "ENV", "drones", "`D01:ENV:ASK:x:y:z` -> `ENV:D01:ANS:content`"),
    KeySpec("ENV/MAP", "query", m.MapRequest, m.WorldMap, "ENV", "GCS, drones",
            "the static world, for drawing (a ground station) or sensing without a round trip (a drone process)"),
    KeySpec("{drone}/NPS", "put", m.Nps, None, "DRONE", "SRV", "`D01:ENV:NPS:x:y:z`: the drone's move"),
    KeySpec("{entity}/MOVES", "put", m.Moves, None, "DRONE", "SRV",
            "a swarm host's NPS for all its drones at once (the entity is the host)"),
    KeySpec("ENV/UPD", "put", m.Upd, None, "ENV", "SRV", "`ENV:OBS:UPD:x:y:z:content`, all changed cells at once"),
    KeySpec("{entity}/ALIVE/{session}", "liveliness", None, None, "each entity", "SRV, entities",
            "presence token of a process (one per Zenoh session, so an impostor cannot mask a death)"),
)


#: Bytes of a payload beyond its tables and its cells: the header and the other fields, with room to spare.
ENVELOPE = 1024
#: Bytes one cell may take in MessagePack (an array of three integers of up to 5 bytes each).
CELL_BYTES = 16
#: Bytes one drone id may take in MessagePack (a string of up to 6 ASCII characters, D65535, and its header).
ID_BYTES = 7


def size_limit(message: type[m.Message]) -> int:
    """The most bytes a valid `message` can take on the wire: its tables at `MAX_DRONE` rows, an ASK's
    `MAX_ASKED` cells, a UPD's cells (two per drone) and drone ids, an ANS's kinds and drones, a CONNECT's
    drone ids (a swarm host's, up to `MAX_DRONE` canonical ones), plus
    `ENVELOPE`; a world's map (MAP, WELCOME) is bounded by `MAX_PAYLOAD` alone. Every receiver refuses a
    bigger payload before reading it, and the secured router's `low_pass_filter` (schema/acl.py) drops it
    on the way."""
    if message in (m.WorldMap, m.Welcome):
        return m.MAX_PAYLOAD
    size = ENVELOPE
    for hint in typing.get_type_hints(message).values():
        if isinstance(hint, type) and issubclass(hint, Table):
            size += hint.DTYPE.itemsize * MAX_DRONE
    if message is m.Ask:
        size += CELL_BYTES * m.MAX_ASKED
    elif message is m.Ans:
        size += m.MAX_ASKED + MAX_DRONE * 12
    elif message is m.Upd:
        size += 2 * MAX_DRONE * (CELL_BYTES + 3) + MAX_DRONE * ID_BYTES
    elif message is m.Connect:
        size += MAX_DRONE * ID_BYTES
    return size


class Keys:
    """Concrete key expressions under one root (several simulations can share one router)."""

    __slots__ = ("root",)

    def __init__(self, root: str = "sim") -> None:
        if not _ROOT.match(root):
            raise ValueError(f"bad key root {root!r}: use letters, digits, '_', '-' and '/'")
        self.root = root

    def _k(self, *parts: str) -> str:
        return "/".join((self.root, *parts))

    # fixed keys
    @property
    def connect(self) -> str: return self._k("SRV", "CONNECT")
    @property
    def turn(self) -> str: return self._k("SRV", "TURN", "*")  # every phase (viewers)
    def turn_of(self, phase: m.Phase) -> str: return self._k("SRV", "TURN", phase.value)
    @property
    def over(self) -> str: return self._k("SRV", "OVER")
    @property
    def status(self) -> str: return self._k("OBS", "STATUS")
    @property
    def gcs_done(self) -> str: return self._k("GCS", "DONE")
    @property
    def ask(self) -> str: return self._k("ENV", "ASK")
    @property
    def map(self) -> str: return self._k("ENV", "MAP")
    @property
    def upd(self) -> str: return self._k("ENV", "UPD")

    # per-drone keys and their wildcards
    def tgt(self, drone: str) -> str: return self._k(drone, "TGT")
    def nps(self, drone: str) -> str: return self._k(drone, "NPS")
    def moves(self, host: str) -> str: return self._k(host, "MOVES")
    @property
    def any_moves(self) -> str: return self._k("*", "MOVES")
    @property
    def any_tgt(self) -> str: return self._k("*", "TGT")
    @property
    def any_nps(self) -> str: return self._k("*", "NPS")

    # presence: one liveliness token per process, <root>/<ENTITY>/ALIVE/<session id>
    def alive(self, entity: str, session: str) -> str: return self._k(entity, "ALIVE", session)
    @property
    def any_alive(self) -> str: return self._k("*", "ALIVE", "*")
    def alive_of(self, entity: str) -> str: return self._k(entity, "ALIVE", "*")

    def presence_of(self, key: str) -> tuple[str, str]:
        """(entity, session) of a presence token's key."""
        prefix = self.root + "/"
        parts = key[len(prefix):].split("/") if key.startswith(prefix) else []
        if len(parts) != 3 or parts[1] != "ALIVE":
            raise ValueError(f"{key!r} is not <root>/<ENTITY>/ALIVE/<session>")
        return parts[0], parts[2]

    def origin_of(self, key: str) -> str:
        """Who writes a put key, by the key table: its writer role (SRV also for OBS/STATUS, the GCS for a
        drone's TGT), or the key's entity for keys each drone or host writes (NPS, MOVES). ValueError if
        the key is not one of ours."""
        entity, action = self.parts_of(key)[:2]
        writer = _WRITERS.get(action)
        return entity if writer is None else writer

    def entity_of(self, key: str) -> str:
        """The ENTITY part of ``<root>/<ENTITY>/<ACTION>[/<PHASE>]`` (ValueError if not under root)."""
        return self.parts_of(key)[0]

    def parts_of(self, key: str) -> list[str]:
        """``[ENTITY, ACTION]`` or ``[ENTITY, ACTION, PHASE]`` of a key (ValueError if not one of ours)."""
        prefix = self.root + "/"
        if not key.startswith(prefix):
            raise ValueError(f"{key!r} is not under {self.root!r}")
        parts = key[len(prefix):].split("/")
        if not (len(parts) == 2 or (len(parts) == 3 and parts[1] == "TURN")):
            raise ValueError(f"{key!r} is not <root>/<ENTITY>/<ACTION> (or <root>/SRV/TURN/<PHASE>)")
        return parts


#: The writer of each put key's action (None: the key's entity, a drone or a host), from `KEY_TABLE`.
_WRITERS: dict[str, str | None] = {
    spec.template.split("/")[1]: None if spec.writer == "DRONE" else spec.writer
    for spec in KEY_TABLE if spec.how == "put"
}
