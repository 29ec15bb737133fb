"""A journal that cannot be written (issue 33, 4): a full disk (ENOSPC, a small tmpfs) or a file size limit
(EFBIG past RLIMIT_FSIZE). The journal keeps only whole records, the game ends at once with OVER JOURNAL_FAILED,
every process exits 75 (EX_TEMPFAIL), and `--resume` plays the game on from the journal once there is room:
the journal is then an uninterrupted run's, byte for byte."""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from coordinator.journal import JournalFailed
from dronesim import child_env
from network.signals import JOURNAL_FAILED_STATUS, Interrupted
from network.transport import Presence
from schema import EndReason, Over, Phase, Status, Turn
from tests.harness import Cluster, embedded_router, journal_records
from tests.test_coordinator import Run

#: A child that appends journal records of ~700 bytes until the journal fails, then says how far it got.
WRITER = """
import sys
from coordinator.journal import JournalFailed, JournalWriter
n = 0
with JournalWriter(sys.argv[1]) as w:
    try:
        while n < 1000:
            w.append({"record": "turn", "turn": n, "pad": "x" * 700})
            n += 1
    except JournalFailed as err:
        print(n, err)
"""


def whole_records(path: Path, written: int) -> None:
    data = path.read_bytes()
    assert data.endswith(b"\n"), "a torn last line"
    lines = data.decode().splitlines()
    assert [json.loads(line)["turn"] for line in lines] == list(range(written))


def test_past_a_file_size_limit_the_journal_keeps_only_whole_records(tmp_path: Path) -> None:
    path, limit = tmp_path / "j.jsonl", 10_000
    out = subprocess.run([sys.executable, "-c", WRITER, str(path)], capture_output=True, text=True, timeout=60,
                         env=child_env(), check=True,
                         preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    written, why = out.stdout.split(" ", 1)
    assert int(written) == limit // len(b'{"pad":"' + b"x" * 700 + b'","record":"turn","turn":0}\n') > 0
    assert "File too large" in why and str(path) in why
    whole_records(path, int(written))
    assert os.path.getsize(path) <= limit


def test_on_a_full_disk_the_journal_keeps_only_whole_records(tmp_path: Path) -> None:
    """A 16 KiB tmpfs, mounted in a mount namespace of the child's own (`unshare -rm`: no root needed where
    user namespaces are allowed); the child copies what the journal holds out before its mount goes."""
    if shutil.which("unshare") is None:
        print("no unshare(1): the full tmpfs is not tried (the file size limit is)")
        pytest.skip("unshare(1) is missing")
    disk, copy = tmp_path / "disk", tmp_path / "copy.jsonl"
    disk.mkdir()
    script = f'mount -t tmpfs -o size=16k none {disk} && "$@" && cp {disk}/j.jsonl {copy}'
    out = subprocess.run(["unshare", "-rm", "sh", "-c", script, "sh", sys.executable, "-c", WRITER,
                          str(disk / "j.jsonl")], capture_output=True, text=True, timeout=60, env=child_env())
    if out.returncode and "mount" in out.stderr:
        print(f"cannot mount a tmpfs here ({out.stderr.strip()}): the full disk is not tried")
        pytest.skip(f"no tmpfs: {out.stderr.strip()}")
    assert out.returncode == 0, out.stderr
    written, why = out.stdout.split(" ", 1)
    assert 0 < int(written) < 1000 and "No space left on device" in why
    whole_records(copy, int(written))


class Refusing:
    """A journal that takes `room` records, then fails as a full disk does."""

    def __init__(self, room: int) -> None:
        self.records: list[dict] = []
        self.room = room

    def append(self, record: dict) -> None:
        if len(self.records) >= self.room:
            raise JournalFailed("cannot write the journal j: No space left on device")
        self.records.append(record)


def test_a_journal_that_fails_ends_the_game_at_once_with_over_journal_failed() -> None:
    run = Run(drones=1)
    run.srv.effects.writer = run.journal = Refusing(room=2)  # (the header is in) turns 1 and 2
    for turn in (1, 2, 3):
        run.play(turn, {"D01": (turn, 0, 0)})
    over = run.engine.end
    assert over is not None and over.reason is EndReason.JOURNAL_FAILED and over.turn == 3
    assert "No space left on device" in over.text and "--resume" in over.text
    assert [r.get("turn") for r in run.journal.records] == [1, 2], "no over record: it resumes"
    assert run.wire.of(Over) == [over]
    assert [s.turn for s in run.wire.of(Status)] == [0, 1, 2], "the lost turn's STATUS is not sent"
    assert not [t for t in run.wire.of(Turn) if t.turn == 4 and t.phase is Phase.GCS], "nor the next turn"
    for e in ("ENV", "GCS", "D01"):  # they see OVER and leave: the coordinator is done
        run.srv.handle(Presence(e, {"ENV": "e0", "GCS": "g0", "D01": "d1"}[e], False))
    assert run.srv.finished()


def test_a_lost_over_record_still_sends_the_games_own_over() -> None:
    run = Run(drones=1)
    run.srv.effects.writer = run.journal = Refusing(room=1)  # (the header is in) turn 1; not the over record
    run.play(1, {"D01": (1, 0, 0)})
    run.srv.handle(Interrupted(signal.SIGTERM))
    assert [o.reason for o in run.wire.of(Over)] == [EndReason.INTERRUPTED]
    assert run.srv.effects.failed is not None, "the coordinator exits 75: its journal lacks the over record"


SEED, GOALS = ("--seed", "7"), ("--targets", "D01=9,9,0;D02=9,0,3")


def game(c: Cluster, journal: Path, *, limit: int | None = None, resume: bool = False) -> dict[str, int]:
    """One game (or, `resume`, the rest of one) by real processes: the coordinator (under a file size limit of
    `limit` bytes: `prlimit`), the environment, two drones and a scripted ground station; their exit codes."""
    flags = ["--journal", str(journal), "--drones", "2", "--admit-deadline", "60", *SEED,
             *(["--resume"] if resume else [])]
    srv = c.start("SRV", "coordinator", *flags, wrap=("prlimit", f"--fsize={limit}") if limit else ())
    srv.expect("coordinator ready")
    c.start("ENV", "env", "--no-draw")
    for d in ("D01", "D02"):  # v1 drones decide from where they are only: new processes decide as the first did
        c.start(d, "drone", "--id", d, "--autopilot", "v1")
    c.start("GCS", "gcs", *GOALS, "--quiet", "--no-draw")
    return c.wait_all(timeout=120)


@pytest.mark.integration
def test_a_full_journal_ends_the_game_every_process_exits_75_and_resume_plays_it_on(tmp_path: Path) -> None:
    if shutil.which("prlimit") is None:
        print("no prlimit(1): the file size limit cannot be set on the coordinator alone")
        pytest.skip("prlimit(1) is missing")
    for run in ("clean", "full", "resumed"):
        (tmp_path / run).mkdir()
    with embedded_router() as locator:
        clean = tmp_path / "clean" / "j.jsonl"
        with Cluster(locator, tmp_path / "clean") as c:
            assert set(game(c, clean).values()) == {0}, [p.text for p in c.procs]
        lines = clean.read_bytes().splitlines(keepends=True)
        assert len(lines) > 8, "too short a game to fail in its middle"
        limit = sum(map(len, lines[:6])) + len(lines[6]) // 2  # turn 6's record is cut by the limit
        journal = tmp_path / "full" / "j.jsonl"
        with Cluster(locator, tmp_path / "full") as c:
            codes = game(c, journal, limit=limit)
            srv = next(p for p in c.procs if p.name == "SRV")
            assert codes == dict.fromkeys(codes, JOURNAL_FAILED_STATUS), [p.text for p in c.procs]
            assert "Traceback" not in "".join(p.text for p in c.procs)
            srv.expect(r"OVER at turn 6: JOURNAL_FAILED: the journal could not be written \(.*File too large")
        assert journal.read_bytes() == b"".join(lines[:6]), "only whole records: the header and turns 1-5"
        verify = subprocess.run([sys.executable, "-m", "dronesim", "replay", "--verify", str(journal)],
                                capture_output=True, text=True, timeout=120, env=child_env())
        assert verify.returncode == 0 and "its last turn is 5" in verify.stdout, verify.stdout + verify.stderr
        with Cluster(locator, tmp_path / "resumed") as c:  # room again: the game plays on from its journal
            codes = game(c, journal, resume=True)
            assert set(codes.values()) == {0}, [p.text for p in c.procs]
            next(p for p in c.procs if p.name == "SRV").expect("the game resumes at turn 6")
    assert journal.read_bytes() == clean.read_bytes()
    assert [r["record"] for r in journal_records(journal)].count("over") == 1
