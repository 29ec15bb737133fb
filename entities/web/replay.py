"""A journal as frames the page plays (``dronesim gcs --web PORT --replay JOURNAL``). Pure, no network.

Frame 0 is the start, frame k the state after the k-th turn record (`coordinator.journal.tracks`): every drone's
cell, state, cause and target; trails are the page's to accumulate (so the data grows with turns x drones,
not with its square).
"""

from __future__ import annotations

import pathlib

from coordinator.journal import TurnRecord, header_config, over_of, read, tracks, turns
from schema import Cause, Intent, UsageError
from world.grid import build_world

from .model import ALIVE, DEAD, LOST, REACHED, change_entry, drone_json, entry, fmt, over_entry, world_json


def _status(track) -> str:
    """The journal does not record the drones' notes: "reached" is standing on the target, never "unreachable"."""
    if track.state in ("DEAD", "LOST"):
        return track.state.lower()
    return REACHED if track.target is not None and tuple(track.pos) == tuple(track.target) else ALIVE


def _cause(text: str) -> Cause:
    try:
        return Cause(text)
    except ValueError:
        return Cause.NONE


class Replay:
    """A loaded journal: its world and its frames (see the module doc)."""

    def __init__(self, path: str | pathlib.Path) -> None:
        self.path = pathlib.Path(path)
        records = list(read(self.path))
        if not records:
            raise UsageError(f"{self.path} is empty: not a journal")
        self.config, self.autopilots = header_config(records[0])
        self.world = build_world(self.config.world, (d.start for d in self.config.drones))
        over = over_of(records)
        self.over = None if over is None else {"turn": over["turn"], "reason": over["reason"],
                                               "text": over.get("text", "")}
        self.frames = self._frames(records)

    def _frames(self, records: list[dict]) -> list[dict]:
        try:
            played = list(turns(records))
            frames: list[dict] = []
            before: dict[str, str] = {}
            for k, until in enumerate([0, *(r.turn for r in played)]):
                tr, _ = tracks(self.config, records, until=until)
                record = played[k - 1] if k else TurnRecord(turn=0)
                events = [entry(until, "target", f"target of {d} set to {fmt(p)}")
                          for d, p in sorted(record.targets.items())]
                if hovered := record.hovered:
                    events.append(entry(until, "info", f"no move in time from {', '.join(hovered)}: hovering"))
                drones = []
                for d, t in tr.items():
                    status = _status(t)
                    cause = _cause(t.cause) if status in (DEAD, LOST) else Cause.NONE
                    if k and before.get(d, ALIVE) != status:
                        events.append(change_entry(until, d, status, cause, t.pos, t.target))
                    before[d] = status
                    drones.append({**drone_json(d, t.pos, status, cause, t.target),
                                   "autopilot": self.autopilots.get(d, "")})
                if record.intent is Intent.QUIT:
                    events.append(entry(until, "control", "the ground station ended the game"))
                frames.append({"turn": until, "drones": drones, "events": events})
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise UsageError(f"{self.path}: bad journal record: {exc!r}") from None
        if self.over is not None:
            frames[-1]["events"].append(over_entry(self.over["turn"], self.over["reason"], self.over["text"]))
        return frames

    def world_json(self) -> dict:
        return world_json(self.world, mode="replay", title=self.path.name)

    def replay_json(self) -> dict:
        return {"journal": self.path.name, "starts": {d.drone: list(d.start) for d in self.config.drones},
                "frames": self.frames, "over": self.over}
