"""`dronesim bench export` on a small game: it plays the journal once (then reads it from its cache), exports the
whole game and its first tenth in child processes, and writes its table and verdicts into BENCHMARKS.md.
Behaviour only: no wall-clock assertion."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks import BENCHMARKS, export

pytest.importorskip("foxglove", reason="foxglove-sdk is in the ros2 extra: pip install -e '.[ros2]'")
pytestmark = pytest.mark.integration


def test_a_small_run_writes_its_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert BENCHMARKS["export"] == "export"
    out_file = tmp_path / "BENCHMARKS.md"
    out_file.write_text("# Benchmarks\n\n## Performance\n\nkept\n", encoding="utf-8")
    argv = ["--drones", "8", "--turns", "20", "--runs", "1", "--cache", str(tmp_path / "cache"), "--write",
            "--output", str(out_file)]
    assert export.main(argv) == 0
    journals = sorted(p.name for p in (tmp_path / "cache").glob("*.journal"))
    assert journals == ["export-8x20-256x256x32-seed3-first2.journal", "export-8x20-256x256x32-seed3.journal"]
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| ")]
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = [dict(zip(head, (c.strip() for c in ln.strip("|").split("|")))) for ln in lines[1:]]
    assert [r["journal"] for r in rows] == ["whole", "first tenth"]
    assert [int(r["turns"]) for r in rows] == [22, 3]  # (turn 0 and the game's 21; 0 to 2)
    assert all(int(r["ROS 2 messages"]) > 0 and float(r["CPU s (user + system)"]) > 0 for r in rows)
    text = out_file.read_text(encoding="utf-8")
    assert "## Performance\n\nkept" in text and "## MCAP export" in text and "- Time (8 drones, 20 turns" in text
    assert "`dronesim bench export --drones 8 --turns 20 --runs 1 --cache" in text
    assert export.main(argv) == 0  # the journals again, from the cache
    assert sorted(p.name for p in (tmp_path / "cache").glob("*.journal")) == journals
