"""Goals from ROS 2, pure: a ``geometry_msgs/msg/PoseStamped`` on ``/<namespace>/<Dnn>/goal_pose`` (what RViz's
goal tool sends) becomes that drone's target, or is refused with a reason and counted (nothing else changes)."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

from schema import Cell, UsageError
from schema.errors import excerpt
from world.grid import World

from ..gcs import check_cell
from .cdr import deserialize
from .model import FRAME, POSE


def reason(err: UsageError) -> str:
    """The reason of a goal's refusal: its text up to the first colon ("outside the world", "malformed", ...)."""
    return str(err).split(":", 1)[0]


@dataclass(frozen=True, slots=True)
class Goal:
    """A goal's payload as it came, on the topic of `drone` (posted by a Zenoh callback)."""

    drone: str
    payload: bytes


@dataclass(slots=True)
class Goals:
    """Reads goals for the drones of `world` (a cell is `cell_size` metres; ``map`` is the only frame)."""

    world: World
    drones: frozenset[str]
    cell_size: float = 1.0
    refused: Counter = field(default_factory=Counter)  # reason -> count
    taken: int = 0

    def read(self, goal: Goal) -> tuple[str, Cell]:
        """(drone, cell) of a goal; UsageError (its reason counted in `refused`, its text an excerpt: a goal's frame
        or numbers may be long) if it cannot be one."""
        try:
            cell = self._cell(goal)
        except UsageError as err:
            self.refused[reason(err)] += 1
            raise UsageError(excerpt(str(err))) from None
        self.taken += 1
        return goal.drone, cell

    def refuse(self, err: UsageError) -> None:
        """A goal read well, then refused by the ground station (its drone gone, the game over): counted so."""
        self.taken -= 1
        self.refused[reason(err)] += 1

    def _cell(self, goal: Goal) -> Cell:
        if goal.drone not in self.drones:
            raise UsageError(f"unknown drone: {goal.drone} is not in this game")
        try:
            msg = deserialize(goal.payload, POSE)
            frame = msg.header.frame_id
            p = msg.pose.position
            xyz = (float(p.x), float(p.y), float(p.z))
        except Exception as exc:  # rosbags raises what its reader meets: any of them means malformed
            raise UsageError(f"malformed: not a {POSE} ({type(exc).__name__})") from None
        if frame != FRAME:
            raise UsageError(f"other frame: {frame!r}, goals are in {FRAME!r}")
        if not all(map(math.isfinite, xyz)):
            raise UsageError(f"not finite: {xyz}")
        scaled = [v / self.cell_size for v in xyz]
        if not all(map(math.isfinite, scaled)):  # (finite metres, but beyond a float in cells: far outside)
            raise UsageError(f"outside the world: {xyz} m is beyond any cell of {self.cell_size} m")
        cell = tuple(round(v) for v in scaled)
        try:
            return check_cell((cell[0], cell[1], cell[2]), self.world.size, self.world)
        except UsageError as err:
            kind = "in a building" if "building" in str(err) else "outside the world"
            raise UsageError(f"{kind}: {err}") from None
