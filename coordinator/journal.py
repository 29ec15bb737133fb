"""The append-only journal: one JSON line per record (header, one per turn, over). Lines are canonical JSON
(sorted keys, no spaces, no timestamps) so two runs of the same scenario give byte-identical journals,
whatever the process layout."""

from __future__ import annotations

import json
import os
import pathlib
from collections.abc import Iterator

from schema import UsageError


def dumps(record: dict) -> str:
    return json.dumps(record, sort_keys=True, separators=(",", ":"))


class JournalWriter:
    """Appends records to a file, flushed line by line (a crash loses at most the line being written)."""

    def __init__(self, path: str | os.PathLike[str] | None) -> None:
        self._f = open(path, "a", buffering=1, encoding="utf-8") if path else None  # noqa: SIM115

    def append(self, record: dict) -> None:
        if self._f is not None:
            self._f.write(dumps(record) + "\n")

    def __enter__(self) -> JournalWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._f is not None:
            self._f.close()


def repair_tail(path: str | os.PathLike[str]) -> None:
    """Cut a torn last line (a crash mid-write) so that appending goes on from a whole record."""
    try:
        data = pathlib.Path(path).read_bytes()
    except OSError as exc:
        raise UsageError(f"cannot read journal {path}: {exc}") from None
    if data and not data.endswith(b"\n"):
        os.truncate(path, data.rfind(b"\n") + 1)


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
