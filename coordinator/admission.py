"""Admission: who may join the game (`Roster`), who is there, and the presence a CONNECT must show first
(`Presences`). Pure, like the engine: no network and no clock of its own (the time is passed in).
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Iterable, Sequence
from typing import Generic, TypeVar

from schema import Connect, Role
from schema.errors import RemoteInputError
from schema.messages import drone_id, is_host_id
from schema.tables import drone_number
from schema.tuning import CONNECT_WAITING, CONNECT_WAITING_PER_SENDER, PRESENCE_WAIT_S

from .fleet import ALIVE, STATES, Fleet

Q = TypeVar("Q")  # what a CONNECT is answered through (a Zenoh query in the adapter)


def _due(waiting: tuple[float, object, Connect]) -> float:
    """A waiting CONNECT's deadline."""
    return waiting[0]


class Roster:
    """The admitted entities: id -> role, and the Zenoh session each was admitted with."""

    def __init__(self) -> None:
        self.roles: dict[str, Role] = {}
        self.sessions: dict[str, str] = {}

    def has(self, role: Role) -> bool:
        return role in self.roles.values()

    def refusal(self, msg: Connect, fleet: Fleet, *, over: bool, admitting: bool) -> str:
        """Why `msg` cannot be admitted ("" if it can). `admitting`: the game has not started (or is being
        resumed), so drones may still join."""
        if over:
            return "the game is over"
        if msg.sender in self.roles:
            if msg.session and self.sessions.get(msg.sender) == msg.session and self.roles[msg.sender] is msg.role:
                return ""  # the same process again (e.g. after a cut link): welcome it back
            return f"{msg.sender} is already connected"
        if msg.role is not Role.DRONE:  # the environment or the ground station
            return "" if msg.sender == msg.role.value else \
                f"the {msg.role.value} must connect as {msg.role.value}, not {msg.sender}"
        if not is_host_id(msg.sender) and msg.drones != (msg.sender,):
            return (f"{msg.sender} cannot connect for {', '.join(msg.drones)}: a drone flies itself, "
                    "a swarm host connects as Hnn")
        if not admitting:  # (a LOST drone that comes back included: it stays LOST)
            ended = [f"{d} is {STATES[fleet.state[fleet.index[d]]].value}" for d in msg.drones
                     if d in fleet.index and fleet.state[fleet.index[d]] != ALIVE]
            return f"{', '.join(ended)}: drones cannot join a running game" if ended else \
                "drones cannot join a running game"
        for d in msg.drones:
            if d not in fleet.index:
                return f"unknown drone {d}: this game flies {', '.join(fleet.ids)}"
            if (host := fleet.host[fleet.index[d]]) is not None:
                return f"drone {d} is already taken by {host}"
        return ""

    def claimed(self, msg: Connect, fleet: Fleet) -> bool:
        """Whether `msg` (refused) claims a drone id another process already holds: what each drone replica that
        tries ids in turn meets on a normal start (docker/entrypoint.py), expected, not a fault."""
        return msg.role is Role.DRONE and (msg.sender in self.roles or any(
            d in fleet.index and fleet.host[fleet.index[d]] not in (None, msg.sender) for d in msg.drones))

    def admit(self, msg: Connect) -> bool:
        """Admit `msg`'s sender (checked by `refusal`); True if it was admitted already (the same process
        connecting again)."""
        again = msg.sender in self.roles
        self.enter(msg.sender, msg.role, msg.session)
        return again

    def enter(self, entity: str, role: Role, session: str = "") -> None:
        """`entity` is there as `role` (admitted, or in the engine's process: `Engine.start_here`)."""
        self.roles[entity], self.sessions[entity] = role, session

    def leave(self, entity: str, session: str = "") -> Role | None:
        """`entity`'s presence went away: its role, if that was the admitted process's own (`session`; ""
        stands for any), else None and nothing changes (a refused impostor's token does not count)."""
        if entity not in self.roles or (session and self.sessions.get(entity) not in ("", session)):
            return None
        self.sessions.pop(entity, None)
        return self.roles.pop(entity)

    def missing(self, fleet: Fleet, rows: Sequence[int] | None = None) -> list[str]:
        """Who is not there: the drones (of `rows`, or all) nobody flies, then the environment and the GCS."""
        return ([fleet.ids[i] for i in (range(len(fleet)) if rows is None else rows) if fleet.host[i] is None]
                + [r.value for r in (Role.ENV, Role.GCS) if not self.has(r)])


class Presences(Generic[Q]):
    """The presence tokens seen, and the CONNECTs waiting for theirs. A CONNECT names its sender and session;
    it is admitted only once the presence token of that same (sender, session) is seen. Under the router's
    access control only the real principal may declare that token, so a process cannot take another's seat
    by writing its name in a CONNECT (the coordinator cannot see who sent a query). The token may arrive just
    after the query (another path), hence a short wait; a CONNECT without one is refused."""

    def __init__(self, room: int = CONNECT_WAITING, per_sender: int = CONNECT_WAITING_PER_SENDER) -> None:
        self.present: set[tuple[str, str]] = set()
        self._waiting: list[tuple[float, Q, Connect]] = []  # in order of their deadlines (`due_in`, `expired`: the
        # coordinator's loop asks for each event it takes; up to `room` wait under a flood of CONNECTs)
        self.room, self.per_sender = room, per_sender  # CONNECTs waiting at most, in all and naming one sender

    def connect(self, query: Q, msg: Connect, now: float) -> list[tuple[Q, Connect]]:
        """A CONNECT: ready at once if its token is there, else it waits (up to PRESENCE_WAIT_S); a `flood`
        RemoteInputError if `room` CONNECTs wait already, or `per_sender` naming its sender (it is refused: a
        flood with invented sessions holds no memory, and the real process asks again)."""
        if (msg.sender, msg.session) in self.present:
            return [(query, msg)]
        if len(self._waiting) >= self.room:
            raise RemoteInputError(f"{len(self._waiting)} CONNECTs already wait for their presence token",
                                   reason="flood")
        if sum(w[2].sender == msg.sender for w in self._waiting) >= self.per_sender:
            raise RemoteInputError(f"{self.per_sender} CONNECTs from {msg.sender} already wait for their presence "
                                   "token", reason="flood")
        bisect.insort(self._waiting, (now + PRESENCE_WAIT_S, query, msg), key=_due)
        return []

    def waiting(self) -> int:
        """CONNECTs waiting for their token."""
        return len(self._waiting)

    def presence(self, entity: str, session: str, alive: bool) -> list[tuple[Q, Connect]]:
        """A token came or went: the CONNECTs it makes ready."""
        if not alive:
            self.present.discard((entity, session))
            return []
        self.present.add((entity, session))
        ready = [(q, m) for _, q, m in self._waiting if (m.sender, m.session) == (entity, session)]
        self._waiting = [w for w in self._waiting if (w[2].sender, w[2].session) != (entity, session)]
        return ready

    def due_in(self, now: float) -> float | None:
        """Seconds until the first waiting CONNECT expires (None: none waits)."""
        return max(0.0, self._waiting[0][0] - now) if self._waiting else None

    def expired(self, now: float) -> list[tuple[Q, Connect]]:
        """The CONNECTs whose token did not come in time (to be refused)."""
        if not self._waiting or self._waiting[0][0] > now:
            return []
        cut = bisect.bisect_right(self._waiting, now, key=_due)
        gone = [(q, m) for _, q, m in self._waiting[:cut]]
        del self._waiting[:cut]
        return gone

    def others(self) -> set[str]:
        """The entities with a token, but the coordinator."""
        return {e for e, _ in self.present} - {"SRV"}


def id_ranges(drones: Iterable[str]) -> str:
    """Drone ids as runs of consecutive numbers, as `dronesim drone --id` reads them: "D01-D03, D07"."""
    runs = itertools.groupby(enumerate(sorted(map(drone_number, drones))), lambda item: item[1] - item[0])
    ends = [(run[0][1], run[-1][1]) for run in (list(items) for _, items in runs)]
    return ", ".join(drone_id(a) if a == b else f"{drone_id(a)}-{drone_id(b)}" for a, b in ends)
