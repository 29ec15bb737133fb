"""Key expressions: the only module that builds or parses them.

`KEY_TABLE` gives each key (``<root>/<ENTITY>/<ACTION>``, the design card's form: README.md) its message type,
writer role and readers; the access-control rules and README.md are generated from it.
"""

from __future__ import annotations

import dataclasses
import re
import typing

from . import messages as m
from .tables import MAX_DRONE, Table

_ROOT = re.compile(r"[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*\Z")
#: The key root of a simulation that names none (`--root`): every key is under it.
ROOT = "sim"


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


#: Bytes a payload may take beyond its tables and `ENVELOPE`: an ASK's `MAX_ASKED` cells, an ANS's kinds and
#: drones, a UPD's cells (two per drone) and drone ids, a CONNECT's drone ids (a swarm host's, up to `MAX_DRONE`).
_BEYOND: dict[type[m.Message], int] = {
    m.Ask: CELL_BYTES * m.MAX_ASKED, m.Ans: m.MAX_ASKED + MAX_DRONE * 12,
    m.Upd: 2 * MAX_DRONE * (CELL_BYTES + 3) + MAX_DRONE * ID_BYTES, m.Connect: MAX_DRONE * ID_BYTES,
}


def size_limit(message: type[m.Message]) -> int:
    """The most bytes a valid `message` can take on the wire: its tables at `MAX_DRONE` rows, plus `_BEYOND`
    and `ENVELOPE`; a world's map (MAP, WELCOME) is bounded by `MAX_PAYLOAD` alone. Every receiver refuses a
    bigger payload before reading it, and the secured router's `low_pass_filter` (schema/acl.py) drops it
    on the way."""
    if message in (m.WorldMap, m.Welcome):
        return m.MAX_PAYLOAD
    tables = [h for h in typing.get_type_hints(message).values() if isinstance(h, type) and issubclass(h, Table)]
    return ENVELOPE + _BEYOND.get(message, 0) + sum(h.DTYPE.itemsize * MAX_DRONE for h in tables)


class Keys:
    """Concrete key expressions under one root (several simulations can share one router)."""

    def __init__(self, root: str = ROOT) -> None:
        if not _ROOT.match(root):
            raise ValueError(f"bad key root {root!r}: use letters, digits, '_', '-' and '/'")
        self.root = root
        # fixed keys
        self.connect = self._k("SRV", "CONNECT")
        self.turn = self._k("SRV", "TURN", "*")  # every phase (viewers)
        self.over = self._k("SRV", "OVER")
        self.status = self._k("OBS", "STATUS")
        self.gcs_done = self._k("GCS", "DONE")
        self.ask = self._k("ENV", "ASK")
        self.map = self._k("ENV", "MAP")
        self.upd = self._k("ENV", "UPD")
        # wildcards of the per-drone and per-host keys, and of the presence tokens
        self.any_moves = self._k("*", "MOVES")
        self.any_tgt = self._k("*", "TGT")
        self.any_nps = self._k("*", "NPS")
        self.any_alive = self._k("*", "ALIVE", "*")

    def _k(self, *parts: str) -> str:
        return "/".join((self.root, *parts))

    def turn_of(self, phase: m.Phase) -> str: return self._k("SRV", "TURN", phase.value)
    def tgt(self, drone: str) -> str: return self._k(drone, "TGT")
    def nps(self, drone: str) -> str: return self._k(drone, "NPS")
    def moves(self, host: str) -> str: return self._k(host, "MOVES")

    # presence: one liveliness token per process, <root>/<ENTITY>/ALIVE/<session id>
    def alive(self, entity: str, session: str) -> str: return self._k(entity, "ALIVE", session)
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
        return _WRITERS.get(action) or entity

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


class RosKeys:
    """The key expressions of ROS 2's Zenoh middleware (rmw_zenoh, ROS 2 Jazzy and newer) for one domain:
    a topic's data key ``<domain>/<topic>/<DDS type name>/<RIHS01 hash>`` and the liveliness tokens under
    ``@ros2_lv/<domain>/<zenoh id>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>[/...]`` that
    make a node (``NN``), its publishers (``MP``) and subscriptions (``MS``) appear in ROS 2's graph (a name's
    ``/`` is ``%`` there; an empty enclave or namespace is ``%``)."""

    ADMIN = "@ros2_lv"
    NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"

    def __init__(self, domain: int = 0) -> None:
        if not (isinstance(domain, int) and 0 <= domain <= 232):
            raise ValueError(f"bad ROS domain id {domain!r}: 0..232")
        self.domain = domain

    @staticmethod
    def dds_type(typename: str) -> str:
        """``geometry_msgs/msg/PoseStamped`` -> ``geometry_msgs::msg::dds_::PoseStamped_``."""
        package, kind, name = typename.split("/")
        return f"{package}::{kind}::dds_::{name}_"

    @staticmethod
    def mangle(name: str) -> str:
        return name.replace("/", "%") or "%"

    def topic(self, topic: str, typename: str, type_hash: str) -> str:
        return f"{self.domain}/{topic.strip('/')}/{self.dds_type(typename)}/{type_hash}"

    def node_token(self, zid: str, node_id: int, namespace: str, node: str) -> str:
        return f"{self.ADMIN}/{self.domain}/{zid}/{node_id}/{node_id}/{self.NODE}/%/{self.mangle(namespace)}/{node}"

    def node_tokens(self, node: str) -> str:
        """The pattern of the node tokens named `node` on this domain, from any process."""
        return f"{self.ADMIN}/{self.domain}/*/*/*/{self.NODE}/%/*/{node}"

    def endpoint_token(self, zid: str, node_id: int, entity_id: int, kind: str, namespace: str, node: str,
                       topic: str, typename: str, type_hash: str, qos: str) -> str:
        return (f"{self.ADMIN}/{self.domain}/{zid}/{node_id}/{entity_id}/{kind}/%/{self.mangle(namespace)}/{node}/"
                f"{self.mangle(topic)}/{self.dds_type(typename)}/{type_hash}/{qos}")
