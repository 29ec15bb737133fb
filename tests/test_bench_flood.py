"""`dronesim bench flood --quick` (the secured router): the same game clean, under a flood of stale NPS
and under a flood of big ASKs; the table has its four rows, every journal equals the clean game's, every
process exits 0, and the rejections are reported (the environment refuses exactly the ASKs the attacker
saw refused).

Behaviour only: no wall-clock assertion (the machine may be busy); the speed target is the benchmark's."""

from __future__ import annotations

import re

import pytest

from benchmarks import BENCHMARKS, flood
from tests.test_bench_perf import _rows

pytestmark = pytest.mark.integration


def test_quick_run_records_the_table_and_the_floods_change_no_journal(capsys, tmp_path):
    assert BENCHMARKS["flood"] == "flood"
    recorded = tmp_path / "recorded.md"
    # the attacker as an equal: this test checks what the floods do (journals, rejections), not a speed, and a
    # niced attacker on a busy machine may not have sent its flood before the quick game ends
    code = flood.main(["--quick", "--attacker-nice", "0", "--write", "--output", str(recorded)])
    out, err = capsys.readouterr()
    assert code == 0, "\n".join(line for line in err.splitlines() if line.startswith("not ok"))[-4000:] + err[-2000:]
    section = recorded.read_text(encoding="utf-8").split(flood.SECTION, 1)[1]
    assert section.splitlines()[2].startswith(
        "Command: `dronesim bench flood --quick --attacker-nice 0 --write --output ")
    assert re.search(r"Load average \(1 min\) before the run \d+\.\d\d", section)
    rows = _rows(section, "game")
    counts = flood.QUICK_FLOODS
    nps, ask = f"flood (a): {counts['nps']:,} stale NPS", f"flood (b): {counts['ask']} ASKs of 32,768 cells"
    done, tgt = f"flood (c): {counts['done']:,} stale DONEs", f"flood (d): {counts['tgt']:,} stale TGTs"
    connect = f"flood (e): {counts['connect']:,} CONNECTs with invented sessions"
    maps = f"flood (f): {counts['map']:,} requests for the map"
    assert list(rows) == ["clean", nps, ask, done, tgt, connect, maps, "clean again"]
    for row in rows.values():
        assert row["same journal / states"] == "yes / yes", row
        assert row["exit codes"] == "0 / 0 / 0", row
        assert re.fullmatch(r"\d+\.\d", row["turns/s (measured turns)"]), row
        # the station's own DONEs sent again, as the game went (a router's budget may drop those that travel together)
        assert re.fullmatch(r"\d+ / \d+", row["station's DONEs sent again: announced / timed out"]), row
    for name in (nps, ask):
        assert re.fullmatch(r"\d+\.\d\d", rows[name]["÷ clean"]), rows[name]
        assert re.fullmatch(r"\d+\.\d", rows[name]["longest turn in the flood (ms)"]), rows[name]
        assert rows[name][f"target ≥ {flood.TARGET:g}"] in ("met", "MISSED"), rows[name]
    attacker = "attacker: sent / answered / refused (its CPU s)"
    found = re.fullmatch(r"([\d,]+) / ([\d,]+) / ([\d,]+) \(\d+\.\d\d\)(?:, ([\d,]+) unanswered)?",
                         rows[ask][attacker])
    assert found, rows[ask]
    sent, answered, refused, unanswered = (int((v or "0").replace(",", "")) for v in found.groups())
    # (whether this tiny game's burst outruns the environment's budget depends on the machine: on a fast one the
    # environment keeps up and its last queries come after the game's end; tests/test_flood.py holds the refusals)
    assert sent == flood.QUICK_FLOODS["ask"] and answered + refused + unanswered == sent, rows[ask]
    # a query without a reply reached the environment after it left, the game over: only if the flood outlasted it
    assert not unanswered or "cut" in rows[ask]["turns/s during the flood (turns, s)"], rows[ask]
    rejected = f"{{'flood': {refused}}}, from {{'D01': {refused}}}" if refused else "-"
    assert rejected == rows[ask]["rejected by the environment"], rows[ask]
    assert rows[nps][attacker].startswith(f"{flood.QUICK_FLOODS['nps']:,} / 0 / 0 ("), rows[nps]
    # every game may also count the ground station's own stale DONEs (it re-sends a phase's DONE until that turn's
    # STATUS comes: a loaded machine's re-send can arrive after the phase closed), as its session or as its key's
    # origin ("DONE from GCS")
    for name, flooded in ((nps, "D01"), (done, None), (tgt, None)):  # stale, refused unread, counted by origin
        found = re.fullmatch(r"\{'stale-turn': (\d+)\}, from \{(.*)\}", rows[name]["rejected by the coordinator"])
        assert found, rows[name]
        origins = {o: int(n) for o, n in re.findall(r"'([^']*)': (\d+)", found.group(2))}
        assert origins and all(o == flooded or "GCS" in o for o in origins), rows[name]
        assert flooded is None or origins.get(flooded, 0) > 0, rows[name]
        assert sum(origins.values()) == int(found.group(1)), rows[name]
    # CONNECTs with invented sessions: the router ends most at once without a reply (its budget of CONNECTs a
    # session), the coordinator refuses those it lets by (no presence token; past the room to wait, at once); the
    # journal unchanged (checked above); every one is accounted for
    found = re.fullmatch(r"([\d,]+) / ([\d,]+) / ([\d,]+) \(\d+\.\d\d\)(?:, ([\d,]+) unanswered)?",
                         rows[connect][attacker])
    assert found, rows[connect]
    sent, answered, refused, unanswered = (int((v or "0").replace(",", "")) for v in found.groups())
    assert sent == counts["connect"] and answered + refused + unanswered == sent and unanswered > 0, rows[connect]
    seen = re.match(r"\{([^}]*)\}", rows[connect]["rejected by the coordinator"])
    assert sum(int(n) for n in re.findall(r": (\d+)", seen.group(1) if seen else "")) < sent, rows[connect]
    # requests for the map: the router ends most at once without a reply (its budget of MAP queries a session); the
    # environment answers those it lets by (the map is no secret), refusing none
    found = re.fullmatch(r"([\d,]+) / ([\d,]+) / ([\d,]+) \(\d+\.\d\d\)(?:, ([\d,]+) unanswered)?",
                         rows[maps][attacker])
    assert found, rows[maps]
    sent, answered, refused, unanswered = (int((v or "0").replace(",", "")) for v in found.groups())
    assert sent == counts["map"] and answered + refused + unanswered == sent, rows[maps]
    assert 1 <= answered < sent and refused == 0 and rows[maps]["rejected by the environment"] == "-", rows[maps]
