"""`dronesim bench callbacks`: a message on Zenoh's thread, its thread state kept and made anew
(docs/performance.md)."""

from __future__ import annotations

import json

import pytest

from benchmarks import BENCHMARKS, callbacks

pytestmark = pytest.mark.integration


def test_both_ways_are_measured_in_processes_of_their_own_every_message_counted(capsys) -> None:
    assert BENCHMARKS["callbacks"] == "callbacks"
    assert callbacks.main(["--messages", "2000", "--repeat", "1"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("kept :") and lines[1].startswith("fresh:"), lines
    ratios = json.loads(lines[2])["fresh_over_kept_cpu"]
    assert len(ratios) == 1 and ratios[0] > 0  # (a figure, not a speed: tests check behaviour)


def test_a_measurement_whose_messages_did_not_all_come_fails(monkeypatch) -> None:
    class Ran:
        stdout = "1999 3.0 3.5\n"

    monkeypatch.setattr(callbacks.subprocess, "run", lambda *a, **k: Ran())
    with pytest.raises(RuntimeError, match="1999 of 2000"):
        callbacks.measure("kept", 2000)
