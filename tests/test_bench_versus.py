"""`dronesim bench versus REV`: this tree against another revision, each figure from a fresh process of each tree.
Behaviour only (HEAD against itself, one short repeat): every row is there, each ratio a number; no wall-clock
assertion."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from benchmarks import BENCHMARKS, versus

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]


def test_head_against_itself_gives_every_row(capsys):
    if subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True).returncode:
        pytest.fail("the benchmark extracts revisions with git: run the tests in a clone")
    assert BENCHMARKS["versus"] == "versus"
    assert versus.main(["HEAD", "--counts", "1", "--seconds", "0.05", "--games", "1", "--turns", "5",
                        "--repeat", "1"]) == 0
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in capsys.readouterr().out.splitlines()
            if ln.startswith("| ") and not ln.startswith("| row")]
    assert [r[0] for r in rows] == ["RL local, 1 agent, safe", "RL local, 1 agent, random",
                                    "game, 1 drones @ 64x64x16, up to 5 turns, every process",
                                    "game, 1 drones @ 64x64x16, up to 5 turns, replay --verify"]
    for row in rows:
        low, high = (float(x) for x in row[4].split("–"))
        assert 0 < low <= high


def test_an_unknown_revision_is_refused(capsys):
    assert versus.main(["no-such-revision-anywhere"]) == 2
    assert "'no-such-revision-anywhere' is not a revision" in capsys.readouterr().err
