"""The seed's smart drone (seed spec, section 4.1.2, tables 4.1-4.4 and Algorithm 1).

Coordinates follow the seed's drawings: row = x, column = y, (0, 0) top-left, so

    NORTH = x - 1,  SOUTH = x + 1,  EAST = y + 1,  WEST = y - 1.

Each turn, from `pos` towards `target`:

1. On the target: stay, ``Note.REACHED``. No target: hover.
2. Align z first. If ``pos.z != target.z`` the drone senses the vertically adjacent cell towards the target (an ASK,
   unless memory already knows it) and moves there if it is empty. If it is blocked (a building roof below, say) the
   seed does not say what to do; the safe reading used here is to take this turn's horizontal step instead (step 3)
   and try the vertical again next turn.
3. 2D on the current floor: ``directionOrder`` is the 4 horizontal directions sorted by Euclidean distance from the
   neighbour to the target's (x, y), ties broken NORTH, SOUTH, EAST, WEST. Directions leading outside the world are
   replaced by the best valid one (the seed's corner example: SOUTH, EAST, SOUTH, SOUTH). Then SMARTMOVE
   (Algorithm 1) over the memory ``cases``:

   * an unknown neighbour is asked about (one ASK round trip per candidate, in order, exactly like the seed's
     iterated question/answer); the answer is appended to memory; if the cell is empty the drone goes there,
     otherwise it tries the next direction;
   * a known empty neighbour has priority = its index in ``cases``, a known non-empty one MAX_INDEX;
   * when no unknown empty neighbour exists, the drone goes to the known empty neighbour with the smallest index
     (the first in ``cases``): that is how it backs out of a dead end;
   * nothing at all (boxed in, which the seed assumes never happens): hover, ``Note.UNREACHABLE``.

"Empty" means the cell is inside the world with no building (``CellKind.EMPTY``); other drones do not make a cell
non-empty (the seed flew a single drone; this pilot does not avoid drones). Memory keeps every cell the drone
learned about, in the order learned; the start cell (any position not yet known, in fact) is stored as visited and
empty when the drone first stands in it. Buildings never move, so what is learned stays true for the whole game,
targets included.

Known limitation, kept on purpose (it is the seed's algorithm): backtracking to "the first cell of the array" is not
complete. Once every neighbour of two adjacent cells is known, each cell's earliest-learned empty neighbour can be
the other one and the drone shuttles between them for ever, never reaching a far unexplored gap (see
`test_seed_livelock_is_faithful`). It never enters a building, though; the game's turn limit ends such a flight.

Round trips: at most `MAX_ASKS` (4) per turn. The seed's sequential questions need up to 4 for the horizontal step
plus 1 for the vertical probe; in that rare case (roof below and the first horizontal candidates unknown and
blocked) the last round trip asks all the remaining unknown candidates at once and the answers are consumed in
directionOrder, exactly as if asked one by one: an answer for a cell after the chosen one is discarded, so memory
and decisions are identical to the one-by-one seed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np

from schema import Cell, CellInfo, CellKind, Note
from schema.tables import code_of
from world.grid import in_bounds

from .base import NO_ANSWER, Decision, Sensing, SwarmBase, SwarmSensing

#: The 4 horizontal directions as (dx, dy), in the seed's tie-break order.
DIRECTIONS: tuple[tuple[str, tuple[int, int]], ...] = (("NORTH", (-1, 0)), ("SOUTH", (1, 0)), ("EAST", (0, 1)),
                                                        ("WEST", (0, -1)))
_RANKED = tuple((rank, dx, dy) for rank, (_, (dx, dy)) in enumerate(DIRECTIONS))


class SeedPilot:
    """The seed's `smart_drone`: z first, then greedy 2D with a memory of learned cells."""

    name: ClassVar[str] = "seed"
    cooperative: ClassVar[bool] = False  # the seed's drone knows nothing of other drones
    senses: ClassVar[bool] = True
    #: Most ASK round trips one turn may take.
    MAX_ASKS: ClassVar[int] = 4

    def __init__(self, *, world_size: Cell) -> None:
        self.world_size: Cell = tuple(world_size)  # type: ignore[assignment]
        self._cases: dict[Cell, tuple[int, bool]] = {}  # the seed's `cases` array: cell -> (index, empty)

    @property
    def memory(self) -> tuple[tuple[Cell, bool], ...]:
        """Every learned cell with its empty flag, in the order learned (the seed's `cases`)."""
        return tuple((cell, empty) for cell, (_, empty) in self._cases.items())

    def _learn(self, cell: Cell, empty: bool) -> None:
        self._cases.setdefault(cell, (len(self._cases), empty))

    def _record(self, cell: Cell, answers: Mapping[Cell, CellInfo]) -> bool:
        """Store the environment's answer about `cell`; True if it is empty. No answer: not empty for this turn, and
        nothing learned."""
        info = answers.get(cell)
        if info is None:
            return False
        self._learn(cell, empty := info.kind is CellKind.EMPTY)
        return empty

    def direction_order(self, pos: Cell, target: Cell) -> tuple[str, ...]:
        """The seed's directionOrder: 4 direction names, best first; invalid directions (leading outside the world)
        replaced by the best valid one. Empty if no direction is valid."""
        return tuple(DIRECTIONS[rank][0] for rank in self._ranks(pos, target))

    def _ranks(self, pos: Cell, target: Cell) -> list[int]:
        """`direction_order` as indices into DIRECTIONS."""
        x, y, z = pos
        valid = sorted(((x + dx - target[0]) ** 2 + (y + dy - target[1]) ** 2, rank) for rank, dx, dy in _RANKED
                       if in_bounds((x + dx, y + dy, z), self.world_size))
        ranks = [rank for _, rank in valid]
        return ranks + ranks[:1] * (len(DIRECTIONS) - len(ranks))

    def step(self, pos: Cell, target: Cell | None) -> Sensing:
        if target is None:
            return Decision(pos=pos)
        self._learn(pos, True)  # standing in it: visited and empty
        if pos == target:
            return Decision(pos=pos, note=Note.REACHED)
        asks = 0

        # 1. Align z with the target.
        if pos[2] != target[2]:
            up = (pos[0], pos[1], pos[2] + (1 if target[2] > pos[2] else -1))
            if in_bounds(up, self.world_size):
                known = self._cases.get(up)
                if known is None:
                    asks = 1
                    empty = self._record(up, (yield (up,)))
                else:
                    empty = known[1]
                if empty:
                    return Decision(pos=up)
            # blocked (or outside): fall back to the horizontal step this turn

        # 2. SMARTMOVE on the current floor.
        order = [(pos[0] + _RANKED[r][1], pos[1] + _RANKED[r][2], pos[2]) for r in self._ranks(pos, target)]
        back: list[tuple[int, Cell]] = []  # the known empty candidates (index in `cases`, cell); others: MAX_INDEX
        pending: Mapping[Cell, CellInfo] = {}  # answers of a batched last round trip
        for i, cell in enumerate(order):
            known = self._cases.get(cell)
            if known is None:  # EMPTYCASE == -1: never learned, ask the environment
                if cell not in pending:
                    if asks >= self.MAX_ASKS:
                        continue  # the last round trip asked it, and got no answer
                    last = asks == self.MAX_ASKS - 1  # the last round trip: every remaining one
                    batch = tuple(dict.fromkeys(c for c in order[i:] if c not in self._cases)) if last else (cell,)
                    answers = yield batch
                    asks += 1
                    pending = {c: answers[c] for c in batch if c in answers}
                if self._record(cell, pending):
                    return Decision(pos=cell)
                continue
            if known[1]:
                back.append((known[0], cell))
        return Decision(pos=min(back)[1]) if back else Decision(pos=pos, note=Note.UNREACHABLE)


_DXY = np.array([(dx, dy) for _, (dx, dy) in DIRECTIONS], dtype=np.int64)
_NONE, _REACHED, _UNREACHABLE = (code_of(n) for n in (Note.NONE, Note.REACHED, Note.UNREACHABLE))
_FAR = np.iinfo(np.int64).max
_RANK = np.arange(4)
_COLUMNS = np.arange(6)


class SeedSwarm(SwarmBase):
    """`SeedPilot` for many drones at once (a swarm host's), over arrays: the same decisions and the same memory, in
    the same order, as one `SeedPilot` per drone (a property test holds the two to it).

    Memory is one dict for the whole swarm: (drone's row × world cells + the cell's grid index) -> the cell's index
    in that drone's ``cases`` × 2 + 1 if empty. A turn looks at six cells per drone at once: where it stands, its
    vertical cell and the 4 of its directionOrder, and takes `SeedPilot.step`'s rules over them as array operations:

    - the vertical cell if it is empty (known so, or told so now);
    - else the first candidate of directionOrder that was unknown and is told empty;
    - else the known empty candidate learned earliest (backing out), else hover, UNREACHABLE.

    A drone learns, in that order, where it stands and the cells it was told up to the one it takes. A
    directionOrder repeats its best cell where a direction leads outside the world; the repeats change nothing (the
    cell is known by then, or was never answered) and are skipped.

    Sensing: it asks once per turn, for every candidate some drone does not know: all a turn may need. A drone
    learns only the cells it gets to, so asking more changes nothing but the number of round trips: one per turn at
    most, where the seed's sequential questions take up to 4.
    """

    def __init__(self, *, world_size: Cell, drones: Sequence[int]) -> None:
        super().__init__(world_size=world_size, drones=drones)
        self._memory: dict[int, int] = {}
        self._count = np.zeros(len(self._drones), dtype=np.int64)  # cells learned, per drone

    def memory(self, drone: int) -> tuple[tuple[Cell, bool], ...]:
        """Drone number `drone`'s learned cells with their empty flag, in the order learned (as `SeedPilot.memory`)."""
        mine = self._memory_of(self._memory, int(self._rows([drone])[0]))  # cell -> index learned × 2 + empty
        return tuple((cell, bool(v & 1)) for cell, v in sorted(mine.items(), key=lambda item: item[1]))

    def step(self, drones: np.ndarray, pos: np.ndarray, target: np.ndarray) -> SwarmSensing:
        """`SwarmPilot.step`: returns (new cells (n, 3) int64, note codes (n,) uint8)."""
        nx, ny, nz = self.size
        rows, pos, target = self._orders(drones, pos, target)
        new = pos.copy()
        note = np.full(len(drones), _NONE, dtype=np.uint8)
        has = target[:, 0] >= 0
        here = has & (pos == target).all(axis=1)
        note[here] = _REACHED
        go = np.flatnonzero(has)  # the drones with a target (only they learn where they stand)
        if not len(go):
            return new, note
        p, t, moving, k = pos[go], target[go], ~here[go], len(go)

        # Six candidates a drone: where it stands (0), its vertical cell (1), its directionOrder (2-5).
        cand = np.repeat(p[:, None], 6, axis=1)  # (k, 6, 3): the drone's cell, moved below
        cand[:, 1, 2] += np.sign(t[:, 2] - p[:, 2])
        around = p[:, None, :2] + _DXY  # (k, 4, 2), in DIRECTIONS order
        inside = ((around >= 0) & (around < (nx, ny))).all(axis=2)
        distance = ((around - t[:, None, :2]) ** 2).sum(axis=2) * 4 + _RANK  # ties: the seed's order
        order = np.argsort(np.where(inside, distance, _FAR), axis=1)
        valid = inside.sum(axis=1)
        cand[:, 2:, :2] += _DXY[order]
        usable = np.ones((k, 6), dtype=bool)
        usable[:, 1] = moving & (t[:, 2] != p[:, 2]) & (cand[:, 1, 2] >= 0) & (cand[:, 1, 2] < nz)
        usable[:, 2:] = moving[:, None] & (_RANK < valid[:, None])  # the valid directions, no repeats
        keys = self._keys(rows[go], cand)
        entry = np.full((k, 6), -1, dtype=np.int64)
        entry[usable] = self._lookup(self._memory, keys[usable])
        unknown = usable & (entry < 0)
        told = np.full((k, 6), NO_ANSWER, dtype=np.uint8)
        told[:, 0] = CellKind.EMPTY  # standing in it: visited and empty, nothing asked
        ask = unknown & (_COLUMNS > 0)
        if ask.any():
            told[ask] = yield cand[ask]
        fresh_empty = unknown & (told == CellKind.EMPTY)
        known_empty = usable & (entry >= 0) & (entry & 1 == 1)

        up = known_empty[:, 1] | fresh_empty[:, 1]
        ahead = fresh_empty[:, 2:] & ~up[:, None]
        chosen = np.where(up, 1, np.where(ahead.any(axis=1), ahead.argmax(axis=1) + 2, 6))  # 6: none
        earliest = np.where(known_empty[:, 2:], entry[:, 2:] >> 1, _FAR)
        back = earliest.argmin(axis=1) + 2
        stuck = (chosen == 6) & (earliest.min(axis=1) == _FAR)
        dest = np.where(chosen < 6, chosen, np.where(stuck, 0, back))
        new[go[moving]] = cand[moving, dest[moving]]
        note[go[moving & stuck]] = _UNREACHABLE

        # Learn, in order: where it stands, then every cell told up to the one taken.
        learn = unknown & (told != NO_ANSWER) & (_COLUMNS <= chosen[:, None])
        learn[:, 0] = unknown[:, 0]
        index = self._count[rows[go]][:, None] + learn.cumsum(axis=1) - 1
        self._count[rows[go]] += learn.sum(axis=1)
        value = index * 2 + (told == CellKind.EMPTY)
        self._memory.update(zip(keys[learn].tolist(), value[learn].tolist()))
        return new, note
