"""Lifelong targets, pure: a drone that reaches its target is given a new one (the lifelong MAPF of the League of
Robot Runners, whose measure is the tasks done per turn; `dronesim up --lifelong`, a scenario's ``"lifelong"``).

The ground station (`entities.gcs.Station`) and the in-process game (`dronesim.local`) draw them alike, in the GCS
phase of turn t, from the STATUS of turn t - 1: every alive drone on its target (REACHED) or without one gets a
new target, a free cell of its own cell's component of the static world (so that a way always exists), neither
its cell nor a target in force, drawn uniformly from a numpy Generator seeded with (seed, t). A draw is a
function of the seed, the turn and that STATUS alone: a station that joins or comes back draws what the one
before it would have; the journal records every target given, so `dronesim replay --verify` and `--resume`
need no seed.
"""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

from schema import Cell, Note, Status
from schema.tables import code_of, drone_name, drone_number
from world.grid import Regions, World, linear_rows, pick_cell

_REACHED = code_of(Note.REACHED)


class Tasks:
    """The lifelong targets of a game in `world`, drawn with `seed` (`assign`)."""

    def __init__(self, world: World, seed: int) -> None:
        self.world, self.seed = world, seed
        self.regions = Regions(world)

    def assign(self, turn: int, status: Status, given: Collection[str] = ()) -> dict[str, Cell]:
        """The new targets of the GCS phase of `turn`, given `status` (the STATUS of turn - 1): drone id -> cell,
        for every alive drone on its target or without one, but those `given` a target by someone else in this
        phase (a plan's); a drone whose component has no cell left keeps its target."""
        table = status.drones
        rows = table.rows
        target = rows["target"].astype(np.int64)
        alive = table.alive_mask()
        due = alive & ((target[:, 0] < 0) | (rows["note"] == _REACHED))
        if given:
            due &= ~np.isin(table.numbers, [drone_number(d) for d in given])
        if not np.count_nonzero(due):
            return {}
        size = self.world.size
        taken = np.zeros(self.world.grid.size, bool)
        aimed = alive & (target[:, 0] >= 0)
        taken[linear_rows(target[aimed], size)] = True  # the targets in force (a drone due gives its own up below)
        due_rows = np.flatnonzero(due)
        due_rows = due_rows[np.argsort(table.numbers[due_rows], kind="stable")]  # (drawn in drone number order)
        pos = rows["pos"][due_rows].astype(np.int64)
        here = linear_rows(pos, size)
        comps = self.regions.labels(here, pos)
        rng = np.random.default_rng((self.seed, turn))
        out: dict[str, Cell] = {}
        for n, cell, comp in zip(table.numbers[due_rows].tolist(), here.tolist(), comps.tolist()):
            if comp < 0:  # (a drone inside a building: it is dying)
                continue
            own = taken[cell]
            taken[cell] = True
            lin = pick_cell(rng, self.regions.members(comp), taken)
            taken[cell] = own
            if lin >= 0:
                taken[lin] = True
                x, rest = divmod(lin, size[1] * size[2])
                y, z = divmod(rest, size[2])
                out[drone_name(n)] = (x, y, z)
        return out
