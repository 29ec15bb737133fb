"""Move arbitration for drones that avoid each other: propose, then resolve by a fixed priority.

Every drone proposes its move in the DRONES phase (all in parallel, one round trip). Before the moves
are applied, cooperative drones (those whose autopilot asked for arbitration) give way, so that no two
of them ever share a cell or swap cells:

- a cooperative drone whose destination is claimed by a drone that does not give way (a non-cooperative
  drone, a hovering drone, or a cooperative one with a smaller id) hovers instead;
- so does one whose move would swap cells with such a drone;
- hovering can in turn block a drone that was following it, so the rule is applied until nothing changes
  (moves only ever turn into hovers, so this ends after at most N passes).

Non-cooperative drones (the seed's V1 and smart drones) move as they said, and may still collide: the
observer judges them. Priority is the drone id: a total order, so the result never depends on the order
in which proposals arrived. No extra network round trip: the coordinator resolves it alone.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Set

from dronesim.schema import Cell


def arbitrate(before: Mapping[str, Cell], proposed: Mapping[str, Cell], cooperative: Set[str]) -> dict[str, Cell]:
    """The moves after arbitration: `proposed` with some cooperative drones' moves turned into hovers."""
    final = dict(proposed)
    coop = sorted(d for d in cooperative if d in final)
    changed = bool(coop)  # nobody gives way: nothing to do
    while changed:
        changed = False
        claims: dict[Cell, list[str]] = defaultdict(list)
        for d, cell in final.items():
            claims[cell].append(d)
        for d in coop:
            src, dst = before[d], final[d]
            if dst == src:
                continue
            blocked = any(e != d and (e not in cooperative or final[e] == before[e] or e < d) for e in claims[dst])
            # a swap: a drone entering our cell from the one we enter (there may be several entering it)
            blocked = blocked or any(e != d and before[e] == dst and (e not in cooperative or e < d)
                                     for e in claims[src])
            if blocked:
                final[d] = src
                claims[dst].remove(d)
                claims[src].append(d)
                changed = True
    return final
