"""The append-only journal: one JSON line per record (header, one per turn, over). Lines are canonical JSON
(sorted keys, no spaces, no timestamps) so two runs of the same scenario give byte-identical journals,
whatever the process layout."""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
from collections.abc import Iterator

from schema import UsageError


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
        over = over or record.get("record") == "over"
        turn = record.get("turn", turn) if isinstance(record.get("turn"), int) else turn
    return over, turn


def read(path: str | os.PathLike[str]) -> Iterator[dict]:
    """The records of a journal; a torn last line (a crash mid-write) is ignored, anything else bad is an error."""
    try:
        lines = pathlib.Path(path).read_text(encoding="utf-8").split("\n")
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"cannot read journal {path}: {exc}") from None
    for n, line in enumerate(lines, 1):
        if not line:
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if n == len(lines):  # the last line, without its newline: torn by a crash
                return
            record = None
        if not isinstance(record, dict) or "record" not in record:
            raise UsageError(f"{path}:{n}: not a journal record")
        yield record
