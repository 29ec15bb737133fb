"""`dronesim bench perf --quick`: the table has its rows and every process of every game exited 0.

Behaviour only: no wall-clock assertion (the machine may be busy)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from benchmarks import BENCHMARKS, games, perf, pogema
from benchmarks.measure import size_text
from benchmarks.mechanisms import MECHANISMS, MECHANISMS_TITLE, code_lines

pytestmark = pytest.mark.integration


def _rows(text: str, first: str = "row") -> dict[str, dict[str, str]]:
    """The rows, by name, of the table in `text` whose first column is headed `first`."""
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"| {first} |"))
    table = list(itertools.takewhile(lambda ln: ln.startswith("|"), lines[start:]))
    head = [c.strip() for c in table[0].strip("|").split("|")]
    rows = {}
    for ln in table[2:]:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        rows[cells[0]] = dict(zip(head, cells))
    return rows


def test_quick_run_prints_the_table_and_every_process_exits_0(capsys, tmp_path):
    assert BENCHMARKS["perf"] == "perf"
    out_file = tmp_path / "BENCHMARKS.md"
    out_file.write_text("# Benchmarks\n\n## Autopilot benchmark\n\nkept\n", encoding="utf-8")
    code = perf.main(["--quick", "--write", "--output", str(out_file)])
    out, err = capsys.readouterr()
    rows = _rows(out)
    assert code == 0, err + out
    for name in ("floor: pub/sub round trip (callback replies)", "floor: pub/sub round trip (main thread replies)",
                 "floor: query round trip (callback replies)", "floor: query round trip (main thread replies)"):
        assert rows[name]["exit codes"] == "helper 0"
        median, p99 = (float(v) for v in rows[name]["turn (or round trip) ms median / p99"].split(" / "))
        assert 0 < median <= p99
    for name in ("1 drone @ 10x10x10", "16 drones @ 10x10x10"):
        row = rows[name]
        assert row["exit codes"] == "0/0/0", row
        assert not row["target"].startswith("FAILED"), row
        assert float(row["turns/s"]) > 0 and float(row["in-process turns/s"]) > 0
        assert row["alive at end, moving per turn, same game in-process"].endswith("yes"), row
        cpu = [float(v) for v in
               row["CPU ms per turn coordinator / env / swarm / router / ground station"].split(" / ")]
        assert len(cpu) == 5 and all(v >= 0 for v in cpu)
        for col in ("coordinator MiB (÷ model)", "environment MiB (÷ model)"):
            mib, ratio = row[col].replace("(", "").replace(")", "").split()
            assert float(mib) > 0 and float(ratio) > 0
    # met or UNMET, measured either way
    assert rows["1 drone @ 10x10x10"]["target"].startswith(f"≤ {perf.TARGETS['latency']:g}x RTT: ")
    assert rows["128 drones @ 10x10x10"]["target"].startswith("skipped: 128 drones do not fit")
    assert "world generation 64x64x16" in rows
    assert rows["MAVLink ground station, 100 vehicles"]["target"].startswith("≥ 20 turns/s: ")  # (docs/mavlink.md)
    # each mechanism that remains: its lines of code, and, switched off, the same game (4 drones here)
    mechanisms = _rows(out, "mechanism")
    assert len(mechanisms) == len(MECHANISMS)
    for m in MECHANISMS:
        row = mechanisms[m.name]
        assert int(row["lines of code"]) == code_lines(m.code) > 0
        if m.off is None:
            assert row["switched off by"].startswith("not switched off: "), row
        elif m.windows is not None:  # one game, the switch flipped in windows of it (ABBA)
            assert row["game"] == "4 drones @ 10x10x10" and row["same game"] == "one game", row
            assert row["gain (off ÷ on)"].startswith("keeps ") and "ABBA" in row["gain (off ÷ on)"], row
        else:
            assert row["game"] == "4 drones @ 10x10x10" and row["same game"] == "yes", row
            assert row["gain (off ÷ on)"].startswith("turn "), row
    # --write replaced only its own section
    text = out_file.read_text(encoding="utf-8")
    assert "## Autopilot benchmark\n\nkept\n" in text
    assert text.count("## Performance") == 1 and "`dronesim bench perf --quick --write --output" in text
    assert "1 drone @ 10x10x10" in text.split("## Performance", 1)[1]
    assert MECHANISMS_TITLE in text.split("## Performance", 1)[1]


def test_lines_of_code_are_counted_once_from_definitions_and_regexes(tmp_path):
    (tmp_path / "m.py").write_text(
        "X = 1\n\n\n@dec\nclass A:\n    def f(self):\n        return X\n\n    def g(self):\n"
        "        pass\n\n\ndef h():\n    # uses X\n    return 2\n", encoding="utf-8")
    assert code_lines(["m.py::X"], tmp_path) == 1
    assert code_lines(["m.py::A"], tmp_path) == 7  # its decorator in
    assert code_lines(["m.py::A.g"], tmp_path) == 2
    assert code_lines(["m.py::A.f", "m.py:/X/"], tmp_path) == 4  # line 7 once
    assert code_lines(["m.py"], tmp_path) == 15
    for missing in ("m.py::B", "m.py::A.k", "m.py:/nowhere/"):
        with pytest.raises(KeyError):
            code_lines([missing], tmp_path)
    for m in MECHANISMS:  # every name the table counts is there
        assert code_lines(m.code) > 0, m.name
        assert (m.off is None) == (not m.games) and m.switch, m.name


def test_scenarios_fit_start_free_and_are_valid(tmp_path):
    from dronesim.scenario import Scenario
    from entities.environment import build_world

    assert games.make_scenario(games.Case(1000, (10, 10, 10), 5, 10)) is None
    for case in (games.Case(16, (10, 10, 10), 3, 20), games.Case(128, (64, 64, 16), 10, 30)):
        data = games.make_scenario(case)
        path = tmp_path / "s.json"
        path.write_text(json.dumps(data), encoding="utf-8")
        sc = Scenario.load(path)
        assert len(sc.drones) == case.drones and set(sc.autopilots.values()) == {"seed"}
        world = build_world(sc.world, [d.start for d in sc.drones])
        assert not any(world.is_building(d.start) for d in sc.drones)
        plan = sc.plan()
        cells = {c for _, _, c in plan.items}
        assert not any(world.is_building(c) for c in cells)
        assert plan.drones() == set(sc.autopilots)
        assert sc.max_turns > case.end_turn


def test_memory_growth_is_judged_per_drone_and_per_world_byte():
    small, mid, large = perf.WORLDS
    peaks = {  # KiB
        ("coordinator", 1, mid): 49_000, ("coordinator", 128, mid): 50_256,
        ("coordinator", 1000, mid): 52_000,  # 2.00 KiB per drone from 128 to 1000: UNMET
        ("env", 1, mid): 49_000, ("env", 128, mid): 50_000, ("env", 1000, mid): 50_872,  # 1.00: met
        ("coordinator", 1, small): 50_000, ("coordinator", 1, large): 52_000,
        ("env", 1, small): 50_000, ("env", 1, large): 60_000,
    }
    rows = {r.name: r for r in perf.memory_growth(peaks)}
    per_drone = rows[f"memory per drone (128 → 1000 drones @ {size_text(mid)})"]
    assert per_drone.cells["srv"] == "2.00 KiB/drone" and per_drone.cells["env"] == "1.00 KiB/drone"
    assert per_drone.cells["target"] == "≤ 1 KiB per drone: UNMET"  # the worse of the two decides
    from_one = rows[f"memory per drone from 1 drone (1 → 1000 drones @ {size_text(mid)})"]
    assert from_one.cells["srv"] == f"{3_000 / 999:.2f} KiB/drone"
    assert from_one.cells["env"] == f"{1_872 / 999:.2f} KiB/drone"
    assert from_one.cells["target"].startswith("—")  # shown, not judged
    grown = int(np.prod(large)) - int(np.prod(small))
    per_byte = rows[f"memory per world byte (1 drone, {size_text(small)} → {size_text(large)})"]
    assert per_byte.cells["srv"] == f"{2_000 * 1024 / grown:.2f} bytes/byte"
    assert per_byte.cells["env"] == f"{10_000 * 1024 / grown:.2f} bytes/byte"
    expect = "met" if 10_000 * 1024 / grown <= 2 else "UNMET"
    assert per_byte.cells["target"] == f"≤ 2 × the world array: {expect}"
    assert len(rows) == 3  # no 1000-drone game on the other worlds: no row for them
    assert perf.memory_growth({}) == []


def test_game_rows_are_set_against_pogema_with_as_many_agents():
    assert perf.versus_pogema(200.0, None, 128) == ("-", [])  # not measured: no cell, no verdict
    assert perf.versus_pogema(200.0, 1000.0, 128) == ("20%", ["≥ 25% of POGEMA's 1000 steps/s: UNMET"])
    assert perf.versus_pogema(300.0, 1000.0, 128) == ("30%", ["≥ 25% of POGEMA's 1000 steps/s: met"])
    assert perf.versus_pogema(30.0, 100.0, 1000) == ("30%", [])  # the issue sets no POGEMA target there


@pytest.mark.slow
def test_pogema_anchor_installs_and_measures_steps_per_second():
    """The anchor as the benchmark runs it: POGEMA installed into its own cached environment (PyPI, the
    first time), a short measurement for two agent counts."""
    try:
        pogema.python()
    except pogema.Unavailable as exc:  # no venv module or no package index here: say so (pytest -rs)
        pytest.skip(f"POGEMA could not be installed here: {exc}")
    rates = pogema.steps_per_second([1, 16], seconds=0.2)
    assert set(rates) == {1, 16}
    assert all(r > 0 for r in rates.values())


def test_dronesim_bench_help_lists_every_benchmark(capsys) -> None:
    from benchmarks import cli
    from dronesim.cli import main

    assert main(["bench", "--help"]) == 0
    out = capsys.readouterr().out
    assert all(f"  {name} " in out for name in BENCHMARKS), out
    assert cli(["no-such-bench"]) == 2 and "usage: dronesim bench" in capsys.readouterr().err
