"""`dronesim bench instructions REV`: each process's instructions a turn under callgrind, this tree against another.
Behaviour only (HEAD against itself, a short game, one process measured): the row is there, each figure a number."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from benchmarks import BENCHMARKS, instructions

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]


def test_head_against_itself_measures_each_role_asked(capsys):
    if shutil.which("valgrind") is None:
        pytest.skip("valgrind is not installed (Debian's valgrind package)")
    if subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True).returncode:
        pytest.fail("the benchmark extracts revisions with git: run the tests in a clone")
    assert BENCHMARKS["instructions"] == "instructions"
    assert instructions.main(["HEAD", "--row", "^1 drone @ 10x10x10", "--roles", "env", "--turns", "2,4"]) == 0
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in capsys.readouterr().out.splitlines()
            if ln.startswith("| ") and not ln.startswith("| process")]
    assert [r[0] for r in rows] == ["env"]
    for cell in rows[0][1:3]:
        float(cell.rstrip("k").replace(",", ""))  # a number (a short game's may be below 0: start-up varies)


def test_an_unknown_revision_or_role_is_refused(capsys):
    assert instructions.main(["no-such-revision-anywhere", "--row", "x", "--roles", "env"]) == 2
    assert "'no-such-revision-anywhere' is not a revision" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        instructions.main(["HEAD", "--row", "x", "--roles", "gcs"])
    assert exit_.value.code == 2
