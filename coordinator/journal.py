"""The journal, the one home of its record format: written here (`header_record`, `TurnLog`, `over_record`, one
JSON line each, by `JournalWriter`; a turn's state digest, `state_hash`) and read here (`read`, `header_of`,
`header_pilots`, `header_config`, `TurnRecord`, `turns`, `over_of`, `is_turn`, `tracks`) by the engine, resume,
`dronesim replay` and `export`, the web page's replay and the benchmarks. Lines are canonical JSON (sorted keys, no
spaces, no timestamps) so two runs of the same scenario give byte-identical journals, whatever the process layout.

  header  {"record": "header", "format": "dronesim-journal", "version": 1, "world": {size, seed, cells},
           "drones": [{drone, start, autopilot, cooperative}], "max_turns", "lost_after"}
  turn    {"record": "turn", "turn": t, and what the turn changed: "targets", "intent", "moves", "notes",
           "gave_way", "yielded", "hovered", "deaths", "lost", "state" (the STATUS's digest)}
  over    {"record": "over", "turn": t, "reason", "text"; a lifelong game's: "tasks", the tasks done}
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pathlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from schema import Cause, Cell, Intent, Note, RemoteInputError, Status, UsageError, WorldSpec, encode

from .config import LOST_AFTER, DroneSpec, GameConfig

FORMAT = "dronesim-journal"
VERSION = 1
#: The records' kinds (their "record" field).
HEADER, TURN, OVER = "header", "turn", "over"


def dumps(record: dict) -> str:
    return json.dumps(record, sort_keys=True, separators=(",", ":"))


class JournalFailed(Exception):
    """The journal could not take a record (a full disk, a file size limit, an I/O error): the record is not in
    it, the journal holds only the whole records written before."""


class JournalWriter:
    """Appends records to a file, one write of a whole line each. A line that cannot be written whole (ENOSPC,
    EFBIG past RLIMIT_FSIZE, EIO) is cut off again at once (`JournalFailed`): the journal holds only whole
    records, and resumes (`--resume`) from the last once there is room."""

    def __init__(self, path: str | os.PathLike[str] | None) -> None:
        self.path = path
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666) if path else None
        except OSError as exc:
            raise UsageError(f"cannot open journal {path}: {exc.strerror or exc}") from None

    def append(self, record: dict) -> None:
        if self._fd is None:
            return
        line = memoryview((dumps(record) + "\n").encode())
        end = os.lseek(self._fd, 0, os.SEEK_END)
        try:
            while line:
                line = line[os.write(self._fd, line):]
        except OSError as exc:
            with contextlib.suppress(OSError):  # (shrinking a file needs no room, nor passes a size limit)
                os.ftruncate(self._fd, end)
            raise JournalFailed(f"cannot write the journal {self.path}: {exc.strerror or exc}") from exc

    def __enter__(self) -> JournalWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def repair_tail(path: str | os.PathLike[str]) -> None:
    """Cut a torn last line (a crash mid-write) so that appending goes on from a whole record."""
    try:
        data = pathlib.Path(path).read_bytes()
    except OSError as exc:
        raise UsageError(f"cannot read journal {path}: {exc}") from None
    if data and not data.endswith(b"\n"):
        os.truncate(path, data.rfind(b"\n") + 1)


def held_game(path: str | os.PathLike[str]) -> tuple[bool, int] | None:
    """The game a journal already holds: (whether it is over, its last turn); None when the file is missing or
    empty. A journal holds one game: a coordinator starting a new one on it refuses, or resumes it."""
    if not os.path.exists(path) or os.path.getsize(path) == 0:
        return None
    over, turn = False, 0
    for record in read(path):
        over = over or is_over(record)
        turn = record.get("turn", turn) if isinstance(record.get("turn"), int) else turn
    return over, turn


def read(path: str | os.PathLike[str]) -> Iterator[dict]:
    """The records of a journal, one line at a time (a game of any length in the memory of its largest turn); a
    torn last line (a crash mid-write) is ignored, anything else bad is an error."""
    try:
        with open(path, encoding="utf-8") as f:
            for n, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
                    record = json.loads(line)
                except (ValueError, RecursionError):  # (not JSON, an integer of 4300 digits, nested too deeply)
                    if not line.endswith("\n"):  # the last line, without its newline: torn by a crash
                        return
                    record = None
                if not isinstance(record, dict) or "record" not in record:
                    raise UsageError(f"{path}:{n}: not a journal record")
                yield record
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"cannot read journal {path}: {exc}") from None


# --------------------------------------------------------------------------- the header


def header_record(config: GameConfig, size: Cell, drones: Iterable[tuple[str, list[int], str, bool]] | None) -> dict:
    """The journal's first record: what identifies the game (resume checks it). `drones`: each drone's id,
    start, autopilot and whether it cooperates; None leaves out the drones and the world's cells (a game
    without a journal, which would only drop them)."""
    world: dict[str, Any] = {"size": list(size), "seed": config.world.seed}
    header: dict[str, Any] = {"record": HEADER, "format": FORMAT, "version": VERSION, "world": world,
                              "max_turns": config.max_turns, "lost_after": config.lost_after}
    if config.arbiter != "lacam":
        header["arbiter"] = config.arbiter
    if config.lifelong:
        header["lifelong"] = True
    if drones is not None:  # (the journal's lines sort their keys: the order here is not the written one)
        world["cells"] = config.world.cells.hex()
        header["drones"] = [dict(zip(("drone", "start", "autopilot", "cooperative"), row)) for row in drones]
    return header


def header_pilots(header: dict) -> Iterator[tuple[Any, Any, Any]]:
    """Each drone a header lists (`header_record`): its id, autopilot and whether it cooperates, as written (a
    header not of the format gives what it holds: compared with the game's own header, it differs)."""
    for d in header.get("drones", []):
        if isinstance(d, dict):
            yield d.get("drone"), d.get("autopilot", ""), d.get("cooperative", False)


def header_config(header: dict) -> tuple[GameConfig, dict[str, str]]:
    """The game a journal's header describes, and each drone's autopilot. UsageError if it is not a header."""
    if header.get("record") != HEADER or header.get("format") != FORMAT:
        raise UsageError("not a dronesim journal: the first record must be its header")
    try:
        w = header["world"]
        spec = WorldSpec(size=tuple(w["size"]), seed=w["seed"], cells=bytes.fromhex(w["cells"]))
        drones = tuple(DroneSpec(drone=d["drone"], start=tuple(d["start"])) for d in header["drones"])
        autopilots = {d["drone"]: d["autopilot"] for d in header["drones"]}
        config = GameConfig(world=spec, drones=drones, max_turns=header["max_turns"],
                            lost_after=header.get("lost_after", LOST_AFTER), arbiter=header.get("arbiter", "lacam"),
                            lifelong=header.get("lifelong", False) is True)
    except (KeyError, TypeError, ValueError, IndexError, RemoteInputError) as exc:
        raise UsageError(f"bad journal header: {exc}") from None
    return config, autopilots


# --------------------------------------------------------------------------- turns and the end


class TurnLog:
    """One turn's record as the engine writes it: what the turn changed, drone by drone."""

    __slots__ = ("record",)

    def __init__(self, turn: int) -> None:
        self.record: dict[str, Any] = {"record": TURN, "turn": turn}

    def targets(self, drones: Sequence[str], cells: list[list[int]]) -> None:
        self.record["targets"] = dict(zip(drones, cells))

    def intent(self, intent: Intent) -> None:
        self.record["intent"] = intent.value

    def arbitration(self, gave_way: Sequence[str], yielded: Sequence[str]) -> None:
        """Who gave way (their priorities reset) and who did not get its first choice."""
        if gave_way:
            self.record["gave_way"] = list(gave_way)
        if yielded:
            self.record["yielded"] = list(yielded)

    def moves(self, drones: Sequence[str], cells: list[list[int]]) -> None:
        self.record["moves"] = dict(zip(drones, cells))

    def notes(self, drones: Sequence[str], notes: Iterable[Note]) -> None:
        self.record["notes"] = {d: n.value for d, n in zip(drones, notes)}

    def hovered(self, drones: Sequence[str]) -> None:
        self.record["hovered"] = list(drones)

    def deaths(self, drones: Sequence[str], causes: Iterable[Cause]) -> None:
        self.record["deaths"] = {d: c.value for d, c in zip(drones, causes)}

    def lost(self, drone: str) -> None:
        self.record.setdefault("lost", []).append(drone)

    def state(self, digest: str) -> None:
        self.record["state"] = digest


def over_record(turn: int, reason: str, text: str, tasks: int | None = None) -> dict:
    """The journal's last record; `tasks`: a lifelong game's tasks done (None: not lifelong)."""
    record = {"record": OVER, "turn": turn, "reason": reason, "text": text}
    return record if tasks is None else {**record, "tasks": tasks}


@dataclass(frozen=True, slots=True, kw_only=True)
class TurnRecord:
    """A turn record as read back (see the module doc)."""

    turn: int
    targets: dict[str, Cell] = field(default_factory=dict)
    intent: Intent | None = None
    moves: dict[str, Cell] = field(default_factory=dict)
    notes: dict[str, Note] = field(default_factory=dict)
    gave_way: tuple[str, ...] = ()
    hovered: tuple[str, ...] = ()
    deaths: dict[str, Cause] = field(default_factory=dict)
    lost: tuple[str, ...] = ()
    state: str | None = None

    @classmethod
    def of(cls, r: dict) -> TurnRecord:
        """The turn record `r`; KeyError, TypeError or ValueError if it is not of the format."""
        intent = r.get("intent")
        return cls(turn=int(r["turn"]),
                   targets={d: _cell(p) for d, p in r.get("targets", {}).items()},
                   intent=None if intent is None else Intent(intent),
                   moves={d: _cell(p) for d, p in r.get("moves", {}).items()},
                   notes={d: Note(n) for d, n in r.get("notes", {}).items()},
                   gave_way=tuple(r.get("gave_way", ())), hovered=tuple(r.get("hovered", ())),
                   deaths={d: Cause(c) for d, c in r.get("deaths", {}).items()},
                   lost=tuple(r.get("lost", ())), state=r.get("state"))


def _cell(p: Sequence[int]) -> Cell:
    x, y, z = p
    return (int(x), int(y), int(z))


def state_hash(status: Status) -> str:
    """A turn record's "state": the digest of the turn's STATUS as the wire says it, the game's identity left out (a
    journal depends on the seed, the scenario and the inputs only)."""
    return hashlib.sha256(encode(Status(turn=status.turn, sender=status.sender, drones=status.drones))).hexdigest()[:16]


def is_turn(record: dict) -> bool:
    return record.get("record") == TURN


def is_over(record: dict) -> bool:
    return record.get("record") == OVER


def header_of(records: Sequence[dict]) -> dict | None:
    """The header that opens `records`, if they begin with one."""
    return records[0] if records and records[0].get("record") == HEADER else None


def turns(records: Iterable[dict]) -> Iterator[TurnRecord]:
    """The turn records among `records`, read."""
    return (TurnRecord.of(r) for r in records if is_turn(r))


def over_of(records: Iterable[dict]) -> dict | None:
    """The over record among `records`, if the game ended."""
    return next((r for r in records if is_over(r)), None)


@dataclass(slots=True)
class Track:
    """One drone's story as the journal tells it, up to some turn."""

    pos: Cell
    state: str = "ALIVE"
    cause: str = ""
    path: list[Cell] = field(default_factory=list)
    target: Cell | None = None
    tasks: int = 0  # arrivals on a target given, each counted once (a lifelong game's tasks, as the engine counts)
    done: bool = False  # on its target at the end of a turn since that target was given


def tracks(config: GameConfig, records: Iterable[dict], until: int | None = None) -> tuple[dict[str, Track], int]:
    """Every drone's track after turn `until` (the last: None), and that turn."""
    out = {d.drone: Track(pos=d.start, path=[d.start]) for d in config.drones}
    last = 0
    for r in turns(records):
        if until is not None and r.turn > until:
            continue
        last = r.turn
        for d, p in r.targets.items():
            out[d].target, out[d].done = p, False
        for d, p in r.moves.items():
            out[d].pos = p
            out[d].path.append(p)
        for d, cause in r.deaths.items():
            out[d].state, out[d].cause = "DEAD", cause.value
        for d in r.lost:
            out[d].state, out[d].cause = "LOST", "LOST"
        for d in r.targets.keys() | r.moves.keys():  # (only these can have arrived)
            t = out[d]
            if not t.done and t.state == "ALIVE" and t.pos == t.target:
                t.tasks, t.done = t.tasks + 1, True
    return out, last
